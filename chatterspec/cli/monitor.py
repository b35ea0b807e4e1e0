"""``chatterspec monitor MODEL.toml --data DATA.csv|DATA.npz|-``: monitor a user's own plant.

The model file and data format are documented in ``examples/README.md`` and
:mod:`chatterspec.plants.modelfile`. A finished file is replayed through the online monitor
(as fast as possible, or paced with ``--rate``); ``--data -`` reads CSV rows from
standard input as they arrive and ``--follow`` reads a file another process is
still writing (see :mod:`chatterspec.viewer.live_stream`: gaps, restarts, bad rows,
latency, rotating recordings). Detection events are printed (``--events jsonl``:
one JSON object per line on stdout, human lines on stderr), and the run is
recorded (``--record``, rotated with ``--record-every``) and/or streamed to a
viewer (``--live``). End of input, Ctrl-C and SIGTERM all finish cleanly:
recordings get their footer and the summary is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from ..errors import ParameterError
from ..jsonout import dumps
from . import _identify
from ._alarm_args import _alarm_line, _alarm_short, add_alarm_args, alarm_choice, alarm_doc
from ._common import Outputs, band_from_args, check_record_path, positive_int_arg, stderr_note
from ._monitor_identification import MonitorIdentification
from ._monitor_stream import _emit_line, _run_stream
from ._options import add, add_report_args, command

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.calibration import MonitorSettings
    from ..detection.spectral import STFTConfig
    from ..online.monitor import ChatteringMonitor, DetectionEvent
    from ..plants.datafile import DataSet
    from ..plants.modelfile import ModelSpec
    from ..plants.nonlinear import Model
    from ..studies.calibration_result import Calibration
    from ..viewer.recordings import RecordingSummary
    from ._alarm_args import AlarmChoice


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec monitor`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "monitor",
        run,
        help="run the online chattering monitor on your own model and data",
        description="Replay measurement data through the SVSF chattering monitor of a user model and "
        "report fault start/end events per channel. Model: TOML (A, B, C, Q, R, dt, psi, gamma, channel "
        "names; or a nonlinear model naming Python functions for f and its Jacobian, with --calibration); "
        "data: CSV or NPZ with columns named after the model's outputs and inputs.",
    )
    p.add_argument(
        "model",
        metavar="MODEL",
        type=Path,
        help="model file (.toml; linear, or nonlinear with --calibration)",
    )
    p.add_argument(
        "--data",
        required=True,
        type=Path,
        help="data file (.csv or .npz), or '-' for CSV rows on standard input (header first), read as "
        "they arrive",
    )
    p.add_argument(
        "--follow",
        action="store_true",
        help="keep reading the CSV file as another process appends to it (like tail -f); stop with "
        "Ctrl-C / SIGTERM or --idle-timeout",
    )
    p.add_argument("--from-end", action="store_true", help="with --follow: skip the rows already in the file")
    p.add_argument(
        "--idle-timeout",
        type=float,
        default=None,
        metavar="S",
        help="with --follow: stop after S seconds without new data (default: never)",
    )
    p.add_argument(
        "--events",
        choices=("text", "jsonl"),
        default="text",
        help="'jsonl': one JSON object per event (fault-start/-end, gap, restart) on stdout, flushed "
        "at once; human lines go to stderr (default 'text')",
    )
    p.add_argument(
        "--skip-bad-rows",
        action="store_true",
        help="streams: skip (and report) rows that do not parse or hold NaN/inf, as a gap; default: "
        "stop with the error",
    )
    p.add_argument(
        "--record-every",
        type=float,
        default=None,
        metavar="MINUTES",
        help="streams: start a new .rrd every MINUTES of data (>= 0.05; each complete on its own, named "
        "<record stem>-<UTC start time>.rrd)",
    )
    add(
        p,
        "--rate",
        default=0.0,
        help="replay speed of a file: data seconds per wall second (default 0 = as "
        "fast as possible; 1.0 = real time)",
    )
    add(p, "--record", type=Path, default=None, help="write a Rerun recording")
    add(
        p,
        "--live",
        default=None,
        help="stream to a running viewer (rerun+http://host:port/proxy) or 'spawn' one",
    )
    add(
        p,
        "--alpha",
        default=None,
        help="per-frame false-alarm probability: the frame rule at this level, every frame a test (the "
        "rule before alarm budgets; ~42 false alarms per hour at 0.001 on 3 channels). Only with --rule "
        "frame; default: the [detector] alpha of the model file (0.001), which then only sets the "
        "per-frame verdict drawn in the recording",
    )
    add_alarm_args(p)
    add(
        p,
        "--band",
        default=None,
        help="test only the frame bins with LO <= f <= HI (Hz); the correction counts only these bins "
        "(default: [detector] band of the model file, else every bin but DC and Nyquist)",
    )
    add(
        p,
        "--calibration",
        type=Path,
        default=None,
        help="use the empirical per-frame threshold of a calibration file ('chatterspec calibrate "
        "MODEL.toml --out FILE'); refused if it was made for another model or STFT setting",
    )
    p.add_argument(
        "--chunk",
        type=positive_int_arg,
        default=None,
        help="samples per push (default: one STFT hop with --rate > 0, 250 hops otherwise; the output does "
        "not depend on it)",
    )
    _identify.add_identification_args(p)
    _identify.add_tolerance_args(p)
    p.add_argument(
        "--identification-events",
        choices=("none", "changes", "every-hop"),
        default="none",
        help="with --events jsonl: an 'identification' event (every parameter's estimate, interval, "
        "detectable change and state; the fault named, only while an alarm is active) whenever the fault "
        "named or a state (healthy, fault, not excited) changes, or at every hop; emitted after the "
        "monitor's events of the same push (order by sample_time_s). Default none",
    )
    add_report_args(p, progress=False, json_help="print one JSON summary on stdout")


#: Smallest ``--record-every`` (minutes): 0.0001 min would write 667 files for 4 s of data.
MIN_RECORD_EVERY_MIN = 0.05


def _stream_mode(args: argparse.Namespace) -> bool:
    stdin = str(args.data) == "-"
    if args.follow and stdin:
        raise ParameterError("--follow needs a file; '--data -' already reads standard input as it arrives")
    stream = stdin or args.follow
    if not args.follow and (args.from_end or args.idle_timeout is not None):
        raise ParameterError("--from-end and --idle-timeout apply to --follow")
    if stream and args.rate:
        raise ParameterError("--rate paces a file replay; a stream is monitored as it arrives")
    if not stream and (args.skip_bad_rows or args.record_every is not None):
        raise ParameterError(
            "--skip-bad-rows and --record-every apply to streams (--data - or --follow); a file is "
            "checked whole before it is replayed"
        )
    if args.record_every is not None and not args.record_every >= MIN_RECORD_EVERY_MIN:
        raise ParameterError(
            f"--record-every must be >= {MIN_RECORD_EVERY_MIN:g} minutes (one file per "
            f"{60 * MIN_RECORD_EVERY_MIN:g} s of data at most: each file holds whole spectrogram frames and "
            f"costs a rotation); got {args.record_every}"
        )
    if args.idle_timeout is not None and not args.idle_timeout > 0:
        raise ParameterError(f"--idle-timeout must be > 0 s; got {args.idle_timeout}")
    if args.identification_events != "none" and args.events != "jsonl":
        raise ParameterError(
            "--identification-events writes JSON lines: it needs --events jsonl (the text lines always say "
            "what was identified)"
        )
    return stream


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec monitor`` with the parsed ``args``; returns the exit status."""
    from ..plants.modelfile import load_model

    check_record_path(args.record)
    stream = _stream_mode(args)
    jsonl = args.events == "jsonl"
    # stdout carries only JSON with --events jsonl or --json; the human lines go to stderr then
    human = sys.stderr if (jsonl or (args.json and stream)) else sys.stdout
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = load_model(args.model)
    for w in caught:
        print(f"chatterspec monitor: warning: {w.message}", file=sys.stderr)
    if args.tolerance:
        spec = dataclasses.replace(spec, model=_identify.with_tolerance_args(spec.model, args))
    pmap = getattr(spec.model, "parameter_map", None)
    tolerances = pmap is not None and pmap.has_tolerances
    from ..online.monitor import ChatteringMonitor, MonitorSettings  # after the model file: its errors first
    from ..plants.nonlinear import require_linear_measurement

    require_linear_measurement(spec.model, "the chattering monitor")
    if not spec.is_linear and args.calibration is None:
        raise ParameterError(
            f"{args.model} is a nonlinear model: it has no closed-form chattering spectrum, so the monitor "
            f"needs a threshold calibrated on healthy runs: `chatterspec calibrate {args.model} --out "
            "CAL.npz`, then --calibration CAL.npz"
        )
    settings = MonitorSettings.from_detector(
        spec.detector,
        gamma=spec.gamma,
        psi=None if spec.psi is None else spec.psi.tolist(),  # nonlinear: the sgn-SVSF only
        alpha=args.alpha,
        band=band_from_args(args),
    )
    stft = settings.stft
    # a bad file fails before any simulation (a followed file: its header, when it has one)
    data: DataSet | None = None
    if args.follow:
        _follow_header(args, spec.model)
    elif not stream:
        data = _replay_data(args, spec, stft)
    cal = None
    if args.calibration is not None:
        if args.alpha is not None:
            raise ParameterError(
                "--alpha cannot be used with --calibration: the calibration file fixes the per-frame "
                "threshold and its alpha (drop one of them)"
            )
        from ..studies.calibration import load_calibration
        from ..studies.calibration_support import require_support

        cal = load_calibration(args.calibration, spec.model, config=stft)
        require_support(cal, "monitor", args.calibration)  # enough runs for its per-frame alpha
    file_rule = None if cal is None or cal.alarm is None else cal.alarm.rule.name
    choice = alarm_choice(args, alpha_given=args.alpha is not None, default_rule=file_rule)
    if cal is not None:
        settings = dataclasses.replace(settings, threshold=cal.threshold("frame-family-wise"))
        src = cal.source  # recorded healthy data, or simulated runs
        made = f"{cal.runs} healthy runs"
        if src:
            made = f"{src['hours']:.3g} h of recorded healthy data {src['data']}"
        print(
            f"chatterspec monitor: empirical per-frame threshold of {args.calibration} "
            f"(alpha {cal.alpha:g} per frame, {made})",
            file=sys.stderr,
        )
    setup, why_not = _identify.setup_or_reason(spec.model, args)
    if tolerances:
        if setup is None:
            raise ParameterError(
                f"the tolerances of {args.model} are decided on the identified parameters, and this model's "
                f"cannot be identified: {why_not}"
            )
        if args.alpha is not None:
            raise ParameterError(
                "--alpha sets the spectral frame rule's per-frame level; with tolerances the decision is "
                "taken on the identified parameters at a false-alarm budget: give --false-alarms-per-hour"
            )
    else:  # with tolerances the spectral detector only reports mismatch: no alarm rule to calibrate
        settings = _alarm_settings(args, choice, spec.model, settings, cal)
    decision = None
    if setup is not None:
        from ..detection.alarms.rules import make_rule
        from ..detection.parameter_decision import parameter_alarm_settings
        from ..errors import IdentifiabilityError

        hop = stft.n_hop(spec.model.dt)
        X = settings.false_alarms_per_hour or choice.budget
        try:
            decision = parameter_alarm_settings(
                setup,
                hop_s=hop * spec.model.dt,
                window_hops=max(1, round(stft.n_window(spec.model.dt) / hop)),
                rule=make_rule(choice.rule, **choice.parameters),
                false_alarms_per_hour=X,
            )
        except IdentifiabilityError as exc:  # the parameters cannot all be fitted at once
            if tolerances:
                raise
            setup, why_not = None, str(exc)
    if tolerances and decision is not None and decision.calibration is not None:
        print(
            "chatterspec monitor: decision on the identified parameters (tolerances; the spectral detector "
            f"reports mismatch only): {decision.calibration.describe()}",
            file=sys.stderr,
        )
    else:
        print(f"chatterspec monitor: {_alarm_line(settings)}", file=sys.stderr)
    if why_not is not None and not args.no_identify:
        print(f"chatterspec monitor: no fault identification: {why_not}", file=sys.stderr)

    def identification(t0: float) -> MonitorIdentification | None:
        """Per-hop identification over the STFT window and the decisions on the parameters."""
        if setup is None or decision is None:
            return None
        from ..online.identification_monitor import IdentificationMonitor

        mon = IdentificationMonitor(
            setup,
            decision,
            t0=t0,
            alpha=settings.alpha,
            confidence=args.confidence,
            frame_samples=stft.n_window(spec.model.dt),
        )
        events = {"none": None, "changes": False, "every-hop": True}[args.identification_events]
        return MonitorIdentification(
            mon,
            _emit_line if jsonl else None,
            lambda text: print(text, file=human, flush=True) if not args.json or jsonl else None,
            every_hop=events,
        )

    if stream:
        return _run_stream(args, spec, settings, jsonl, human, identification(0.0))
    assert data is not None  # a file replay read its data above

    from ..viewer.live_stream import StreamEvent
    from ..viewer.recordings import run_monitor
    from ..viewer.sinks import default_recording_path, open_sinks

    preload = _preload_rerun() if (args.record is not None or args.live is not None) else None
    monitor = ChatteringMonitor(spec.model, settings, t0=float(data.t[0]))
    _warm_up(monitor)  # kernels and FFT plans load here (while Rerun loads on its thread), not in the loop
    if preload is not None:
        preload.join()
    outputs = Outputs()  # a recording that cannot be written: the run is reported first, then exit 2
    name = f"monitor {args.data.name}"
    sinks = outputs.write(
        "--record",
        args.record,
        open_sinks,
        record=args.record,
        live=args.live,
        recording_name=name,
        default_record=default_recording_path(args.data.stem),
    )
    if sinks is None:
        sinks = open_sinks(live=args.live, recording_name=name)
    for note in sinks.notes:
        print(f"chatterspec monitor: {note}", file=sys.stderr)
    shown = len(sinks.notes)

    ident = identification(float(data.t[0]))

    def show(ev: DetectionEvent) -> None:
        if ident is not None:  # the alarm of the fault named; with tolerances a mismatch only
            ident.note(ev.kind, ev.channel, ev.alarm_time_s)
            if ident.tolerances:
                return
        sev = StreamEvent.from_detection(ev, time.time())
        if jsonl:
            _emit_line(sev.to_json())
        if not args.json or jsonl:
            print(sev.describe(), file=human, flush=True)

    try:
        summary = run_monitor(
            monitor,
            sinks,
            z=data.z,
            u=data.u,
            chunk_samples=args.chunk,
            rate=args.rate or None,  # 0: as fast as possible
            on_event=show,
            identifier=None if ident is None else ident.monitor,
            on_identification=None if ident is None else ident.handle,
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
    if summary.write_error:
        outputs.failures.append(
            f"--record {str(args.record)!r} could not be completed ({summary.write_error})"
        )
    _report_replay(args, summary, jsonl, human, settings, ident, why_not)
    outputs.finish()
    return 0


def _follow_header(args: argparse.Namespace, model: Model) -> None:
    """``--follow FILE``: the file exists and, once it has a header line, that header fits the model.

    Raises
    ------
    ParameterError
        The file does not exist.
    DataFileError
        Its header lacks a column of the model (or repeats one).
    """
    import time

    from ..online.stream import CsvRows

    where = f"data file {str(args.data)!r}"
    if not args.data.is_file():
        raise ParameterError(f"--follow: {where} does not exist (create it, header first, then follow it)")
    with open(args.data, "rb") as f:
        head = f.read(1 << 16)
    CsvRows(model, where).feed(head[: head.rfind(b"\n") + 1], time.perf_counter())  # complete lines only


def _replay_data(args: argparse.Namespace, spec: ModelSpec, stft: STFTConfig) -> DataSet:
    """The data file of a replay, read and checked whole: at least one STFT window of chattering.

    Raises
    ------
    DataFileError
        The file cannot be read, does not fit the model, or is shorter than one window (the chattering
        starts at the second sample: ``rows - 1`` samples).
    """
    from ..errors import DataFileError
    from ..plants.datafile import load_data

    model = spec.model
    data = load_data(args.data, model)
    n_window = stft.n_window(model.dt)
    rows = data.z.shape[0]
    if rows - 1 < n_window:
        raise DataFileError(
            f"data file {str(args.data)!r}: {rows} rows give {rows - 1} chattering samples "
            f"({(rows - 1) * model.dt:.3g} s), fewer than one STFT window of {n_window} samples "
            f"(window_s = {stft.window_s:g} s at dt = {model.dt:g} s); give longer data or a "
            f"shorter [detector] window_s in {args.model}"
        )
    return data


def _report_replay(
    args: argparse.Namespace,
    summary: RecordingSummary,
    jsonl: bool,
    human: TextIO,
    settings: MonitorSettings,
    ident: MonitorIdentification | None = None,
    why_not: str | None = None,
) -> None:
    """Print the summary of a file replay (the data held at least one STFT frame: :func:`_replay_data`)."""
    if args.json:
        doc = {
            "model": str(args.model),
            "data": str(args.data),
            "alarm": alarm_doc(settings),
            **summary.to_dict(),
        }
        if ident is None:
            doc["identification"] = {"reason": why_not}
        else:
            ident.into_summary(doc)
        if jsonl:
            _emit_line(dumps({"event": "summary", **doc}, allow_nan=True))
        else:
            print(dumps(doc, indent=2, allow_nan=True))
        return
    n = sum(e.kind == "fault-start" for e in summary.events)
    rule = _alarm_short(settings)
    if ident is not None and ident.tolerances:
        n, rule = ident.starts, ident.rule_short()
    print(
        f"{summary.duration_s:.2f} s of data, {summary.n_frames} frames, {n} fault start(s) "
        f"[{rule}]; {summary.wall_s:.2f} s wall",
        file=human,
    )
    if ident is not None:
        for line in ident.status_lines():
            print(f"  {line}", file=human)
    if summary.path is not None and not summary.write_error:
        print(f"recording: {summary.path} (open with `chatterspec replay {summary.path}`)", file=human)


def _preload_rerun() -> threading.Thread:
    """Import Rerun, its blueprint classes and pyarrow.compute on a thread (~0.25 s of CPU at every start)
    while the main thread reads the data and loads the compiled kernels: on two cores the two overlap."""

    def load() -> None:
        try:
            import pyarrow.compute  # noqa: F401  (Rerun's first send_columns imports it)
            import rerun
            import rerun.blueprint  # noqa: F401
        except Exception:  # pragma: no cover - the main thread imports them again and reports any error
            pass

    thread = threading.Thread(target=load, name="chatterspec-preload", daemon=True)
    thread.start()
    return thread


def _warm_up(monitor: ChatteringMonitor) -> None:
    """One window of zeros through a throw-away copy of ``monitor`` (same model, settings, threshold):
    the compiled kernels (numba cache) and FFT plans load before the replay's clock starts, as in the
    stream monitor and the in-process benchmark."""
    import numpy as np

    from ..online.monitor import ChatteringMonitor

    m = monitor.model
    settings = dataclasses.replace(monitor.settings, threshold=monitor.threshold)
    warm = ChatteringMonitor(m, settings)
    n = warm.n_window + 2
    warm.push(np.zeros((n, m.n_outputs)), np.zeros((n, m.n_inputs)))


def _alarm_settings(
    args: argparse.Namespace,
    choice: AlarmChoice,
    model: Model,
    settings: MonitorSettings,
    cal: Calibration | None,
) -> MonitorSettings:
    """The monitor's alarm rule: ``--alpha`` (the per-frame rule), a calibration file's, or set here."""
    from ..studies.alarm_budget import alarm_settings

    c = choice  # AlarmChoice
    if args.alpha is not None:
        return dataclasses.replace(settings, alpha=float(args.alpha))
    file_alarm = getattr(cal, "alarm", None)
    if file_alarm is not None:
        from ._alarm_args import check_file_alarm

        rc = check_file_alarm(c, file_alarm, args.calibration)
        return alarm_settings(model, settings, calibration=rc)
    from ..plants.nonlinear import is_linear

    if not is_linear(model) and (c.explicit_rule or c.explicit_budget):
        raise ParameterError(
            f"{args.calibration} holds no alarm threshold, and a nonlinear model's needs simulated healthy "
            f"records: `chatterspec calibrate {args.model} --rule {c.rule} --false-alarms-per-hour "
            f"{c.budget:g} --out FILE`, then --calibration FILE"
        )
    if cal is not None and not (c.explicit_rule or c.explicit_budget):
        print(
            f"chatterspec monitor: note: {args.calibration} holds no alarm calibration (made without "
            f"--rule): the per-frame rule at its alpha {cal.alpha:g}",
            file=sys.stderr,
        )
        return settings
    hours = c.hours  # (None: the in-call default)
    return alarm_settings(
        model,
        settings,
        c.rule,
        c.budget,
        hours=hours,
        note=stderr_note("monitor"),
        **c.parameters,
    )
