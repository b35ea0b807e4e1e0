"""Rerun output of the online monitor: sinks (file / live viewer), entity layout, default blueprint.

``rerun`` is imported lazily inside the functions: ``import chatterspec.live``
does not load it, and the numeric core never imports this module.

Entity layout (timeline ``time``, seconds; ``<c>`` is an output channel name):

====================================  =================================================================
``/chattering/<c>/e``                 chattering ``e(k|k-1)`` of the auxiliary filter (bulk ``send_columns``)
``/chattering/<c>/psi_upper|lower``   the SVSF boundary layer ``+-psi`` (when known)
``/signal/<c>/measured|estimate``     measurement and ``sat``-SVSF estimate ``C x(k|k)`` (raw data only)
``/spectrum/<c>``                     one exact STFT column per hop (``Tensor``, dim ``freq``, float64)
``/spectrogram/<c>``                  scrolling 2-D view, dB re the expected healthy frame spectrum
``/detection/<c>/peak_ratio``         largest ``S / threshold`` over the tested bins, per frame
``/detection/<c>/threshold``          the decision level 1.0 on the same axis
``/detection/<c>/verdict``            per-frame verdict, 1 = fault, 0 = healthy
``/threshold/<c>``, ``/expected/<c>`` static frame threshold and expected healthy spectrum per bin
``/state/<c>``                        state lane ``healthy`` / ``fault``
``/truth/plant``                      true fault timeline (simulated data only)
``/events``                           text log of fault start / end events
====================================  =================================================================

The scrolling spectrogram is a 2-D float16 ``Tensor`` of the last ``scroll_frames``
columns; it goes to a live viewer at every hop but into a file only every
``file_scroll_every`` hops and at the end (a 2-D tensor per hop would cost ~90 MB per minute).

Default recording folder of ``chatterspec demo``: ``recordings/`` in the
current directory (git-ignored).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import uuid
import warnings
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

import numpy as np

from .monitor import ChatteringMonitor, DetectionEvent, MonitorSettings, MonitorUpdate
from .spectral import expected_frame_spectrum

if TYPE_CHECKING:
    from .pipeline import ChatteringRecord
    from .simulate import Simulation

__all__ = [
    "DEFAULT_RECORDINGS_DIR",
    "LiveViewerWarning",
    "RecordingSummary",
    "RerunLogger",
    "Sinks",
    "blueprint",
    "default_recording_path",
    "find_viewer",
    "has_display",
    "open_sinks",
    "record_detection",
    "run_monitor",
]

#: Folder (relative to the current directory) where ``chatterspec demo`` writes recordings.
DEFAULT_RECORDINGS_DIR = Path("recordings")
#: Seconds to wait for a TCP connection to a live viewer before giving up on it.
CONNECT_TIMEOUT_S = 2.0
TIMELINE = "time"
#: Colour range (dB above the expected healthy frame spectrum) of the scrolling spectrogram.
DB_RANGE = (-10.0, 30.0)


class LiveViewerWarning(UserWarning):
    """The live viewer is unreachable or cannot be started; the file sink (if any) is kept."""


def has_display() -> bool:
    """True when a graphical session exists (``DISPLAY`` or ``WAYLAND_DISPLAY`` set, or macOS/Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def find_viewer() -> str | None:
    """Path of the ``rerun`` viewer executable: next to the Python interpreter, else on PATH."""
    here = Path(sys.executable).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    if here.exists():
        return str(here)
    return shutil.which("rerun")


def default_recording_path(name: str, folder: str | Path = DEFAULT_RECORDINGS_DIR) -> Path:
    """``recordings/<name>-<YYYYmmdd-HHMMSS>.rrd`` (folder created on open)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "chatterspec"
    return Path(folder) / f"{safe}-{stamp}.rrd"


def _grpc_url(live: str) -> str:
    """Accept ``rerun+http://host:port/proxy``, ``host:port`` or a port number."""
    if live.isdigit():
        return f"rerun+http://127.0.0.1:{live}/proxy"
    if "://" not in live:
        return f"rerun+http://{live}/proxy"
    return live


def _reachable(url: str, timeout: float = CONNECT_TIMEOUT_S) -> tuple[bool, str]:
    parsed = urlparse(url.replace("rerun+", "", 1))
    host, port = parsed.hostname or "127.0.0.1", parsed.port or 9876
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True, ""
    except OSError as exc:
        return False, f"{host}:{port}: {exc.strerror or exc}"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Sinks:
    """The open Rerun streams of one run: a file stream and/or a live-viewer stream (same recording id).

    Use as a context manager (or call :meth:`close`): the streams are always
    disconnected, which writes the ``.rrd`` footer, also on Ctrl-C. A dead live
    viewer is never flushed against, so closing takes at most a few seconds.
    """

    file_stream: Any | None = None
    live_stream: Any | None = None
    path: Path | None = None
    live_url: str | None = None
    notes: list[str] = field(default_factory=list)
    viewer_process: subprocess.Popen | None = None
    _closed: bool = False

    @property
    def streams(self) -> list[Any]:
        return [s for s in (self.file_stream, self.live_stream) if s is not None]

    @property
    def live(self) -> bool:
        return self.live_stream is not None

    def __enter__(self) -> Sinks:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send_blueprint(self, bp: Any) -> None:
        for s in self.streams:
            s.send_blueprint(bp, make_active=True, make_default=True)

    def close(self) -> None:
        """Disconnect every stream (writes the file footer); idempotent."""
        if self._closed:
            return
        self._closed = True
        if self.file_stream is not None:
            self.file_stream.flush(timeout_sec=30.0)
            self.file_stream.disconnect()
        if self.live_stream is not None:
            ok, why = _reachable(self.live_url or "", timeout=1.0)
            if ok:
                try:
                    self.live_stream.flush(timeout_sec=5.0)
                except RuntimeError as exc:  # viewer went away meanwhile
                    _warn(f"live viewer {self.live_url}: pending data dropped ({exc})")
            else:
                _warn(f"live viewer {self.live_url} went away ({why}); pending live data dropped")
            self.live_stream.disconnect()


def _warn(msg: str) -> None:
    warnings.warn(msg, LiveViewerWarning, stacklevel=3)


def open_sinks(
    *,
    record: str | Path | None = None,
    live: str | None = None,
    application_id: str = "chatterspec",
    recording_id: str | None = None,
    recording_name: str | None = None,
    default_record: str | Path | None = None,
) -> Sinks:
    """Open the sinks of ``--record FILE.rrd`` and ``--live URL|spawn``.

    Parameters
    ----------
    record : path, optional
        ``.rrd`` file to write (parent folders are created).
    live : str, optional
        ``"spawn"`` starts the ``rerun`` viewer (only when a display exists);
        otherwise a gRPC URL ``rerun+http://host:port/proxy``, ``host:port`` or a
        port. An unreachable viewer is reported once (:class:`LiveViewerWarning`)
        after at most :data:`CONNECT_TIMEOUT_S` seconds and skipped.
    application_id, recording_id, recording_name : str
        Rerun identifiers (``recording_id`` defaults to a fresh UUID; both
        streams share it so the viewer merges them).
    default_record : path, optional
        File written when the live viewer cannot be used and ``record`` is None
        (so the data is never lost).

    Returns
    -------
    Sinks
        Possibly with no stream at all (nothing requested, or viewer unusable
        and no fallback file); ``notes`` holds what the user should be told.
    """
    import rerun as rr

    rid = recording_id or str(uuid.uuid4())
    sinks = Sinks()

    def new_stream() -> Any:
        s = rr.RecordingStream(application_id, recording_id=rid)
        if recording_name:
            s.send_recording_name(recording_name)
        return s

    if live is not None:
        url: str | None = None
        if live == "spawn":
            exe = find_viewer()
            if not has_display():
                sinks.notes.append(
                    "no display (DISPLAY / WAYLAND_DISPLAY unset): the viewer was not started; "
                    "open the recording later with `chatterspec replay FILE.rrd` on a machine with a display"
                )
            elif exe is None:
                sinks.notes.append("the `rerun` viewer executable was not found; install rerun-sdk")
            else:
                port = _free_port()
                proc = subprocess.Popen(
                    [exe, "--port", str(port)],
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,
                )
                url = f"rerun+http://127.0.0.1:{port}/proxy"
                deadline = time.monotonic() + 10.0
                while time.monotonic() < deadline and not _reachable(url, 0.2)[0]:
                    if proc.poll() is not None:
                        break
                    time.sleep(0.1)
                sinks.viewer_process = proc
        else:
            url = _grpc_url(live)
        if url is not None:
            ok, why = _reachable(url)
            if ok:
                s = new_stream()
                s.set_sinks(rr.GrpcSink(url))
                sinks.live_stream, sinks.live_url = s, url
            else:
                _warn(f"live viewer {url} is unreachable ({why}); continuing without it")
                sinks.notes.append(f"live viewer {url} unreachable; nothing streamed")
        if sinks.live_stream is None and record is None and default_record is not None:
            record = default_record
    if record is not None:
        path = Path(record)
        path.parent.mkdir(parents=True, exist_ok=True)
        s = new_stream()
        s.set_sinks(rr.FileSink(str(path)))
        sinks.file_stream, sinks.path = s, path
    return sinks


# --------------------------------------------------------------------------- blueprint
def _entity(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def blueprint(channels: tuple[str, ...], *, has_truth: bool = False, history_s: float = 10.0) -> Any:
    """The default layout: per channel (columns) chattering, scrolling spectrogram, detection statistic;
    below, the state lanes (verdict per channel and true fault) and the event log."""
    import rerun as rr
    import rerun.blueprint as rrb

    recent = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-history_s),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    columns = []
    for name in channels:
        c = _entity(name)
        columns.append(
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=f"/chattering/{c}",
                    name=f"{name}: chattering e(k|k-1) and boundary ±psi",
                    time_ranges=recent,
                ),
                rrb.TensorView(
                    origin=f"/spectrogram/{c}",
                    name=f"{name}: spectrogram, dB above healthy (freq up, time right)",
                    slice_selection=rrb.TensorSliceSelection(
                        width=rr.components.TensorWidthDimension(dimension=1),
                        height=rr.components.TensorHeightDimension(dimension=0, invert=True),
                    ),
                    scalar_mapping=rrb.TensorScalarMapping(colormap="viridis"),
                ),
                rrb.TimeSeriesView(
                    origin=f"/detection/{c}",
                    name=f"{name}: peak S/threshold (fault when > 1)",
                    time_ranges=recent,
                ),
                row_shares=[1, 1.4, 1],
            )
        )
    lanes = ["/state/**", "/truth/**"] if has_truth else ["/state/**"]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*columns),
            rrb.Horizontal(
                rrb.StateTimelineView(
                    origin="/",
                    contents=lanes,
                    name="verdict per channel" + (" vs true fault" if has_truth else ""),
                ),
                rrb.TextLogView(origin="/events", name="detection events"),
                column_shares=[2, 1],
            ),
            row_shares=[4, 1],
        ),
        rrb.TimePanel(state="expanded", timeline=TIMELINE),
        collapse_panels=True,
    )


