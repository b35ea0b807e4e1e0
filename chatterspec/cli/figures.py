"""``chatterspec figures``: regenerate the core paper's Figs 2 and 4-12 as PNG files.

Usage::

    chatterspec figures [--out figures/] [--runs R] [--seed S] [--only fig4,fig5] [--dpi N] [--list] [--json]

Each figure is computed by :mod:`chatterspec.figures.paper_figures` and written as
``<out>/<name>.png`` (e.g. ``figures/fig5.png``). ``--runs`` sets the Monte
Carlo realizations of the figures that average (Fig 2: boundary-layer study,
Fig 6: averaged spectrum, default 20 and 100); the other figures show one
realization, as the paper does.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import ParameterError
from ._options import add, add_report_args, add_runs_args, command
from ._report import Outputs, check_output_path, print_json


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec figures`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "figures",
        run,
        help="regenerate the paper's figures (Figs 2, 4-12) as PNG files",
        description="Recompute the core paper's Figs 2 and 4-12 with chatterspec and write them as "
        "PNG files. Spectrum figures draw the paper's flat threshold (eq 58-62, alpha per bin) and the "
        "exact chi-squared threshold (eq 56, alpha family-wise, Bonferroni).",
    )
    add(p, "--figures-dir", default="figures")
    add_runs_args(
        p,
        None,  # each figure's own
        runs_help="Monte Carlo realizations for the averaging figures (Fig 2 study, Fig 6 average); "
        "default 20 for Fig 2 and 100 for Fig 6",
    )
    p.add_argument(
        "--only",
        default=None,
        metavar="NAMES",
        help="comma-separated subset, e.g. fig4,fig5 (default: all; see --list)",
    )
    add(p, "--dpi")
    p.add_argument("--list", action="store_true", help="list the figure names and exit")
    add_report_args(p, progress=False)


def selected_figures(only: str | None) -> list[str]:
    """Figure names from ``--only`` (comma-separated), in paper order; all by default.

    Raises
    ------
    ParameterError
        An unknown name (the message lists the valid ones) or an empty selection.
    """
    from ..figures.paper_figures import figure_names

    valid = figure_names()
    if only is None:
        return list(valid)
    wanted = [w.strip().lower() for w in only.split(",") if w.strip()]
    wanted = [w if w.startswith("fig") else f"fig{w}" for w in wanted]  # "5" -> "fig5"
    unknown = [w for w in wanted if w not in valid]
    if unknown:
        raise ParameterError(f"unknown figure(s) {', '.join(unknown)}; valid figures: {', '.join(valid)}")
    if not wanted:
        raise ParameterError(f"--only selects no figure; valid figures: {', '.join(valid)}")
    return [v for v in valid if v in wanted]


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec figures`` with the parsed ``args``; returns the exit status."""
    if not args.list:  # before the (slow) imports: a bad --figures-dir fails at once
        out = Path(args.figures_dir)
        check_output_path(out, "--figures-dir", folder=True)
    from ..figures import plotting
    from ..figures.paper_figures import FIGURES, render
    from ..progress import Progress

    names = selected_figures(args.only)
    if args.list:
        if args.json:
            print_json({"figures": [{"name": n, "caption": FIGURES[n].caption} for n in names]})
        else:
            for n in names:
                print(f"{n:<6} {FIGURES[n].caption}")
        return 0
    outputs = Outputs()
    dpi = plotting.DEFAULT_DPI if args.dpi is None else args.dpi
    entries = []
    t_all = time.perf_counter()
    with Progress(len(names), "figures") as bar:
        for name in names:
            t0 = time.perf_counter()
            fig = render(name, runs=args.runs, seed=args.seed)
            target = out / f"{name}.png"
            path = outputs.write("--figures-dir", target, plotting.save_figure, fig.figure, target, dpi=dpi)
            seconds = time.perf_counter() - t0
            if path is None:
                bar.update(1, note=f"{name} not written")
                continue
            entries.append(
                {
                    "name": name,
                    "path": str(path),
                    "bytes": path.stat().st_size,
                    "seconds": round(seconds, 3),
                    "notes": list(fig.notes),
                }
            )
            bar.update(1, note=name)
            if not args.json:
                print(f"wrote {path} ({path.stat().st_size / 1024:.0f} kB, {seconds:.1f} s)")
                for note in fig.notes:
                    print(f"  {note}")
                sys.stdout.flush()
    total = time.perf_counter() - t_all
    if args.json:
        print_json(
            {
                "figures_dir": str(out),
                "seed": args.seed,
                "runs": args.runs,
                "seconds": round(total, 3),
                "figures": entries,
            }
        )
    else:
        print(f"{len(entries)} figure(s) in {total:.1f} s")
    outputs.finish()
    return 0
