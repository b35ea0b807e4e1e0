"""Sums of products that fault identification needs, per realization and window (private module).

Identification regresses the chattering ``e(k+1)`` on regressors ``x(k) = [z_J(k), u_L(k)]``
with instruments ``w(k) = [z_J(k-1), u_L(k)]`` (see :mod:`chatterspec.detection.identification`).
Everything it needs from the data is four sums over the window's sample indices ``k``::

    Swx = sum w(k) x(k)'      Swe = sum w(k) e_R(k+1)'
    S0  = sum w(k) w(k)'      S1  = sum w(k) w(k+1)'     (pairs inside the window)

plus the instrument vectors at the window's first and last sample, so that the sums of two
adjacent windows add up exactly to the sums of their union (the online form adds hops).
The sums are additive over realizations too (the pooled estimate of many records).

They are computed as dot products of channel-major rows (``numpy.vecdot``, vectorized;
the views need no copy when the data are stored channel by channel, as the fused
simulation kernel writes them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["IdentificationMoments", "compute_moments"]


@dataclass(frozen=True, eq=False)
class IdentificationMoments:
    """The sums of one window for ``runs`` realizations (leading axis).

    Attributes
    ----------
    swx, s0, s1 : (runs, q, q) arrays
        ``sum w x'``, ``sum w w'``, ``sum w(k) w(k+1)'``.
    swe : (runs, q, r) arrays
        ``sum w e_R(k+1)'``.
    w_first, w_last : (runs, q) arrays
        Instrument vector at the window's first and last sample index.
    n_samples : int
        Number of sample indices k in the window (per realization).
    t_start, t_stop : float
        Times (s) of the first and one past the last chattering sample ``e(k+1)`` used.
    records : int
        Realizations summed into each row (1, or R for a pooled total).
    """

    swx: np.ndarray
    swe: np.ndarray
    s0: np.ndarray
    s1: np.ndarray
    w_first: np.ndarray
    w_last: np.ndarray
    n_samples: int
    t_start: float
    t_stop: float
    records: int = 1

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.swx.shape[0]

    def then(self, later: IdentificationMoments) -> IdentificationMoments:
        """Sums over this window followed by the adjacent window ``later`` (same realizations).

        Exact: the lag-1 pair that straddles the boundary is added from the edge vectors.
        """
        if self.n_samples == 0:
            return later
        if later.n_samples == 0:
            return self
        bridge = self.w_last[:, :, None] * later.w_first[:, None, :]
        return IdentificationMoments(
            swx=self.swx + later.swx,
            swe=self.swe + later.swe,
            s0=self.s0 + later.s0,
            s1=self.s1 + later.s1 + bridge,
            w_first=self.w_first,
            w_last=later.w_last,
            n_samples=self.n_samples + later.n_samples,
            t_start=self.t_start,
            t_stop=later.t_stop,
            records=self.records,
        )

    def total(self) -> IdentificationMoments:
        """Sums over every realization: one row, ``records`` = runs x records (the pooled estimate)."""
        return IdentificationMoments(
            swx=self.swx.sum(axis=0, keepdims=True),
            swe=self.swe.sum(axis=0, keepdims=True),
            s0=self.s0.sum(axis=0, keepdims=True),
            s1=self.s1.sum(axis=0, keepdims=True),
            w_first=self.w_first[:1] * np.nan,  # edges of a pooled sum do not chain
            w_last=self.w_last[:1] * np.nan,
            n_samples=self.n_samples,
            t_start=self.t_start,
            t_stop=self.t_stop,
            records=self.records * self.runs,
        )

    def add_records(self, other: IdentificationMoments) -> IdentificationMoments:
        """Pooled sums of two sets of realizations (same window): rows of ``total()`` added."""
        a, b = self.total(), other.total()
        return IdentificationMoments(
            swx=a.swx + b.swx,
            swe=a.swe + b.swe,
            s0=a.s0 + b.s0,
            s1=a.s1 + b.s1,
            w_first=a.w_first,
            w_last=a.w_last,
            n_samples=a.n_samples,
            t_start=a.t_start,
            t_stop=a.t_stop,
            records=a.records + b.records,
        )


def _rows(a: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """``a[:, idx, :]`` as a view when ``idx`` is a contiguous range (no copy)."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return a[:, idx[0] : idx[0] + idx.size, :]
    return a[:, idx, :]


def _pairs(pairs: np.ndarray | None, q: int, r: int) -> list[tuple[int, int]]:
    if pairs is None:
        return [(c, ri) for c in range(q) for ri in range(r)]
    return [(int(c), int(ri)) for c, ri in np.asarray(pairs).reshape(-1, 2)]


