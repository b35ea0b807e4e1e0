"""Compiled batch loops of the SVSF (:mod:`chatterspec.filters.svsf`), built from its steps.

Private. :func:`_svsf_kernel` runs :func:`~chatterspec.filters.svsf_steps.svsf_step` (eq 4-12) and
:func:`_closed_form_kernel` runs :func:`~chatterspec.filters.svsf_steps.closed_form_step` (eq 23)
over runs and samples: the batch path of :meth:`SVSF.update`. Compiled by numba when it is
installed, called as plain Python otherwise (tests compare both with the numpy formulation of
:meth:`SVSF.update`). The steps live in :mod:`chatterspec.filters.svsf_steps` (public: the online
monitor's push and the fused simulate-and-chatter loop call them too).
"""

from __future__ import annotations

import numpy as np

from .. import _jit
from .protocol import finite_sample
from .svsf_steps import closed_form_step, matvec_step, rows_times_step, svsf_step

__all__ = ["svsf_one_kernel", "svsf_one_offsets"]


@_jit.njit
def _svsf_kernel(
    z: np.ndarray,
    Gu: np.ndarray,
    PhiT: np.ndarray,
    L: np.ndarray,
    P: np.ndarray,
    inv_psi: np.ndarray,
    gamma: float,
    S_inv: np.ndarray,
    y: np.ndarray,
    ep: np.ndarray,
    e_out: np.ndarray,
    x_out: np.ndarray,
    ep_out: np.ndarray,
    lower_out: np.ndarray,
) -> None:  # pragma: no cover - compiled (Python form tested in tests/test_kernels.py)
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


@_jit.step
def svsf_one_offsets(n: int, m: int, p: int, nl: int) -> tuple[int, int, int, int, int, int, int, int]:
    """Offsets in ``cst`` of :func:`_svsf_one` after its 8-value header: ``G^T`` (p, n), ``Phi^T`` (n, n),
    ``L``, ``P`` (nl, m), ``1/psi`` (n), ``S^-1`` (n, n), ``S^-T`` (n, n), and the length."""
    o_GT = 8
    o_PhiT = o_GT + p * n
    o_L = o_PhiT + n * n
    o_P = o_L + nl * m
    o_psi = o_P + nl * m
    o_Si = o_psi + n
    o_SiT = o_Si + n * n
    return o_GT, o_PhiT, o_L, o_P, o_psi, o_Si, o_SiT, o_SiT + n * n


def _svsf_one(buf, cst, z, u):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """One sample of one realization of :meth:`SVSF.update`: the steps of its batch paths, packed arrays.

    ``cst``: header ``[n, m, p, nl, sat, gamma, closed, 0]`` (``closed``: the sgn filter with full
    measurement started with ``e(k|k) = 0``, whose closed form then applies to every sample), then
    :func:`svsf_one_offsets`. ``buf``: ``y`` (n), ``e(k|k)`` (m), then the sample's ``e(k+1|k)`` (m)
    and ``x(k+1|k+1)`` (n). ``G u(k)`` by :func:`rows_times_step`; eq (23) by :func:`closed_form_step`
    when ``closed`` (the choice :meth:`SVSF.update` makes for a record that starts so), else eq
    (4)-(12) by :func:`svsf_step`.
    Returns 0, 3 (NaN/inf input) or 4 (a non-finite estimate; the state is then left unchanged).
    """
    b = _jit.borrow
    buf, cst, z, u = b(buf), b(cst), b(z), b(u)
    n, m, p, nl = NX if NX > 0 else int(cst[0]), NZ if NZ > 0 else int(cst[1]), int(cst[2]), int(cst[3])
    sat, gamma, closed = cst[4] != 0.0, cst[5], cst[6] != 0.0
    if not finite_sample(z, m, u, p):
        return 3
    o_GT, o_PhiT, o_L, o_P, o_psi, o_Si, o_SiT, _ = svsf_one_offsets(n, m, p, nl)
    GT = cst[o_GT:o_PhiT].reshape((p, n))
    PhiT = cst[o_PhiT:o_L].reshape((n, n))
    L = cst[o_L:o_P].reshape((nl, m))
    P = cst[o_P:o_psi].reshape((nl, m))
    inv_psi = cst[o_psi:o_Si]
    S_inv = cst[o_Si:o_SiT].reshape((n, n))
    S_invT = cst[o_SiT : o_SiT + n * n].reshape((n, n))
    gu = _jit.scratch(n)
    y = _jit.scratch(n)
    ep = _jit.scratch(m)
    e = _jit.scratch(m)
    x = _jit.scratch(n)
    for i in range(n):
        y[i] = buf[i]
    for i in range(m):
        ep[i] = buf[n + i]
    rows_times_step(u, GT, gu, p, n)
    if closed:  # eq (23): y(k|k) = z(k) exactly, e(k+1|k+1) = 0
        for i in range(m):
            e[i] = closed_form_step(i, z[i], gu[i], PhiT, y, m)
        for i in range(m):
            y[i] = z[i]
        rows_times_step(z, S_invT, x, n, n)
    else:
        yp = _jit.scratch(n)
        le = _jit.scratch(nl)
        svsf_step(z, gu, PhiT, L, P, inv_psi, gamma, y, ep, yp, e, le, n, m, nl, sat)
        matvec_step(S_inv, y, x, n, n)
    for i in range(n):
        if not np.isfinite(y[i]):
            return 4
    for i in range(n):
        buf[i] = y[i]
        buf[n + 2 * m + i] = x[i]
    for i in range(m):
        buf[n + i] = ep[i]
        buf[n + m + i] = e[i]
    return 0


#: Sizes of :func:`_svsf_one` (0: from ``cst``), bound by :func:`svsf_one_kernel`.
NX = NZ = 0


def svsf_one_kernel(n: int, m: int):  # type: ignore[no-untyped-def]
    """:func:`_svsf_one` for n states and m outputs (literal sizes up to 4: loops unrolled)."""
    return _jit.specialize_sizes(_svsf_one, "svsf_one", {"NX": n, "NZ": m})
