"""``chatterspec monitor --model MODEL.toml --data DATA.csv|DATA.npz``: monitor a user's own plant.

The model file and data format are documented in ``examples/README.md`` and
:mod:`chatterspec.plants.modelfile`. The data are replayed through the online monitor
(as fast as possible, or paced with ``--rate``), detection events are printed,
and the run is recorded (``--record``) and/or streamed to a viewer (``--live``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from pathlib import Path

from ..errors import ParameterError
from ._common import alpha_arg, check_record_path, live_arg, positive_int_arg


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "monitor",
        help="run the online chattering monitor on your own model and data",
        description="Replay measurement data through the SVSF chattering monitor of a user model and "
        "report fault start/end events per channel. Model: TOML (A, B, C, Q, R, dt, psi, gamma, channel "
        "names); data: CSV or NPZ with columns named after the model's outputs and inputs.",
    )
    p.add_argument("--model", required=True, type=Path, help="model file (.toml)")
    p.add_argument("--data", required=True, type=Path, help="data file (.csv or .npz)")
    p.add_argument(
        "--rate",
        type=float,
        default=None,
        help="replay speed, 1.0 = real time (default: as fast as possible)",
    )
    p.add_argument("--record", type=Path, default=None, metavar="FILE.rrd", help="write a Rerun recording")
    p.add_argument(
        "--live",
        type=live_arg,
        default=None,
        metavar="URL|spawn",
        help="stream to a running viewer (rerun+http://host:port/proxy) or 'spawn' one",
    )
    p.add_argument(
        "--alpha", type=alpha_arg, default=None, help="per-frame false-alarm probability (default 0.001)"
    )
    p.add_argument(
        "--calibration",
        type=Path,
        default=None,
        metavar="FILE",
        help="use the empirical per-frame threshold of a calibration file ('chatterspec calibrate "
        "MODEL.toml --out FILE'); refused if it was made for another model or STFT setting",
    )
    p.add_argument(
        "--chunk",
        type=positive_int_arg,
        default=None,
        help="samples per push (default: one STFT hop with --rate, five otherwise)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON summary on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..detection.spectral import STFTConfig
    from ..online.drivers import run_monitor
    from ..online.monitor import ChatteringMonitor, MonitorSettings
    from ..online.viewer import default_recording_path, open_sinks
    from ..plants.modelfile import load_data, load_model

    if args.rate is not None and not args.rate > 0:
        raise ParameterError(f"--rate must be > 0 (1.0 = real time); got {args.rate}")
    check_record_path(args.record)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = load_model(args.model)
    for w in caught:
        print(f"chatterspec monitor: warning: {w.message}", file=sys.stderr)
    data = load_data(args.data, spec.model)
    det = spec.detector
    stft = STFTConfig(
        window_s=float(det.get("window_s", 1.0)),
        hop_s=float(det.get("hop_s", 0.2)),
        window=str(det.get("window", "hamming")),
    )
    settings = MonitorSettings(
        stft=stft,
        alpha=float(args.alpha if args.alpha is not None else det.get("alpha", 1e-3)),
        correction=str(det.get("correction", "bonferroni")),  # type: ignore[arg-type]
        gamma=spec.gamma,
        psi=tuple(spec.psi.tolist()),
    )
    if args.calibration is not None:
        from ..studies.calibration import load_calibration

        cal = load_calibration(args.calibration, spec.model, config=stft)
        settings = dataclasses.replace(settings, threshold=cal.threshold("frame-family-wise"))
        print(
            f"chatterspec monitor: empirical per-frame threshold of {args.calibration} "
            f"(alpha {cal.alpha:g} per frame, {cal.runs} healthy runs)",
            file=sys.stderr,
        )
    monitor = ChatteringMonitor(spec.model, settings, t0=float(data.t[0]))
    sinks = open_sinks(
        record=args.record,
        live=args.live,
        recording_name=f"monitor {args.data.name}",
        default_record=default_recording_path(args.data.stem),
    )
    for note in sinks.notes:
        print(f"chatterspec monitor: {note}", file=sys.stderr)
    shown = len(sinks.notes)

    def show(ev: object) -> None:
        if not args.json:
            print(ev.describe())  # type: ignore[attr-defined]

    try:
        summary = run_monitor(
            monitor, sinks, z=data.z, u=data.u, chunk_samples=args.chunk, rate=args.rate, on_event=show
        )
    except KeyboardInterrupt:
        if sinks.path is not None:  # run_monitor closed the sinks: the file has its footer
            print(
                f"chatterspec monitor: interrupted after {monitor.n_samples * monitor.dt:.2f} s of data; "
                f"partial recording: {sinks.path} (open with `chatterspec replay {sinks.path}`)",
                file=sys.stderr,
            )
        raise
    for note in summary.notes[shown:]:  # e.g. a live viewer that went away during the run
        print(f"chatterspec monitor: {note}", file=sys.stderr)
    no_frame = None
    if summary.n_frames == 0:
        n_window = stft.n_window(spec.model.dt)
        no_frame = (
            f"no STFT frame could be analysed: the data give {summary.n_samples} chattering samples "
            f"({summary.duration_s:.3g} s), fewer than one window of {n_window} samples "
            f"(window_s = {stft.window_s:g} s at dt = {spec.model.dt:g} s); give longer data or a "
            f"shorter [detector] window_s in {args.model}"
        )
    if args.json:
        doc = {"model": str(args.model), "data": str(args.data), **summary.to_dict()}
        if no_frame is not None:
            doc["notes"] = [*doc["notes"], no_frame]
        print(json.dumps(doc, indent=2))
        return 0 if no_frame is None else 1
    if no_frame is not None:
        print(f"chatterspec monitor: error: {no_frame}", file=sys.stderr)
        return 1
    else:
        n = sum(e.kind == "fault-start" for e in summary.events)
        print(
            f"{summary.duration_s:.2f} s of data, {summary.n_frames} frames, {n} fault start(s); "
            f"{summary.wall_s:.2f} s wall"
        )
        if summary.path is not None:
            print(f"recording: {summary.path} (open with `chatterspec replay {summary.path}`)")
    return 0
