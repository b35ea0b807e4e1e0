"""The SVSF's per-sample steps (eq 4-12 and eq 23 of the core paper) and its fixed-order products.

Public because every loop that runs the SVSF is built from these steps: the batch kernels of
:meth:`chatterspec.filters.svsf.SVSF.update`, the online monitor's push
(:mod:`chatterspec.online.monitor`) and the fused simulate-and-chatter loop
(:mod:`chatterspec.detection.pipeline`). The steps (:func:`chatterspec._jit.step`) are inlined by
numba into every loop that calls them and run as plain Python without numba:

* :func:`svsf_step`: one sample of the recursion of eq (4)-(12) (sat or sgn, full or reduced order);
* :func:`closed_form_step`: one channel of the auxiliary filter's closed form, eq (23);
* :func:`rows_times_step`, :func:`matvec_step`: the products ``G u(k)`` and ``S^-1 y`` summed in a
  fixed order.

The numpy helpers :func:`rows_times` (``a @ M^T`` in the order of :func:`rows_times_step`, so that
chunked and whole-record processing agree bit for bit) and :func:`switch` (``sat`` or ``sgn``, eq 8)
serve the numpy path. Every step is checked against eq (8)-(12) written out by hand
(``tests/test_steps.py``).

See Also
--------
chatterspec.filters.svsf.SVSF : the filter built on these steps.
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__ = ["closed_form_step", "matvec_step", "rows_times", "rows_times_step", "svsf_step", "switch"]


@_jit.step
def svsf_step(
    zk: np.ndarray,
    guk: np.ndarray,
    PhiT: np.ndarray,
    L: np.ndarray,
    P: np.ndarray,
    inv_psi: np.ndarray,
    gamma: float,
    y: np.ndarray,
    ep: np.ndarray,
    yp: np.ndarray,
    e: np.ndarray,
    le: np.ndarray,
    n: int,
    m: int,
    nl: int,
    sat: bool,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_kernels.py)
    """One sample of eq (4)-(12) for one realization, in measurement-aligned coordinates (THE SVSF step).

    Inputs: ``zk`` (m,) = z(k+1); ``guk`` (n,) = G u(k); ``PhiT`` = Phi^T (n, n); ``L`` =
    Phi22 Phi12^-1 and ``P`` = Phi12^-1 ((nl, m), nl = n - m, empty for full measurement);
    ``inv_psi`` = 1/psi (m or n entries, used when ``sat``; ``sgn`` otherwise).
    State, updated in place: ``y`` (n,) = y(k|k) -> y(k+1|k+1), ``ep`` (m,) = e(k|k) -> e(k+1|k+1).
    Outputs: ``yp`` (n,) = y(k+1|k), ``e`` (m,) = e(k+1|k), ``le`` (nl,) = Phi22 Phi12^-1 e(k+1|k).

    Eq (4) ``y(k+1|k) = Phi y(k|k) + G u(k)`` (sum over j = 0 .. n-1, then ``+ G u``), eq (6)
    ``e = z - y_u(k+1|k)``; eq (10)-(12) for the unmeasured coordinates (before ``ep`` changes):
    ``y_l = y_l(k+1|k) + sw(L e) (|L e| + gamma |P e(k|k)|)``; eq (8)/(9) and (12) for the measured
    ones, ``e(k+1|k+1) = e - sw(e) (|e| + gamma |e(k|k)|)``, ``y_u = z - e(k+1|k+1)``, with
    ``sw(a) = sat(a / psi) = clip(a / psi, -1, 1)`` or ``sgn(a)``.
    """
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += y[j] * PhiT[j, i]
        yp[i] = acc + guk[i]
    for i in range(m):
        e[i] = zk[i] - yp[i]
    for i in range(nl):
        lv = 0.0
        pv = 0.0
        for j in range(m):
            lv += L[i, j] * e[j]
            pv += P[i, j] * ep[j]
        if sat:
            sw = min(max(lv * inv_psi[m + i], -1.0), 1.0)
        else:
            sw = np.sign(lv)
        y[m + i] = yp[m + i] + sw * (abs(lv) + gamma * abs(pv))
        le[i] = lv
    for i in range(m):
        if sat:
            sw = min(max(e[i] * inv_psi[i], -1.0), 1.0)
        else:
            sw = np.sign(e[i])
        ep[i] = e[i] - sw * (abs(e[i]) + gamma * abs(ep[i]))
        y[i] = zk[i] - ep[i]


@_jit.step
def closed_form_step(i: int, zi: float, gi: float, PhiT: np.ndarray, zp: np.ndarray, m: int) -> float:
    """Eq (23), channel ``i``: ``e_i(k+1|k) = ((z_i(k+1) - G_i u(k)) - Phi_i0 z_0(k)) - Phi_i1 z_1(k) ...``.

    The auxiliary sgn filter with ``e(k|k) = 0`` keeps ``y(k|k) = z(k)`` exactly (see
    :meth:`chatterspec.filters.svsf.SVSF.update`), so its a-priori error needs only ``z(k)``
    (``zp``, (m,)) and ``z(k+1)``; the terms are subtracted in this order, j = 0 .. m-1.
    """
    acc = zi - gi
    for j in range(m):
        acc -= PhiT[j, i] * zp[j]
    return acc


@_jit.step
def rows_times_step(a: np.ndarray, MT: np.ndarray, out: np.ndarray, p: int, n: int) -> None:
    """``out = a @ MT`` for one row ``a`` (p,), summed as :func:`rows_times` (``a_0 M_0``, ``+ a_j M_j``)."""
    for i in range(n):
        acc = a[0] * MT[0, i]
        for j in range(1, p):
            acc += a[j] * MT[j, i]
        out[i] = acc


@_jit.step
def matvec_step(M: np.ndarray, v: np.ndarray, out: np.ndarray, n: int, q: int) -> None:
    """``out = M v`` summed from 0.0 over j = 0 .. q-1 (``x(k|k) = S^-1 y(k|k)``)."""
    for i in range(n):
        acc = 0.0
        for j in range(q):
            acc += M[i, j] * v[j]
        out[i] = acc


def rows_times(a: np.ndarray, MT: np.ndarray, channel_major: bool = False) -> np.ndarray:
    """``a @ MT`` over the last axis, element-wise in a fixed order.

    Unlike BLAS, the rounding of each output element does not depend on the
    number of rows, so chunked and whole-record processing agree bit for bit.
    ``channel_major=True`` returns the same numbers as a ``(..., n)`` view of
    ``(n, ...)`` storage, which numpy fills ~3x faster when n is small (the
    online monitor's per-push ``G u(k)``; the kernels take any strides).

    Parameters
    ----------
    a : (..., p) array
        Rows, e.g. inputs ``u(k)`` (input units).
    MT : (p, n) array
        Transposed matrix, e.g. ``G^T`` of eq (4).
    channel_major : bool
        Compute in ``(n, ...)`` storage and return a transposed view (same numbers).

    Returns
    -------
    (..., n) array
        ``sum_j a[..., j] MT[j]``, summed j = 0 .. p-1 (zeros when p = 0).

    See Also
    --------
    rows_times_step : the same sum for one row, in compiled loops.
    """
    if channel_major and a.shape[-1]:
        out = np.multiply.outer(MT[0], a[..., 0])
        for j in range(1, a.shape[-1]):
            out += np.multiply.outer(MT[j], a[..., j])
        return out.transpose((*range(1, out.ndim), 0))
    out = np.multiply.outer(a[..., 0], MT[0]) if a.shape[-1] else np.zeros((*a.shape[:-1], MT.shape[1]))
    for j in range(1, a.shape[-1]):
        out += np.multiply.outer(a[..., j], MT[j])
    return out


def switch(e: np.ndarray, inv_psi: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
    """The switching term of eq (8)-(10): ``sgn(e)``, or ``sat(e / psi) = clip(e / psi, -1, 1)``.

    Parameters
    ----------
    e : array
        Output errors (output units).
    inv_psi : array or None
        ``1 / psi`` per channel (broadcast along the last axis); None gives ``sgn`` (eq 17).
    out : array, optional
        Where to write the result.

    Returns
    -------
    array like ``e``
        Values in [-1, 1].
    """
    if inv_psi is None:
        return np.sign(e, out=out)
    out = np.multiply(e, inv_psi, out=out)
    return np.clip(out, -1.0, 1.0, out=out)