# --------------------------------------------------------------------------- logging
class RerunLogger:
    """Writes :class:`~chatterspec.monitor.MonitorUpdate` objects to the open sinks.

    Parameters
    ----------
    sinks : Sinks
    monitor : ChatteringMonitor
        Gives channels, frequencies, threshold and the boundary layer.
    scroll_frames : int
        Columns in the scrolling spectrogram (50 = 10 s at a 0.2 s hop).
    file_scroll_every : int
        Frames between two scrolling-spectrogram tensors in the file (the live
        viewer gets one per frame); the last one is always written on close.
    batch_samples : int
        Samples buffered before a bulk ``send_columns`` when no viewer is live.
    truth : list of (start_s, label, is_fault), optional
        True fault timeline to draw in ``/truth/plant``.
    """

    def __init__(
        self,
        sinks: Sinks,
        monitor: ChatteringMonitor,
        *,
        scroll_frames: int = 50,
        file_scroll_every: int = 25,
        batch_samples: int = 2000,
        truth: list[tuple[float, str, bool]] | None = None,
        send_blueprint: bool = True,
    ) -> None:
        import rerun as rr

        self.rr = rr
        self.sinks = sinks
        self.monitor = monitor
        self.channels = monitor.channels
        self.keys = [_entity(c) for c in self.channels]
        self.scroll_frames = int(scroll_frames)
        m = len(self.channels)
        bins = monitor.freqs_hz.shape[0]
        self._expected = expected_frame_spectrum(
            monitor.model, monitor.freqs_hz, monitor.settings.stft, monitor.dt
        )
        self._scroll = np.full((m, bins, self.scroll_frames), DB_RANGE[0], dtype=np.float16)
        self._frames_since_file_scroll = 0
        self.file_scroll_every = int(file_scroll_every)
        self.batch_samples = int(batch_samples)
        self._pending: list[MonitorUpdate] = []
        self._pending_samples = 0
        self._last_frame_time: float | None = None
        self.psi = monitor.settings.psi
        if send_blueprint:
            sinks.send_blueprint(blueprint(self.channels, has_truth=bool(truth)))
        self._log_static(truth)

    def _each(self, fn: Any) -> None:
        for s in self.sinks.streams:
            fn(s)

    def _log_static(self, truth: list[tuple[float, str, bool]] | None) -> None:
        rr = self.rr
        thr = self.monitor.threshold
        units = self.monitor.model.output_units
        colors = [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189]]
        for i, (name, c) in enumerate(zip(self.channels, self.keys, strict=True)):
            unit = f" [{units[i]}]" if units[i] else ""

            def static(s: Any, name: str = name, c: str = c, i: int = i, unit: str = unit) -> None:
                col = colors[i % len(colors)]
                s.log(
                    f"/chattering/{c}/e", rr.SeriesLines(colors=[col], names=[f"{name}{unit}"]), static=True
                )
                for side in ("upper", "lower"):
                    s.log(
                        f"/chattering/{c}/psi_{side}",
                        rr.SeriesLines(colors=[[120, 120, 120]], widths=[1.0], names=[f"±psi {side}"]),
                        static=True,
                    )
                s.log(f"/signal/{c}/measured", rr.SeriesLines(colors=[col], names=["measured"]), static=True)
                s.log(
                    f"/signal/{c}/estimate",
                    rr.SeriesLines(colors=[[0, 0, 0]], names=["SVSF estimate"]),
                    static=True,
                )
                s.log(
                    f"/detection/{c}/peak_ratio",
                    rr.SeriesLines(colors=[col], widths=[2.0], names=["peak S/threshold"]),
                    static=True,
                )
                s.log(
                    f"/detection/{c}/threshold",
                    rr.SeriesLines(colors=[[214, 39, 40]], widths=[1.0], names=["threshold (1.0)"]),
                    static=True,
                )
                s.log(
                    f"/detection/{c}/verdict",
                    rr.SeriesPoints(colors=[[214, 39, 40]], names=["verdict (1 = fault)"]),
                    static=True,
                )
                s.log(f"/threshold/{c}", rr.Tensor(thr.values[:, i], dim_names=["freq"]), static=True)
                s.log(f"/expected/{c}", rr.Tensor(self._expected[:, i], dim_names=["freq"]), static=True)
                s.log(
                    f"/state/{c}",
                    rr.StateConfiguration(
                        values=["healthy", "fault"],
                        labels=[f"{name}: healthy", f"{name}: FAULT"],
                        colors=[0x4CAF50FF, 0xEF5350FF],
                    ),
                    static=True,
                )

            self._each(static)
        self._each(
            lambda s: s.log(
                "/frequencies",
                rr.TextDocument(
                    f"Spectra: {len(self.monitor.freqs_hz)} bins, 0 .. {self.monitor.freqs_hz[-1]:g} Hz "
                    f"(step {self.monitor.freqs_hz[1]:g} Hz). {thr.describe()}"
                ),
                static=True,
            )
        )
        if truth:
            t0 = truth[0][0]

            def log_truth(s: Any) -> None:
                labels = sorted({lab for _, lab, _ in truth})
                s.log(
                    "/truth/plant",
                    rr.StateConfiguration(
                        values=labels,
                        labels=[f"true plant: {lab}" for lab in labels],
                        colors=[0x9E9E9EFF if lab == "healthy" else 0xFF9800FF for lab in labels],
                    ),
                    static=True,
                )
                for start, label, _ in truth:
                    s.set_time(TIMELINE, duration=max(start, t0))
                    s.log("/truth/plant", rr.StateChange(state=label))

            self._each(log_truth)
        self._each(self._initial_state)

    def _initial_state(self, s: Any) -> None:
        s.set_time(TIMELINE, duration=float(self.monitor.frame_time(0)))
        for c in self.keys:
            s.log(f"/state/{c}", self.rr.StateChange(state="healthy"))

    def log_update(self, upd: MonitorUpdate) -> None:
        """Log one update: one spectrum column per frame and events at once; sample series and
        per-frame scalars are buffered and sent with ``send_columns`` in batches of at least
        ``batch_samples`` samples (at every update when a live viewer is attached)."""
        rr = self.rr
        fr = upd.frames
        if upd.t.shape[0]:
            self._pending.append(upd)
            self._pending_samples += upd.t.shape[0]
        elif fr.n_frames:
            self._pending.append(upd)
        for f in range(fr.n_frames):
            tf = float(fr.times_s[f])
            for s in self.sinks.streams:
                s.set_time(TIMELINE, duration=tf)
                for i, c in enumerate(self.keys):
                    s.log(f"/spectrum/{c}", rr.Tensor(fr.power[f, :, i], dim_names=["freq"]))
            self._scroll_push(fr.power[f], tf)
        for ev in upd.events:
            self.log_event(ev)
        if self.sinks.live or self._pending_samples >= self.batch_samples:
            self.flush()

    def flush(self) -> None:
        """Send the buffered sample series and per-frame scalars (bulk ``send_columns``)."""
        if not self._pending:
            return
        rr = self.rr
        ups, self._pending, self._pending_samples = self._pending, [], 0
        t = np.concatenate([u.t for u in ups])
        if t.size:
            tcol = rr.TimeColumn(TIMELINE, duration=t)
            ends = rr.TimeColumn(TIMELINE, duration=t[[0, -1]])
            series = {"e": np.concatenate([u.chattering for u in ups])}
            for key in ("measured", "estimate"):
                parts = [getattr(u, key) for u in ups]
                if all(p is not None for p in parts):
                    series[key] = np.concatenate(parts)
            for i, c in enumerate(self.keys):
                for key, arr in series.items():
                    path = f"/chattering/{c}/e" if key == "e" else f"/signal/{c}/{key}"
                    cols = rr.Scalars.columns(scalars=arr[:, i])
                    for s in self.sinks.streams:
                        s.send_columns(path, indexes=[tcol], columns=cols)
                if self.psi is not None:
                    for side, v in (("upper", self.psi[i]), ("lower", -self.psi[i])):
                        cols = rr.Scalars.columns(scalars=np.array([v, v]))
                        for s in self.sinks.streams:
                            s.send_columns(f"/chattering/{c}/psi_{side}", indexes=[ends], columns=cols)
        frames = [u.frames for u in ups if u.frames.n_frames]
        if frames:
            times = np.concatenate([f.times_s for f in frames])
            ratio = np.concatenate([f.peak_ratio for f in frames])
            flags = np.concatenate([f.flags for f in frames])
            fcol = rr.TimeColumn(TIMELINE, duration=times)
            for i, c in enumerate(self.keys):
                for key, vals in (
                    ("peak_ratio", ratio[:, i]),
                    ("threshold", np.ones(times.shape[0])),
                    ("verdict", flags[:, i].astype(float)),
                ):
                    cols = rr.Scalars.columns(scalars=vals)
                    for s in self.sinks.streams:
                        s.send_columns(f"/detection/{c}/{key}", indexes=[fcol], columns=cols)

    def close(self) -> None:
        """Send what is buffered, and the final scrolling spectrogram to the file."""
        self.flush()
        if self._last_frame_time is not None and self._frames_since_file_scroll:
            self._log_scroll(
                [self.sinks.file_stream] if self.sinks.file_stream else [], self._last_frame_time
            )

    def _scroll_push(self, column: np.ndarray, t: float) -> None:
        with np.errstate(divide="ignore", invalid="ignore"):
            db = 10.0 * np.log10(np.maximum(column, 1e-300) / self._expected)
        self._scroll[:, :, :-1] = self._scroll[:, :, 1:]
        self._scroll[:, :, -1] = np.clip(db, DB_RANGE[0], DB_RANGE[1]).T
        self._last_frame_time = t
        self._frames_since_file_scroll += 1
        targets = [self.sinks.live_stream] if self.sinks.live_stream is not None else []
        if self._frames_since_file_scroll >= self.file_scroll_every and self.sinks.file_stream is not None:
            targets.append(self.sinks.file_stream)
            self._frames_since_file_scroll = 0
        self._log_scroll(targets, t)

    def _log_scroll(self, targets: list[Any], t: float) -> None:
        rr = self.rr
        for s in targets:
            s.set_time(TIMELINE, duration=t)
            for i, c in enumerate(self.keys):
                s.log(
                    f"/spectrogram/{c}",
                    rr.Tensor(self._scroll[i], dim_names=["freq", "time"], value_range=list(DB_RANGE)),
                )

    def log_event(self, ev: DetectionEvent) -> None:
        rr = self.rr
        c = _entity(ev.channel)
        level = "WARN" if ev.kind == "fault-start" else "INFO"
        for s in self.sinks.streams:
            s.set_time(TIMELINE, duration=ev.time_s)
            s.log("/events", rr.TextLog(f"{ev.kind} {ev.channel}: {ev.describe()}", level=level))
            s.log(f"/state/{c}", rr.StateChange(state="fault" if ev.kind == "fault-start" else "healthy"))


