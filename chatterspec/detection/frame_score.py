"""The chattering route's frame score: ``-log p`` of each STFT frame and channel.

``p`` is the Bonferroni p-value of the frame's largest bin over the ``n`` tested bins,
``p = min(1, n * min_k p_k)``, with ``p_k = P(S_k > s_k)`` the p-value of bin ``k`` under
its healthy law, so the score is

    score = max(0, max_k (-log p_k) - log n)     (nats; 0 when the frame looks healthy)

and the per-frame rule at level ``alpha`` (:func:`chatterspec.detection.thresholds.frame_threshold`,
Bonferroni) flags exactly the frames with ``score >= -log(alpha)`` (up to the 1e-10 relative
tolerance of the threshold's quantile). Under the healthy law ``P(p <= x) <= x``, so a healthy
score exceeds ``h`` with probability at most ``exp(-h)``. The score feeds the alarm rules of
:mod:`chatterspec.detection.alarms.streams` (e.g. a CUSUM ``g = max(0, g + score - drift)``).

Laws
    ``exact`` (a threshold with ``eigenvalues``, i.e. a linear model): a healthy frame bin is
    ``S = l1 Z1^2 + l2 Z2^2`` (:func:`chatterspec.detection.spectral.frame_eigenvalues`). With
    ``Z = R (cos phi, sin phi)`` (``R^2`` exponential with mean 2, ``phi`` uniform)
    ``P(S > s) = (1 / pi) int_0^pi exp(-s / (2 lambda(phi))) dphi``,
    ``lambda = l1 cos^2 phi + l2 sin^2 phi``, hence, with ``u = s / (2 l1)`` and ``r = l2 / l1``,

        -log p_k = u - log J(u),   J(u) = (1 / pi) int_0^pi exp(-u c(phi)) dphi,
        c(phi) = (1 - r) sin^2 phi / (cos^2 phi + r sin^2 phi) >= 0.

    ``J`` is the mean of a smooth periodic function, which the trapezoid rule integrates with
    exponential accuracy; the node count of each bin is doubled at construction until ``log J``
    changes by less than 1e-13 at ``u = 200`` (``-log p_k`` about 200; larger scores keep the
    rule's bounds below and only ever raise alarms), 2 nodes for the ``r ~ 1`` bins that make up
    almost the whole band, up to 64 for the lowest bins. ``r = 1`` gives ``J = 1`` (``l chi2(2)``).
    ``exponential`` (a threshold without eigenvalues but with ``expected`` ``E``, e.g. the
    empirical normalization of a calibrated nonlinear model): every bin is taken as ``E chi2(2) / 2``,
    ``-log p_k = S / E``. This law is an approximation there, so the thresholds of the alarm rules
    on it must come from simulated healthy streams (they do: :mod:`.alarm_calibration`).

Cost
    A special function on every bin of every frame would cost more than the monitor's whole
    analysis. Since ``u <= -log p_k <= u / r`` (``c`` lies in ``[0, (1 - r) / r]``), one pass over
    the tested bins computes ``u`` (one product per bin) and keeps its two largest values; ``J`` is
    evaluated at the bin of largest ``u``, then at the few "low" bins (``r`` well below 1: the
    lowest frequencies, ``r`` down to 0.44 on the EHA position channel) whose bound ``u / r``
    exceeds the best exact value, and at the other bins only when the second largest ``u`` times
    their common bound ``max 1 / r <= 1 + LOW_GAP`` exceeds it (about 1 frame in 100): usually one
    special-function evaluation per frame and channel.

Paths
    :class:`FrameScore` runs the compiled kernel :func:`_score_kernel` when
    :func:`chatterspec._jit.enabled`, otherwise numpy for the bounds and the same scalar code
    (:func:`_exact_log_sf`, ``math.exp`` / ``math.log``, nodes summed in order) at the candidate
    bins; the two agree to rounding (``tests/test_frame_score.py``: relative 1e-13).

See Also
--------
chatterspec.detection.thresholds.frame_threshold : the per-frame threshold at a fixed alpha.
chatterspec.detection.thresholds.weighted_chi2_sf : the same law by Gauss-Legendre quadrature.
"""

from __future__ import annotations

import math

import numpy as np

from .. import _jit
from ..errors import ParameterError
from ..plants.models import LinearModel
from .spectral import STFTConfig
from .thresholds import Threshold