def _dots(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``out[r, i, j] = sum_k a[r, i, k] b[r, j, k]`` (leading axes broadcast)."""
    return np.vecdot(a[:, :, None, :], b[:, None, :, :])


def compute_moments(
    z: np.ndarray,
    u: np.ndarray,
    e: np.ndarray,
    J: np.ndarray,
    L: np.ndarray,
    R: np.ndarray,
    ka: int,
    kb: int,
    times: tuple[float, float],
    swe_pairs: np.ndarray | None = None,
) -> IdentificationMoments:
    """The sums of :class:`IdentificationMoments` over sample indices ``ka <= k < kb``.

    Parameters
    ----------
    z : (runs, T, m) array
        Measurements (any strides; channel-major storage avoids copies).
    u : (T, p) or (runs, T, p) array
        Inputs.
    e : (runs, T - 1, m) array
        Chattering, ``e[:, k] = e(k+1|k)``.
    J, L, R : int arrays
        Measured channels used as regressors, input columns used as regressors, channels
        whose chattering is regressed.
    ka, kb : int
        Window of regressor indices, ``1 <= ka < kb <= T - 1``.
    times : (float, float)
        ``(t_start, t_stop)`` stored with the sums.
    swe_pairs : (P, 2) int array, optional
        The ``(regressor column, chattering row)`` pairs of ``Swe`` to compute (those of the
        estimated entries); the others are left 0. Default: all.
    """
    runs = z.shape[0]
    n = kb - ka
    zt = z.transpose(0, 2, 1)  # (runs, m, T) views
    et = e.transpose(0, 2, 1)
    zm1 = _rows(zt, J)[:, :, ka - 1 : kb - 1]  # z_J(k-1)
    z0 = _rows(zt, J)[:, :, ka:kb]  # z_J(k)
    er = _rows(et, R)[:, :, ka:kb]  # e_R(k+1)
    qj, pl = J.size, L.size
    # row-by-row dot products (np.vecdot: vectorized, ~3x faster than small batched matmuls); the
    # symmetric Gram once per pair, and of the chattering only the pairs some entry uses
    zz0 = np.empty((runs, qj, qj))
    for i in range(qj):
        for j in range(i, qj):
            zz0[:, i, j] = zz0[:, j, i] = np.vecdot(zm1[:, i], zm1[:, j])
    zz1 = _dots(zm1, z0)
    uL = u[..., L].swapaxes(-1, -2)  # (pl, T) or (runs, pl, T)
    if uL.ndim == 2:
        uL = uL[None]
    Uk, Uk1 = uL[:, :, ka:kb], uL[:, :, ka + 1 : kb]  # u(k), u(k+1)
    zu1 = _dots(zm1, Uk)  # sum z(k-1) u(k)'
    zu0 = _dots(z0, Uk)  # sum z(k) u(k)'
    zu2 = _dots(zm1[:, :, : n - 1], Uk1)  # sum_{k < kb-1} z(k-1) u(k+1)'
    r_ = er.shape[1]
    swe = np.zeros((runs, qj + pl, r_))
    for c, ri in _pairs(swe_pairs, qj + pl, r_):
        a = zm1[:, c] if c < qj else Uk[:, c - qj]
        swe[:, c, ri] = np.vecdot(a, er[:, ri])
    uu0 = np.broadcast_to(_dots(Uk, Uk), (runs, pl, pl))
    uu1 = np.broadcast_to(_dots(Uk[:, :, :-1], Uk1), (runs, pl, pl))
    u_first = np.broadcast_to(Uk[:, :, 0], (runs, pl))
    u_last = np.broadcast_to(Uk[:, :, -1], (runs, pl))
    q = qj + pl
    swx = np.empty((runs, q, q))
    s0 = np.empty((runs, q, q))
    s1 = np.empty((runs, q, q))
    swx[:, :qj, :qj], swx[:, :qj, qj:] = zz1, zu1
    swx[:, qj:, :qj], swx[:, qj:, qj:] = zu0.transpose(0, 2, 1), uu0
    s0[:, :qj, :qj], s0[:, :qj, qj:] = zz0, zu1
    s0[:, qj:, :qj], s0[:, qj:, qj:] = zu1.transpose(0, 2, 1), uu0
    # S1 pairs k, k+1 both inside [ka, kb): the k = kb - 1 term of zz1 and zu0 is not a pair
    z_prev_last, z_last = zm1[:, :, -1], z0[:, :, -1]
    s1[:, :qj, :qj] = zz1 - z_prev_last[:, :, None] * z_last[:, None, :]
    s1[:, :qj, qj:] = zu2
    s1[:, qj:, :qj] = zu0.transpose(0, 2, 1) - u_last[:, :, None] * z_last[:, None, :]
    s1[:, qj:, qj:] = uu1
    w_first = np.concatenate([zm1[:, :, 0], u_first], axis=1)
    w_last = np.concatenate([z_prev_last, u_last], axis=1)
    return IdentificationMoments(
        swx=swx,
        swe=swe,
        s0=s0,
        s1=s1,
        w_first=w_first,
        w_last=w_last,
        n_samples=n,
        t_start=float(times[0]),
        t_stop=float(times[1]),
    )
