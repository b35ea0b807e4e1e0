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
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarm_rules import alarm_label
from ..errors import DataFileError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorSettings, MonitorUpdate
from ..online.stream import (
    BadRow,
    CsvRows,
    LatencyStats,
    Restart,
    RowBlock,
)
from ..plants.nonlinear import Model
from .stream_recordings import StreamRecordings, period_bounds
from .stream_segments import Segment, StreamSegments

if TYPE_CHECKING:  # pragma: no cover
    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate

__all__ = ["MAX_EVENTS", "StreamEvent", "StreamMonitor", "StreamSummary", "drive"]

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
        self._proto = ChatteringMonitor(model, settings, t0=0.0)
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
