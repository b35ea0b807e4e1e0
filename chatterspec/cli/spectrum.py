"""``chatterspec spectrum NAME``: PNG of one scenario's chattering spectrum with its thresholds.

Usage::

    chatterspec spectrum NAME [--plot FILE.png] [--channel C|all] [--alpha A]
                              [--threshold exact|paper|both] [--correction bonferroni|sidak|none]
                              [--seed S] [--runs R] [--dpi N] [--json]

Draws the periodogram (eq 49) of one realization, or with ``--runs R > 1`` the
mean of R periodograms over the first one in grey, the expected healthy
spectrum (eq 56) and the chosen thresholds: the paper's flat bound (eq 58-62,
``alpha`` per bin; for an R-run mean scaled to chi2 with 2R degrees of freedom)
and/or the exact chi-squared bound (``alpha`` family-wise over the tested bins
with the chosen correction, per bin with ``--correction none``; chi2 with 2R
degrees of freedom for an R-run average).
Without ``--plot`` the PNG goes to ``figures/NAME-spectrum.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ._options import add, add_name, add_report_args, add_runs_args, command
from ._report import Outputs, check_output_path, report

#: Folder of ``spectrum``'s PNG when ``--plot`` is not given (like ``demo``'s ``figures/demo``; created).
DEFAULT_FOLDER = Path("figures")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec spectrum`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "spectrum",
        run,
        help="write a PNG of one scenario's chattering spectrum with expected value and thresholds",
        description="Simulate NAME, compute the chattering periodogram (eq 49) and draw it with the "
        "expected healthy spectrum (eq 56) and the paper's and/or the exact threshold.",
    )
    add_name(p, "scenario name (see 'chatterspec scenarios')")
    add(p, "--plot", help="the PNG to write (default figures/NAME-spectrum.png)")
    p.add_argument(
        "--channel",
        default=None,
        help="output channel (e.g. velocity, pressure) or 'all' (default: the scenario's fault channel, "
        "all channels for healthy scenarios)",
    )
    add(
        p,
        "--alpha",
        default=1e-3,
        help="false-alarm probability (default 0.001): per bin for 'paper', family-wise for 'exact'",
    )
    add(
        p,
        "--threshold",
        choices=("exact", "paper", "both"),
        default="both",
        help="threshold(s) to draw (default both)",
    )
    add(
        p,
        "--correction",
        help="family-wise correction of the exact threshold (default bonferroni; none = per-bin alpha)",
    )
    add_runs_args(p, 1, runs_help="realizations averaged (default 1)")
    add(p, "--dpi")
    add_report_args(p, progress=False)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec spectrum`` with the parsed ``args``; returns the exit status."""
    # before the (slow) imports: a bad path fails at once; the default folder is created
    if args.plot:
        out = check_output_path(args.plot, "--plot", suffixes=(".png",))
    else:
        out = check_output_path(DEFAULT_FOLDER, "--plot", folder=True) / f"{args.name}-spectrum.png"

    from ..figures import plotting
    from ..figures.paper_figures import scenario_spectrum
    from ..plants.scenarios import scenario

    scenario(args.name)  # UnknownScenarioError (listing the valid names) before any work
    outputs = Outputs()
    raw: str | None = args.channel
    channel: str | int | None = int(raw) if raw is not None and raw.isdigit() else raw
    fig = scenario_spectrum(
        args.name,
        channel=channel,
        alpha=args.alpha,
        threshold=args.threshold,
        correction=args.correction,
        runs=args.runs,
        seed=args.seed,
    )
    dpi = plotting.DEFAULT_DPI if args.dpi is None else args.dpi
    path = outputs.write("--plot", out, plotting.save_figure, fig.figure, out, dpi=dpi)
    doc = {
        "scenario": args.name,
        "path": None if path is None else str(path),
        "bytes": None if path is None else path.stat().st_size,
        "alpha": args.alpha,
        "threshold": args.threshold,
        "correction": args.correction,
        "runs": args.runs,
        "seed": args.seed,
        "notes": list(fig.notes),
    }

    def text() -> None:
        if path is not None:
            print(f"wrote {path} ({doc['bytes'] / 1024:.0f} kB)")
        for note in fig.notes:
            print(f"  {note}")

    return report(args, doc, outputs, text)
