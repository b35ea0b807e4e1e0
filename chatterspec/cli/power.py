"""``chatterspec power FAMILY``: detection probability vs fault size and noise level, and ROC curves."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

from ..errors import ParameterError
from ._common import check_figure_path, report_study
from ._options import add, add_study_args, command, study_keywords
from ._power_closed_loop import add_closed_loop_args, run_closed_loop

if TYPE_CHECKING:  # pragma: no cover
    from ..studies.detection_rates import PowerResult

#: The fault families of :data:`chatterspec.studies.detection_rates.POWER_FAMILIES` (listed here so that
#: parsing the command line does not import the studies; a test keeps the two equal).
FAMILY_NAMES: tuple[str, ...] = ("leakage", "bulk-modulus", "friction", "f0")


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec power`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "power",
        run,
        help="detection power vs fault size and noise level",
        description="Sweep a fault family's size and the measurement-noise level; report detection "
        "probability with Clopper-Pearson intervals for the paper, exact per-bin and exact family-wise "
        "thresholds, and ROC curves (false-alarm vs detection rate as alpha varies).",
    )
    p.add_argument("family", metavar="FAMILY", choices=FAMILY_NAMES, help=", ".join(FAMILY_NAMES))
    add_study_args(p, alpha=1e-3, runs=200)
    p.add_argument("--sizes", type=float, nargs="+", help="fault sizes (default: the family's grid)")
    p.add_argument("--noise", type=float, nargs="+", help="measurement-noise multipliers of R")
    add(p, "--plot", help="save power and ROC curves")
    add_closed_loop_args(p)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec power`` with the parsed ``args``; returns the exit status."""
    check_figure_path(args.plot)
    if args.closed_loop:
        return run_closed_loop(args)
    for opt in ("dither", "references", "dither_hz", "position_noise_mm"):
        if getattr(args, opt) is not None:
            raise ParameterError(f"--{opt.replace('_', '-')} needs --closed-loop")
    from ..studies.detection_rates import power_study

    res = power_study(
        args.family,
        sizes=args.sizes,
        noise=args.noise,
        **study_keywords(args),
    )
    return report_study(args, res, "plot_studies.power_figure", lambda doc: _print_power(res))


def _print_power(res: PowerResult) -> None:
    """The text table of a power study ``res``: detection rate per noise level, size and threshold kind."""
    from ..studies.detection_rates import POWER_FAMILIES

    print(
        f"detection power, {res.family} ({POWER_FAMILIES[res.family]['unit']}), channel {res.channel}, "
        f"alpha = {res.alpha:g}, {res.runs} runs per point"
    )
    print(f"{'noise':>6} {'size':>10}  " + "  ".join(f"{k:<26}" for k in res.kinds))
    for i, nz in enumerate(res.noise):
        for j, sz in enumerate(res.sizes):
            cells = []
            for k in res.kinds:
                e = res.estimate(i, j, k)
                cells.append(f"{e.rate:.3f} [{e.ci_low:.3f}, {e.ci_high:.3f}]".ljust(26))
            print(f"{nz:>6g} {sz:>10.3g}  " + "  ".join(cells) + ("  (healthy)" if j == 0 else ""))
