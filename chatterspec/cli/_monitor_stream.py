"""``chatterspec monitor`` on a live stream (standard input or a growing file): the read loop, its
line-by-line output and the end-of-stream summary."""

from __future__ import annotations

import argparse
import signal
import sys
from typing import TYPE_CHECKING

from ..jsonout import dumps
from ._alarm_args import _alarm_short, alarm_doc
from ._monitor_identification import MonitorIdentification

if TYPE_CHECKING:  # pragma: no cover
    from types import FrameType
    from typing import TextIO

    from ..detection.alarms.calibration import MonitorSettings
    from ..plants.modelfile import ModelSpec
    from ..viewer.live_stream import StreamEvent, StreamSummary

__all__: list[str] = []


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
        )
    except OSError as exc:  # e.g. disk full when the recording opens: before any row is read
        from ._common import OutputPathError

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
    try:
        drive(chunks, rows, mon)
    except KeyboardInterrupt:
        stopped = "SIGINT"
    except _Terminated:
        stopped = "SIGTERM"
    except BrokenPipeError:
        stopped = "output closed"
        _quiet_stdout()
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
        _quiet_stdout()
    if error is not None:
        raise error
    return EXIT_STATUS.get(stopped, 0)


def _quiet_stdout() -> None:
    """The reader of stdout went away: send further output (and the exit flush) to /dev/null."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


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
        doc = {"model": str(args.model), "data": str(args.data), "alarm": alarm_doc(settings)}
        doc.update(s.to_dict())
        if ident is not None:
            ident.into_summary(doc)
        if jsonl:
            _emit_line(dumps({"event": "summary", **doc}))
        else:
            print(dumps(doc, indent=2))
        return
    lat = s.latency
    c = s.counts
    latency = (
        f"latency median {lat['median_ms']:.2f} ms, max {lat['max_ms']:.2f} ms"
        if lat["frames"]
        else "no frame completed"
    )
    starts, rule = c["fault-start"], _alarm_short(settings)
    if ident is not None and ident.tolerances:
        starts, rule = ident.starts, ident.rule_short()
    print(
        f"{s.duration_s:.2f} s of data ({s.n_rows} rows), {s.n_frames} frames, "
        f"{starts} fault start(s) [{rule}], {c['gap']} gap(s), "
        f"{c['restart']} restart(s), "
        f"{c['bad-row']} bad row(s) skipped; {latency}; {s.wall_s:.2f} s wall; "
        f"stopped by {s.stopped_by}",
        file=human,
    )
    if ident is not None:
        for line in ident.status_lines():
            print(f"  {line}", file=human)
    for rec in s.recordings:
        print(f"recording: {rec['path']} (open with `chatterspec replay {rec['path']}`)", file=human)
