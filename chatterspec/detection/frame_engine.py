"""The STFT column engine of :func:`chatterspec.detection.spectral.frame_columns` and the monitor.

Used by the online monitor and the alarm budget too: :class:`FrameEngine` computes the frame
spectra of :class:`~chatterspec.detection.spectral.Spectrogram` for one ``(config, dt)`` with reusable
scratch buffers; :func:`_taper_kernel` and :func:`_power_kernel` are its compiled loops (same
operations as the numpy form, same bits: tests/test_spectral.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import numpy as np
import scipy.fft

from .. import _jit
from .._stft import STFTConfig

__all__ = ["FrameEngine", "power_step"]


class FrameEngine:
    """:func:`frame_columns` for one ``(config, dt)``, unchecked, with reusable scratch buffers.

    ``ShortTimeFFT.stft(seg, k_offset=W // 2)`` computes ``rfft(seg[p H : p H + W] * win.conj(), n=W)``
    one frame per Python iteration; the same products and the same ``scipy.fft.rfft`` over a block of
    frames at once give bit-identical columns (tests/test_spectral.py) with much less CPU per frame.
    ``|Y|^2 / sum w^2`` is evaluated as ``(Re Y * Re Y + Im Y * Im Y) / scale``, the same correctly
    rounded operations as ``(Y.real**2 + Y.imag**2) / scale`` (numpy's ``x**2`` is ``x * x``), written
    straight into the ``(..., frames, bins, m)`` output. Blocks of frames keep the windowed copy
    cache-sized (2^15 values, 256 kB) whatever the runs axes.

    ``compiled=True`` (the online monitor, when :func:`chatterspec._jit.enabled`) does the taper
    product and the power in the compiled kernels :func:`_taper_kernel` and :func:`_power_kernel`
    (one pass each instead of a strided view and four ufunc passes; the same operations, hence
    the same bits: tests/test_spectral.py) for inputs with at most one runs axis; the FFT is
    ``scipy.fft.rfft`` either way. :func:`frame_columns` uses the numpy form (no numba import).

    The online monitor keeps one engine per monitor, so that a push allocates only its output
    (the windowed frames and the spectrum's real part live in buffers kept between calls):
    one engine must not be shared between threads. :func:`frame_columns` makes a new one per call.
    The caller has validated ``x`` (a float array, time on axis -2) and ``first_sample`` (int >= 0).

    Parameters
    ----------
    config : STFTConfig
        Window, hop and taper (seconds).
    dt : float
        Sampling time (s).
    compiled : bool
        Use the compiled taper and power loops (same bits as the numpy form).

    See Also
    --------
    chatterspec.detection.spectral.frame_columns : the checked public form.
    """

    def __init__(self, config: STFTConfig, dt: float, compiled: bool = False) -> None:
        self.W, self.H = config.n_window(dt), config.n_hop(dt)
        self.n_bins = self.W // 2 + 1
        w = config.taper(dt)  # the taper the batch STFT (ShortTimeFFT) is built with: the same bits
        self.win = np.ascontiguousarray(w.conj())
        self.scale = float(np.dot(w, w))
        self.compiled = compiled
        self._work: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}

    def _buffers(self, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        bufs = self._work.get(shape)
        if bufs is None:
            if len(self._work) > 4:  # a handful of shapes (full blocks, the last block, one per push size)
                self._work.clear()
            bufs = (np.empty(shape), np.empty((*shape[:-1], self.n_bins)))
            self._work[shape] = bufs
        return bufs

    def grid(self, n: int, first_sample: int) -> tuple[int, int, int]:
        """``(j_first, n_frames, offset)``: the complete global frames of ``n`` samples from ``first_sample``.

        Frame ``j_first + f`` starts at sample ``offset + f H`` of those samples.
        """
        H = self.H
        j_first = -(-first_sample // H)  # first global frame starting at or after first_sample
        j_last = (first_sample + n - self.W) // H  # last global frame ending inside x
        return j_first, max(j_last - j_first + 1, 0), j_first * H - first_sample

    def transforms(self, x: np.ndarray, offset: int, n_frames: int) -> Iterator[tuple[int, int, np.ndarray]]:
        """The compiled path's windowed transforms: ``(lo, hi, Y)`` per block of frames ``lo .. hi - 1``.

        ``x`` (n, m) or (runs, n, m); ``Y`` (runs, m, hi - lo, bins) complex, ``rfft`` of the
        tapered frames (:func:`_taper_kernel`); frame f starts at sample ``offset + f H``.
        """
        W, H = self.W, self.H
        # C-contiguous input: one compiled specialization (a copy only for strided input)
        x3 = np.ascontiguousarray(x) if x.ndim == 3 else np.ascontiguousarray(x)[None]
        m = x3.shape[2]
        block = max(1, (1 << 15) // max(1, x3.shape[0] * m * W))
        for lo in range(0, n_frames, block):
            hi = min(lo + block, n_frames)
            tapered = self._buffers((x3.shape[0], m, hi - lo, W))[0]
            _taper_kernel(x3, offset + lo * H, H, self.win, tapered)
            yield lo, hi, scipy.fft.rfft(tapered, n=W, axis=-1)

    def __call__(self, x: np.ndarray, first_sample: int) -> tuple[np.ndarray, np.ndarray]:
        W, H, n_bins = self.W, self.H, self.n_bins
        j_first, n_frames, offset = self.grid(x.shape[-2], first_sample)
        lead, m = x.shape[:-2], x.shape[-1]
        if n_frames == 0:
            return np.arange(0), np.zeros((*lead, 0, n_bins, m))
        j_last = j_first + n_frames - 1
        per_frame = max(1, math.prod(lead) * m * W)
        block = max(1, (1 << 15) // per_frame)
        power = np.empty((*lead, n_frames, n_bins, m))
        if self.compiled and x.ndim <= 3:
            p3 = power if x.ndim == 3 else power[None]
            for lo, hi, Y in self.transforms(x, offset, n_frames):
                _power_kernel(Y, self.scale, p3[:, lo:hi])
            return np.arange(j_first, j_last + 1), power
        seg = x[..., offset : offset + (n_frames - 1) * H + W, :]
        s_t, s_c = seg.strides[-2], seg.strides[-1]
        # (..., m, F, W) view: frame f of channel c is seg[..., f H : f H + W, c]
        frames = np.lib.stride_tricks.as_strided(
            seg, (*lead, m, n_frames, W), (*seg.strides[:-2], s_c, H * s_t, s_t), writeable=False
        )
        pv = np.moveaxis(power, -1, -3)  # (..., m, F, bins) view of the output
        for lo in range(0, n_frames, block):
            hi = min(lo + block, n_frames)
            tapered, re2 = self._buffers((*lead, m, hi - lo, W))
            np.multiply(frames[..., lo:hi, :], self.win, out=tapered)
            Y = scipy.fft.rfft(tapered, n=W, axis=-1)  # (..., m, f, bins)
            out = pv[..., lo:hi, :]
            np.multiply(Y.real, Y.real, out=re2)
            np.multiply(Y.imag, Y.imag, out=out)
            np.add(re2, out, out=out)
            np.divide(out, self.scale, out=out)
        return np.arange(j_first, j_last + 1), power


@_jit.njit
def _taper_kernel(
    x: np.ndarray, start: int, hop: int, win: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_spectral.py)
    """``out[r, c, f, k] = x[r, start + f hop + k, c] * win[k]``: the windowed frames (one product each).

    ``x`` (runs, n, m); ``out`` (runs, m, F, W). Compiled form of the strided view times the taper
    in :class:`FrameEngine` (same products, same bits).
    """
    runs, m, F, W = out.shape
    for r in range(runs):
        for c in range(m):
            for f in range(F):
                s = start + f * hop
                for k in range(W):
                    out[r, c, f, k] = x[r, s + k, c] * win[k]


@_jit.njit
def _power_kernel(
    Y: np.ndarray, scale: float, out: np.ndarray
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_spectral.py)
    """``out[r, f, b, c] = (Re Y[r, c, f, b]^2 + Im Y[r, c, f, b]^2) / scale`` in that order.

    ``Y`` (runs, m, F, bins) complex; ``out`` (runs, F, bins, m), any strides. No FMA contraction
    without fastmath, so each element is ``fl(fl(fl(re * re) + fl(im * im)) / scale)``, as numpy's
    ``(Y.real**2 + Y.imag**2) / scale`` (tests/test_spectral.py compares the bits).
    """
    runs, m, F, B = Y.shape
    row = np.empty(B)  # one contiguous line of bins, then scattered to the (bins, m) layout
    for r in range(runs):
        for c in range(m):
            for f in range(F):
                power_step(Y[r, c, f], scale, row, out[r, f], c, B)


@_jit.step
def power_step(y: np.ndarray, scale: float, row: np.ndarray, out: np.ndarray, c: int, B: int) -> None:
    """One frame and channel of :func:`_power_kernel`: ``out[b, c] = (Re y_b^2 + Im y_b^2) / scale``.

    ``y`` (B,) complex, ``row`` (B,) scratch (the contiguous line, then scattered to ``out`` (B, m)).
    """
    for b in range(B):
        v = y[b]
        row[b] = (v.real * v.real + v.imag * v.imag) / scale
    for b in range(B):
        out[b, c] = row[b]
