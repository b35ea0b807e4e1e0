"""Column-wise Rerun logging of monitor updates (:class:`RerunLogger`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.spectral import expected_frame_spectrum
from ..plants.nonlinear import is_linear
from .blueprint import _entity, blueprint
from .monitor import ChatteringMonitor, DetectionEvent, MonitorUpdate
from .viewer import DB_RANGE, TIMELINE, Sinks

if TYPE_CHECKING:
    pass

__all__ = [
    "RerunLogger",
]

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
    """Writes :class:`~chatterspec.online.monitor.MonitorUpdate` objects to the open sinks.

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
        if not is_linear(monitor.model):  # nonlinear: the calibrated threshold's empirical normalization
            self._expected = np.asarray(monitor.threshold.expected)
        else:
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