# --------------------------------------------------------------------------- drivers
@dataclass(frozen=True)
class RecordingSummary:
    """Outcome of :func:`record_detection` / :func:`run_monitor`.

    Attributes
    ----------
    path : Path or None
        The ``.rrd`` written (None if no file sink).
    live_url : str or None
        The viewer streamed to (None if none or unreachable).
    events : tuple of DetectionEvent
    n_samples, n_frames : int
        Chattering samples and STFT frames processed.
    duration_s : float
        Data time covered (s).
    wall_s : float
        Wall-clock time of the run (s).
    notes : tuple of str
        Messages for the user (no display, unreachable viewer, ...).
    """

    path: Path | None
    live_url: str | None
    events: tuple[DetectionEvent, ...]
    n_samples: int
    n_frames: int
    duration_s: float
    wall_s: float
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, object]:
        return {
            "recording": None if self.path is None else str(self.path),
            "live_url": self.live_url,
            "n_samples": self.n_samples,
            "n_frames": self.n_frames,
            "duration_s": self.duration_s,
            "wall_s": self.wall_s,
            "events": [
                {
                    "kind": e.kind,
                    "channel": e.channel,
                    "time_s": e.time_s,
                    "estimate_s": e.estimate_s,
                    "frame": e.frame,
                    "peak_hz": e.peak_hz,
                    "peak_ratio": e.peak_ratio,
                }
                for e in self.events
            ],
            "notes": list(self.notes),
        }


