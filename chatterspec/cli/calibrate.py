"""``chatterspec calibrate NAME --alpha A --runs R``: analytic vs empirical thresholds from healthy runs.

The options it shares with the other Monte Carlo study commands (far, power) are
:func:`chatterspec.cli._options.add_study_args`.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from ..errors import ParameterError
from ._alarm_args import add_alarm_args, alarm_choice, positive_number
from ._common import Outputs, check_figure_path, check_output_path, parsed_arg, report, write_plot
from ._options import add, add_name, add_study_args, command, study_keywords


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec calibrate`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "calibrate",
        run,
        help="calibrate thresholds on healthy Monte Carlo runs",
        description="Analytic thresholds (paper, exact, family-wise) beside empirical ones (per-bin and "
        "per-frame quantiles, family-wise quantile of the maximum normalized bin) with order-statistic "
        "confidence intervals. NAME is a healthy catalogue scenario or a TOML model file. --out writes a "
        "calibration file (.json or .npz) that detection can load instead of the analytic threshold. With "
        "--rule / --false-alarms-per-hour the file also holds the monitor's alarm threshold for that "
        "budget (rule, budget and frames per hour recorded; the monitor refuses it for another rule).",
    )
    add_name(p)
    add_study_args(p, alpha=1e-2, runs=1000)
    add_alarm_args(p, what="the monitor using the file", hours=False)
    p.add_argument(
        "--hours",
        default=None,
        metavar="H",
        help="with --rule / --false-alarms-per-hour: hours of healthy data simulated for the alarm "
        "threshold (default 48; its interval shrinks like 1/sqrt(H))",
    )
    p.add_argument("--out", metavar="FILE", help="write the calibration file (.json or .npz)")
    add(p, "--plot", help="save a figure of analytic vs empirical thresholds")
    p.add_argument(
        "--tail-budget",
        type=_megabytes,
        default=None,
        metavar="MB",
        help="memory (MB) allowed for the exact order-statistic tails, which grow like runs x alpha "
        "(default 128); above it the quantiles come from fixed-size tail histograms (point at most one "
        "fine bucket above the exact one, intervals widened outward); 0 forces the histograms",
    )


def _megabytes(text: str) -> int:
    """``--tail-budget MB`` -> bytes (MB = 2^20 bytes)."""
    mb = parsed_arg(
        text,
        float,
        lambda v: v >= 0 and v != float("inf"),
        "expected a number of MB; got {text!r}",
        "expected a finite number of MB >= 0; got {text!r}",
    )
    return int(mb * 2**20)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec calibrate`` with the parsed ``args``; returns the exit status."""
    check_output_path(args.out, "--out")
    check_figure_path(args.plot)
    outputs = Outputs()
    supports = _check_support(args)  # also an unknown name or a bad model file, before the heavy imports
    choice = alarm_choice(args)
    wants_alarm = choice.explicit_rule or choice.explicit_budget or args.hours is not None
    hours = _hours(args.hours)
    from ..studies.calibration import calibrate

    tails = {} if args.tail_budget is None else {"tail_budget": args.tail_budget}
    cal = calibrate(args.name, **study_keywords(args), **tails)
    if wants_alarm:
        cal = _with_alarm(cal, args.name, choice, hours, args.seed)
    doc = cal.to_dict()
    doc["support"] = {use: s.to_dict() for use, s in supports.items()}
    if args.out:
        saved = outputs.write("--out", args.out, _save_calibration, cal, args.out)
        doc["calibration_file"] = None if saved is None else str(saved)
    write_plot(outputs, args, doc, "plot_studies.calibration_figure", cal)
    return report(args, doc, outputs, lambda: _print_calibration(cal, doc), allow_nan=True)


def _print_calibration(cal: Any, doc: dict) -> None:
    """The text report of a calibration ``cal`` (``doc``: its JSON document)."""
    if cal.alarm is not None:
        print(f"alarm rule for the monitor: {cal.alarm.describe()}")
    if cal.normalization == "empirical":
        _print_empirical(cal, doc)
        return
    a, ag = doc["analytic_factor"], doc["agreement"]
    print(f"calibration of {cal.scenario}: alpha = {cal.alpha:g}, {cal.runs} healthy runs, seed {cal.seed}")
    print(f"  normalized thresholds S/E[S] ({cal.confidence:.0%} intervals):")
    print(f"  exact per-bin (analytic)      {a['exact_per_bin']:.3f}")
    for ch, v in zip(cal.channels, doc["empirical"]["per_bin_factor_median"], strict=True):
        print(f"  empirical per-bin, {ch:<10} median {v:.3f}")
    print(
        f"  per-bin agreement: analytic inside {ag['per_bin_coverage']:.1%} of the empirical intervals "
        f"({ag['per_bin_misses']} misses, <= {ag['per_bin_misses_allowed']} expected)"
    )
    print(
        f"  family-wise (Bonferroni) analytic {a['family_wise_bonferroni']:.3f}, "
        f"Sidak {a['family_wise_sidak']:.3f}"
    )
    for ch, q, ok in zip(cal.channels, cal.family_wise, ag["family_wise_agrees"], strict=True):
        print(
            f"  empirical family-wise, {ch:<10} {q.value:.3f} [{q.ci_low:.3f}, {q.ci_high:.3f}]"
            + ("" if ok else "  <- analytic outside")
        )
    print(f"  per-frame median ratio empirical/analytic {ag['per_frame_median_ratio']:.3f}")
    _print_tails(cal.tails)
    if doc.get("calibration_file") is not None:
        print(f"  calibration file: {doc['calibration_file']}")


