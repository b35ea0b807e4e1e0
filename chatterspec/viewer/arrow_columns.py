"""Rerun ``send_columns`` columns built straight from numpy arrays (zero-copy arrow views).

Private helpers of :mod:`chatterspec.viewer.rerun_log`: time indexes in integer
nanoseconds, float64 scalar columns and batches of ``Tensor`` rows (which
``rr.Tensor`` cannot build itself).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from .sinks import TIMELINE

if TYPE_CHECKING:  # pragma: no cover
    from types import ModuleType

__all__: list[str] = []

#: numpy dtype -> variant of Rerun's ``TensorBuffer`` union
_TENSOR_DTYPES = {
    np.dtype(np.float64): "F64",
    np.dtype(np.float32): "F32",
    np.dtype(np.float16): "F16",
}
#: Most tensors per ``send_columns`` call (keeps chunks and int32 arrow offsets small).
_MAX_TENSOR_ROWS = 256
#: Everything of a tensor batch but its values, per (rows, shape, dim names, dtype): the same for every
#: batch of one layout, so built once per process (~0.15 ms each) and shared by all loggers.
_PARTS: dict[tuple, tuple] = {}


class _ArrowBatch:
    """A ready pyarrow array as a Rerun component batch (the ``ComponentBatchLike`` protocol)."""

    __slots__ = ("array",)

    def __init__(self, array: Any) -> None:
        self.array = array

    def as_arrow_array(self) -> Any:
        return self.array


def _arrow(pa: Any, x: np.ndarray, type_: Any) -> Any:
    """Zero-copy arrow view of a 1-D numpy array (``pa.array`` copies and scans: ~25 ns per value)."""
    x = np.ascontiguousarray(x)
    buf = pa.py_buffer(x)  # keeps x alive as long as the arrow array
    return pa.Array.from_buffers(type_, x.shape[0], [None, buf])


#: numpy dtype -> arrow type of the zero-copy views
_ARROW_TYPES = {
    np.dtype(np.float64): "float64",
    np.dtype(np.float32): "float32",
    np.dtype(np.float16): "float16",
}


class _TimeIndex:
    """A ``time`` column converted to arrow once and shared by several ``send_columns`` calls."""

    __slots__ = ("array",)

    def __init__(self, pa: Any, ns: np.ndarray) -> None:
        self.array = _arrow(pa, np.asarray(ns, dtype=np.int64), pa.duration("ns"))

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

    def __init__(self, rr: ModuleType, value_range: tuple[float, float]) -> None:
        import pyarrow as pa  # a dependency of rerun-sdk

        self.rr, self.pa = rr, pa
        self.scalars = rr.Scalars.descriptor_scalars()
        self.tensor = rr.Tensor.descriptor_data()
        self.value_range = rr.Tensor.descriptor_value_range()
        self._parts = _PARTS  # shared by every logger of the process (immutable arrow arrays)
        self.value_range_row = rr.Tensor(
            np.zeros((1, 1)), value_range=list(value_range)
        ).value_range.as_arrow_array()
        self.tensors_ok = False
        try:
            for probe in (np.array([[1.0, 2.0, 3.0]]), np.arange(6, dtype=np.float16).reshape(1, 3, 2)):
                names = ("freq",) if probe.ndim == 2 else ("freq", "time")
                ref = rr.Tensor(probe[0], dim_names=list(names)).data.as_arrow_array()
                self.tensor_type = ref.type
                if not self._tensor_array(probe, names, cache=False).equals(ref):
                    return
            self.tensors_ok = True
        except Exception:  # any layout change of a future Rerun: fall back to rr.log per tensor
            self.tensors_ok = False

    def scalars_column(self, values: np.ndarray, own: bool = False) -> Any:
        """One scalar per row from a 1-D ``values``; ``k`` scalars per row (one line per column in
        Rerun's plot, e.g. one per channel) from a 2-D ``(rows, k)`` one. Rerun's cost is per row (a
        16-byte row id and an 8-byte time besides the values): 60 000 samples of 3 channels as one
        entity of 3 scalars per row plus one of 6 (measured and estimate) cost 11.4 ms CPU and 6.0 MB,
        as 3 + 3 per-channel entities 24.6 ms and 9.4 MB (send + flush + close, best of 15).

        ``own``: the caller hands ``values`` over (a fresh array it will not modify): no copy when it
        is already C-contiguous float64."""
        # otherwise a private copy (~20 us per 60k values): Rerun encodes later, the caller may reuse
        # its array
        values = np.array(values, dtype=np.float64, order="C", copy=None if own else True)
        arr = _arrow(self.pa, values.reshape(-1), self.pa.float64())
        if values.ndim == 1:
            return self.rr.ComponentColumn(self.scalars, _ArrowBatch(arr))
        k = values.shape[1]
        offsets = np.arange(0, values.size + 1, k, dtype=np.int32)
        return self.rr.ComponentColumn(self.scalars, _ArrowBatch(arr), offsets=offsets)

    def tensor_columns(
        self, data: np.ndarray, names: tuple[str, ...], *, value_range: bool = False, cache: bool = True
    ) -> list:
        """One ``Tensor`` row per ``data[k]`` (and the dB ``value_range`` on each row if asked); ``cache``
        False builds everything afresh and keeps nothing: for a layout that will not come back (the live
        spectrogram names its newest time) and for the layout probe."""
        cols = [self.rr.ComponentColumn(self.tensor, _ArrowBatch(self._tensor_array(data, names, cache)))]
        if value_range:
            vr = self.pa.concat_arrays([self.value_range_row] * data.shape[0])
            cols.append(self.rr.ComponentColumn(self.value_range, _ArrowBatch(vr)))
        return cols

    def _tensor_array(self, data: np.ndarray, names: tuple[str, ...], cache: bool = True) -> Any:
        pa, t = self.pa, self.tensor_type
        data = np.ascontiguousarray(data)
        n, shape = data.shape[0], data.shape[1:]
        key = (n, shape, names, data.dtype, t)
        parts = self._parts.get(key) if cache else None
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
            if cache:
                if len(self._parts) > 64:
                    self._parts.clear()
                self._parts[key] = parts
        shape_arr, names_arr, union, k, children, offsets, union_buffers = parts
        children = list(children)
        flat = _arrow(pa, data.reshape(-1), getattr(pa, _ARROW_TYPES[data.dtype])())
        children[k] = pa.ListArray.from_arrays(offsets, flat, type=union[k].type)
        buffer = pa.Array.from_buffers(type=union, length=n, buffers=union_buffers, children=children)
        return pa.Array.from_buffers(
            type=t, length=n, buffers=[None], children=[shape_arr, names_arr, buffer]
        )
