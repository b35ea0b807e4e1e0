"""Per-push helpers of the online monitor: frame verdicts and compiled loops (see :mod:`chatterspec._jit`).

Each kernel does, in one pass, what a few numpy calls (or Python-level calls of
the SVSF) do in :mod:`chatterspec.online.monitor`, with the same correctly
rounded operations in the same order, so that the monitor's numbers do not
depend on whether numba is installed (tests/test_monitor.py compares the paths
bit for bit; the sat SVSF's numpy fallback is the one exception, equal to
1e-12, see :meth:`chatterspec.filters.svsf.SVSF.update`).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import _jit
from ..filters.svsf_steps import closed_form_step, matvec_step, rows_times_step, svsf_step

__all__: list[str] = []

#: Sizes of :func:`_filters_loop` (states, outputs, unmeasured states), bound by :func:`filters_kernel`;
#: 0 reads them from the arrays.
NX = NZ = NL = 0


def _filters_loop(
    z: np.ndarray,
    u: np.ndarray,
    GT: np.ndarray,
    aux_PhiT: np.ndarray,
    aux_y: np.ndarray,
    e_out: np.ndarray,
    Gu: np.ndarray,
    run_sat: bool,
    PhiT: np.ndarray,
    L: np.ndarray,
    P: np.ndarray,
    inv_psi: np.ndarray,
    gamma: float,
    S_inv: np.ndarray,
    y: np.ndarray,
    ep: np.ndarray,
    sat_e: np.ndarray,
    x_out: np.ndarray,
    none: np.ndarray,
) -> None:  # pragma: no cover - compiled (Python form tested in tests/test_monitor.py)
    """One push of the monitor's two filters in one call: G u(k), the aux chattering, the sat SVSF.

    ``z`` (1, K, m) = z(k+1); ``u`` (K, p), p >= 1, = u(k); ``GT`` = G^T (p, n). Per sample:
    ``G u(k)`` by :func:`~chatterspec.filters.svsf_steps.rows_times_step` (the sums of
    ``_rows_times``; written to ``Gu`` (1, K, n) unless it is empty), the chattering (eq 23) by
    :func:`~chatterspec.filters.svsf_steps.closed_form_step` into ``e_out`` (1, K, m) from
    ``aux_y`` = y(k|k) = z(k) before the push, and, when ``run_sat``, the sat SVSF by
    :func:`~chatterspec.filters.svsf_steps.svsf_step` (``y``, ``ep`` (1, n), (1, m) in place;
    ``sat_e`` (1, K, m) unless empty, ``x_out`` (1, K, n) = S^-1 y). ``none`` is unused (kept for
    the call signature). The steps of ``SVSF.update``, so the same bits (tests/test_monitor.py).
    A template: :func:`filters_kernel` binds ``NX``, ``NZ`` (0: sizes read from the arrays).
    """
    b = _jit.borrow
    z, u, GT, aux_PhiT, aux_y, e_out, Gu = b(z), b(u), b(GT), b(aux_PhiT), b(aux_y), b(e_out), b(Gu)
    PhiT, L, P, inv_psi, S_inv, y, ep = b(PhiT), b(L), b(P), b(inv_psi), b(S_inv), b(y), b(ep)
    sat_e, x_out = b(sat_e), b(x_out)
    K = z.shape[1]
    p = GT.shape[0]
    n = NX if NX > 0 else GT.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    nl = NL if NX > 0 else L.shape[0]
    want_gu = Gu.shape[0] > 0
    want_e = sat_e.shape[0] > 0
    gu = _jit.scratch(n)
    zp = _jit.scratch(m)
    yc = _jit.scratch(n)
    epc = _jit.scratch(m)
    yp = _jit.scratch(n)
    e = _jit.scratch(m)
    le = _jit.scratch(nl)
    xc = _jit.scratch(n)
    for i in range(m):
        zp[i] = aux_y[0, i]
    if run_sat:
        for i in range(n):
            yc[i] = y[0, i]
        for i in range(m):
            epc[i] = ep[0, i]
    for k in range(K):
        rows_times_step(u[k], GT, gu, p, n)
        if want_gu:
            for i in range(n):
                Gu[0, k, i] = gu[i]
        for i in range(m):
            e_out[0, k, i] = closed_form_step(i, z[0, k, i], gu[i], aux_PhiT, zp, m)
        for i in range(m):
            zp[i] = z[0, k, i]
        if run_sat:
            svsf_step(z[0, k], gu, PhiT, L, P, inv_psi, gamma, yc, epc, yp, e, le, n, m, nl, True)
            if want_e:
                for i in range(m):
                    sat_e[0, k, i] = e[i]
            matvec_step(S_inv, yc, xc, n, n)
            for i in range(n):
                x_out[0, k, i] = xc[i]
    if run_sat:
        for i in range(n):
            y[0, i] = yc[i]
        for i in range(m):
            ep[0, i] = epc[i]


#: The push loop for any model size (sizes read from the arrays).
_filters_kernel = _jit.specialize(_filters_loop, "any", NX=0, NZ=0, NL=0)


def filters_kernel(n: int, m: int) -> Callable[..., None]:
    """The push loop for n states and m outputs (full measurement: n = m); small sizes unrolled.

    The same template and steps as :data:`_filters_kernel`, hence the same bits; literal sizes let
    LLVM keep the per-run state in registers (the EHA's 3 states: 0.53 against 1.36 ms per minute
    of 1 kHz data for both filters, the same as the loop written out by hand).
    """
    return _jit.specialize_sizes(_filters_loop, "push", {"NX": n, "NZ": m, "NL": n - m})
