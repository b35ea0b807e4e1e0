"""``chatterspec monitor`` on a live stream (standard input or a growing file): the read loop, its
line-by-line output and the end-of-stream summary."""

from __future__ import annotations

import argparse
import signal
import sys

from ..errors import ParameterError
from ..jsonout import dumps
from . import _identify
from ._alarm_args import _alarm_short, alarm_doc

__all__: list[str] = []


class _Terminated(Exception):
    """SIGTERM arrived (raised from the signal handler to unwind the read loop)."""


def _emit_line(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


def _run_stream(
    args: argparse.Namespace,
    spec: object,
    settings: object,
    jsonl: bool,
    human: object,
    ident: _identify.MonitorIdentification | None = None,
) -> int:
    from ..errors import ChatterspecError
    from ..online.stream import CsvRows, follow_file, read_fd
    from ..viewer.live_stream import StreamMonitor, drive

    stdin = str(args.data) == "-"
    where = "standard input" if stdin else f"data file {str(args.data)!r}"
    if args.follow and not args.data.is_file():
        raise ParameterError(f"--follow: {where} does not exist (create it, header first, then follow it)")
    model = spec.model  # type: ignore[attr-defined]

    def on_event(ev: object) -> None:
        if jsonl:
            _emit_line(ev.to_json())  # type: ignore[attr-defined]
        print(ev.describe(), file=human, flush=True)  # type: ignore[attr-defined]

    def on_note(text: str) -> None:
        print(f"chatterspec monitor: {text}", file=sys.stderr, flush=True)

    try:
        mon = StreamMonitor(
            model,
            settings,  # type: ignore[arg-type]
            record=args.record,
            record_every_s=None if args.record_every is None else 60.0 * args.record_every,
            live=args.live,
            recording_name="monitor stdin" if stdin else f"monitor {args.data.name}",
            skip_bad_rows=args.skip_bad_rows,
            on_event=on_event,
            on_note=on_note,
            on_push=None if ident is None else ident.push,
            on_reset=None if ident is None else ident.reset,
            identification=None if ident is None else (ident.identifier.setup, ident.identifier.confidence),
        )
    except OSError as exc:  # e.g. disk full when the recording opens: before any row is read
        from ._common import OutputPathError

        raise OutputPathError(
            f"--record {str(args.record)!r} cannot be written ({exc.strerror or exc}); nothing was monitored"
        ) from None
    if ident is not None:  # the human identification lines follow the alarms; the recordings draw it
        ident.alarm_active = lambda: mon.monitor is not None and bool(mon.monitor.active.any())
        ident.on_output = mon.log_identification
    rows = CsvRows(model, where)
    if stdin:
        chunks = read_fd(sys.stdin.fileno())
    else:
        chunks = follow_file(args.data, from_end=args.from_end, idle_timeout_s=args.idle_timeout)

    def on_term(signum: int, frame: object) -> None:
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
    return 0


def _quiet_stdout() -> None:
    """The reader of stdout went away: send further output (and the exit flush) to /dev/null."""
    import os

    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())


def _report(
    args: argparse.Namespace,
    summary: object,
    jsonl: bool,
    human: object,
    settings: object,
    ident: _identify.MonitorIdentification | None = None,
) -> None:
    s = summary  # StreamSummary
    if args.json:
        doc = {"model": str(args.model), "data": str(args.data), "alarm": alarm_doc(settings)}
        doc.update(s.to_dict())  # type: ignore[attr-defined]
        if ident is not None:
            doc["identification"] = ident.to_dict()
        if jsonl:
            _emit_line(dumps({"event": "summary", **doc}))
        else:
            print(dumps(doc, indent=2))
        return
    lat = s.latency  # type: ignore[attr-defined]
    c = s.counts  # type: ignore[attr-defined]
    latency = (
        f"latency median {lat['median_ms']:.2f} ms, max {lat['max_ms']:.2f} ms"
        if lat["frames"]
        else "no frame completed"
    )
    print(
        f"{s.duration_s:.2f} s of data ({s.n_rows} rows), {s.n_frames} frames, "  # type: ignore[attr-defined]
        f"{c['fault-start']} fault start(s) [{_alarm_short(settings)}], {c['gap']} gap(s), "
        f"{c['restart']} restart(s), "
        f"{c['bad-row']} bad row(s) skipped; {latency}; {s.wall_s:.2f} s wall; "  # type: ignore[attr-defined]
        f"stopped by {s.stopped_by}",  # type: ignore[attr-defined]
        file=human,
    )
    for rec in s.recordings:  # type: ignore[attr-defined]
        print(f"recording: {rec['path']} (open with `chatterspec replay {rec['path']}`)", file=human)
