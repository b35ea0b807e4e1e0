"""Monitor a live measurement stream: gaps, restarts, bad rows, events, latency, rotating recordings.

:class:`StreamMonitor` takes the rows of :class:`chatterspec.online.stream.CsvRows`
as they arrive and drives a :class:`~chatterspec.online.monitor.ChatteringMonitor`
(both SVSFs, the same kernel as the batch path) through them.

Gaps. Samples must be ``dt`` apart for the SVSF prediction and the STFT. With a
time column, a step outside ``(0.5 dt, 1.5 dt]`` (a jump, a repeated or a
backwards time) is a *gap*; without one, a skipped bad row is (a sample is
missing). A gap is not a fault: a ``gap`` event is emitted at the next good
sample, the filters and the STFT buffer are reset (a new monitor whose first
measurement is that sample, with the same per-frame threshold), and the
monitor resumes. A fault that was open is not declared ended: the ``gap`` event
lists it in ``open_faults`` and the fault state restarts as healthy. A restart
(a second header, a truncated or replaced followed file) resets the same way.

Events: :class:`StreamEvent` (``fault-start``, ``fault-end`` per channel,
``gap``, ``restart``) with sample time, wall time, channel, peak frequency and
``S / threshold`` ratio; :meth:`StreamEvent.to_json` is one JSON object.

Latency: for every completed frame, the wall time from the arrival of the
bytes holding its last sample (the read that returned them) to its verdict
(after its events were handed to ``on_event``); median and max in the summary.
Time a row spent in the pipe before it was read is not seen by the monitor.

Memory is bounded whatever the duration: the monitor holds less than one STFT
window, the Rerun logger a bounded batch, the summary the last
:data:`MAX_EVENTS` events and fixed-size latency histogram. With
``record_every_s`` the recording rotates: one complete ``.rrd`` per period of
*data* time (footer written, static data and blueprint repeated, so each file
opens on its own), named by its wall-clock start time.

Rotation is off the verdict path. Opening a recording (stream, file sink,
blueprint, static data: ~70-110 ms) and closing one (last batch, spectrogram
block, footer: ~50-80 ms; more on a loaded machine) both run on one background
thread: the next file is opened ahead under a temporary name
(``.<stem>-<id>.rrd.part``) and, at the rotation, renamed to its final name and
taken over by the loop (a rename and a pointer swap), while the background
thread finishes the old one. Rows keep flowing meanwhile. rerun-sdk 0.41 keeps
every dropped ``RecordingStream`` (and its batcher and sink threads, ~1-2 MB)
in a list of "orphaned" recordings that only ``rr.init`` sweeps; after each
closed file the background thread sweeps it
(``rerun.bindings.flush_and_cleanup_orphaned_recordings``), so memory and
threads stay flat over any number of rotations.

Segmenting (:class:`StreamSegments`): gap and restart segmenting of a live stream's rows, what
:class:`StreamMonitor` delegates between the parser and the monitor: the rows of
:class:`~chatterspec.online.stream.CsvRows` go through the sampling-rate check
(:class:`~chatterspec.online.stream.RateGate`), get their times (the time column, or ``dt``
apart from the last one without it) and are cut into :class:`Segment` objects at every gap (a time
step outside ``(0.5 dt, 1.5 dt]``, :func:`~chatterspec.online.stream.time_gaps`, or a skipped
bad row) and after a restart. Each segment that starts a fresh monitor says so, and why when it is a
gap. Pure bookkeeping: no monitor, no events, no Rerun.

Recordings (:class:`StreamRecordings`): a file and / or a live viewer, or rotating files; the Rerun side
of :class:`StreamMonitor`: it opens the sinks before any data arrives, logs each monitor update, and
with rotation opens the next file ahead and closes the old one on a background thread (see above). Each
file's final blueprint, sent when it closes, is paused on its own span
(:meth:`~chatterspec.viewer.rerun_log.RerunLogger.close`).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import threading
import time
import uuid
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarms.rules import alarm_label
from ..errors import DataFileError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorSettings, MonitorUpdate
from ..online.stream import (
    BadRow,
    CsvRows,
    LatencyStats,
    RateGate,
    Restart,
    RowBlock,
    time_gaps,
)
from ..plants.nonlinear import Model

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream
    from rerun.blueprint import Blueprint

    from ..detection.thresholds import Threshold
    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from .sinks import Sinks

__all__ = [
    "MAX_EVENTS",
    "MAX_PENDING_CLOSES",
    "Segment",
    "StreamEvent",
    "StreamMonitor",
    "StreamRecordings",
    "StreamSegments",
    "StreamSummary",
    "drive",
    "period_bounds",
]


#: Events (and recordings) kept for the summary (older ones are counted, not kept).
MAX_EVENTS = 1000


@dataclass(frozen=True)
class StreamEvent:
    """One event of a live run, as ``--events jsonl`` prints it.

    Attributes
    ----------
    kind : {"fault-start", "fault-end", "gap", "restart"}
    sample_time_s : float or None
        Data time (s): for fault events the alarm time, the last sample of the deciding frame (when the
        detector knew; the fault state changes here); the resuming sample for a gap, the last sample
        before a restart (None if there was none).
    wall_time : float
        Unix time (s) when the event was emitted.
    channel : str or None
        Output channel of a fault event.
    peak_hz : float or None
        Frequency (Hz) of the largest ``S / threshold`` (fault events).
    ratio : float or None
        That largest ``S / threshold`` (fault events; > 1 is above threshold).
    estimate_s : float or None
        Onset / offset estimate (s) of a fault event (window extent: half a hop before the deciding
        frame's centre), earlier than ``sample_time_s``.
    line : int or None
        Input line where a gap or restart was seen.
    reason : str
        Why a gap or restart happened.
    open_faults : tuple of str
        Channels whose fault was open when a gap or restart reset the monitor.
    rule : str or None
        The alarm rule of a fault event; ``false_alarms_per_hour`` its budget (None: per-frame alpha).
    score : float or None
        The frame score ``-log p`` of a fault event's frame (nats).
    """

    kind: str
    sample_time_s: float | None
    wall_time: float
    channel: str | None = None
    peak_hz: float | None = None
    ratio: float | None = None
    estimate_s: float | None = None
    line: int | None = None
    reason: str = ""
    open_faults: tuple[str, ...] = ()
    rule: str | None = None
    false_alarms_per_hour: float | None = None
    score: float | None = None

    @classmethod
    def from_detection(cls, ev: DetectionEvent, wall_time: float) -> StreamEvent:
        """Wrap a monitor's fault event.

        Parameters
        ----------
        ev : DetectionEvent
            The monitor's event.
        wall_time : float
            Unix time (s) of emission.
        """
        return cls(
            ev.kind, ev.alarm_time_s, wall_time, ev.channel, ev.peak_hz, ev.peak_ratio, ev.estimate_s,
            rule=ev.rule, false_alarms_per_hour=ev.false_alarms_per_hour, score=ev.score,
        )  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """The event as a JSON-ready dict: ``"event"`` (its kind) first, then every field (times in s,
        frequencies in Hz); ``open_faults`` as a list.

        See Also
        --------
        to_json : the same as one JSON line (non-finite numbers as null).
        """
        d = dataclasses.asdict(self)
        d["event"] = d.pop("kind")
        d["open_faults"] = list(self.open_faults)
        return {"event": d.pop("event"), **d}

    def to_json(self) -> str:
        """One line of JSON (no NaN: non-finite numbers become null)."""
        d = {
            k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in self.to_dict().items()
        }
        from ..jsonout import dumps

        return dumps(d)

    def describe(self) -> str:
        """One human line: a fault start/end with its channel, alarm time (end of the deciding frame) and
        onset / offset estimate (s), peak ratio and frequency (Hz) and the alarm rule; a gap, restart or
        bad row with its line number and what was reset."""
        if self.kind in ("fault-start", "fault-end"):
            start = self.kind == "fault-start"
            return (
                f"{'fault start' if start else 'fault end'} on {self.channel}: alarm "
                f"{'raised' if start else 'cleared'} at t = {self.sample_time_s:.2f} s (end of the deciding "
                f"frame), {'onset' if start else 'offset'} estimated {self.estimate_s:.2f} s "
                f"(peak {self.ratio:.2f} x threshold at {self.peak_hz:.1f} Hz) "
                f"[{alarm_label(self.rule or 'frame', self.false_alarms_per_hour)}]"
            )
        at = "" if self.sample_time_s is None else f" at t = {self.sample_time_s:.3f} s"
        opened = f"; open fault(s) on {', '.join(self.open_faults)} reset" if self.open_faults else ""
        return f"{self.kind}{at} (line {self.line}): {self.reason}; filters and spectrogram reset{opened}"


@dataclass(frozen=True)
class StreamSummary:
    """Outcome of a live run.

    Attributes
    ----------
    n_rows : int
        Rows (measurements) monitored.
    n_frames : int
        STFT frames (verdicts) over all resets.
    duration_s : float
        Data time covered, ``n_rows * dt`` (s).
    wall_s : float
        Wall-clock time of the run (s).
    events : tuple of StreamEvent
        The last :data:`MAX_EVENTS` events.
    counts : dict
        Events per kind (all of them), and ``bad-row`` (rows skipped).
    latency : dict
        ``frames``, ``median_ms``, ``max_ms`` (see :class:`LatencyStats`), and
        ``rotation_max_ms``: the longest stop of the loop at a rotation (taking
        over the file opened ahead and handing the old one to the rotation
        thread; the opening and closing themselves run on that thread).
    recordings : tuple of dict
        Per ``.rrd`` written (the last :data:`MAX_EVENTS`): ``path``, ``start_s`` /
        ``stop_s`` (data time), ``bytes``.
    live_url : str or None
        Viewer streamed to.
    stopped_by : str
        ``"end of input"``, ``"SIGTERM"``, ``"SIGINT"``, ``"idle timeout"`` or an error.
    notes : tuple of str
        Messages for the user.
    """

    n_rows: int
    n_frames: int
    duration_s: float
    wall_s: float
    events: tuple[StreamEvent, ...]
    counts: dict[str, int]
    latency: dict[str, float | int | None]
    recordings: tuple[dict[str, Any], ...]
    live_url: str | None
    stopped_by: str
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The run as a JSON-ready dict (the ``monitor --json`` summary of a stream): counts, durations
        (s), latency, recordings, the live viewer's URL and every event (:meth:`StreamEvent.to_dict`)."""
        return {
            "n_rows": self.n_rows,
            "n_frames": self.n_frames,
            "duration_s": self.duration_s,
            "wall_s": self.wall_s,
            "stopped_by": self.stopped_by,
            "counts": dict(self.counts),
            "latency": dict(self.latency),
            "recordings": [dict(r) for r in self.recordings],
            "live_url": self.live_url,
            "events": [e.to_dict() for e in self.events],
            "notes": list(self.notes),
        }


class StreamMonitor:
    """Drive a :class:`ChatteringMonitor` over rows as they arrive (see the module docstring).

    Parameters
    ----------
    model : LinearModel
        Nominal model.
    settings : MonitorSettings
        Detector settings (``psi`` set: both SVSFs run).
    record : path, optional
        ``.rrd`` file; with ``record_every_s`` the base name of the rotated files
        ``<stem>-<YYYYmmdd-HHMMSS.mmm>.rrd`` (UTC wall time of the period's first sample).
    record_every_s : float, optional
        Data seconds per recording (rotation).
    live : str, optional
        ``"spawn"`` or a viewer URL (see :func:`chatterspec.viewer.sinks.open_sinks`).
    recording_name : str
        Name shown in the viewer.
    skip_bad_rows : bool
        Skip (and report) bad rows instead of stopping with :class:`DataFileError`.
    on_event : callable, optional
        Called with each :class:`StreamEvent` as soon as it happens.
    on_note : callable, optional
        Called with human-readable notes (skipped rows, recordings closed).
    on_push : callable, optional
        Called with every block of raw rows ``(z (K, m), u (K, p))`` after the monitor's verdicts
        (the CLI feeds online fault identification with it).
    on_reset : callable, optional
        Called with the new ``t0`` (s) when a gap or restart starts the filters over.
    identification : IdentificationMonitor, optional
        The run's identification beside the monitor (fed by ``on_push``), drawn in every recording, whose
        lanes follow its windows: give each push's update to :meth:`log_identification`.
    threshold : Threshold, optional
        The per-frame threshold of ``model`` and ``settings``
        (:func:`~chatterspec.detection.thresholds.monitor_threshold`) when the caller has it already;
        computed here by default (once: every monitor of the stream shares it).
    """

    def __init__(
        self,
        model: Model,
        settings: MonitorSettings,
        *,
        record: str | Path | None = None,
        record_every_s: float | None = None,
        live: str | None = None,
        recording_name: str = "monitor",
        skip_bad_rows: bool = False,
        on_event: Callable[[StreamEvent], None] | None = None,
        on_note: Callable[[str], None] | None = None,
        on_push: Callable[[np.ndarray, np.ndarray], None] | None = None,
        on_reset: Callable[[float], None] | None = None,
        identification: IdentificationMonitor | None = None,
        threshold: Threshold | None = None,
    ) -> None:
        self.on_push = on_push  # e.g. online fault identification, fed the same raw rows
        self.on_reset = on_reset  # called with t0 when a gap or restart starts the filters over
        self.model = model
        self.dt = model.dt
        self.settings = settings
        self.skip_bad_rows = skip_bad_rows
        self.on_event = on_event
        self.on_note = on_note
        self.recording_name = recording_name
        self.record = None if record is None else Path(record)
        self.record_every = None if record_every_s is None else max(1, round(record_every_s / self.dt))
        self.live = live
        self.monitor: ChatteringMonitor | None = None
        # the Rerun loggers are bound to this one (channels, threshold, layout); the sinks are opened
        # before any data arrives so that opening them does not count as latency
        self._proto = ChatteringMonitor(model, settings, t0=0.0, threshold=threshold)
        self._threshold_settings = dataclasses.replace(settings, threshold=self._proto.threshold)
        self._warm_up()
        if self.record is not None or self.live is not None:
            import rerun  # noqa: F401  (loaded now, not when the first rows are waiting)
        self._t_wall0 = time.perf_counter()
        # rate check, time base and the gap / restart segmenting of the rows (stream_segments)
        self._segments = StreamSegments(self.dt)
        self.n_rows = 0
        self._frames_done = 0  # frames of monitors already replaced
        self.events: deque[StreamEvent] = deque(maxlen=MAX_EVENTS)
        self.counts = {"fault-start": 0, "fault-end": 0, "gap": 0, "restart": 0, "bad-row": 0}
        self.latency = LatencyStats()
        self.notes: list[str] = []

        self._rec = StreamRecordings(
            self._proto,
            record=self.record,
            record_every=self.record_every,
            live=self.live,
            recording_name=self.recording_name,
            notes=self.notes,
            on_note=self.on_note,
            max_kept=MAX_EVENTS,
            identification=identification,
        )

    def log_identification(self, upd: IdentificationUpdate) -> None:
        """Draw one push's fault identification (:class:`~chatterspec.online.identification_monitor.
        IdentificationUpdate`) in the recordings, after the push's rows."""
        self._rec.log_identification(upd)

    # ------------------------------------------------------------------ input
    def process(self, item: RowBlock | BadRow | Restart) -> None:
        """Handle one parser output.

        Parameters
        ----------
        item : RowBlock, BadRow or Restart
            From :meth:`CsvRows.feed` / :meth:`CsvRows.finish`.

        Raises
        ------
        DataFileError
            A bad row without ``skip_bad_rows``.
        """
        if isinstance(item, RowBlock):
            self._run(self._segments.rows(item))
            return
        self._run(self._segments.release())  # rows held for the rate check go first, in input order
        if isinstance(item, BadRow):
            if not self.skip_bad_rows:
                raise DataFileError(
                    f"{item.message} (use --skip-bad-rows to skip such rows; a skipped row is a gap)"
                )
            self.counts["bad-row"] += 1
            self._note(f"skipped {item.message}")
            self._segments.bad_row(item.line)
        elif isinstance(item, Restart):
            self._emit(
                StreamEvent(
                    "restart",
                    self._segments.last_t,
                    time.time(),
                    line=item.line,
                    reason=item.reason,
                    open_faults=self._open_faults(),
                )
            )
            self._segments.restart()

    def end_of_input(self) -> None:
        """The source ended: rows still held for the rate check are checked (if >= 3) and monitored.

        Raises
        ------
        DataFileError
            The held rows show a sampling interval other than the model's ``dt``.
        """
        self._run(self._segments.end())

    def _run(self, segments: Iterable[Segment]) -> None:
        """Monitor ``segments`` in order: a gap event and a fresh monitor where one starts."""
        for seg in segments:
            if seg.gap is not None:
                reason, line = seg.gap
                self._emit(
                    StreamEvent(
                        "gap",
                        float(seg.t[0]),
                        time.time(),
                        line=line,
                        reason=reason,
                        open_faults=self._open_faults(),
                    )
                )
            if seg.fresh:
                self._new_monitor(float(seg.t[0]))
            self._push(seg.z, seg.u, seg.t, seg.arrival)

    # --------------------------------------------------------------- internals
    def _warm_up(self) -> None:
        """Run one window of zeros through a throw-away monitor before any data arrives, so that the
        first real frame does not pay for loading compiled kernels (numba cache) or FFT plans."""
        warm = ChatteringMonitor(self.model, self._threshold_settings)
        n = warm.n_window + 2
        warm.push(np.zeros((n, self.model.n_outputs)), np.zeros((n, self.model.n_inputs)))

    def _open_faults(self) -> tuple[str, ...]:
        if self.monitor is None:
            return ()
        return tuple(c for c, a in zip(self.monitor.channels, self.monitor.active, strict=True) if a)

    def _new_monitor(self, t0: float) -> None:
        if self.monitor is not None:
            self._frames_done += self.monitor.n_frames
        # every monitor shares the first one's threshold (no recomputation at a reset)
        self.monitor = ChatteringMonitor(self.model, self._threshold_settings, t0=t0)
        if self.on_reset is not None:
            self.on_reset(t0)

    def _push(self, z: np.ndarray, u: np.ndarray, t: np.ndarray, arrival: float) -> None:
        # verdicts first (events out, latency taken), then logging and recording rotation, so that
        # neither Rerun nor opening / closing a file delays a verdict of rows already read
        K = z.shape[0]
        parts: list[tuple[MonitorUpdate, int, int]] = []
        rec = self._rec
        monitor = self.monitor
        assert monitor is not None  # (made by the first push, before this)
        for lo, hi in period_bounds(K, self.record_every, rec.file_rows):
            upd = monitor.push(z[lo:hi], u[lo:hi])
            self.n_rows += hi - lo
            for ev in upd.events:
                self._emit(StreamEvent.from_detection(ev, time.time()))
            if upd.frames.n_frames:
                self.latency.add(time.perf_counter() - arrival, upd.frames.n_frames)
            parts.append((upd, lo, hi))
        if self.on_push is not None:
            self.on_push(z, u)
        for upd, lo, hi in parts:  # recordings: the period's file opened / closed around its rows
            rec.log_rows(upd, float(t[lo]), float(t[hi - 1]) + self.dt, hi - lo)
        rec.collect_closed(block=False)

    def _emit(self, ev: StreamEvent) -> None:
        self.events.append(ev)
        self.counts[ev.kind] = self.counts.get(ev.kind, 0) + 1
        if self.on_event is not None:
            self.on_event(ev)
        if ev.kind in ("gap", "restart"):
            self._rec.log_text(ev)

    def _note(self, text: str) -> None:
        if self.on_note is not None:
            self.on_note(text)

    # ------------------------------------------------------------------ Rerun
    @property
    def recordings(self) -> deque[dict[str, Any]]:
        """The recordings written so far (path, data span, bytes), the last :data:`MAX_EVENTS`."""
        return self._rec.recordings

    @property
    def n_recordings(self) -> int:
        """Recordings completed (all of them)."""
        return self._rec.n_recordings

    def wait_closed(self) -> None:
        """Wait until every rotated-out recording is complete (footer written) and listed."""
        self._rec.wait_closed()

    def close(self, stopped_by: str = "end of input") -> StreamSummary:
        """Flush and close every recording (footer written) and return the summary.

        Parameters
        ----------
        stopped_by : str
            Why the run ended (reported in the summary).
        """
        self._run(self._segments.release())  # rows held for the rate check when the input stopped early
        t_stop = self._segments.t_next if self.monitor is not None else None
        self._rec.close(t_stop)
        frames = self._frames_done + (self.monitor.n_frames if self.monitor is not None else 0)
        return StreamSummary(
            n_rows=self.n_rows,
            n_frames=frames,
            duration_s=self.n_rows * self.dt,
            wall_s=time.perf_counter() - self._t_wall0,
            events=tuple(self.events),
            counts=dict(self.counts),
            latency={**self.latency.to_dict(), "rotation_max_ms": 1e3 * self._rec.rotation_max_s},
            recordings=tuple(self.recordings),
            live_url=self._rec.live_url,
            stopped_by=stopped_by,
            notes=tuple(self.notes),
        )


def drive(chunks: Iterable[tuple[bytes, float]], rows: CsvRows, monitor: StreamMonitor) -> None:
    """Feed byte chunks through the parser into the monitor until the source ends.

    Parameters
    ----------
    chunks : iterable of (bytes, float)
        From :func:`chatterspec.online.stream.read_fd` or
        :func:`~chatterspec.online.stream.follow_file`.
    rows : CsvRows
        The parser.
    monitor : StreamMonitor
        Receives every parsed item; call its :meth:`StreamMonitor.close` afterwards
        (also on an exception or a signal).
    """
    for data, arrival in chunks:
        for item in rows.feed(data, arrival):
            monitor.process(item)
    for item in rows.finish(time.perf_counter()):
        monitor.process(item)
    monitor.end_of_input()
    if rows.header is None and monitor.n_rows == 0:
        raise DataFileError(f"{rows.where}: no header line (the first line must name the columns)")


# ----------------------------------------------------------- gap and restart segmenting of the rows


@dataclass(frozen=True)
class Segment:
    """Consecutive rows for one monitor.

    Attributes
    ----------
    z, u : ndarray, shapes (K, m) and (K, p)
        Measurements and inputs.
    t : ndarray, shape (K,)
        Sample times (s).
    arrival : float
        ``time.perf_counter()`` when the bytes holding the rows were read.
    fresh : bool
        A new monitor starts at the first row (the first rows, a gap or a restart before them).
    gap : (str, int) or None
        The reasons (``"; "``-joined) and input line of a gap before the first row.
    """

    z: np.ndarray
    u: np.ndarray
    t: np.ndarray
    arrival: float
    fresh: bool
    gap: tuple[str, int] | None = None


class StreamSegments:
    """Cuts the parsed rows of a live stream into :class:`Segment` objects at gaps and restarts.

    Parameters
    ----------
    dt : float
        The model's sampling interval (s).

    Attributes
    ----------
    last_t : float or None
        Time (s) of the last row segmented since the last restart (None: none yet).
    t_next : float
        Time (s) the next row gets without a time column (one ``dt`` after the last).
    started : bool
        A segment has been handed out (a monitor is running).
    """

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.last_t: float | None = None
        self.t_next = 0.0  # synthesized time (no time column)
        self.started = False
        self._pending: list[str] = []  # reasons of a gap to emit at the next sample
        self._pending_line: int | None = None
        self._reset_next = False
        self._gate = RateGate(dt)  # the first rows, held until the sampling-rate check

    def rows(self, b: RowBlock) -> Iterator[Segment]:
        """The segments of a block of parsed rows (after the rate check releases them)."""
        for block in self._gate.feed(b):
            yield from self._split(block)

    def release(self) -> Iterator[Segment]:
        """The rows held for the rate check, unchecked: something else came first (a bad row, a restart,
        the end of the input)."""
        for block in self._gate.release():
            yield from self._split(block)

    def end(self) -> Iterator[Segment]:
        """The source ended: the held rows are checked (if >= 3) and segmented.

        Raises
        ------
        DataFileError
            The held rows show a sampling interval other than ``dt``.
        """
        for block in self._gate.end():
            yield from self._split(block)

    def bad_row(self, line: int) -> None:
        """A bad row at input ``line`` was skipped: a gap before the next sample (a sample is missing)."""
        self._pending.append(f"bad row at line {line} skipped")
        self._pending_line = self._pending_line or line
        if self.started:
            self.t_next += self.dt

    def restart(self) -> None:
        """The input restarted (a second header, a truncated or replaced file): the next segment starts a
        fresh monitor, its time base is not compared with the old one and its sampling is checked again."""
        self._reset_next = True
        self._pending, self._pending_line = [], None
        self.last_t = None
        self._gate.recheck()

    def _split(self, b: RowBlock) -> Iterator[Segment]:
        """Split one released block at its gaps (and at a pending gap / restart before its first row)."""
        K = b.n_rows
        if K == 0:
            return
        dt = self.dt
        t = b.t if b.t is not None else self.t_next + dt * np.arange(K)
        self.t_next = float(t[-1]) + dt
        # split points: gaps by time step, a pending gap / restart at the first row
        starts = time_gaps(t, self.last_t, dt) if b.t is not None else {}
        if self._pending and self.started:
            starts.setdefault(0, [])[:0] = self._pending
        elif not self.started:
            self._pending_line = None  # nothing to reset yet
        self._pending = []
        for lo, hi in itertools.pairwise(sorted({0, *starts, K})):
            reasons = starts.get(lo)
            gap = None
            if reasons and self.started:
                line = int(b.lines[lo]) if self._pending_line is None else self._pending_line
                gap, self._pending_line = ("; ".join(reasons), line), None
            fresh = gap is not None or not self.started or self._reset_next
            if fresh:
                self.started, self._reset_next = True, False
            yield Segment(b.z[lo:hi], b.u[lo:hi], t[lo:hi], b.arrival, fresh, gap)
        self.last_t = float(t[-1])


# ------------------------------------------------------------------ the recordings of a live stream

#: Closed-file jobs the rotation thread may fall behind by before the loop waits for it.
MAX_PENDING_CLOSES = 2


class StreamRecordings:
    """The sinks of one live run: a file (``record``) and / or a live viewer (``live``), or a file per
    ``record_every`` samples of data (rotation).

    Parameters
    ----------
    proto : ChatteringMonitor
        A monitor of the run's settings: the loggers take channels, threshold and layout from it.
    record : Path, optional
        ``.rrd`` file; with ``record_every`` the base name of the rotated files.
    record_every : int, optional
        Samples per rotated file.
    live : str, optional
        ``"spawn"`` or a viewer URL.
    recording_name : str
        Name shown in the viewer.
    notes : list of str
        Receives the sinks' notes (shared with the caller's summary).
    on_note : callable, optional
        Called with human-readable notes (recordings closed).
    max_kept : int
        Recordings kept for the summary (older ones are counted).
    identification : IdentificationMonitor, optional
        The run's identification beside the monitor: every recording draws it and its lanes follow its
        windows (:meth:`log_identification`, :mod:`~chatterspec.viewer.rerun_log`).
    """

    def __init__(
        self,
        proto: ChatteringMonitor,
        *,
        record: Path | None,
        record_every: int | None,
        live: str | None,
        recording_name: str,
        notes: list[str],
        on_note: Callable[[str], None] | None,
        max_kept: int,
        identification: IdentificationMonitor | None = None,
    ) -> None:
        self._proto = proto
        self.identification = identification
        self._identified: list[IdentificationUpdate] = []  # windows of this push, logged after its rows
        self.record, self.record_every, self.live = record, record_every, live
        self.recording_name = recording_name
        self.notes, self.on_note = notes, on_note
        self.recordings: deque[dict[str, Any]] = deque(maxlen=max_kept)
        self.n_recordings = 0  # recordings completed (all of them)
        self._loggers: list[Any] = []
        self._live_sinks: Any = None
        self._file_sinks: Any = None
        self.file_logger: Any = None
        self.file_rows = 0
        self._file_start: float | None = None
        self.live_url: str | None = None
        self.rotation_max_s = 0.0
        self._rotator: ThreadPoolExecutor | None = None  # opens the next file, closes the old ones
        self._spare: Future | None = None  # the next file, opened ahead: (sinks, logger)
        self._closing: deque[Future] = deque()  # files being closed, oldest first
        if self.live is not None or (self.record is not None and self.record_every is None):
            self._open_live()
        if self.record_every is not None:  # the first file is opened now (errors surface here)
            from .sinks import default_recording_path

            self._base = self.record or default_recording_path(self.recording_name)
            self._spare = Future()
            self._spare.set_result(self._make_file())

    def _note(self, text: str) -> None:
        if self.on_note is not None:
            self.on_note(text)

    def _logger(self, sinks: Sinks) -> Any:
        from .rerun_log import RerunLogger

        return RerunLogger(sinks, self._proto, identification=self.identification) if sinks.streams else None

    def _open_live(self) -> None:
        from .sinks import default_recording_path, open_sinks

        if self.record_every is None:  # a viewer that cannot be used falls back to a file, as for replays
            sinks = open_sinks(
                record=self.record,
                live=self.live,
                recording_name=self.recording_name,
                default_record=default_recording_path(self.recording_name),
            )
        elif self.live is not None:
            sinks = open_sinks(live=self.live, recording_name=self.recording_name)
        else:
            return
        self._live_sinks = sinks
        self.live_url = sinks.live_url
        for note in sinks.notes:
            self.notes.append(note)
            self._note(note)
        logger = self._logger(sinks)
        if logger is not None:
            self._loggers.append(logger)
        if sinks.path is not None:
            self.recordings.append({"path": str(sinks.path), "start_s": None, "stop_s": None, "bytes": None})

    def _pool(self) -> ThreadPoolExecutor:
        if self._rotator is None:
            self._rotator = ThreadPoolExecutor(max_workers=1, thread_name_prefix="chatterspec-rotation")
        return self._rotator

    def _make_file(self) -> tuple[Any, Any]:
        """Open the next recording under a temporary name (rotation thread, or the constructor)."""
        from .sinks import open_sinks

        base = self._base
        tmp = base.parent / f".{base.stem}-{uuid.uuid4().hex[:12]}.rrd.part"
        sinks = open_sinks(record=tmp, recording_name=self.recording_name)
        from .rerun_log import RerunLogger

        logger = RerunLogger(sinks, self._proto, send_blueprint=False, identification=self.identification)
        for st in sinks.streams:
            _send_blueprint_released(st, logger.layout(span_s=None))
        # on close: paused on the file's whole record, sent without leaking either
        logger.file_layout, logger.send_file_blueprint = {}, _send_blueprint_released
        return sinks, logger

    def open_file(self, t_start: float) -> None:
        """Take over the file opened ahead: rename it after this moment, and open the next one."""
        t_open = time.perf_counter()
        spare = self._spare
        assert spare is not None  # (opened ahead: __init__, then each rotation)
        sinks, logger = spare.result()  # ready unless the rotation thread is far behind
        self._spare = None
        base = self._base
        now = time.time()
        stamp = time.strftime("%Y%m%d-%H%M%S", time.gmtime(now)) + f".{int(now % 1 * 1000):03d}"
        stem = base.stem
        path = base.parent / f"{stem}-{stamp}.rrd"
        k = 1
        while path.exists():
            path = base.parent / f"{stem}-{stamp}-{k}.rrd"
            k += 1
        Path(sinks.path).rename(path)  # the sink keeps writing to the open file
        sinks.path = path
        for st in sinks.streams:
            st.send_recording_name(f"{self.recording_name} {stamp}")
        self._file_sinks, self.file_logger = sinks, logger
        self.file_rows = 0
        self._file_start = t_start
        self._spare = self._pool().submit(self._make_file)
        self.rotation_max_s = max(self.rotation_max_s, time.perf_counter() - t_open)

    def close_file(self, t_stop: float | None, *, wait: bool = True) -> None:
        """Hand the current file to the rotation thread (``wait``: and wait until every file is done)."""
        if self._file_sinks is not None:
            held = [self._file_sinks, self.file_logger]  # the job empties it: no reference outlives it
            self.file_logger = self._file_sinks = None
            self._closing.append(self._pool().submit(_finish_file, held, self._file_start, t_stop))
        while len(self._closing) > MAX_PENDING_CLOSES:
            self._collect_one()
        if wait:
            self.wait_closed()

    def _collect_one(self) -> None:
        rec = self._closing.popleft().result()  # an error while closing is raised here
        self.recordings.append(rec)
        self.n_recordings += 1
        size = "file gone" if rec["bytes"] is None else f"{rec['bytes'] / 1e6:.1f} MB"
        self._note(f"recording {rec['path']} closed ({size})")

    def collect_closed(self, *, block: bool) -> None:
        """List the closed files (``block``: wait for every pending close)."""
        while self._closing and (block or self._closing[0].done()):
            self._collect_one()

    def wait_closed(self) -> None:
        """Wait until every rotated-out recording is complete (footer written) and listed."""
        self.collect_closed(block=True)

    def log(self, upd: MonitorUpdate) -> None:
        """Log one monitor update to every open logger (live viewer, file, current rotated file)."""
        for logger in self._loggers:
            logger.log_update(upd)
        if self.file_logger is not None:
            self.file_logger.log_update(upd)

    def log_rows(self, upd: MonitorUpdate, t_first: float, t_after: float, n: int) -> None:
        """Log ``upd`` (``n`` rows, the first at ``t_first`` s); when rotating, open the period's file
        before and close it (off the loop) once it holds ``record_every`` rows, ``t_after`` (s) being one
        ``dt`` after its last row (cut the rows with :func:`period_bounds` first)."""
        rotating = self.record_every is not None
        if rotating and self.file_logger is None:
            self.open_file(t_first)
        self.log(upd)
        # the push's identification after its first rows (a window rotated past goes to the older file)
        self.send_identification()
        if self.record_every is not None:  # (rotating)
            self.file_rows += n
            if self.file_rows >= self.record_every:
                t_rot = time.perf_counter()
                self.close_file(t_after, wait=False)
                self.rotation_max_s = max(self.rotation_max_s, time.perf_counter() - t_rot)

    def log_identification(self, upd: IdentificationUpdate) -> None:
        """Keep one push's identification (:class:`~chatterspec.online.identification_monitor.
        IdentificationUpdate`, made before its rows are logged: the verdicts go out first) until
        :meth:`send_identification`."""
        self._identified.append(upd)

    def send_identification(self) -> None:
        """Log the kept identification to every open recording, after rows of its push (:meth:`log_rows`;
        a file's lanes start with its record: windows decided before a rotated file's start are not
        drawn there)."""
        kept, self._identified = self._identified, []
        loggers = [*self._loggers, *([self.file_logger] if self.file_logger is not None else [])]
        for upd in kept:
            for logger in loggers:
                logger.log_identification(upd)

    def log_text(self, ev: StreamEvent) -> None:
        """Log a gap or restart event to the open streams' event log at its sample time."""
        sinks = [x for x in (self._live_sinks, self._file_sinks) if x is not None]
        streams = [s for x in sinks for s in x.streams]
        if not streams or ev.sample_time_s is None:
            return
        from .events import EVENTS, log_text_rows

        for s in streams:
            text = f"{ev.sample_time_s:.2f} s {ev.kind}: {ev.describe()}"
            log_text_rows(s, EVENTS, [ev.sample_time_s], [text], ["WARN"])

    # ------------------------------------------------------------------ end
    def discard_spare(self) -> None:
        """Close and delete the file opened ahead for a period that never came; stop the thread."""
        spare, self._spare = self._spare, None
        try:
            if spare is not None:
                held = list(spare.result())
                path = held[0].path
                self._pool().submit(_finish_file, held, None, None).result()
                Path(path).unlink(missing_ok=True)
        finally:
            if self._rotator is not None:
                self._rotator.shutdown(wait=True)
                self._rotator = None

    def close(self, t_stop: float | None) -> None:
        """Close every recording (footer written) and fill in their sizes.

        Parameters
        ----------
        t_stop : float or None
            Data time (s) where the current rotated file stops.
        """
        try:
            self.close_file(t_stop)
        finally:
            try:
                self.discard_spare()
            finally:
                try:
                    for logger in self._loggers:
                        logger.close()
                finally:
                    if self._live_sinks is not None:
                        self._live_sinks.close()
        for rec in self.recordings:
            if rec["bytes"] is None and Path(rec["path"]).exists():
                rec["bytes"] = Path(rec["path"]).stat().st_size
        if self.record_every is None:
            self.n_recordings = len(self.recordings)


def period_bounds(n: int, every: int | None, in_file: int) -> list[tuple[int, int]]:
    """``(lo, hi)`` pieces of ``n`` new rows cut where the recording periods of ``every`` rows end, the
    current file holding ``in_file`` rows already (one piece without rotation, ``every`` None)."""
    if every is None:
        return [(0, n)]
    bounds, lo = [], 0
    while lo < n:
        hi = min(n, lo + every - in_file)
        bounds.append((lo, hi))
        in_file, lo = (in_file + hi - lo) % every, hi
    return bounds


def _send_blueprint_released(stream: RecordingStream, bp: Blueprint) -> None:
    """Send the blueprint ``bp`` to ``stream`` (active and default, as :class:`RerunLogger` does) without
    leaking.

    ``RecordingStream.send_blueprint`` builds the blueprint in a temporary blueprint
    stream whose memory sink refers back to it; rerun-sdk 0.41 never frees that stream
    (measured: +2 OS threads per call, also after the orphan sweep). Here it is built the
    same way and disconnected once sent, which frees it. Falls back to the public call
    if those internals are not there (another rerun-sdk version).
    """
    import rerun as rr

    native = getattr(rr.bindings, "new_blueprint", None)
    from_native = getattr(rr.RecordingStream, "_from_native", None)
    full = bp.to_blueprint()
    if native is None or from_native is None or not hasattr(full, "_log_to_stream"):  # pragma: no cover
        stream.send_blueprint(bp, make_active=True, make_default=True)
        return
    app_id = stream.get_application_id()  # type: ignore[misc]  # rerun types it as a plain function attribute
    bp_stream = from_native(native(application_id=app_id, make_default=False, make_thread_default=False))
    try:
        bp_stream.set_time("blueprint", sequence=0)
        full._log_to_stream(bp_stream)
        storage = bp_stream.memory_recording().storage
        rr.bindings.send_blueprint(storage, True, True, recording=stream.to_native())
        del storage
    finally:
        bp_stream.disconnect()


def _finish_file(held: list[Any], t_start: float | None, t_stop: float | None) -> dict[str, Any]:
    """Close one recording (rotation thread): last batch and spectrogram block, footer; then let
    rerun-sdk free it. ``held`` is ``[sinks, logger]`` and is emptied, so that when the streams are
    closed nothing refers to them any more and the orphan sweep releases them (and their threads)."""
    sinks, logger = held
    held.clear()
    try:
        if logger is not None:
            logger.close()
    finally:
        sinks.close()
    path = sinks.path
    size = path.stat().st_size if path.exists() else None  # None: removed by someone else meanwhile
    rec = {"path": str(path), "start_s": t_start, "stop_s": t_stop, "bytes": size}
    del sinks, logger
    _sweep_orphaned_recordings()
    return rec


_sweep_lock = threading.Lock()


def _sweep_orphaned_recordings() -> None:
    """Free the recordings nothing refers to any more.

    rerun-sdk 0.41 moves a dropped ``RecordingStream`` into a list of orphaned
    recordings, where it keeps its batcher and sink threads and buffers (measured:
    +2 threads and ~1-2 MB per rotated file), until ``rr.init`` calls
    ``flush_and_cleanup_orphaned_recordings``; we call it after each closed file.
    That function also clears Rerun's *global* recording (this module never
    uses it), so a global recording set by the caller is put back.
    """
    import rerun as rr

    sweep = getattr(rr.bindings, "flush_and_cleanup_orphaned_recordings", None)
    if sweep is None:  # pragma: no cover  (another rerun-sdk version)
        return
    with _sweep_lock:
        previous = rr.bindings.get_global_data_recording()
        try:
            sweep()
        except RuntimeError:  # pragma: no cover  (a flush of some live stream timed out: sweep next time)
            pass
        finally:
            if previous is not None:
                rr.bindings.set_global_data_recording(previous)
