"""``chatterspec calibrate NAME --alpha A --runs R``: analytic vs empirical thresholds from healthy runs.

The options it shares with the other Monte Carlo study commands (far, power) are
:func:`chatterspec.cli._options.add_study_args`.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import DataFileError, ParameterError
from ._options import (
    add,
    add_alarm_args,
    add_name,
    add_study_args,
    alarm_choice,
    command,
    parsed_arg,
    study_keywords,
)
from ._report import Outputs, check_figure_path, check_output_path, report, stderr_note, write_plot

if TYPE_CHECKING:  # pragma: no cover
    from ..studies.calibration.result import Calibration
    from ._options import AlarmChoice


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
        "budget (rule, budget and frames per hour recorded; the monitor refuses it for another rule). "
        "With --data the thresholds come from a recorded healthy run of your plant instead of simulated "
        "runs (the same file; it records the data file's name, SHA-256 and span).",
    )
    add_name(p)
    add_study_args(p, alpha=1e-2, runs=1000)
    add_alarm_args(
        p,
        what="the monitor using the file",
        hours_default=f"{ALARM_HOURS:g}, with --rule / --false-alarms-per-hour: the file's threshold for "
        "all-day use; its interval shrinks like 1/sqrt(H)",
    )
    add(p, "--out", help="write the calibration file (.json or .npz)")
    add(
        p,
        "--data",
        help="read the thresholds from a recorded healthy run (.csv or .npz with the model's columns, or "
        "'-' for CSV rows on standard input) instead of simulating: per-frame and record thresholds with "
        "order-statistic intervals, and with --rule / --false-alarms-per-hour the alarm threshold with "
        "its jackknife interval; a budget the recording is too short for is refused with the hours it needs",
    )
    p.add_argument(
        "--normalization",
        choices=("model", "data"),
        default=None,
        help="with --data: normalize the spectra by the model's healthy spectrum ('model', the default for a "
        "linear model) or by the recording's own mean spectrum ('data': a healthy spectrum of another shape, "
        "e.g. coloured sensor noise or mains hum, is not taken for a fault; the only one for a nonlinear "
        "model)",
    )
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


#: Hours of healthy data simulated for the file's alarm threshold by default (``--alarm-hours``).
ALARM_HOURS = 48.0


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
    if args.data is not None:  # thresholds from a recorded healthy run
        return run_recorded(args)
    if args.normalization is not None:
        raise ParameterError(
            "--normalization applies to --data (a simulated calibration of a linear model "
            "uses the model's spectrum, of a nonlinear one the pilot runs' mean)"
        )
    check_output_path(args.out, "--out")
    check_figure_path(args.plot)
    outputs = Outputs()
    supports = _check_support(args)  # also an unknown name or a bad model file, before the heavy imports
    choice = alarm_choice(args)
    wants_alarm = choice.explicit_rule or choice.explicit_budget or choice.hours is not None
    hours = ALARM_HOURS if choice.hours is None else choice.hours
    if wants_alarm:  # the budget and the hours can be computed: checked before the healthy runs
        _check_alarm_plan(args.name, choice, hours)
    from ..studies.calibration.thresholds import calibrate

    tails = {} if args.tail_budget is None else {"tail_budget": args.tail_budget}
    cal = calibrate(args.name, **study_keywords(args), **tails)
    if wants_alarm:
        cal = _with_alarm(
            cal, args.name, choice, hours, args.seed, progress=False if args.no_progress else None
        )
    doc = cal.to_dict()
    doc["support"] = {use: s.to_dict() for use, s in supports.items()}
    if args.out:
        saved = outputs.write("--out", args.out, _save_calibration, cal, args.out)
        doc["calibration_file"] = None if saved is None else str(saved)
    write_plot(outputs, args, doc, "plot_studies.calibration_figure", cal)
    return report(args, doc, outputs, lambda: _print_calibration(cal, doc), allow_nan=True)


def _print_calibration(cal: Calibration, doc: dict) -> None:
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


def _check_alarm_plan(name: str, choice: Any, hours: float) -> None:
    """The budget has a threshold and ``hours`` can be simulated, for the STFT of the calibration
    (:func:`chatterspec.studies.alarm_budget.check_hours`): one line before any healthy run."""
    from ..detection.alarms.calibration import MonitorSettings, check_budget
    from ..plants.simulate import as_scenario
    from ..studies.alarm_budget import check_hours, frames_per_hour

    sc = as_scenario(name)
    settings = MonitorSettings()  # the STFT of `calibrate` (chatterspec.studies.calibration)
    F = frames_per_hour(settings, sc.dt)
    check_budget(choice.budget, "--false-alarms-per-hour", steps_per_hour=F, channels=sc.nominal.n_outputs)
    check_hours(sc.nominal, settings, hours, sc)


def _with_alarm(
    cal: Calibration, name: str, choice: AlarmChoice, hours: float, seed: int, progress: bool | None
) -> Calibration:
    """``cal`` with the monitor's alarm threshold for ``choice``, on the score the monitor computes with
    this file (its empirical per-frame threshold's normalization)."""
    import dataclasses

    from ..detection.alarms.calibration import MonitorSettings
    from ..detection.alarms.rules import make_rule
    from ..detection.spectral import STFTConfig
    from ..plants.simulate import as_scenario
    from ..studies.alarm_budget import calibrate_alarm

    sc = as_scenario(name)
    stft = STFTConfig(**cal.stft)
    settings = MonitorSettings(stft=stft, threshold=cal.threshold("frame-family-wise"))
    rule = make_rule(choice.rule, **choice.parameters)
    rc = calibrate_alarm(
        sc.nominal,
        settings,
        rule,
        choice.budget,
        hours=hours,
        seed=seed,
        scenario=sc,
        note=stderr_note("calibrate"),
        progress=progress,
    )
    return dataclasses.replace(cal, alarm=rc)


def _check_support(args: argparse.Namespace) -> dict[str, Any]:
    """Before computing: refuse runs that support alpha for neither use; warn when only one is supported.

    The record family-wise threshold (``detect --calibration``) needs ``ceil(1/alpha) - 1`` runs; the
    per-frame one (``monitor`` / ``diagnose --calibration``) pools the non-overlapping frames of every
    run (:mod:`chatterspec.studies.calibration.result`).
    """
    from ..studies.calibration.support import frames_per_run, support_for
    from ._options import load_scenario

    sc = load_scenario(args.name)
    per_frame = frames_per_run(sc.n_samples - 1, 1.0, sc.dt)  # the calibration's STFT: 1 s windows
    supports = {
        "detect": support_for("detect", args.runs, args.alpha, args.mc_confidence),
        "monitor": support_for("monitor", args.runs, args.alpha, args.mc_confidence, per_frame),
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


def _save_calibration(cal: Calibration, path: str) -> Path:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return cal.save(path)


def _print_empirical(cal: Calibration, doc: dict[str, Any]) -> int:
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


# ----------------------------------------------------------------------------------------------------
# ``chatterspec calibrate NAME --data HEALTHY.csv|.npz|-``: thresholds from a recorded healthy run.
#
# The computation is :func:`chatterspec.online.recorded_calibration.calibrate_recorded`; this part
# reads the data (a file, or CSV rows on standard input), builds the monitor's settings from the model
# file exactly as ``chatterspec monitor`` does, and prints the report.

#: Options that only simulated calibrations take (their defaults; any other value is refused with --data).
_SIMULATION_DEFAULTS = {"runs": 1000, "seed": 0, "workers": 1}
_SIMULATION_ONLY = ("alarm_hours", "scheduler", "chunk_runs", "tail_budget", "plot")


def run_recorded(args: argparse.Namespace) -> int:
    """``calibrate --data``: read, calibrate, report; returns the exit status."""
    given = [o for o in _SIMULATION_ONLY if getattr(args, o, None) is not None]
    given += [o for o, d in _SIMULATION_DEFAULTS.items() if getattr(args, o) != d]
    if given:
        names = " and ".join(f"--{o.replace('_', '-')}" for o in given)
        raise ParameterError(
            f"{names} cannot be used with --data: they set the simulated healthy runs, and with --data the "
            "recording is the healthy data (drop them, or drop --data)"
        )
    check_output_path(args.out, "--out")
    choice = alarm_choice(args)
    wants_alarm = choice.explicit_rule or choice.explicit_budget
    from ._options import load_scenario

    sc = load_scenario(args.name)  # the record length of `detect NAME` (a model file's [simulation])
    model = sc.nominal
    spec = None
    if str(args.name).endswith(".toml"):
        from ..plants.modelfile import load_model

        spec = load_model(args.name)
    settings = monitor_settings(spec)
    data, recording = read_healthy_data(args.data, model)
    from ..detection.alarms.rules import make_rule
    from ..online.recorded_calibration import calibrate_recorded
    from ..studies.calibration.recorded import array_chunks
    from ..studies.calibration.support import calibration_support

    rule = make_rule(choice.rule, **choice.parameters) if wants_alarm else None
    cal = calibrate_recorded(
        model,
        array_chunks(data.z, data.u, max(1, round(60.0 / model.dt))),
        data.z.shape[0],
        settings=settings,
        alpha=args.alpha,
        confidence=args.mc_confidence,
        normalization=args.normalization,
        record_s=sc.duration,
        rule=rule,
        false_alarms_per_hour=choice.budget if wants_alarm else None,
        recording=recording,
    )
    supports = calibration_support(cal)
    if not supports["detect"].supported:
        print(
            "chatterspec calibrate: warning: the file will be refused by detect: "
            f"{supports['detect'].message()} (with --data: record more healthy data; records of "
            f"{sc.duration:g} s are the runs)",
            file=sys.stderr,
        )
    outputs = Outputs()
    doc = cal.to_dict()
    doc["support"] = {use: s.to_dict() for use, s in supports.items()}
    if args.out:
        saved = outputs.write("--out", args.out, _save, cal, args.out)
        doc["calibration_file"] = None if saved is None else str(saved)
    return report(args, doc, outputs, lambda: _print(cal, doc), allow_nan=True)


def _save(cal: Any, path: str) -> Path:
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return cal.save(path)


def monitor_settings(spec: Any) -> Any:
    """The settings ``chatterspec monitor`` uses with model file ``spec`` (``[detector]`` STFT and band,
    ``[svsf]`` gamma; its defaults without a file): what the calibrated scores must be computed with."""
    from ..detection.spectral import STFTConfig
    from ..online.monitor import MonitorSettings

    if spec is None:
        return MonitorSettings()
    det = spec.detector
    stft = STFTConfig(
        window_s=float(det.get("window_s", 1.0)),
        hop_s=float(det.get("hop_s", 0.2)),
        window=str(det.get("window", "hamming")),
    )
    return MonitorSettings(stft=stft, gamma=spec.gamma, band=det.get("band"))


def read_healthy_data(arg: Path | str, model: Any) -> tuple[Any, Any]:
    """The :class:`~chatterspec.plants.datafile.DataSet` of ``--data`` and its provenance.

    ``-`` reads CSV rows from standard input to its end (header first), with the checks of a data file
    (columns, finite values, sampling at the model's ``dt``); its SHA-256 is of the bytes read.
    """
    from ..plants.datafile import load_data
    from ..studies.calibration.recorded import HealthyRecording, recording_of_file

    if str(arg) != "-":
        data = load_data(arg, model)
        return data, recording_of_file(arg)
    h = hashlib.sha256()
    with tempfile.TemporaryDirectory(prefix="chatterspec-") as tmp:
        path = Path(tmp) / "stdin.csv"
        with path.open("wb") as fh:
            for block in iter(lambda: sys.stdin.buffer.read(1 << 20), b""):
                h.update(block)
                fh.write(block)
        try:
            data = load_data(path, model)
        except DataFileError as exc:
            raise DataFileError(str(exc).replace(f"data file {str(path)!r}", "standard input")) from None
    return data, HealthyRecording("standard input", h.hexdigest())


def _print(cal: Any, doc: dict) -> None:
    """The text report of a calibration from recorded data."""
    s = cal.source
    print(
        f"calibration of {cal.model_name!r} from recorded healthy data: {s['data']} "
        f"(sha256 {s['sha256'][:12]}), "
        f"{s['span_s'][1] - s['span_s'][0]:.1f} s ({s['hours']:.3g} h), {s['frames']} frames, "
        f"{s['records']} records of {s['record_s']:g} s"
    )
    if cal.normalization == "analytic":
        print("  normalization: the model's healthy spectrum (closed form, eq 56)")
    else:
        width = 2 * cal.normalization_info["smooth_half_width_bins"] + 1
        print(f"  normalization: the recording's mean spectrum, smoothed over {width} bins")
    print(
        f"  per-frame family-wise thresholds on S / E, alpha {cal.alpha:g} per frame "
        f"({cal.confidence:.0%} order-statistic intervals, {s['non_overlapping_frames']} "
        "non-overlapping frames):"
    )
    for ch, q in zip(cal.channels, cal.frame_family_wise, strict=True):
        print(f"  {ch:<14} {q.value:.3f} [{q.ci_low:.3f}, {q.ci_high:.3f}]")
    print(f"  record family-wise thresholds (detect), alpha {cal.alpha:g} per record, {cal.runs} records:")
    for ch, q in zip(cal.channels, cal.family_wise, strict=True):
        print(f"  {ch:<14} {q.value:.3f} [{q.ci_low:.3f}, {q.ci_high:.3f}]")
    if cal.alarm is not None:
        a = cal.alarm
        lo, hi = a.threshold_interval
        print(f"  alarm rule for the monitor: {a.describe()}")
        print(f"  threshold interval ({a.confidence:.0%}): [{lo:.3g}, {hi:.3g}]")
    if doc.get("calibration_file") is not None:
        print(f"  calibration file: {doc['calibration_file']}")
