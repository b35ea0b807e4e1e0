"""``chatterspec far NAME --alpha A --runs R``: false-alarm rates of every threshold kind on healthy runs."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ._options import add, add_name, add_study_args, command, study_keywords
from ._report import check_figure_path, report_study

if TYPE_CHECKING:  # pragma: no cover
    from ..studies.detection_rates import FalseAlarmResult


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec far`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "far",
        run,
        help="false-alarm rates on healthy Monte Carlo runs",
        description="Per-bin, per-frame and family-wise false-alarm rates of the paper, exact (per-bin, "
        "Bonferroni, Sidak), STFT and (with --calibration) empirical thresholds, with Clopper-Pearson "
        "intervals and a verdict against the nominal alpha.",
    )
    add_name(p)
    add_study_args(p, alpha=1e-2, runs=1000, multi_alpha=True)
    add(p, "--calibration", help="also test the empirical thresholds of this file")
    p.add_argument("--no-frames", action="store_true", help="skip the STFT (per-frame) detector")
    add(p, "--plot", help="save the per-bin rate vs frequency figure")


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec far`` with the parsed ``args``; returns the exit status."""
    check_figure_path(args.plot)
    from ..studies.calibration.result import load_calibration
    from ..studies.detection_rates import false_alarm_study

    cal = load_calibration(args.calibration) if args.calibration else None
    res = false_alarm_study(
        args.name,
        calibration=cal,
        frames=not args.no_frames,
        **study_keywords(args),
    )
    return report_study(args, res, "plot_studies.far_figure", lambda doc: _print_rates(res))


def _print_rates(res: FalseAlarmResult) -> None:
    """The text table of a false-alarm study ``res``."""
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
        assert grp is not None  # (a record or a frame rate: one of the two)
        w = max(grp, key=lambda e: e.rate)
        print(
            f"{r.kind:<22} {r.alpha:>7.2g} {r.alpha_meaning:<12} "
            f"{pb.rate:.3e} [{pb.ci_low:.2e}, {pb.ci_high:.2e}]   "
            f"{w.rate:.4f} [{w.ci_low:.4f}, {w.ci_high:.4f}]          {r.verdict}"
        )
