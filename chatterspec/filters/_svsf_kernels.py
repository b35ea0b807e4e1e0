"""Compiled per-sample kernels of the SVSF (:mod:`chatterspec.filters.svsf`) and their small helpers.

Private: :func:`_svsf_kernel` is the recursion of eq (4)-(12) (sat or sgn, full or reduced
order), :func:`_closed_form_kernel` the auxiliary filter's closed form of eq (23); both are
compiled by :func:`chatterspec._jit.njit` when numba is installed and called as plain Python
otherwise (tests compare both with the numpy formulation of :meth:`SVSF.update`).
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__: list[str] = []


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
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_kernels.py)
    """Eq (4)-(12) for ``runs`` realizations and K samples, in measurement-aligned coordinates.

    Inputs: ``z`` (runs, K, m); ``Gu`` (1 or runs, K, n) = G u(k); ``PhiT`` = Phi^T (n, n);
    ``L`` = Phi22 Phi12^-1 and ``P`` = Phi12^-1, (n-m, m) or (0, 0) for full measurement;
    ``inv_psi`` = 1/psi (m or n entries) for sat, empty for sgn; ``S_inv`` (n, n).
    State, updated in place: ``y`` (runs, n) = y(k|k), ``ep`` (runs, m) = e(k|k).
    Outputs: ``e_out`` (runs, K, m) = e(k+1|k); ``x_out`` (runs, K, n), ``ep_out`` (runs, K, m),
    ``lower_out`` (runs, K, n-m), each skipped when its first axis is empty.
    The arithmetic per element is that of :meth:`SVSF.update`'s numpy loop except the order
    of the sums in the matrix-vector products (BLAS there, j = 0..n-1 here).
    """
    runs, K, m = z.shape
    n = PhiT.shape[0]
    nl = L.shape[0]
    sat = inv_psi.shape[0] > 0
    shared = Gu.shape[0] == 1
    want_x = x_out.shape[0] > 0
    want_ep = ep_out.shape[0] > 0
    want_lower = lower_out.shape[0] > 0
    yc = np.empty(n)  # y(k|k) of the current run
    epc = np.empty(m)  # e(k|k) of the current run
    yp = np.empty(n)
    e = np.empty(m)
    for r in range(runs):
        g = 0 if shared else r
        for j in range(n):
            yc[j] = y[r, j]
        for j in range(m):
            epc[j] = ep[r, j]
        for k in range(K):
            # eq (4): y(k+1|k) = Phi y(k|k) + G u(k)
            for i in range(n):
                acc = 0.0
                for j in range(n):
                    acc += yc[j] * PhiT[j, i]
                yp[i] = acc + Gu[g, k, i]
            for i in range(m):
                e[i] = z[r, k, i] - yp[i]  # eq (6)
                e_out[r, k, i] = e[i]
            # eq (10)-(12), unmeasured part (uses e(k|k) before it is overwritten)
            for i in range(nl):
                le = 0.0
                pe = 0.0
                for j in range(m):
                    le += L[i, j] * e[j]
                    pe += P[i, j] * epc[j]
                if sat:
                    sw = min(max(le * inv_psi[m + i], -1.0), 1.0)
                else:
                    sw = np.sign(le)
                yc[m + i] = yp[m + i] + sw * (abs(le) + gamma * abs(pe))
                if want_lower:
                    lower_out[r, k, i] = le
            # eq (8)/(9) and (12), measured part: y_u = z - e(k+1|k+1), e(k+1|k+1) = e - K_u
            for i in range(m):
                if sat:
                    sw = min(max(e[i] * inv_psi[i], -1.0), 1.0)
                else:
                    sw = np.sign(e[i])
                epc[i] = e[i] - sw * (abs(e[i]) + gamma * abs(epc[i]))
                yc[i] = z[r, k, i] - epc[i]
                if want_ep:
                    ep_out[r, k, i] = epc[i]
            if want_x:
                for i in range(n):
                    acc = 0.0
                    for j in range(n):
                        acc += S_inv[i, j] * yc[j]
                    x_out[r, k, i] = acc
        for j in range(n):
            y[r, j] = yc[j]
        for j in range(m):
            ep[r, j] = epc[j]


@_jit.njit
def _closed_form_kernel(
    z: np.ndarray, Gu: np.ndarray, PhiT: np.ndarray, y0: np.ndarray, e_out: np.ndarray, time_major: bool
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_kernels.py)
    """Eq (23) of the sgn filter with e(k|k) = 0 (:meth:`SVSF._update_closed_form`), compiled.

    ``z`` (runs, K, m) = z(k+1); ``Gu`` (1 or runs, K, m) = G u(k); ``PhiT`` = Phi^T (m, m);
    ``y0`` (runs, m) = y(k|k) before the chunk; ``e_out`` (runs, K, m) receives e(k+1|k), any strides.
    Per element ``acc = z_i(k+1) - G_i u(k)``, then ``acc -= Phi_ij y_j(k|k)`` for j = 0 .. m-1
    with ``y(k|k) = z(k)`` (``y0`` at the chunk's first sample): exactly the operations and order
    of the numpy closed form, so the same bits. ``time_major`` only picks the loop nest that walks
    memory in order (samples outer for time-major storage, runs outer otherwise).
    """
    runs, K, m = z.shape
    shared = Gu.shape[0] == 1
    if time_major:
        for k in range(K):
            for r in range(runs):
                g = 0 if shared else r
                for i in range(m):
                    acc = z[r, k, i] - Gu[g, k, i]
                    if k == 0:
                        for j in range(m):
                            acc -= PhiT[j, i] * y0[r, j]
                    else:
                        for j in range(m):
                            acc -= PhiT[j, i] * z[r, k - 1, j]
                    e_out[r, k, i] = acc
    else:  # the same element loop body, runs outer
        for r in range(runs):
            g = 0 if shared else r
            for k in range(K):
                for i in range(m):
                    acc = z[r, k, i] - Gu[g, k, i]
                    if k == 0:
                        for j in range(m):
                            acc -= PhiT[j, i] * y0[r, j]
                    else:
                        for j in range(m):
                            acc -= PhiT[j, i] * z[r, k - 1, j]
                    e_out[r, k, i] = acc


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