__all__ = ["FrameScore", "frame_scores"]

#: ``u`` (about ``-log p_k``) at which the trapezoid rule is converged to 1e-13 in ``log J``.
U_CONVERGED = 200.0
#: Bins with ``l1 / l2 > 1 + LOW_GAP`` are checked one by one; the others share one bound.
LOW_GAP = 1e-3
_TOL = 1e-13
_MAX_NODES = 4096


def _half_nodes(r: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Trapezoid nodes on ``[0, pi)`` folded by the symmetry ``phi -> pi - phi``: ``(c, w)``.

    ``r`` (q,) -> ``c`` (q, N/2 + 1) = ``c(phi_j)``, ``phi_j = pi j / N``, and weights ``w``
    (N/2 + 1,) = ``(1, 2, ..., 2, 1) / N`` summing to 1.
    """
    phi = np.pi * np.arange(N // 2 + 1) / N
    s2, c2 = np.sin(phi) ** 2, np.cos(phi) ** 2
    r = r[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(s2 > 0, (1.0 - r) * s2 / (c2 + r * s2), 0.0)
    w = np.full(N // 2 + 1, 2.0 / N)
    w[0] = w[-1] = 1.0 / N
    return c, w


def _log_j(u: float, c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``log J(u)`` by the folded trapezoid rule, rows of ``c``."""
    with np.errstate(invalid="ignore"):
        t = np.where(np.isinf(c), 0.0, np.exp(-u * np.where(np.isinf(c), 0.0, c)))
    return np.log(t @ w)


def _node_tables(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per element of ``r`` (flat, ``0 <= r <= 1``): converged node tables, ragged.

    Returns ``(offset, count, c_values, weights)``: element ``i`` uses ``c_values[offset[i] :
    offset[i] + count[i]]`` with the matching ``weights``; ``count = 0`` means ``J = 1``
    (``r = 1``, the plain exponential law).
    """
    q = r.size
    count = np.zeros(q, dtype=np.int64)
    tables: list[tuple[np.ndarray, np.ndarray] | None] = [None] * q
    todo = np.flatnonzero(r < 1.0)
    N = 2
    prev_c, prev_w = _half_nodes(r[todo], N)
    prev = _log_j(U_CONVERGED, prev_c, prev_w)
    while todo.size:
        if N > _MAX_NODES:  # pragma: no cover - r -> 0 only (a bin with one degree of freedom)
            for i, row in enumerate(todo):
                tables[row] = (prev_c[i], prev_w)
            break
        c2, w2 = _half_nodes(r[todo], 2 * N)
        cur = _log_j(U_CONVERGED, c2, w2)
        done = np.abs(cur - prev) <= _TOL * np.maximum(1.0, np.abs(cur))
        for j in np.flatnonzero(done):
            tables[todo[j]] = (prev_c[j], prev_w)  # N nodes already agree with 2N
        keep = ~done
        todo, prev_c, prev, prev_w = todo[keep], c2[keep], cur[keep], w2
        N *= 2
    offset = np.zeros(q, dtype=np.int64)
    cs: list[np.ndarray] = []
    ws: list[np.ndarray] = []
    pos = 0
    for i, table in enumerate(tables):
        offset[i] = pos
        if table is not None:
            count[i] = table[0].size
            cs.append(table[0])
            ws.append(table[1])
            pos += table[0].size
    cvals = np.concatenate(cs) if cs else np.zeros(0)
    wvals = np.concatenate(ws) if ws else np.zeros(0)
    return offset, count, np.ascontiguousarray(cvals), np.ascontiguousarray(wvals)


@_jit.njit
def _exact_log_sf(u: float, off: int, cnt: int, cvals: np.ndarray, wvals: np.ndarray) -> float:
    """``-log p_k = u - log J(u)`` of one bin from its node table (``cnt = 0``: ``J = 1``)."""
    if cnt == 0 or u <= 0.0:
        return u
    acc = 0.0
    for t in range(off, off + cnt):
        x = u * cvals[t]
        if x < 745.2:  # exp(-x) underflows to 0 beyond (and c = inf at r = 0)
            acc += wvals[t] * math.exp(-x)
    return u - math.log(acc)


@_jit.njit
def _score_kernel(
    power: np.ndarray,
    idx: np.ndarray,
    inv1: np.ndarray,
    invr: np.ndarray,
    off: np.ndarray,
    cnt: np.ndarray,
    cvals: np.ndarray,
    wvals: np.ndarray,
    low: np.ndarray,
    n_low: np.ndarray,
    is_low: np.ndarray,
    hi_invr: np.ndarray,
    inv1T: np.ndarray,
    log_n: float,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_frame_score.py)
    """Frame scores of ``power`` (F, bins, m) over the tested bins ``idx`` into ``out`` (F, m).

    ``inv1`` = 1 / (2 l1), ``invr`` = l1 / l2 (>= 1, inf for l2 = 0), ``off`` / ``cnt`` the node
    tables of :func:`_node_tables`, ``is_low`` (bool), all (n_tested, m). The "low" bins of channel
    ``c`` (``r < 1 / (1 + LOW_GAP)``, a handful at the lowest frequencies) are ``low[c, :n_low[c]]``;
    every other bin has ``invr <= hi_invr[c]``; ``inv1T`` is ``inv1`` channel-major (m, n_tested).
    One pass takes ``u = S inv1``, its largest value ``A``
    (bin ``kA``) and the second largest ``U2``; the exact value at ``kA`` is then compared with the
    upper bounds ``u invr`` of the low bins and, only when ``U2 hi_invr`` exceeds it (rare), of every
    other bin: the maximum of the exact values over the bins that can hold it.
    """
    F = power.shape[0]
    m = power.shape[2]
    for f in range(F):
        for c in range(m):
            e = score_step(
                power, f, c, idx, inv1, invr, off, cnt, cvals, wvals, low, n_low, is_low, hi_invr, inv1T
            )
            out[f, c] = max(e - log_n, 0.0)


@_jit.step
def score_step(
    power: np.ndarray,
    f: int,
    c: int,
    idx: np.ndarray,
    inv1: np.ndarray,
    invr: np.ndarray,
    off: np.ndarray,
    cnt: np.ndarray,
    cvals: np.ndarray,
    wvals: np.ndarray,
    low: np.ndarray,
    n_low: np.ndarray,
    is_low: np.ndarray,
    hi_invr: np.ndarray,
    inv1T: np.ndarray,
) -> float:  # pragma: no cover - compiled (inlined into _score_kernel and the monitor's hop loop)
    """``max_k -log p_k`` of frame ``f``, channel ``c`` (arguments of :func:`_score_kernel`)."""
    nt = idx.shape[0]
    lo = idx[0]
    contiguous = idx[nt - 1] - lo == nt - 1  # the usual case: a slice of bins, no index loads
    A = -1.0
    kA = 0
    U2 = -1.0
    w = inv1T[c]
    for j in range(nt):
        u = (power[f, lo + j, c] if contiguous else power[f, idx[j], c]) * w[j]
        if u > U2:
            if u > A:
                U2 = A
                A = u
                kA = j
            else:
                U2 = u
    e = _exact_log_sf(A, off[kA, c], cnt[kA, c], cvals, wvals)
    for t in range(n_low[c]):
        j = low[c, t]
        if j != kA:
            u = power[f, idx[j], c] * inv1[j, c]
            if u * invr[j, c] > e:
                ej = _exact_log_sf(u, off[j, c], cnt[j, c], cvals, wvals)
                if ej > e:
                    e = ej
    if U2 * hi_invr[c] > e:
        for j in range(nt):
            if j != kA and not is_low[j, c]:
                u = power[f, idx[j], c] * inv1[j, c]
                if u * invr[j, c] > e:
                    ej = _exact_log_sf(u, off[j, c], cnt[j, c], cvals, wvals)
                    if ej > e:
                        e = ej
    return e


class FrameScore:
    """``-log`` Bonferroni p-value of each frame and channel (see the module docstring).

    Parameters
    ----------
    threshold : Threshold
        A per-frame threshold that says which bins are tested (its ``tested``, hence its
        ``band``) and carries the healthy law: ``eigenvalues`` (``law="exact"``, from
        :func:`~chatterspec.detection.thresholds.frame_threshold`) or, failing that,
        ``expected`` (the exponential law; e.g. a calibration's ``threshold("frame-family-wise")``).
        Its ``values`` and ``alpha`` are not used.
    compiled : bool, optional
        Use the compiled kernel (default: :func:`chatterspec._jit.enabled` at each call).

    Attributes
    ----------
    law : {"exact", "exponential"}
    n_tested : int
        ``n`` of the Bonferroni correction.
    freqs_hz : (bins,) array
    tested : (bins,) bool array

    Raises
    ------
    ParameterError
        A threshold without ``eigenvalues`` and ``expected``, or a tested bin whose healthy
        power is 0 (no law to test against).

    Examples
    --------
    >>> import numpy as np
    >>> from chatterspec.plants.models import eha_linear
    >>> from chatterspec.detection.spectral import STFTConfig
    >>> from chatterspec.detection.thresholds import frame_threshold
    >>> m, cfg = eha_linear(), STFTConfig()
    >>> th = frame_threshold(m, cfg.freqs_hz(m.dt), cfg, m.dt, alpha=1e-3)
    >>> score = FrameScore(th)
    >>> power = th.values[None].copy()     # one frame exactly at the 0.1 % per-frame threshold
    >>> bool(np.allclose(score(power), -np.log(1e-3), rtol=1e-7))
    True
    """

    def __init__(self, threshold: Threshold, compiled: bool | None = None) -> None:
        if not isinstance(threshold, Threshold):
            raise ParameterError(f"threshold must be a Threshold; got {type(threshold).__name__}")
        tested = np.asarray(threshold.tested, dtype=bool)
        idx = np.flatnonzero(tested)
        if threshold.eigenvalues is not None:
            ev = np.asarray(threshold.eigenvalues, dtype=float)[idx]
            l1, l2 = np.maximum(ev[..., 0], ev[..., 1]), np.minimum(ev[..., 0], ev[..., 1])
            self.law = "exact"
        elif threshold.expected is not None:
            l1 = l2 = 0.5 * np.asarray(threshold.expected, dtype=float)[idx]
            self.law = "exponential"
        else:
            raise ParameterError(
                "the frame score needs the healthy law of each bin: a threshold with eigenvalues "
                "(frame_threshold of a linear model) or an expected spectrum (a calibration)"
            )
        if not (np.all(np.isfinite(l1)) and np.all(l1 > 0) and np.all(l2 >= 0)):
            raise ParameterError(
                "every tested bin needs a positive, finite healthy power for the frame score"
            )
        self.freqs_hz = np.asarray(threshold.freqs_hz, dtype=float)
        self.tested = tested
        self.n_tested = int(idx.size)
        self.n_channels = int(l1.shape[1])
        self.log_n = math.log(self.n_tested)
        self._idx = np.ascontiguousarray(idx, dtype=np.int64)
        self._inv1 = np.ascontiguousarray(0.5 / l1)
        with np.errstate(divide="ignore"):
            self._invr = np.ascontiguousarray(np.where(l2 > 0, l1 / np.where(l2 > 0, l2, 1.0), np.inf))
        r = np.where(l1 > 0, l2 / l1, 1.0)
        r = np.where(l2 == l1, 1.0, np.clip(r, 0.0, 1.0))
        off, cnt, self._cvals, self._wvals = _node_tables(r.ravel())
        self._off = np.ascontiguousarray(off.reshape(r.shape))
        self._cnt = np.ascontiguousarray(cnt.reshape(r.shape))
        invr = self._invr
        is_low = invr > 1.0 + LOW_GAP
        self._is_low = np.ascontiguousarray(is_low)
        self._n_low = np.ascontiguousarray(is_low.sum(axis=0).astype(np.int64))
        self._low = np.zeros((self.n_channels, max(1, int(self._n_low.max()))), dtype=np.int64)
        for c in range(self.n_channels):
            js = np.flatnonzero(is_low[:, c])
            self._low[c, : js.size] = js
        self._hi_invr = np.ascontiguousarray(
            np.array([invr[~is_low[:, c], c].max(initial=1.0) for c in range(self.n_channels)])
        )
        self._kernel_args = (
            self._idx, self._inv1, self._invr, self._off, self._cnt, self._cvals, self._wvals,
            self._low, self._n_low, self._is_low, self._hi_invr, np.ascontiguousarray(self._inv1.T),
            self.log_n,
        )  # fmt: skip
        self._compiled = compiled
        self._exact_py = getattr(_exact_log_sf, "py_func", _exact_log_sf)

    @classmethod
    def from_model(
        cls,
        model: LinearModel,
        config: STFTConfig,
        band: tuple[float, float] | None = None,
    ) -> FrameScore:
        """The exact-law score of a linear model's STFT frames (``config``: an ``STFTConfig``)."""
        from .thresholds import frame_threshold

        dt = model.dt
        th = frame_threshold(model, config.freqs_hz(dt), config, dt, 0.5, band=band)
        return cls(th)

    def bin_scores(self, power: np.ndarray) -> np.ndarray:
        """``-log p_k`` of every tested bin ``(..., frames, n_tested, m)`` (for tests and plots; slow)."""
        p = np.asarray(power, dtype=float)[..., self._idx, :]
        u = p * self._inv1
        out = np.empty(u.shape)
        it = np.nditer(u, flags=["multi_index"])
        for _ in it:
            j, c = it.multi_index[-2], it.multi_index[-1]
            out[it.multi_index] = self._exact_py(
                float(u[it.multi_index]), int(self._off[j, c]), int(self._cnt[j, c]), self._cvals, self._wvals
            )
        return out

    def __call__(self, power: np.ndarray) -> np.ndarray:
        """Scores ``(..., frames, m)`` of frame spectra ``power`` ``(..., frames, bins, m)`` (finite, >= 0).

        Raises
        ------
        ParameterError
            If the last two axes are not this score's ``(bins, m)``.
        """
        p = np.asarray(power, dtype=float)
        if p.ndim < 3 or p.shape[-2] != self.tested.size or p.shape[-1] != self.n_channels:
            raise ParameterError(
                f"power must have shape (..., frames, {self.tested.size}, {self.n_channels}); got {p.shape}"
            )
        compiled = _jit.enabled() if self._compiled is None else self._compiled
        lead = p.shape[:-2]
        flat = p.reshape(-1, *p.shape[-2:])
        out = np.empty((flat.shape[0], self.n_channels))
        if compiled and _jit.HAVE_NUMBA:
            _score_kernel(flat, *self._kernel_args, out)
        else:
            self._numpy(flat, out)
        return out.reshape(*lead, self.n_channels)

    def _unchecked(self, power: np.ndarray) -> np.ndarray:
        """:meth:`__call__` for ``(F, bins, m)`` float arrays of the right shape (the monitor calls it)."""
        out = np.empty((power.shape[0], self.n_channels))
        if self._compiled and _jit.HAVE_NUMBA:
            _score_kernel(power, *self._kernel_args, out)
        elif self._compiled is None:
            return self(power)
        else:
            self._numpy(power, out)
        return out

    def _numpy(self, power: np.ndarray, out: np.ndarray) -> None:
        """Bounds vectorized; the exact value at the candidate bins by the kernel's scalar code."""
        u = power[:, self._idx, :] * self._inv1  # (F, nt, m)
        kA = np.argmax(u, axis=1)  # (F, m): first maximum, as the kernel's strict '>'
        A = np.take_along_axis(u, kA[:, None, :], axis=1)[:, 0, :]
        ex, cv, wv, off, cnt = self._exact_py, self._cvals, self._wvals, self._off, self._cnt
        F, m = A.shape
        e = np.empty((F, m))
        for f in range(F):
            for c in range(m):
                k = int(kA[f, c])
                e[f, c] = ex(float(A[f, c]), int(off[k, c]), int(cnt[k, c]), cv, wv)
        v = u * self._invr
        cand = v > e[:, None, :]
        cand[np.arange(F)[:, None], kA, np.arange(m)[None, :]] = False
        for f, j, c in zip(*np.nonzero(cand), strict=True):
            ej = ex(float(u[f, j, c]), int(off[j, c]), int(cnt[j, c]), cv, wv)
            if ej > e[f, c]:
                e[f, c] = ej
        np.maximum(e - self.log_n, 0.0, out=out)


def frame_scores(power: np.ndarray, threshold: Threshold) -> np.ndarray:
    """``-log`` Bonferroni p-value ``(..., frames, m)`` of frame spectra (one-off :class:`FrameScore`).

    Parameters
    ----------
    power : (..., frames, bins, m) array
        Frame spectra (:func:`chatterspec.detection.spectral.frame_columns`).
    threshold : Threshold
        Gives the tested bins and the healthy law (see :class:`FrameScore`).
    """
    return FrameScore(threshold)(power)
