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

Identification output (:class:`MonitorIdentification`, from
:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`): the parameters' alarm
events (tolerances), the ``identification`` events, the human lines and the summary. JSON lines
(``--events jsonl``):

* with tolerances, the parameters' alarms are the monitor's fault events: ``{"event": "fault-start",
  "sample_time_s": <alarm time: the deciding window's last sample>, "time_s": <its centre>,
  "channel": <parameter>, "parameter": ..., "estimate", "ci_low", "ci_high", "band", "tolerance",
  "score", "statistic", "threshold", "rule", "false_alarms_per_hour", "detectable", ...}``; the
  spectral detector's events are not emitted (they see the in-tolerance mismatch) and are counted in
  the summary's ``spectral_mismatch``;
* ``--identification-events changes``: an ``identification`` event whenever the fault named (only
  under an alarm) or a parameter's or channel's state changes; ``every-hop``: every window. Fields:
  ``sample_time_s``, ``window_s``, ``alarm``, ``fault`` (the name, null between alarms), ``fits`` (false:
  the window is not described by constant parameters, e.g. it straddles a change; no evidence),
  ``parameters`` (joint estimate, interval, band, ``inside``, ``score``, ``state``, ``detectable``),
  ``channels`` (state per output channel), and under a spectral alarm the full report of the window
  (``selected``, ``hypotheses``, ``alpha``).
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import dataclasses
import functools
import gc
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from ..errors import ParameterError
from ..jsonout import dumps
from ._options import (
    add,
    add_alarm_args,
    add_identification_args,
    add_report_args,
    add_tolerance_args,
    alarm_choice,
    command,
    positive_int_arg,
    setup_or_reason,
    with_tolerance_args,
)
from ._report import Outputs, alarm_doc, alarm_line, alarm_short, check_record_path, quiet_stdout, stderr_note

if TYPE_CHECKING:  # pragma: no cover
    from types import FrameType

    from ..detection.alarms.calibration import MonitorSettings
    from ..detection.spectral import STFTConfig
    from ..detection.thresholds import Threshold
    from ..online.identification_monitor import IdentificationUpdate
    from ..online.monitor import ChatteringMonitor, DetectionEvent
    from ..plants.datafile import DataSet
    from ..plants.modelfile import ModelSpec
    from ..plants.nonlinear import Model
    from ..studies.calibration.result import Calibration
    from ..viewer.live_stream import StreamEvent, StreamSummary
    from ..viewer.recordings import RecordingSummary
    from ._options import AlarmChoice


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
        "not depend on it, except the last digits of the parameter identification's fits)",
    )
    add_identification_args(p)
    add_tolerance_args(p)
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
    with _collector_off_in_set_up() as loop_starts:
        return _run(args, loop_starts)


def _run(args: argparse.Namespace, loop_starts: Callable[[], None]) -> int:
    """:func:`run`; ``loop_starts`` is called once the set-up is done, just before the data are read."""
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
        spec = dataclasses.replace(spec, model=with_tolerance_args(spec.model, args))
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
        band=args.band,
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
        from ..studies.calibration.result import load_calibration
        from ..studies.calibration.support import require_support

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
    setup, why_not = setup_or_reason(spec.model, args)
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
    threshold = None  # the per-frame threshold: computed once, for the alarm calibration and the monitor
    if not tolerances:  # with tolerances the spectral detector only reports mismatch: no rule to calibrate
        from ..detection.thresholds import monitor_threshold

        threshold = monitor_threshold(spec.model, settings)
        before, settings = settings, _alarm_settings(args, choice, spec.model, settings, cal, threshold)
        if not settings.same_frame_threshold(before):  # the verdict drawn at the rule's own level
            threshold = None
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
        print(f"chatterspec monitor: {alarm_line(settings)}", file=sys.stderr)
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
        return _run_stream(args, spec, settings, jsonl, human, identification(0.0), threshold, loop_starts)
    assert data is not None  # a file replay read its data above

    from ..viewer.live_stream import StreamEvent
    from ..viewer.recordings import run_monitor
    from ..viewer.sinks import default_recording_path, open_sinks

    preload = _preload_rerun() if (args.record is not None or args.live is not None) else None
    monitor = ChatteringMonitor(spec.model, settings, t0=float(data.t[0]), threshold=threshold)
    # kernels and FFT plans load here (while Rerun loads on its thread), not in the loop
    _warm_up(monitor, peaks=preload is not None)
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

    loop_starts()
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
        doc = _summary_doc(args, settings, summary.to_dict(), ident)
        if ident is None:
            doc["identification"] = {"reason": why_not}
        _print_summary_doc(doc, jsonl, allow_nan=True)
        return
    n, rule = _starts_and_rule(sum(e.kind == "fault-start" for e in summary.events), settings, ident)
    print(
        f"{summary.duration_s:.2f} s of data, {summary.n_frames} frames, {n} fault start(s) "
        f"[{rule}]; {summary.wall_s:.2f} s wall",
        file=human,
    )
    _print_status(ident, human)
    if summary.path is not None and not summary.write_error:
        print(f"recording: {summary.path} (open with `chatterspec replay {summary.path}`)", file=human)


def _summary_doc(
    args: argparse.Namespace,
    settings: MonitorSettings,
    summary: dict[str, Any],
    ident: MonitorIdentification | None,
) -> dict[str, Any]:
    """The JSON summary of a replay or a stream: model, data, alarm, the ``summary`` dict, identification."""
    doc = {"model": str(args.model), "data": str(args.data), "alarm": alarm_doc(settings), **summary}
    if ident is not None:
        ident.into_summary(doc)
    return doc


def _print_summary_doc(doc: dict[str, Any], jsonl: bool, *, allow_nan: bool = False) -> None:
    """The JSON summary: a ``summary`` event line with ``--events jsonl``, else an indented document."""
    if jsonl:
        _emit_line(dumps({"event": "summary", **doc}, allow_nan=allow_nan))
    else:
        print(dumps(doc, indent=2, allow_nan=allow_nan))


def _starts_and_rule(
    starts: int, settings: MonitorSettings, ident: MonitorIdentification | None
) -> tuple[int, str]:
    """The fault starts and the rule of the text summary (with tolerances: the parameters' alarms)."""
    if ident is not None and ident.tolerances:
        return ident.starts, ident.rule_short()
    return starts, alarm_short(settings)


def _print_status(ident: MonitorIdentification | None, human: TextIO) -> None:
    """The identification's status lines of the text summary (none without identification)."""
    if ident is not None:
        for line in ident.status_lines():
            print(f"  {line}", file=human)


def _preload_rerun() -> threading.Thread:
    """Import Rerun and its blueprint classes on a thread (~0.25 s of CPU at every start)
    while the main thread reads the data and loads the compiled kernels: on two cores the two overlap."""

    def load() -> None:
        try:
            import rerun
            import rerun.blueprint  # noqa: F401
        except Exception:  # pragma: no cover - the main thread imports them again and reports any error
            pass

    thread = threading.Thread(target=load, name="chatterspec-preload", daemon=True)
    thread.start()
    return thread


def _warm_up(monitor: ChatteringMonitor, *, peaks: bool = False) -> None:
    """One window of zeros through a throw-away copy of ``monitor`` (same model, settings, threshold):
    the compiled kernels (numba cache) and FFT plans load before the replay's clock starts, as in the
    stream monitor and the in-process benchmark; with ``peaks`` (a recording) also the kernel of the
    frames' peak frequencies that the logger runs on the same frames
    (:class:`~chatterspec.viewer.spectrograms.FramePeaks`)."""
    import numpy as np

    from ..online.monitor import ChatteringMonitor

    m = monitor.model
    settings = dataclasses.replace(monitor.settings, threshold=monitor.threshold)
    warm = ChatteringMonitor(m, settings)
    n = warm.n_window + 2
    upd = warm.push(np.zeros((n, m.n_outputs)), np.zeros((n, m.n_inputs)))
    if peaks:
        from ..viewer.spectrograms import FramePeaks

        FramePeaks(warm, np.zeros_like(warm.threshold.values))([upd.frames])


@contextlib.contextmanager
def _collector_off_in_set_up() -> Iterator[Callable[[], None]]:
    """Python's cyclic garbage collector off during the set-up (the imports of numpy, scipy, numba and
    Rerun make ~150 000 long-lived objects, which its full collections walk again and again: ~0.1 s of
    CPU) and, from the call of the function yielded (the loop starts) to the end, the set-up's objects
    kept out of its collections (``gc.freeze``); the collector is back as it was afterwards. At the
    interpreter's exit they are frozen again: its last collections would walk every object once more
    (~0.35 s of CPU) to free memory the process returns anyway."""
    enabled = gc.isenabled()
    frozen = False

    def loop_starts() -> None:
        nonlocal frozen
        gc.freeze()
        frozen = True
        if enabled:
            gc.enable()

    gc.disable()
    try:
        yield loop_starts
    finally:
        if frozen:
            gc.unfreeze()
        if enabled:
            gc.enable()
        _freeze_at_exit()


@functools.cache
def _freeze_at_exit() -> None:
    atexit.register(gc.freeze)


def _alarm_settings(
    args: argparse.Namespace,
    choice: AlarmChoice,
    model: Model,
    settings: MonitorSettings,
    cal: Calibration | None,
    threshold: Threshold,
) -> MonitorSettings:
    """The monitor's alarm rule: ``--alpha`` (the per-frame rule), a calibration file's, or set here
    (calibrated on the monitor's per-frame ``threshold`` for ``settings``)."""
    from ..studies.alarm_budget import alarm_settings

    c = choice  # AlarmChoice
    if args.alpha is not None:
        return dataclasses.replace(settings, alpha=float(args.alpha))
    file_alarm = getattr(cal, "alarm", None)
    if file_alarm is not None:
        from ._options import check_file_alarm

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
        threshold=threshold,
        **c.parameters,
    )


# --- a live stream (standard input or a growing file): the read loop, its line-by-line output and the
# end-of-stream summary ------------------------------------------------------------------------------
#: The exit status of a stream by what stopped it (the summary is printed and the recordings closed in
#: every case): Ctrl-C 130 and SIGTERM 143 (128 + the signal number, as a shell reports a process the
#: signal ended), as for a file replay; end of input, --idle-timeout and a reader that went away 0.
EXIT_STATUS = {"SIGINT": 128 + signal.SIGINT, "SIGTERM": 128 + signal.SIGTERM}


class _Terminated(Exception):
    """SIGTERM arrived (raised from the signal handler to unwind the read loop)."""


def _emit_line(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _run_stream(
    args: argparse.Namespace,
    spec: ModelSpec,
    settings: MonitorSettings,
    jsonl: bool,
    human: TextIO,
    ident: MonitorIdentification | None = None,
    threshold: Threshold | None = None,
    loop_starts: Callable[[], None] | None = None,
) -> int:
    from ..errors import ChatterspecError
    from ..online.stream import CsvRows, follow_file, read_fd
    from ..viewer.live_stream import StreamMonitor, drive

    stdin = str(args.data) == "-"
    where = "standard input" if stdin else f"data file {str(args.data)!r}"
    model = spec.model

    def on_event(ev: StreamEvent) -> None:
        if ident is not None:  # the alarm of the fault named; with tolerances a mismatch only
            ident.note(ev.kind, ev.channel, ev.sample_time_s)
            if ident.tolerances and ev.kind in ("fault-start", "fault-end"):
                return
        if jsonl:
            _emit_line(ev.to_json())
        print(ev.describe(), file=human, flush=True)

    def on_note(text: str) -> None:
        print(f"chatterspec monitor: {text}", file=sys.stderr, flush=True)

    try:
        mon = StreamMonitor(
            model,
            settings,
            record=args.record,
            record_every_s=None if args.record_every is None else 60.0 * args.record_every,
            live=args.live,
            recording_name="monitor stdin" if stdin else f"monitor {args.data.name}",
            skip_bad_rows=args.skip_bad_rows,
            on_event=on_event,
            on_note=on_note,
            on_push=None if ident is None else ident.push,
            on_reset=None if ident is None else ident.reset,
            identification=None if ident is None else ident.monitor,
            threshold=threshold,
        )
    except OSError as exc:  # e.g. disk full when the recording opens: before any row is read
        from ._report import OutputPathError

        raise OutputPathError(
            f"--record {str(args.record)!r} cannot be written ({exc.strerror or exc}); nothing was monitored"
        ) from None
    if ident is not None:  # the recordings draw the identification and their lanes follow it
        ident.on_update = mon.log_identification
    rows = CsvRows(model, where)
    if stdin:
        chunks = read_fd(sys.stdin.fileno())
    else:
        chunks = follow_file(args.data, from_end=args.from_end, idle_timeout_s=args.idle_timeout)

    def on_term(signum: int, frame: FrameType | None) -> None:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # finishing must not be interrupted again
        raise _Terminated

    previous = signal.signal(signal.SIGTERM, on_term)
    stopped, error = "idle timeout" if args.follow else "end of input", None
    if loop_starts is not None:
        loop_starts()
    try:
        drive(chunks, rows, mon)
    except KeyboardInterrupt:
        stopped = "SIGINT"
    except _Terminated:
        stopped = "SIGTERM"
    except BrokenPipeError:
        stopped = "output closed"
        quiet_stdout()
    except ChatterspecError as exc:
        stopped, error = "error", exc
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        try:
            summary = mon.close(stopped)
        finally:
            signal.signal(signal.SIGINT, signal.default_int_handler)
            signal.signal(signal.SIGTERM, previous)
    try:
        _report(args, summary, jsonl, human, settings, ident)
    except BrokenPipeError:
        quiet_stdout()
    if error is not None:
        raise error
    return EXIT_STATUS.get(stopped, 0)


def _report(
    args: argparse.Namespace,
    summary: StreamSummary,
    jsonl: bool,
    human: TextIO,
    settings: MonitorSettings,
    ident: MonitorIdentification | None = None,
) -> None:
    s = summary  # StreamSummary
    if args.json:
        _print_summary_doc(_summary_doc(args, settings, s.to_dict(), ident), jsonl)
        return
    lat = s.latency
    c = s.counts
    latency = (
        f"latency median {lat['median_ms']:.2f} ms, max {lat['max_ms']:.2f} ms"
        if lat["frames"]
        else "no frame completed"
    )
    starts, rule = _starts_and_rule(c["fault-start"], settings, ident)
    print(
        f"{s.duration_s:.2f} s of data ({s.n_rows} rows), {s.n_frames} frames, "
        f"{starts} fault start(s) [{rule}], {c['gap']} gap(s), "
        f"{c['restart']} restart(s), "
        f"{c['bad-row']} bad row(s) skipped; {latency}; {s.wall_s:.2f} s wall; "
        f"stopped by {s.stopped_by}",
        file=human,
    )
    _print_status(ident, human)
    for rec in s.recordings:
        print(f"recording: {rec['path']} (open with `chatterspec replay {rec['path']}`)", file=human)


# --- the identification output (module docstring) -----------------------------------------------------
class MonitorIdentification:
    """The monitor's identification output (module docstring).

    Parameters
    ----------
    monitor : IdentificationMonitor
    emit : callable or None
        Writes one JSON line (``--events jsonl``); None: no JSON lines.
    say : callable
        Writes one human line.
    every_hop : bool or None
        ``identification`` events at every window (True), at changes (False), none (None).
    """

    def __init__(self, monitor: Any, emit: Any, say: Any, every_hop: bool | None = None) -> None:
        self.monitor = monitor
        self.emit, self.say, self.every_hop = emit, say, every_hop
        self.windows = 0
        self.changes: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self._last: tuple[Any, Any] | None = None  # (update, window) of the last window
        self._last_doc: dict[str, Any] | None = None
        self.spectral_mismatch = 0
        self._key: tuple[Any, ...] | None = None
        self._label: str | None = None
        self._states: tuple[str, ...] | None = None
        self._since_reset = 0  # windows since the start or a reset: the detectability's horizon fills
        self._not_excited = [0.0] * len(monitor.parameters)  # seconds per parameter
        self._hop_s = monitor.settings.hop_s
        #: Called with each push's update before it is reported (e.g. the recordings of a stream).
        self.on_update: Callable[[IdentificationUpdate], None] | None = None

    @property
    def last(self) -> dict[str, Any] | None:
        """The report of the last window (the ``identification`` event's fields), None before one."""
        if self._last_doc is None and self._last is not None:
            self._last_doc = self._doc(*self._last)
        return self._last_doc

    def _current(self) -> dict[str, Any]:
        """:attr:`last` while its window is being reported."""
        doc = self.last
        assert doc is not None  # (set before the window's report is asked for)
        return doc

    def _doc(self, upd: Any, w: Any) -> dict[str, Any]:
        """The fields of window ``w``'s ``identification`` event (``upd`` the push's update)."""
        mon, blk = self.monitor, upd.block
        doc = {
            "sample_time_s": round(w.time_s, 9),
            "window_s": [round(w.window_s[0], 9), round(w.window_s[1], 9)],
            "alarm": w.alarm,
            "fault": w.label,
            "fits": bool(blk.fits[w.index]),
            "parameters": mon.parameter_summary(blk, w),
            "channels": dict(zip(mon.channels, w.channel_states, strict=True)),
        }
        if w.alarm and not self.tolerances:
            rep = upd.report(w.index).to_dict()
            doc.update({k: rep[k] for k in ("selected", "hypotheses", "alpha", "confidence")})
        return doc

    @property
    def identifier(self) -> Any:
        """The online identifier (its setup and confidence name the recording's views)."""
        return self.monitor.identifier

    @property
    def tolerances(self) -> bool:
        """Whether the parameters raise the alarms."""
        return bool(self.monitor.tolerances)

    def reset(self, t0: float) -> None:
        """A gap or restart at ``t0``: start over (the label and states too)."""
        self.monitor.reset(t0)
        self._key = self._label = self._states = None
        self._since_reset = 0

    def note(self, kind: str, channel: str | None, alarm_time_s: float | None) -> None:
        """A spectral event of the monitor decided at ``alarm_time_s`` (the end of its frame): the alarm
        state of the label (no tolerances), or a mismatch counted (tolerances)."""
        if kind not in ("fault-start", "fault-end") or channel is None or alarm_time_s is None:
            return
        if self.tolerances:
            self.spectral_mismatch += kind == "fault-start"
        else:
            self.monitor.note_alarm(kind, channel, alarm_time_s)

    def push(self, z: Any, u: Any) -> None:
        """Identify on one raw push and report it."""
        upd = self.monitor.push(z, u)
        if self.on_update is not None:
            self.on_update(upd)
        self.handle(upd)

    def handle(self, upd: Any) -> None:
        """Report one push's :class:`~chatterspec.online.identification_monitor.IdentificationUpdate`."""
        mon, blk = self.monitor, upd.block
        events: dict[int, list[Any]] = {int(ev.frame): [] for ev in upd.events}
        for ev in upd.events:
            events[int(ev.frame)].append(ev)
        for w in upd.windows:
            self.windows += 1
            self._since_reset += 1
            for ev in events.get(int(blk.frames[w.index]), ()):
                doc = ev.to_dict()
                kind, t = doc.pop("kind"), doc.pop("alarm_time_s")
                line = {"event": kind, "sample_time_s": round(t, 9), "wall_time": time.time(), **doc}
                self.events.append(line)
                if self.emit is not None:
                    self.emit(dumps(line))
                self.say(ev.describe())
            for i, s in enumerate(w.states if "not-excited" in w.states else ()):
                if s == "not-excited":
                    self._not_excited[i] += self._hop_s
            # the window's report is built only where it is written (most windows of a replay are not)
            self._last, self._last_doc = (upd, w), None
            key = (w.label, w.states, w.channel_states)
            changed = key != self._key
            if self.emit is not None and self.every_hop is not None and (self.every_hop or changed):
                self.emit(dumps({"event": "identification", **self._current()}))
            if w.label != self._label:
                self._say_label(w, self._current())
            warm = self._since_reset > mon.settings.horizon_hops  # the horizon holds data only after it
            if warm and self._states is not None and w.states != self._states:
                self._say_states(w, self._current())
            if changed:
                self.changes.append(
                    {
                        "time_s": round(w.time_s, 9),
                        "fault": w.label,
                        "states": dict(zip(mon.parameters, w.states, strict=True)),
                    }
                )
            self._key, self._label, self._states = key, w.label, w.states

    def _say_label(self, w: Any, doc: dict[str, Any]) -> None:
        """A human line when the fault named changes (an alarm starts or ends, or names another fault)."""
        at = f"t = {w.time_s:.2f} s (window {w.window_s[0]:.2f}-{w.window_s[1]:.2f} s)"
        if w.label is None:
            if self._label is not None:
                self.say(f"alarm over at {at}: {self._status(doc)}")
            return
        if self.tolerances:
            return  # the parameters' fault events said it
        rows = [r for r in doc.get("hypotheses", []) if r["hypothesis"] == w.label and r["parameter"]]
        from ._report import summary_line

        what = summary_line({"selected": w.label, "hypotheses": rows}) if rows else w.label
        self.say(f"identified at {at}: {what}")

    def _say_states(self, w: Any, doc: dict[str, Any]) -> None:
        """A human line when a parameter becomes not excited, or excited again."""
        rows = {r["parameter"]: r for r in doc["parameters"]}
        for p, old, new in zip(self.monitor.parameters, self._states or (), w.states, strict=True):
            if (old == "not-excited") == (new == "not-excited"):
                continue
            r = rows[p]
            det = "none" if r["detectable"] is None else f"{r['detectable']:.2g}"
            unit = f" {r['unit']}" if r["unit"] else ""
            horizon = self.monitor.settings.horizon_hops * self._hop_s
            what = "not excited" if new == "not-excited" else "excited"
            self.say(
                f"{p} {what} at t = {w.time_s:.2f} s: changes >= {det}{unit} detectable over the last "
                f"{horizon:g} s (not excited above {self._limit(p)})"
            )

    def _limit(self, p: str) -> str:
        b = self.monitor.settings.bands
        i = b.names.index(p)
        unit = f" {b.units[i]}" if b.units[i] else ""
        return f"{b.limit[i]:.2g}{unit}" + (f", its tolerance {b.tolerances[i]}" if b.tolerances[i] else "")

    def _status(self, doc: dict[str, Any]) -> str:
        return "; ".join(self.status_lines(doc))

    def status_lines(self, doc: dict[str, Any] | None = None) -> list[str]:
        """``"bulk_modulus 1.86e8 Pa, 10 % below nominal, inside its +-15 %"`` per parameter (last window)."""
        import numpy as np  # lazily: building the parser does not import numpy

        from ..detection.parameter_decision import status_text

        doc = self.last if doc is None else doc
        if doc is None:
            return []
        out = []
        for r in doc["parameters"]:
            est, se, lo, hi = (
                np.nan if r[k] is None else r[k] for k in ("estimate", "std_error", "ci_low", "ci_high")
            )
            text = status_text(
                r["parameter"],
                est,
                se,
                (lo, hi),
                r["nominal"],
                r["unit"],
                r["tolerance"] or "",
                r["position"] or "",
            )
            out.append(text + ("" if r["state"] == "healthy" else f" ({r['state']})"))
        return out

    @property
    def starts(self) -> int:
        """The parameters' alarm starts so far (tolerances)."""
        return sum(e["event"] == "fault-start" for e in self.events)

    def rule_short(self) -> str:
        """``"cusum rule, 1 false alarm per 24 h, on the parameters"``."""
        from ..detection.alarms.rules import alarm_label

        cal = self.monitor.settings.calibration
        if cal is None:
            return "no parameter alarm"
        return f"{alarm_label(cal.rule.name, cal.false_alarms_per_hour)}, on the parameters"

    def into_summary(self, doc: dict[str, Any]) -> None:
        """Put the identification into a ``monitor --json`` summary ``doc``; with tolerances the
        parameters' alarms become its ``events`` (and ``counts``), the spectral ones ``spectral_events``."""
        doc["identification"] = self.to_dict()
        if not self.tolerances:
            return
        cal = self.monitor.settings.calibration
        doc["decision"] = "parameters (tolerances)"
        doc["alarm"] = None if cal is None else cal.to_dict()
        doc["spectral_events"] = doc.get("events", [])
        doc["events"] = list(self.events)
        if "counts" in doc:
            counts = dict(doc["counts"])
            doc["spectral_counts"] = {k: counts.get(k, 0) for k in ("fault-start", "fault-end")}
            for k in ("fault-start", "fault-end"):
                counts[k] = sum(e["event"] == k for e in self.events)
            doc["counts"] = counts

    def to_dict(self) -> dict[str, Any]:
        """The summary's ``identification``: windows, the decision's settings, the fault-name and state
        ``changes``, the parameters' alarm events (tolerances), time not excited per parameter, the last
        window."""
        ident = self.monitor.identifier
        return {
            "window_s": ident.window_s,
            "windows": self.windows,
            "decision": self.monitor.settings.to_dict(),
            "changes": self.changes,
            "events": self.events,
            "not_excited_s": {
                p: round(float(s), 9) for p, s in zip(self.monitor.parameters, self._not_excited, strict=True)
            },
            "spectral_mismatch": self.spectral_mismatch if self.tolerances else None,
            "last": self.last,
        }
