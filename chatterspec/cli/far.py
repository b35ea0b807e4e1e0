"""``chatterspec far NAME --alpha A --runs R``: false-alarm rates of every threshold kind on healthy runs."""

from __future__ import annotations

import argparse

from ..jsonout import dumps
from ._common import Outputs, check_output_file, figure_suffixes
from .calibrate import add_common, execution


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec far`` and its options to the subcommand parsers ``sub``."""
    p = sub.add_parser(
        "far",
        help="false-alarm rates on healthy Monte Carlo runs",
        description="Per-bin, per-frame and family-wise false-alarm rates of the paper, exact (per-bin, "
        "Bonferroni, Sidak), STFT and (with --calibration) empirical thresholds, with Clopper-Pearson "
        "intervals and a verdict against the nominal alpha.",
    )
    p.add_argument("name", metavar="NAME", help="healthy scenario name or model file (.toml)")
    add_common(p, alpha=1e-2, runs=1000, multi_alpha=True)
    p.add_argument("--calibration", metavar="FILE", help="also test the empirical thresholds of this file")
    p.add_argument("--no-frames", action="store_true", help="skip the STFT (per-frame) detector")
    p.add_argument("--plot", metavar="FILE", help="save the per-bin rate vs frequency figure")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec far`` with the parsed ``args``; returns the exit status."""
    if args.plot:
        check_output_file(args.plot, "--plot", suffixes=figure_suffixes())
    outputs = Outputs()
    from ..studies.calibration import load_calibration
    from ..studies.false_alarms import false_alarm_study

    cal = load_calibration(args.calibration) if args.calibration else None
    res = false_alarm_study(
        args.name,
        alpha=args.alpha,
        runs=args.runs,
        seed=args.seed,
        calibration=cal,
        frames=not args.no_frames,
        **execution(args),
    )
    doc = res.to_dict()
    if args.plot:
        from ..figures.plot_studies import far_figure, save

        saved = outputs.write("--plot", args.plot, save, far_figure(res), args.plot)
        doc["figure"] = None if saved is None else str(saved)
    if args.json:
        print(dumps(doc, indent=2, allow_nan=True))
        outputs.finish()
        return 0
    print(
        f"false alarms on {res.scenario}: {res.runs} healthy runs, seed {res.seed}, "
        f"{res.confidence:.0%} Clopper-Pearson intervals (per-bin and per-frame: from run-level counts, "
        "effective trials; see docs)"
    )
    print(
        f"{'kind':<22} {'alpha':>7} {'meaning':<12} {'per-bin rate [interval]':<36} "
        f"{'record/frame rate (worst channel)':<36} verdict"
    )
    for r in res.rates:
        pb = r.per_bin
        grp = r.family_wise if r.family_wise is not None else r.per_frame
        w = max(grp, key=lambda e: e.rate)
        print(
            f"{r.kind:<22} {r.alpha:>7.2g} {r.alpha_meaning:<12} "
            f"{pb.rate:.3e} [{pb.ci_low:.2e}, {pb.ci_high:.2e}]   "
            f"{w.rate:.4f} [{w.ci_low:.4f}, {w.ci_high:.4f}]          {r.verdict}"
        )
    if args.plot and doc["figure"] is not None:
        print(f"figure: {doc['figure']}")
    outputs.finish()
    return 0