def _pace(start_wall: float, data_elapsed: float, rate: float | None) -> None:
    if rate is None:
        return
    delay = start_wall + data_elapsed / rate - time.perf_counter()
    if delay > 0:
        time.sleep(delay)


def _chunks(total: int, size: int) -> Iterator[tuple[int, int]]:
    for lo in range(0, total, size):
        yield lo, min(lo + size, total)


def run_monitor(
    monitor: ChatteringMonitor,
    sinks: Sinks,
    *,
    z: np.ndarray | None = None,
    u: np.ndarray | None = None,
    chattering: np.ndarray | None = None,
    chunk_samples: int | None = None,
    rate: float | None = None,
    truth: list[tuple[float, str, bool]] | None = None,
    scroll_frames: int = 50,
    on_event: Any = None,
) -> RecordingSummary:
    """Drive ``monitor`` over raw data (``z`` (T, m), ``u`` (T, p)) or precomputed ``chattering`` (N, m)
    and log everything to ``sinks``; closes the sinks at the end (also on Ctrl-C).

    ``chunk_samples`` defaults to one hop. ``rate`` paces the replay (1.0 = real
    time); ``None`` runs as fast as possible. ``on_event(event)`` is called for
    each detection event (e.g. to print it).
    """
    t_start = time.perf_counter()
    events: list[DetectionEvent] = []
    size = chunk_samples or monitor.n_hop
    try:
        logger = (
            RerunLogger(sinks, monitor, scroll_frames=scroll_frames, truth=truth) if sinks.streams else None
        )
        data = chattering if chattering is not None else z
        if data is None:
            raise ValueError("give z and u, or chattering")
        total = data.shape[0]
        for lo, hi in _chunks(total, size):
            if chattering is not None:
                upd = monitor.push_chattering(chattering[lo:hi])
            else:
                upd = monitor.push(z[lo:hi], u[lo:hi])
            if logger is not None:
                logger.log_update(upd)
            for ev in upd.events:
                events.append(ev)
                if on_event is not None:
                    on_event(ev)
            _pace(t_start, hi * monitor.dt, rate)
    finally:
        try:
            if logger is not None:
                logger.close()
        finally:
            sinks.close()
    return RecordingSummary(
        path=sinks.path,
        live_url=sinks.live_url,
        events=tuple(events),
        n_samples=monitor.n_samples,
        n_frames=monitor.n_frames,
        duration_s=monitor.n_samples * monitor.dt,
        wall_s=time.perf_counter() - t_start,
        notes=tuple(sinks.notes),
    )


