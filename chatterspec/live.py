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

Everything time-indexed is sent column-wise (``send_columns``), also the exact
spectra: one ``Tensor`` row per frame, built in bulk from numpy (``rr.Tensor`` has
no batch constructor), so a reader sees the same rows as from one ``rr.log`` per
frame. A live viewer gets every update at once; a file gets batches of ~10 s of
data (and the rest on close), which keeps logging well below the analysis cost.

The scrolling spectrogram is a 2-D float16 ``Tensor`` (dB, ``freq`` x ``time``) of the
last ``scroll_frames`` columns; it goes to a live viewer at every hop, into a file
only every ``file_scroll_every`` hops (default: one block per ``scroll_frames``, so
the blocks tile the record) and at the end (a 2-D tensor per hop would cost ~90 MB
per minute).

Default recording folder of ``chatterspec demo``: ``recordings/`` in the
current directory (git-ignored).
"""

from __future__ import annotations

import dataclasses
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
    "scenario_truth",
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

    Attributes
    ----------
    file_stream : rerun.RecordingStream or None
        Stream writing the ``.rrd`` file.
    live_stream : rerun.RecordingStream or None
        Stream to the live viewer (gRPC), sharing the file stream's recording id.
    path : Path or None
        The ``.rrd`` file being written.
    live_url : str or None
        gRPC URL of the viewer streamed to.
    notes : list of str
        Messages for the user (no display, unreachable viewer, fallback file).
    viewer_process : subprocess.Popen or None
        The viewer started by ``--live spawn`` (left running for the user).
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
            # a stream the caller set up itself (notebook viewer, memory sink) has no URL to probe
            ok, why = (True, "") if self.live_url is None else _reachable(self.live_url, timeout=1.0)
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
    below, the state lanes (verdict per channel and true fault) and the event log.

    Parameters
    ----------
    channels : tuple of str
        Measured channel names, one column of views each.
    has_truth : bool
        Add the true fault timeline lane (simulated data).
    history_s : float
        Seconds of history shown by the time-series views (cursor-relative).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
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
                    # 501 frequency rows x 50 time columns: stretch to the panel
                    view_fit="Fill",
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
#: numpy dtype -> variant of Rerun's ``TensorBuffer`` union
_TENSOR_DTYPES = {
    np.dtype(np.float64): "F64",
    np.dtype(np.float32): "F32",
    np.dtype(np.float16): "F16",
}
#: Most tensors per ``send_columns`` call (keeps chunks and int32 arrow offsets small).
_MAX_TENSOR_ROWS = 256


class _ArrowBatch:
    """A ready pyarrow array as a Rerun component batch (the ``ComponentBatchLike`` protocol)."""

    __slots__ = ("array",)

    def __init__(self, array: Any) -> None:
        self.array = array

    def as_arrow_array(self) -> Any:
        return self.array


class _TimeIndex:
    """A ``time`` column converted to arrow once and shared by several ``send_columns`` calls."""

    __slots__ = ("array",)

    def __init__(self, rr: Any, seconds: np.ndarray) -> None:
        self.array = rr.TimeColumn(TIMELINE, duration=np.asarray(seconds, dtype=float)).as_arrow_array()

    def timeline_name(self) -> str:
        return TIMELINE

    def as_arrow_array(self) -> Any:
        return self.array

    def __getitem__(self, sl: slice) -> _TimeIndex:
        out = _TimeIndex.__new__(_TimeIndex)
        out.array = self.array[sl]
        return out


class _Columns:
    """``send_columns`` component columns built straight from numpy arrays.

    ``rr.Tensor`` has no ``columns()`` batch constructor ("Tensors do not support
    batches"), so a batch of tensors is assembled here as the arrow array Rerun
    itself produces for one ``rr.log(path, rr.Tensor(...))`` per row (same
    component descriptor, same arrow type): a reader sees one ``Tensor:data`` row
    per frame either way. The layout is checked once against Rerun's own
    encoding; on any mismatch (a future Rerun) ``tensors_ok`` is False and the
    caller falls back to one ``rr.log`` per tensor.
    """

    def __init__(self, rr: Any) -> None:
        import pyarrow as pa  # a dependency of rerun-sdk

        self.rr, self.pa = rr, pa
        self.scalars = rr.Scalars.descriptor_scalars()
        self.tensor = rr.Tensor.descriptor_data()
        self.value_range = rr.Tensor.descriptor_value_range()
        self._parts: dict[tuple, tuple] = {}
        self.value_range_row = rr.Tensor(
            np.zeros((1, 1)), value_range=list(DB_RANGE)
        ).value_range.as_arrow_array()
        self.tensors_ok = False
        try:
            for probe in (np.array([[1.0, 2.0, 3.0]]), np.arange(6, dtype=np.float16).reshape(1, 3, 2)):
                names = ("freq",) if probe.ndim == 2 else ("freq", "time")
                ref = rr.Tensor(probe[0], dim_names=list(names)).data.as_arrow_array()
                self.tensor_type = ref.type
                if not self._tensor_array(probe, names).equals(ref):
                    return
            self.tensors_ok = True
        except Exception:  # any layout change of a future Rerun: fall back to rr.log per tensor
            self.tensors_ok = False

    def scalars_column(self, values: np.ndarray) -> Any:
        arr = self.pa.array(np.ascontiguousarray(values, dtype=np.float64))
        return self.rr.ComponentColumn(self.scalars, _ArrowBatch(arr))

    def tensor_columns(self, data: np.ndarray, names: tuple[str, ...], *, value_range: bool = False) -> list:
        """One ``Tensor`` row per ``data[k]`` (and the dB ``value_range`` on each row if asked)."""
        cols = [self.rr.ComponentColumn(self.tensor, _ArrowBatch(self._tensor_array(data, names)))]
        if value_range:
            vr = self.pa.concat_arrays([self.value_range_row] * data.shape[0])
            cols.append(self.rr.ComponentColumn(self.value_range, _ArrowBatch(vr)))
        return cols

    def _tensor_array(self, data: np.ndarray, names: tuple[str, ...]) -> Any:
        pa, t = self.pa, self.tensor_type
        data = np.ascontiguousarray(data)
        n, shape = data.shape[0], data.shape[1:]
        key = (n, shape, names, data.dtype)
        parts = self._parts.get(key)
        if parts is None:  # everything but the values: the same for every batch of this layout
            size, nd = int(np.prod(shape)), len(shape)
            dim_offsets = pa.array(np.arange(0, n * nd + 1, nd, dtype=np.int32))
            shape_arr = pa.ListArray.from_arrays(
                dim_offsets,
                pa.array(np.tile(np.asarray(shape, dtype=np.uint64), n)),
                type=t.field("shape").type,
            )
            names_arr = pa.ListArray.from_arrays(
                dim_offsets, pa.array(list(names) * n, type=pa.string()), type=t.field("names").type
            )
            union = t.field("buffer").type
            k = [f.name for f in union].index(_TENSOR_DTYPES[data.dtype])
            children = [pa.nulls(0, type=f.type) for f in union]
            offsets = pa.array(np.arange(0, n * size + 1, size, dtype=np.int32))
            union_buffers = [
                None,
                pa.py_buffer(np.full(n, k, np.int8)),
                pa.py_buffer(np.arange(n, dtype=np.int32)),
            ]
            parts = (shape_arr, names_arr, union, k, children, offsets, union_buffers)
            if len(self._parts) > 16:
                self._parts.clear()
            self._parts[key] = parts
        shape_arr, names_arr, union, k, children, offsets, union_buffers = parts
        children = list(children)
        children[k] = pa.ListArray.from_arrays(offsets, pa.array(data.reshape(-1)), type=union[k].type)
        buffer = pa.Array.from_buffers(type=union, length=n, buffers=union_buffers, children=children)
        return pa.Array.from_buffers(
            type=t, length=n, buffers=[None], children=[shape_arr, names_arr, buffer]
        )


@dataclass
class _Outbox:
    """Updates waiting to be sent to one stream."""

    stream: Any
    live: bool
    updates: list[MonitorUpdate] = field(default_factory=list)
    samples: int = 0
    frames: int = 0


class RerunLogger:
    """Writes :class:`~chatterspec.monitor.MonitorUpdate` objects to the open sinks.

    Everything time-indexed is sent column-wise with ``send_columns`` (one call
    per entity and batch, not one ``log`` per sample or frame): to a live viewer
    at every update, to a file in batches of ``batch_samples`` samples or
    ``batch_frames`` frames (and on :meth:`close`). The exact per-frame spectra
    go out the same way, one ``Tensor`` row per frame.

    Parameters
    ----------
    sinks : Sinks
    monitor : ChatteringMonitor
        Gives channels, frequencies, threshold and the boundary layer.
    scroll_frames : int
        Columns in the scrolling spectrogram (50 = 10 s at a 0.2 s hop).
    file_scroll_every : int, optional
        Frames between two scrolling-spectrogram tensors in the file (the live
        viewer gets one per frame); the last one is always written on close.
        Default ``scroll_frames``: the file's 2-D blocks then tile the record
        without overlap (each frame in exactly one block).
    batch_samples, batch_frames : int
        A file batch is sent once this many samples or frames are buffered.
    truth : list of (start_s, label, is_fault), optional
        True fault timeline to draw in ``/truth/plant``.
    send_blueprint : bool
        Send the default :func:`blueprint` to the sinks (default True).
    """

    def __init__(
        self,
        sinks: Sinks,
        monitor: ChatteringMonitor,
        *,
        scroll_frames: int = 50,
        file_scroll_every: int | None = None,
        batch_samples: int = 10_000,
        batch_frames: int = 50,
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
        self._expected_db = (10.0 * np.log10(np.maximum(self._expected, 1e-300))).astype(np.float32)
        # ring of the last scroll_frames columns in dB (slot j % S holds frame j)
        self._ring = np.full((self.scroll_frames, bins, m), DB_RANGE[0], dtype=np.float16)
        self._ring_n = 0
        self._since_file_scroll = 0
        self._file_block_t0 = 0.0
        self.file_scroll_every = int(file_scroll_every or self.scroll_frames)
        self.batch_samples = int(batch_samples)
        self.batch_frames = int(batch_frames)
        self._cols = _Columns(rr)
        self._boxes = [_Outbox(s, live=s is sinks.live_stream) for s in sinks.streams]
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
                        colors=np.array([0x4CAF50FF, 0xEF5350FF], dtype=np.uint32),
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
                        colors=np.array(
                            [0x9E9E9EFF if lab == "healthy" else 0xFF9800FF for lab in labels],
                            dtype=np.uint32,
                        ),
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
        """Queue one update; send it at once to a live viewer, in batches to a file."""
        fr = upd.frames
        if upd.t.shape[0] or fr.n_frames:
            for box in self._boxes:
                box.updates.append(upd)
                box.samples += upd.t.shape[0]
                box.frames += fr.n_frames
                if box.live or box.samples >= self.batch_samples or box.frames >= self.batch_frames:
                    self._send(box)
        if fr.n_frames:
            self._scroll(fr)

    def flush(self) -> None:
        """Send everything buffered (bulk ``send_columns``)."""
        for box in self._boxes:
            self._send(box)

    def close(self) -> None:
        """Send what is buffered, and the final scrolling spectrogram to the file."""
        self.flush()
        if self._last_frame_time is not None and self._since_file_scroll and self.sinks.file_stream:
            self._log_scroll([self.sinks.file_stream], self._file_block_t0)
            self._since_file_scroll = 0

    def _send(self, box: _Outbox) -> None:
        if not box.updates:
            return
        ups, box.updates, box.samples, box.frames = box.updates, [], 0, 0
        s, cols = box.stream, self._cols
        t = np.concatenate([u.t for u in ups]) if len(ups) > 1 else ups[0].t
        if t.size:
            tcol = _TimeIndex(self.rr, t)
            series = {"e": np.concatenate([u.chattering for u in ups])}
            for key in ("measured", "estimate"):
                parts = [getattr(u, key) for u in ups]
                if all(p is not None for p in parts):
                    series[key] = np.concatenate(parts)
            ends = _TimeIndex(self.rr, t[[0, -1]])
            for i, c in enumerate(self.keys):
                for key, arr in series.items():
                    path = f"/chattering/{c}/e" if key == "e" else f"/signal/{c}/{key}"
                    s.send_columns(path, indexes=[tcol], columns=[cols.scalars_column(arr[:, i])])
                if self.psi is not None:
                    for side, v in (("upper", self.psi[i]), ("lower", -self.psi[i])):
                        col = cols.scalars_column(np.array([v, v]))
                        s.send_columns(f"/chattering/{c}/psi_{side}", indexes=[ends], columns=[col])
        frames = [u.frames for u in ups if u.frames.n_frames]
        if frames:
            times = np.concatenate([f.times_s for f in frames])
            power = np.concatenate([f.power for f in frames])
            ratio = np.concatenate([f.peak_ratio for f in frames])
            flags = np.concatenate([f.flags for f in frames])
            fcol = _TimeIndex(self.rr, times)
            ones = np.ones(times.shape[0])
            for i, c in enumerate(self.keys):
                self._send_spectra(s, f"/spectrum/{c}", fcol, times, power[:, :, i])
                for key, vals in (("peak_ratio", ratio[:, i]), ("threshold", ones), ("verdict", flags[:, i])):
                    col = cols.scalars_column(vals)
                    s.send_columns(f"/detection/{c}/{key}", indexes=[fcol], columns=[col])
        events = [ev for u in ups for ev in u.events]
        if events:
            self._send_events(s, events)

    def _send_spectra(
        self, s: Any, path: str, tcol: _TimeIndex, times: np.ndarray, power: np.ndarray
    ) -> None:
        """One exact (float64) ``Tensor`` row per frame: ``power`` is (frames, bins)."""
        if not self._cols.tensors_ok:
            for f in range(power.shape[0]):
                s.set_time(TIMELINE, duration=float(times[f]))
                s.log(path, self.rr.Tensor(power[f], dim_names=["freq"]))
            return
        for lo in range(0, power.shape[0], _MAX_TENSOR_ROWS):
            hi = lo + _MAX_TENSOR_ROWS
            cols = self._cols.tensor_columns(power[lo:hi], ("freq",))
            s.send_columns(path, indexes=[tcol[lo:hi]], columns=cols)

    def _send_events(self, s: Any, events: list[DetectionEvent]) -> None:
        rr = self.rr
        tcol = _TimeIndex(rr, np.array([ev.time_s for ev in events]))
        text = [f"{ev.kind} {ev.channel}: {ev.describe()}" for ev in events]
        level = ["WARN" if ev.kind == "fault-start" else "INFO" for ev in events]
        s.send_columns("/events", indexes=[tcol], columns=rr.TextLog.columns(text=text, level=level))
        for i, c in enumerate(self.keys):
            mine = [k for k, ev in enumerate(events) if ev.channel_index == i]
            if mine:
                state = ["fault" if events[k].kind == "fault-start" else "healthy" for k in mine]
                s.send_columns(
                    f"/state/{c}",
                    indexes=[_TimeIndex(rr, np.array([events[k].time_s for k in mine]))],
                    columns=rr.StateChange.columns(state=state),
                )

    # ------------------------------------------------------------------ scrolling spectrogram
    def _scroll(self, fr: Any) -> None:
        """Push the frames' dB columns into the ring; a live viewer gets the 2-D view after every
        frame, the file one view every ``file_scroll_every`` frames."""
        live, file = self.sinks.live_stream, self.sinks.file_stream
        every = self.file_scroll_every
        F, lo = fr.n_frames, 0
        while lo < F:
            step = 1 if live is not None else max(1, min(F - lo, every - self._since_file_scroll))
            if self._since_file_scroll == 0:
                self._file_block_t0 = float(fr.times_s[lo])
            self._ring_put(fr.power[lo : lo + step])
            lo += step
            self._since_file_scroll += step
            if live is not None:
                self._log_scroll([live], float(fr.times_s[lo - 1]))
            if file is not None and self._since_file_scroll >= every:
                # a file block is stamped with its FIRST frame's time, so that a reviewer
                # scrubbing through the recording sees the block that covers the cursor
                self._log_scroll([file], self._file_block_t0)
                self._since_file_scroll = 0
        self._last_frame_time = float(fr.times_s[-1])

    def _ring_put(self, power: np.ndarray) -> None:
        S, n_all = self.scroll_frames, power.shape[0]
        power = power[-S:]  # older frames would be overwritten in the ring anyway
        n = power.shape[0]
        with np.errstate(divide="ignore", invalid="ignore"):  # 0 -> -inf -> clipped
            db = np.log10(power.astype(np.float32))  # float32 is plenty for a float16 image
        db *= 10.0
        db -= self._expected_db
        np.clip(db, DB_RANGE[0], DB_RANGE[1], out=db)
        self._ring_n += n_all
        self._ring[(self._ring_n - n + np.arange(n)) % S] = db

    def _scroll_image(self) -> np.ndarray:
        """(m, bins, S) float16, oldest column left (blank columns before the first frames)."""
        S = self.scroll_frames
        return np.transpose(self._ring[(self._ring_n + np.arange(S)) % S], (2, 1, 0))

    def _log_scroll(self, targets: list[Any], t: float) -> None:
        rr = self.rr
        img = self._scroll_image()
        tcol = _TimeIndex(rr, np.array([t]))
        for s in targets:
            for i, c in enumerate(self.keys):
                if self._cols.tensors_ok:
                    cols = self._cols.tensor_columns(img[i][None], ("freq", "time"), value_range=True)
                    s.send_columns(f"/spectrogram/{c}", indexes=[tcol], columns=cols)
                else:
                    s.set_time(TIMELINE, duration=t)
                    s.log(
                        f"/spectrogram/{c}",
                        rr.Tensor(img[i], dim_names=["freq", "time"], value_range=list(DB_RANGE)),
                    )

    def log_event(self, ev: DetectionEvent) -> None:
        """Log one detection event at once (text log and state lane) to every stream."""
        for s in self.sinks.streams:
            self._send_events(s, [ev])


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

    Parameters
    ----------
    monitor : ChatteringMonitor
        The online monitor to drive.
    sinks : Sinks
        Where to log (see :func:`open_sinks`); closed at the end.
    z, u : arrays, optional
        Raw measurements (T, m) and inputs (T, p): both SVSFs run online.
    chattering : array, optional
        Precomputed chattering (N, m) instead of ``z``/``u``.
    chunk_samples : int, optional
        Samples per push; default one hop when paced and five hops otherwise
        (the output does not depend on it).
    rate : float, optional
        Replay speed (1.0 = real time); ``None`` runs as fast as possible.
    truth : list of (start_s, label, is_fault), optional
        True fault timeline for the viewer.
    scroll_frames : int
        Columns of the scrolling spectrogram.
    on_event : callable, optional
        Called with each :class:`~chatterspec.monitor.DetectionEvent` (e.g. to print it).

    Returns
    -------
    RecordingSummary
    """
    t_start = time.perf_counter()
    events: list[DetectionEvent] = []
    # paced replays push one hop at a time (smooth live view); unpaced runs push 5 hops
    # (the output does not depend on the chunking, only the per-call overhead does)
    size = chunk_samples or (monitor.n_hop if rate is not None else 5 * monitor.n_hop)
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


def scenario_truth(scenario: Any) -> list[tuple[float, str, bool]]:
    """The true fault timeline of a scenario, as the viewer's truth lane takes it.

    Parameters
    ----------
    scenario : Scenario
        A simulated scenario (its segments of true plant).

    Returns
    -------
    list of (start_s, label, is_fault)
        One entry per segment: start time (s), label, and whether the true plant
        differs from the nominal model there.
    """
    out = []
    for seg in scenario.segments:
        fault = scenario.deviates(seg)
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
    recording_name : str, optional
        Name shown in the viewer (default: the scenario name).
    application_id : str
        Rerun application id.
    on_event : callable, optional
        Called with each detection event.

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
        settings = dataclasses.replace(settings, psi=tuple(scenario.psi))
    if path is None and live is None:
        path = default_recording_path(name)
    truth = scenario_truth(scenario) if scenario is not None else None
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
