"""Compiled per-sample kernels of the SVSF (:mod:`chatterspec.filters.svsf`) and their small helpers.

Private. The steps (:func:`chatterspec._jit.step`, inlined by numba into every loop that calls
them): :func:`svsf_step`, one sample of the recursion of eq (4)-(12) (sat or sgn, full or reduced
order), and :func:`closed_form_step`, the auxiliary filter's closed form of eq (23). The loops
built on them: :func:`_svsf_kernel` and :func:`_closed_form_kernel` here (the batch path of
:meth:`SVSF.update`), the online monitor's push (:mod:`chatterspec.online._push_kernels`) and the
fused simulate-and-chatter loop (:mod:`chatterspec.detection.pipeline`). Compiled by numba when
it is installed, called as plain Python otherwise (tests compare both with the numpy formulation
of :meth:`SVSF.update`, and the steps with eq (8)-(12) written out by hand).
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__: list[str] = []


# ----------------------------------------------------------------------------------------- steps
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
    """``out = a @ MT`` for one row ``a`` (p,), summed as :func:`_rows_times` (``a_0 M_0``, ``+ a_j M_j``)."""
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


# ----------------------------------------------------------------------------------------- loops
@_jit.njit
def _svsf_kernel(z, Gu, PhiT, L, P, inv_psi, gamma, S_inv, y, ep, e_out, x_out, ep_out, lower_out):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled (Python form tested in tests/test_kernels.py)
    """:func:`svsf_step` for ``runs`` realizations and K samples (the batch loop of :meth:`SVSF.update`).

    Inputs: ``z`` (runs, K, m); ``Gu`` (1 or runs, K, n) = G u(k); constants as :func:`svsf_step`;
    ``S_inv`` (n, n). State, updated in place: ``y`` (runs, n) = y(k|k), ``ep`` (runs, m) = e(k|k).
    Outputs: ``e_out`` (runs, K, m) = e(k+1|k); ``x_out`` (runs, K, n) = S^-1 y, ``ep_out``
    (runs, K, m), ``lower_out`` (runs, K, n-m), each skipped when its first axis is empty.
    The arithmetic per element is that of :meth:`SVSF.update`'s numpy loop except the order
    of the sums in the matrix-vector products (BLAS there, j = 0..n-1 here).
    """
    b = _jit.borrow
    z, Gu, PhiT, L, P, inv_psi, S_inv = b(z), b(Gu), b(PhiT), b(L), b(P), b(inv_psi), b(S_inv)
    y, ep, e_out, x_out, ep_out, lower_out = b(y), b(ep), b(e_out), b(x_out), b(ep_out), b(lower_out)
    runs, K, m = z.shape
    n = PhiT.shape[0]
    nl = L.shape[0]
    sat = inv_psi.shape[0] > 0
    shared = Gu.shape[0] == 1
    want_x = x_out.shape[0] > 0
    want_ep = ep_out.shape[0] > 0
    want_lower = lower_out.shape[0] > 0
    yc = _jit.scratch(n)  # y(k|k) of the current run
    epc = _jit.scratch(m)  # e(k|k) of the current run
    yp = _jit.scratch(n)
    e = _jit.scratch(m)
    le = _jit.scratch(nl)
    xc = _jit.scratch(n)
    for r in range(runs):
        g = 0 if shared else r
        for j in range(n):
            yc[j] = y[r, j]
        for j in range(m):
            epc[j] = ep[r, j]
        for k in range(K):
            svsf_step(z[r, k], Gu[g, k], PhiT, L, P, inv_psi, gamma, yc, epc, yp, e, le, n, m, nl, sat)
            for i in range(m):
                e_out[r, k, i] = e[i]
            if want_lower:
                for i in range(nl):
                    lower_out[r, k, i] = le[i]
            if want_ep:
                for i in range(m):
                    ep_out[r, k, i] = epc[i]
            if want_x:
                matvec_step(S_inv, yc, xc, n, n)
                for i in range(n):
                    x_out[r, k, i] = xc[i]
        for j in range(n):
            y[r, j] = yc[j]
        for j in range(m):
            ep[r, j] = epc[j]


@_jit.njit
def _closed_form_kernel(
    z: np.ndarray, Gu: np.ndarray, PhiT: np.ndarray, y0: np.ndarray, e_out: np.ndarray, time_major: bool
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_kernels.py)
    """:func:`closed_form_step` over runs and samples (:meth:`SVSF._update_closed_form`, compiled).

    ``z`` (runs, K, m) = z(k+1); ``Gu`` (1 or runs, K, m) = G u(k); ``PhiT`` = Phi^T (m, m);
    ``y0`` (runs, m) = y(k|k) before the chunk; ``e_out`` (runs, K, m) receives e(k+1|k), any strides.
    The operations and order of the numpy closed form, so the same bits. ``time_major`` only
    picks the loop nest that walks memory in order (samples outer for time-major storage, runs
    outer otherwise).
    """
    b = _jit.borrow
    z, Gu, PhiT, y0, e_out = b(z), b(Gu), b(PhiT), b(y0), b(e_out)
    runs, K, m = z.shape
    shared = Gu.shape[0] == 1
    if time_major:
        for k in range(K):
            for r in range(runs):
                g = 0 if shared else r
                zp = y0[r] if k == 0 else z[r, k - 1]
                for i in range(m):
                    e_out[r, k, i] = closed_form_step(i, z[r, k, i], Gu[g, k, i], PhiT, zp, m)
    else:  # the same element loop body, runs outer
        for r in range(runs):
            g = 0 if shared else r
            for k in range(K):
                zp = y0[r] if k == 0 else z[r, k - 1]
                for i in range(m):
                    e_out[r, k, i] = closed_form_step(i, z[r, k, i], Gu[g, k, i], PhiT, zp, m)


def _rows_times(a: np.ndarray, MT: np.ndarray, channel_major: bool = False) -> np.ndarray:
    """``a @ MT`` over the last axis, element-wise in a fixed order.

    Unlike BLAS, the rounding of each output element does not depend on the
    number of rows, so chunked and whole-record processing agree bit for bit.
    ``channel_major=True`` returns the same numbers as a ``(..., n)`` view of
    ``(n, ...)`` storage, which numpy fills ~3x faster when n is small (the
    online monitor's per-push ``G u(k)``; the kernels take any strides).
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


def _switch(e: np.ndarray, inv_psi: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
    """``sgn(e)`` when ``inv_psi`` is None, else ``sat(e / psi) = clip(e / psi, -1, 1)``."""
    if inv_psi is None:
        return np.sign(e, out=out)
    out = np.multiply(e, inv_psi, out=out)
    return np.clip(out, -1.0, 1.0, out=out)
