"""The recordings of a live stream: a file and / or a live viewer, or rotating files.

:class:`StreamRecordings` is the Rerun side of :class:`~chatterspec.viewer.live_stream.StreamMonitor`:
it opens the sinks before any data arrives, logs each monitor update, and with rotation opens the next
file ahead and closes the old one on a background thread (see :mod:`chatterspec.viewer.live_stream`).
Each file's final blueprint, sent when it closes, is paused on its own span
(:meth:`~chatterspec.viewer.rerun_log.RerunLogger.close`).
"""

from __future__ import annotations

import threading
import time
import uuid
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..online.monitor import ChatteringMonitor, MonitorUpdate

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream
    from rerun.blueprint import Blueprint

    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from .live_stream import StreamEvent
    from .sinks import Sinks

__all__ = ["MAX_PENDING_CLOSES", "StreamRecordings", "period_bounds"]

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
        windows (:meth:`log_identification`, :mod:`~chatterspec.viewer.identification_log`).
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
        from .alarm_events import EVENTS, log_text_rows

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