def _truth_from_scenario(scenario: Any) -> list[tuple[float, str, bool]]:
    from .scenarios import _same_model

    out = []
    for seg in scenario.segments:
        fault = not _same_model(seg.model, scenario.nominal)
        out.append(
            (seg.start, seg.label if fault and seg.label else ("fault" if fault else "healthy"), fault)
        )
    return out


def record_detection(
    source: Simulation | ChatteringRecord,
    settings: MonitorSettings | None = None,
    *,
    path: str | Path | None = None,
    live: str | None = None,
    run: int = 0,
    chunk_samples: int | None = None,
    rate: float | None = None,
    recording_name: str | None = None,
    application_id: str = "chatterspec",
    on_event: Any = None,
) -> RecordingSummary:
    """Run the online monitor over one realization of a simulation or chattering record and record it.

    Parameters
    ----------
    source : Simulation or ChatteringRecord
        A :class:`~chatterspec.simulate.Simulation` is filtered online from its
        raw measurements (both SVSFs, the same kernel as the batch path); a
        :class:`~chatterspec.pipeline.ChatteringRecord` is analysed from its
        chattering. The scenario's true fault timeline is logged when known.
    settings : MonitorSettings, optional
        Detector settings; ``psi`` defaults to the scenario's ``psi`` if it has one.
    path : path, optional
        ``.rrd`` file to write. With neither ``path`` nor ``live`` it defaults
        to :func:`default_recording_path` under ``recordings/``.
    live : str, optional
        ``"spawn"`` or a viewer URL (see :func:`open_sinks`).
    run : int
        Which realization (index into the leading axis).
    chunk_samples, rate : see :func:`run_monitor`.

    Returns
    -------
    RecordingSummary
    """
    from .pipeline import ChatteringRecord
    from .simulate import Simulation

    scenario = getattr(source, "scenario", None)
    name = recording_name or (scenario.name if scenario is not None else "chattering")
    settings = settings or MonitorSettings()
    if settings.psi is None and scenario is not None and scenario.psi is not None:
        settings = MonitorSettings(
            stft=settings.stft,
            alpha=settings.alpha,
            correction=settings.correction,
            gamma=settings.gamma,
            psi=tuple(scenario.psi),
        )
    if path is None and live is None:
        path = default_recording_path(name)
    truth = _truth_from_scenario(scenario) if scenario is not None else None
    if isinstance(source, Simulation):
        model = source.scenario.nominal
        mon = ChatteringMonitor(model, settings, t0=float(source.t[0]))
        kw: dict[str, Any] = {"z": source.z[run], "u": source.u}
    elif isinstance(source, ChatteringRecord):
        mon = ChatteringMonitor(source.model, settings, t0=float(source.t[0]))
        kw = {"chattering": source.values[run]}
    else:
        raise TypeError(f"source must be a Simulation or a ChatteringRecord; got {type(source).__name__}")
    sinks = open_sinks(
        record=path,
        live=live,
        application_id=application_id,
        recording_name=name,
        default_record=default_recording_path(name),
    )
    return run_monitor(
        mon, sinks, chunk_samples=chunk_samples, rate=rate, truth=truth, on_event=on_event, **kw
    )
