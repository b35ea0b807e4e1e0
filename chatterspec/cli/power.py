"""``chatterspec power FAMILY``: detection probability vs fault size and noise level, and ROC curves."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from ..errors import ParameterError
from ._options import add, add_study_args, command, study_keywords
from ._report import check_figure_path, report_study

if TYPE_CHECKING:  # pragma: no cover
    from ..studies.closed_loop import ExcitationResult
    from ..studies.detection_rates import PowerResult


#: The fault families of :data:`chatterspec.studies.power.POWER_FAMILIES` (listed here so that parsing the
#: command line does not import the studies; a test keeps the two equal).
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


# ----------------------------------------------------------------------------------------------------
# ``chatterspec power FAMILY --closed-loop``: the excitation study's table, answer and figure.
def add_closed_loop_args(p: argparse.ArgumentParser) -> None:
    """The ``--closed-loop`` options of ``chatterspec power``."""
    g = p.add_argument_group(
        "closed loop (the EHA under its PI position controller; leakage, friction, bulk-modulus)"
    )
    g.add_argument(
        "--closed-loop",
        action="store_true",
        help="detection power of one fault size under the position controller against the reference's "
        "richness and a dither, with the tracking cost (instead of the open-loop sweep)",
    )
    g.add_argument(
        "--dither",
        type=float,
        nargs="+",
        metavar="LEVEL",
        default=None,
        help="dither amplitudes on the pump-speed command, rad/s per tone (default: 0 1 2 3 4 5 6 8 10 16 "
        "while holding)",
    )
    g.add_argument(
        "--references",
        nargs="+",
        metavar="NAME",
        default=None,
        help="references of the richness axis, each without dither (default: all: hold, 1-move-2mm, "
        "4-moves-1mm, 4-moves-2mm, 1-move, 4-moves, 8-moves, 4-steps, and the dither levels while "
        "holding); with --dither, every reference is crossed with every level",
    )
    g.add_argument(
        "--dither-signal",
        choices=("multisine", "prbs"),
        default="multisine",
        help="multisine (Schroeder phases, equal tones) or PRBS (5 ms clock); default multisine",
    )
    g.add_argument(
        "--dither-at",
        choices=("input", "reference"),
        default="input",
        help="add the dither to the pump-speed command (levels in rad/s, default) or to the position "
        "reference (levels in mm)",
    )
    g.add_argument(
        "--dither-hz",
        type=float,
        nargs="+",
        metavar="F",
        default=None,
        help="multisine tones in Hz (default 20 30 40: above the loop bandwidth, below the 39 Hz mode)",
    )
    g.add_argument(
        "--position-noise-mm",
        type=float,
        nargs="+",
        metavar="MM",
        default=None,
        help="position sensor standard deviation(s) in mm (default 0.01, the closed-loop catalogue's; "
        "eq 66 has 1)",
    )


def run_closed_loop(args: argparse.Namespace) -> int:
    """Run the excitation study and print its table (or JSON), the answer and the figure path."""
    from ..studies.closed_loop import DITHER_TONES_HZ, excitation_points, excitation_study

    if args.sizes is not None and len(args.sizes) != 1:
        raise ParameterError(f"--closed-loop takes one fault size (--sizes S); got {len(args.sizes)}")
    if args.noise is not None:
        raise ParameterError("--closed-loop varies the position sensor: use --position-noise-mm, not --noise")
    if args.dither_hz is not None and args.dither_signal != "multisine":
        raise ParameterError(
            f"--dither-hz sets the tones of the multisine dither; --dither-signal {args.dither_signal} has "
            "none"
        )
    points = excitation_points(args.references, args.dither)
    noise = (1e-5,) if args.position_noise_mm is None else tuple(x * 1e-3 for x in args.position_noise_mm)
    res = excitation_study(
        args.family,
        size=None if args.sizes is None else args.sizes[0],
        points=points,
        dither_kind=args.dither_signal,
        dither_at=args.dither_at,
        tones_hz=DITHER_TONES_HZ if args.dither_hz is None else tuple(args.dither_hz),
        position_noise=noise,
        **study_keywords(args),
    )
    return report_study(
        args,
        res,
        "plot_closed_loop.excitation_figure",
        lambda doc: _print_excitation(res, doc, args.dither_at),
    )


def _print_excitation(res: ExcitationResult, doc: dict[str, Any], dither_at: str) -> None:
    """The text report of an excitation study ``res`` (``doc``: its JSON document): table and answers."""
    print(
        f"closed-loop detection power, {res.family} {res.size:g} {res.unit} on {res.channel}: linear EHA "
        f"under its PI position loop; family-wise alpha = {res.alpha:g} (exact threshold, Bonferroni); "
        f"{res.runs} runs per point, {res.confidence:.0%} Clopper-Pearson"
    )
    print(f"dither: {res.dither_description}")
    print(
        "(v mm/s: RMS velocity of the noise-free healthy response, the reference's richness; cost mm: "
        "tracking RMS minus the same reference's without dither; u RMS: pump speed, rad/s; healthy loop)"
    )
    head = (
        f"{'sensor mm':>9} {'reference':<12} {'v mm/s':>8} {'dither':>6}  {'false alarms':<22} "
        f"{'detection':<22} {'track RMS mm':>12} {'cost mm':>8} {'u RMS':>6}"
    )
    print(head)
    for row in doc["points"]:
        fa, det = row["false_alarm"], row["detection"]
        cost = row["tracking_cost_mm"]
        print(
            f"{row['position_noise_mm']:>9g} {row['reference']:<12} {row['response_speed_rms_mm_s']:>8.1f} "
            f"{row['dither']:>6g}  {_rate(fa):<22} {_rate(det):<22} {row['tracking_rms_mm']:>12.4f} "
            f"{'-' if cost is None else format(cost, '.4f'):>8} {row['u_rms']:>6.1f}"
        )
    for a in doc["smallest_dither_for_95_percent"]:
        where = f"{a['reference']} (sensor {a['position_noise_mm']:g} mm)"
        if a["dither"] is None and not a["dither_tried"]:
            print(f"{where}: detected in {_rate(a['detection_without_dither'])} of runs; no dither tried")
        elif a["dither"] is None:
            print(f"{where}: no dither level tried reaches 95 % detection")
        elif a["dither"] == 0:
            print(f"{where}: detected in {_rate(a['detection'])} of runs without dither")
        else:
            cost = a["tracking_cost_mm"]
            print(
                f"{where}: smallest dither with >= 95 % detection: {a['dither']:g} "
                f"{'mm' if dither_at == 'reference' else 'rad/s'} "
                f"(detection {_rate(a['detection'])}); tracking RMS {a['tracking_rms_mm']:.4f} mm"
                + ("" if cost is None else f", +{cost:.4f} mm over no dither")
            )


def _rate(e: dict) -> str:
    return f"{e['rate']:.3f} [{e['ci_low']:.3f}, {e['ci_high']:.3f}]"
