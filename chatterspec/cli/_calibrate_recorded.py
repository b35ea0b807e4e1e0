"""``chatterspec calibrate NAME --data HEALTHY.csv|.npz|-``: thresholds from a recorded healthy run.

The computation is :func:`chatterspec.online.recorded_calibration.calibrate_recorded`; this module
reads the data (a file, or CSV rows on standard input), builds the monitor's settings from the model
file exactly as ``chatterspec monitor`` does, and prints the report.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from pathlib import Path
from typing import Any

from ..errors import DataFileError, ParameterError
from ._alarm_args import alarm_choice
from ._common import Outputs, check_output_path, report

__all__ = ["run_recorded"]

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
    from ._common import load_scenario

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
    from ..studies.calibration_support import calibration_support
    from ..studies.recorded_calibration import array_chunks

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
    from ..studies.recorded_calibration import HealthyRecording, recording_of_file

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