def _hours(text: str | None) -> float:
    """``--hours H`` (default 48): a positive, finite number of hours."""
    return 48.0 if text is None else positive_number(text, "--hours", "a number of hours")


def _with_alarm(cal: Any, name: str, choice: Any, hours: float, seed: int) -> Any:
    """``cal`` with the monitor's alarm threshold for ``choice``, on the score the monitor computes with
    this file (its empirical per-frame threshold's normalization)."""
    import dataclasses

    from ..detection.alarms import make_rule
    from ..detection.spectral import STFTConfig
    from ..online.monitor_types import MonitorSettings
    from ..studies.alarm_budget import calibrate_alarm
    from ..studies.healthy import resolve_scenario

    sc = resolve_scenario(name)
    stft = STFTConfig(**cal.stft)
    settings = MonitorSettings(stft=stft, threshold=cal.threshold("frame-family-wise"))
    rule = make_rule(choice.rule, **choice.parameters)
    rc = calibrate_alarm(sc.nominal, settings, rule, choice.budget, hours=hours, seed=seed, scenario=sc)
    return dataclasses.replace(cal, alarm=rc)


def _check_support(args: argparse.Namespace) -> dict[str, Any]:
    """Before computing: refuse runs that support alpha for neither use; warn when only one is supported.

    The record family-wise threshold (``detect --calibration``) needs ``ceil(1/alpha) - 1`` runs; the
    per-frame one (``monitor`` / ``diagnose --calibration``) pools the non-overlapping frames of every
    run (:mod:`chatterspec.studies.calibration_support`).
    """
    from ..studies.calibration_support import frames_per_run, support_for
    from ._common import load_scenario

    sc = load_scenario(args.name)
    per_frame = frames_per_run(sc.n_samples - 1, 1.0, sc.dt)  # the calibration's STFT: 1 s windows
    supports = {
        "detect": support_for("detect", args.runs, args.alpha, args.confidence),
        "monitor": support_for("monitor", args.runs, args.alpha, args.confidence, per_frame),
    }
    bad = [s for s in supports.values() if not s.supported]
    if len(bad) == len(supports):
        d, m = supports["detect"], supports["monitor"]
        raise ParameterError(
            f"{d.message()}; per frame (monitor) it needs --runs >= {m.min_runs}; nothing computed"
        )
    for s in bad:
        print(
            f"chatterspec calibrate: warning: the file will be refused by "
            f"{'detect' if s.use == 'detect' else 'monitor and diagnose'}: {s.message()}",
            file=sys.stderr,
        )
    return supports


def _save_calibration(cal: Any, path: str) -> Any:
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return cal.save(path)


def _print_empirical(cal, doc: dict) -> int:
    """Text report of a calibration with an empirical normalization (nonlinear model)."""
    info = cal.normalization_info
    print(f"calibration of {cal.scenario}: alpha = {cal.alpha:g}, {cal.runs} healthy runs, seed {cal.seed}")
    width = 2 * info.get("smooth_half_width_bins", 0) + 1
    print(
        f"  normalization: empirical (no closed-form spectrum for a nonlinear model): mean periodogram of "
        f"{info.get('pilot_runs')} other healthy runs, smoothed over {width} bins"
    )
    print(f"  family-wise thresholds on S / E_hat ({cal.confidence:.0%} order-statistic intervals):")
    for ch, q in zip(cal.channels, cal.family_wise, strict=True):
        print(f"  empirical family-wise, {ch:<14} {q.value:.3f} [{q.ci_low:.3f}, {q.ci_high:.3f}]")
    _print_tails(cal.tails)
    if doc.get("calibration_file") is not None:
        print(f"  calibration file: {doc['calibration_file']}")
    return 0


def _print_tails(tails: dict) -> None:
    """One line on how the empirical quantiles were read (only for the bounded-memory histograms)."""
    if tails.get("method") == "histogram":
        print(
            f"  quantiles from tail histograms (exact tails would need {tails['exact_bytes'] / 2**20:.0f} MB "
            f"> budget {tails['budget_bytes'] / 2**20:.0f} MB): points at most "
            f"{tails['fine_rel_width']:.2%} above the exact order statistics, intervals widened outward"
            + (f"; {tails['outside_window']} read outside the fine window" if tails["outside_window"] else "")
        )
