"""Fault identification online: an estimate and its interval per STFT hop, in bounded memory.

:class:`OnlineIdentifier` takes the same raw pushes as the online monitor
(:class:`chatterspec.online.monitor.ChatteringMonitor`): measurements ``z (K, m)`` and inputs
``u (K, p)``. It cuts the stream into blocks of one hop and keeps the identification sums of
the last ``window`` blocks (:class:`~chatterspec.detection.identification.IdentificationMoments`
add exactly over adjacent blocks); each completed block closes a window, which is identified.
Every block and window of one push is computed in one vectorized call, so a file replayed in
large pushes costs about as much per hop as a live stream pushed hop by hop. The numbers do not
depend on how the stream is cut into pushes.

Window of hop ``j``: the regressor indices ``1 + j H .. j H + W`` (``H`` samples per hop, ``W = n H``
per window): the samples of the monitor's frame ``j`` shifted by one (the first chattering sample
has no instrument).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._validate import finite_array, positive_int
from ..errors import ShapeError
from ._identification_fit import IdentificationSetup
from ._identification_moments import IdentificationMoments, compute_moments
from .identification import identify_moments
from .identification_results import Identification, IdentificationReport

__all__ = ["OnlineIdentification", "OnlineIdentifier", "hop_windows"]


@dataclass(frozen=True, eq=False)
class OnlineIdentification:
    """The windows one push completed.

    Attributes
    ----------
    frames : (F,) int array
        Window (hop) numbers, the monitor's frame numbers.
    times_s : (F,) array
        Centre time (s) of each window.
    window_s : (F, 2) array
        First and one-past-last chattering time (s) of each window.
    result : Identification or None
        One realization per window (``result.report(i)`` for window i); None when F = 0.
    """

    frames: np.ndarray
    times_s: np.ndarray
    window_s: np.ndarray
    result: Identification | None

    @property
    def n_windows(self) -> int:
        """Number of identification windows."""
        return int(self.frames.size)

    def report(self, i: int) -> IdentificationReport:
        """The :class:`~chatterspec.detection.identification_results.IdentificationReport` of window ``i``."""
        if self.result is None:
            raise IndexError("this push completed no window")
        rep = self.result.report(i)
        return dataclasses.replace(rep, window_s=(float(self.window_s[i, 0]), float(self.window_s[i, 1])))


_FIELDS = ("swx", "swe", "s0", "s1")


class OnlineIdentifier:
    """Identification per hop over a sliding window of the raw stream.

    Parameters
    ----------
    setup : IdentificationSetup
        From :func:`chatterspec.detection.identification.identification_setup`.
    hop_samples : int
        Samples per hop (the monitor's ``n_hop``).
    window_hops : int
        Hops per window (default 5: the monitor's 1 s window at a 0.2 s hop).
    t0 : float
        Time (s) of the first measurement pushed.
    alpha, confidence : float
        Test level and interval level (see :func:`~chatterspec.detection.identification.identify_moments`).
    """

    def __init__(
        self,
        setup: IdentificationSetup,
        *,
        hop_samples: int,
        window_hops: int = 5,
        t0: float = 0.0,
        alpha: float = 1e-3,
        confidence: float = 0.95,
    ) -> None:
        self.setup = setup
        self.H = positive_int("hop_samples", hop_samples)
        self.n = positive_int("window_hops", window_hops)
        self.alpha, self.confidence = alpha, confidence
        self.dt = setup.model.dt
        model = setup.model
        self._Phi_T = (model.C @ model.A @ model.C_inv).T
        self._G_T = (model.C @ model.B).T
        self.reset(t0)

    def reset(self, t0: float) -> None:
        """Start over at time ``t0`` (s), e.g. after a gap in the stream: nothing before it is used."""
        m, p = self.setup.model.n_outputs, self.setup.model.n_inputs
        self.t0 = float(t0)
        self._z = np.empty((0, m))  # raw samples from index self._first on
        self._u = np.empty((0, p))
        self._first = 0  # global index of self._z[0]
        self._next_block = 0  # block b covers regressor indices 1 + b H .. (b + 1) H
        self._history: list[IdentificationMoments] = []  # the last n - 1 blocks

    @property
    def window_s(self) -> float:
        """Window length (s)."""
        return self.n * self.H * self.dt

    def push(self, z: np.ndarray, u: np.ndarray) -> OnlineIdentification:
        """Feed ``z (K, m)`` and ``u (K, p)`` (the monitor's raw push); identify every completed window.

        Raises
        ------
        ShapeError, NonFiniteError
            On wrong shapes or NaN/inf samples.
        """
        m, p = self.setup.model.n_outputs, self.setup.model.n_inputs
        z = (
            finite_array("z", z, ndim=(1, 2)).reshape(-1, m)
            if np.ndim(z) == 1
            else finite_array("z", z, ndim=2)
        )
        u = finite_array("u", u, ndim=(1, 2))
        u = u.reshape(-1, p) if u.ndim == 1 else u
        if z.shape[1] != m or u.shape != (z.shape[0], p):
            raise ShapeError(f"z must have shape (K, {m}) and u (K, {p}); got {z.shape} and {u.shape}")
        self._z = np.concatenate([self._z, z])
        self._u = np.concatenate([self._u, u])
        # block b needs raw samples b H .. (b + 1) H + 1 (z(k-1) .. z(k+1) for k = 1 + b H .. (b + 1) H)
        have = self._first + self._z.shape[0]  # raw samples received
        n_new = max(0, (have - 2) // self.H - self._next_block)
        empty = OnlineIdentification(np.empty(0, dtype=int), np.empty(0), np.empty((0, 2)), None)
        if n_new == 0:
            return empty
        blocks = self._blocks(n_new)
        b0 = self._next_block
        self._next_block += n_new
        keep_from = self._next_block * self.H - self._first  # raw index of the next block's start
        self._z, self._u = self._z[keep_from:], self._u[keep_from:]
        self._first += keep_from
        everything = [*self._history, blocks]
        allb = _stack(everything)
        n_prev = allb.runs - n_new
        self._history = [_take(allb, slice(max(0, allb.runs - (self.n - 1)), None))] if self.n > 1 else []
        ends = np.arange(n_prev, allb.runs)  # window ends (block index in allb)
        ends = ends[ends >= self.n - 1]
        if ends.size == 0:
            return empty
        windows = _windows(allb, ends, self.n)
        frames = b0 + (ends - n_prev) - (self.n - 1)
        result = identify_moments(self.setup, windows, alpha=self.alpha, confidence=self.confidence)
        # window j: regressors 1 + j H .. j H + W, chattering e(k+1) at t0 + (k + 1) dt
        first_e = self.t0 + (frames * self.H + 2) * self.dt
        span = self.n * self.H * self.dt
        times = first_e + (self.n * self.H - 1) / 2.0 * self.dt
        win = np.stack([first_e, first_e + span], axis=1)
        return OnlineIdentification(frames=frames, times_s=times, window_s=win, result=result)

    def _blocks(self, count: int) -> IdentificationMoments:
        """Sums of the next ``count`` blocks, stacked as realizations."""
        H = self.H
        start = (
            self._next_block * H - self._first
        )  # raw index (in the buffer) of z(b H) = z(k-1), k = 1 + b H
        idx = start + np.arange(count)[:, None] * H + np.arange(H + 2)[None, :]  # (count, H + 2)
        zb, ub = self._z[idx], self._u[idx]
        e = zb[:, 1:] - zb[:, :-1] @ self._Phi_T - ub[:, :-1] @ self._G_T  # closed form, eq (23)
        t_first = self.t0 + (self._first + start + 2) * self.dt  # e(k+1) of the block's first k
        st = self.setup
        times = (t_first, t_first + H * self.dt)
        return compute_moments(zb, ub, e, st.J, st.L, st.R, 1, H + 1, times, st.swe_pairs)


def _stack(parts: list[IdentificationMoments]) -> IdentificationMoments:
    a = parts[0]

    def cat(k: str) -> np.ndarray:
        return np.concatenate([getattr(p, k) for p in parts])

    return IdentificationMoments(
        swx=cat("swx"),
        swe=cat("swe"),
        s0=cat("s0"),
        s1=cat("s1"),
        w_first=cat("w_first"),
        w_last=cat("w_last"),
        n_samples=a.n_samples,
        t_start=a.t_start,
        t_stop=a.t_stop,
    )


def _take(mom: IdentificationMoments, sl: slice) -> IdentificationMoments:
    return IdentificationMoments(
        swx=mom.swx[sl],
        swe=mom.swe[sl],
        s0=mom.s0[sl],
        s1=mom.s1[sl],
        w_first=mom.w_first[sl],
        w_last=mom.w_last[sl],
        n_samples=mom.n_samples,
        t_start=mom.t_start,
        t_stop=mom.t_stop,
    )


def _windows(blocks: IdentificationMoments, ends: np.ndarray, n: int) -> IdentificationMoments:
    """Sums of the windows of ``n`` consecutive blocks ending at ``ends`` (the S1 pairs across
    block boundaries added from the edge vectors), stacked as realizations. The blocks are added
    in a fixed order, so a window's bits do not depend on how the stream was cut into pushes."""
    starts = ends + 1 - n
    out = {k: getattr(blocks, k)[starts].copy() for k in _FIELDS}
    for i in range(1, n):
        for k in _FIELDS:
            out[k] += getattr(blocks, k)[starts + i]
        # the pair (last sample of block starts + i - 1, first of block starts + i)
        out["s1"] += blocks.w_last[starts + i - 1][:, :, None] * blocks.w_first[starts + i][:, None, :]
    return IdentificationMoments(
        **out,
        w_first=blocks.w_first[starts],
        w_last=blocks.w_last[ends],
        n_samples=n * blocks.n_samples,
        t_start=float("nan"),  # per window: OnlineIdentification.window_s
        t_stop=float("nan"),
    )


def hop_windows(
    setup: IdentificationSetup,
    z: np.ndarray,
    u: np.ndarray,
    *,
    hop_samples: int,
    window_hops: int,
    t0: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, IdentificationMoments]:
    """The sums of every hop's window of whole records at once: :class:`OnlineIdentifier`'s windows of
    each realization, vectorized over realizations and hops.

    Parameters
    ----------
    setup : IdentificationSetup
    z : (runs, T, m) array
        Measurements (finite: simulated or checked data).
    u : (T, p) or (runs, T, p) array
        Inputs.
    hop_samples, window_hops : int
        As :class:`OnlineIdentifier`.
    t0 : float
        Time (s) of ``z[:, 0]``.

    Returns
    -------
    frames : (W,) int array
        Window (hop) numbers (the monitor's frame numbers).
    times_s : (W,) array
        Window centre times (s).
    moments : IdentificationMoments
        ``runs * W`` realizations, run-major (window ``j`` of run ``r`` at ``r * W + j``).
    """
    H, n = positive_int("hop_samples", hop_samples), positive_int("window_hops", window_hops)
    z = z[None] if z.ndim == 2 else z
    runs, T, m = z.shape
    u = u.reshape(T, -1) if u.ndim == 1 else u
    count = max(0, (T - 2) // H)  # blocks: raw samples b H .. (b + 1) H + 1
    W = count - n + 1
    if W < 1:
        raise ShapeError(
            f"records of {T} samples hold {count} hop(s) of {H} samples; a window needs {n} (give longer "
            "records)"
        )
    model = setup.model
    Phi_T, G_T = (model.C @ model.A @ model.C_inv).T, (model.C @ model.B).T
    idx = np.arange(count)[:, None] * H + np.arange(H + 2)[None, :]
    zb = z[:, idx].reshape(runs * count, H + 2, m)
    p = u.shape[-1]
    ub = np.broadcast_to(u[idx] if u.ndim == 2 else u[:, idx], (runs, count, H + 2, p)).reshape(-1, H + 2, p)
    e = zb[:, 1:] - zb[:, :-1] @ Phi_T - ub[:, :-1] @ G_T  # closed form, eq (23)
    st = setup
    blocks = compute_moments(
        zb, ub, e, st.J, st.L, st.R, 1, H + 1, (float("nan"), float("nan")), st.swe_pairs
    )
    ends = (np.arange(runs)[:, None] * count + np.arange(n - 1, count)[None, :]).ravel()
    frames = np.arange(W)
    dt = model.dt
    times = t0 + (frames * H + 2) * dt + (n * H - 1) / 2.0 * dt
    return frames, times, _windows(blocks, ends, n)
