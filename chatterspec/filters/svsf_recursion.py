"""The SVSF's state, its per-chunk outputs and the three ways to advance it (eq 4-12, eq 23).

:meth:`chatterspec.filters.svsf.SVSF.update` checks its input and picks one of these paths; each
gives the same bits for any chunking:

* :func:`closed_form_errors`: the auxiliary ``sgn`` filter with full measurement and
  ``e(k|k) = 0``, eq (23) vectorized over time (compiled loop or numpy, the same bits);
* :func:`compiled_recursion`: eq (4)-(12) sample by sample in the compiled kernel (numba);
* :func:`numpy_recursion`: eq (4)-(12) sample by sample in numpy, vectorized over realizations
  (the fallback without numba; BLAS orders the sums of its matrix products differently, so it
  agrees with the compiled kernel to rounding, 1e-12 of the measurement scale).

The filter's constants (:class:`SVSFConstants`) are in measurement-aligned coordinates ``y = S x``
(see :mod:`chatterspec.filters.svsf_coordinates`).

See Also
--------
chatterspec.filters.svsf_steps : the per-sample steps the compiled paths are built from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from ._svsf_kernels import _closed_form_kernel, _svsf_kernel
from .svsf_steps import rows_times, switch

__all__ = [
    "SVSFConstants",
    "SVSFOutput",
    "SVSFState",
    "closed_form_errors",
    "compiled_recursion",
    "kernel_constants",
    "numpy_recursion",
    "with_initial",
]


@dataclass(frozen=True, eq=False)
class SVSFState:
    """Filter state between chunks.

    Attributes
    ----------
    y : (runs, n) array
        A-posteriori estimate in measurement-aligned coordinates (``x = S^-1 y``).
    e_post : (runs, m) array
        A-posteriori output error ``e(k|k)``.
    k : int
        Index of the last processed sample.
    """

    y: np.ndarray
    e_post: np.ndarray
    k: int

    @property
    def runs(self) -> int:
        """Number of realizations (leading axis of ``y``)."""
        return self.y.shape[0]


@dataclass(frozen=True, eq=False)
class SVSFOutput:
    """Per-sample outputs of one :meth:`SVSF.update` call, shapes ``(runs, K, .)``.

    ``e_prior`` is ``e(k|k-1)`` (the auxiliary filter's chattering, eq 17);
    ``x_post``, ``e_post`` and (reduced-order only) ``e_lower`` =
    ``Phi22 Phi12^-1 e(k|k-1)``, the argument of the unmeasured states' switching
    term (eq 10, 28), are filled only when requested.

    Attributes
    ----------
    e_prior : (runs, K, m) array
        A-priori output error ``e(k|k-1)`` (the chattering of the ``sgn`` filter, eq 17).
    x_post : (runs, K, n) array or None
        Posterior estimate ``x(k|k)`` (when requested).
    e_post : (runs, K, m) array or None
        A-posteriori output error ``e(k|k)`` (when requested).
    e_lower : (runs, K, n - m) array or None
        ``Phi22 Phi12^-1 e(k|k-1)`` of the reduced-order filter (when requested).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    e_prior: np.ndarray
    x_post: np.ndarray | None = None
    e_post: np.ndarray | None = None
    e_lower: np.ndarray | None = None


class SVSFConstants(NamedTuple):
    """The SVSF's constants in measurement-aligned coordinates ``y = S x`` (eq 4-12).

    Attributes
    ----------
    PhiT : (n, n) array
        ``Phi^T``, ``Phi = S A S^-1``.
    L : (n - m, m) array or None
        ``Phi22 Phi12^-1`` (eq 10); None for full measurement.
    P : (n - m, m) array or None
        ``Phi12^-1``; None for full measurement.
    inv_psi : (m,) or (n,) array or None
        ``1 / psi`` (measured first); None for ``sgn``.
    gamma : float
        Convergence rate (eq 8).
    S_inv : (n, n) array
        Maps ``y`` to ``x``.
    """

    PhiT: np.ndarray
    L: np.ndarray | None
    P: np.ndarray | None
    inv_psi: np.ndarray | None
    gamma: float
    S_inv: np.ndarray


def numpy_recursion(
    consts: SVSFConstants,
    state: SVSFState,
    z: np.ndarray,
    Gu: np.ndarray,
    store_states: bool = False,
    store_post_error: bool = False,
    store_lower: bool = False,
) -> tuple[SVSFState, SVSFOutput]:
    """Eq (4)-(12) over a chunk, sample by sample in numpy, vectorized over realizations.

    Parameters
    ----------
    consts : SVSFConstants
        The filter's constants.
    state : SVSFState
        State after sample ``k``.
    z : (runs, K, m) float array
        Measurements ``z(k+1) .. z(k+K)``.
    Gu : (K, n) or (1 | runs, K, n) array
        ``G u(k)`` per sample (:func:`~chatterspec.filters.svsf_steps.rows_times`).
    store_states, store_post_error, store_lower : bool
        Also return ``x(k|k)``, ``e(k|k)`` and (reduced order) ``Phi22 Phi12^-1 e(k|k-1)``.

    Returns
    -------
    (SVSFState, SVSFOutput)

    See Also
    --------
    compiled_recursion : the same recursion in the compiled kernel.
    """
    PhiT, L, P, inv_psi, gamma, S_inv = consts
    runs, K, m = z.shape
    n = PhiT.shape[0]
    # time-major working copies
    zt = np.ascontiguousarray(np.swapaxes(z, 0, 1))  # (K, runs, m)
    if Gu.ndim == 3:
        Gu = np.ascontiguousarray(np.swapaxes(np.broadcast_to(Gu, (runs, K, n)), 0, 1))
    e_out = np.empty((K, runs, m))
    x_out = np.empty((K, runs, n)) if store_states else None
    ep_out = np.empty((K, runs, m)) if store_post_error else None
    lower_out = np.empty((K, runs, n - m)) if (store_lower and n > m) else None

    inv_psi_u = None if inv_psi is None else inv_psi[:m]
    inv_psi_l = None if inv_psi is None else inv_psi[m:]
    reduced = L is not None
    LT = None if L is None else np.ascontiguousarray(L.T)
    PT = None if P is None else np.ascontiguousarray(P.T)
    S_invT = np.ascontiguousarray(S_inv.T)
    shared_input = Gu.ndim == 2
    # y_aug = [y, 1] and W = [[Phi^T], [G u(k)]] fold the input into one matmul
    # (a broadcast add over a 3-wide inner axis costs ~3x a small matmul).
    y_aug = np.empty((runs, n + 1))
    y_aug[:, n] = 1.0
    y_aug[:, :n] = state.y
    y = y_aug[:, :n]
    W = np.empty((n + 1, n))
    W[:n] = PhiT
    W[n] = 0.0
    ep = state.e_post.copy()  # e(k|k), signed
    yp = np.empty((runs, n))
    mag = np.empty((runs, m))
    tmp = np.empty((runs, m))
    Ku = np.empty((runs, m))
    for k in range(K):
        if shared_input:
            W[n] = Gu[k]
            np.matmul(y_aug, W, out=yp)  # eq (4), y coordinates
        else:
            np.matmul(y, PhiT, out=yp)
            yp += Gu[k]
        e = e_out[k]
        np.subtract(zt[k], yp[:, :m], out=e)  # eq (6)
        # eq (8)/(9): K_u = (|e(k+1|k)| + gamma |e(k|k)|) o sat(e(k+1|k), psi)
        np.abs(e, out=mag)
        np.abs(ep, out=tmp)
        tmp *= gamma
        mag += tmp
        switch(e, inv_psi_u, out=Ku)
        Ku *= mag
        if reduced:
            # eq (10): K_l = (|Phi22 Phi12^-1 e(k+1|k)| + gamma |Phi12^-1 e(k|k)|)
            #                o sat(Phi22 Phi12^-1 e(k+1|k), psi_l)
            Le = e @ LT
            mag_l = np.abs(Le)
            mag_l += gamma * np.abs(ep @ PT)
            if lower_out is not None:
                lower_out[k] = Le
            Kl = switch(Le, inv_psi_l)
            Kl *= mag_l
            np.add(yp[:, m:], Kl, out=y[:, m:])  # eq (12), unmeasured part
        # eq (12) for the measured coordinates, written as y_u = z - e(k+1|k+1)
        # with e(k+1|k+1) = e(k+1|k) - K_u (see Notes)
        np.subtract(e, Ku, out=ep)
        np.subtract(zt[k], ep, out=y[:, :m])
        if ep_out is not None:
            ep_out[k] = ep
        if x_out is not None:
            np.matmul(y, S_invT, out=x_out[k])
    new_state = SVSFState(y=y.copy(), e_post=ep, k=state.k + K)
    return new_state, SVSFOutput(
        e_prior=np.swapaxes(e_out, 0, 1),
        x_post=None if x_out is None else np.swapaxes(x_out, 0, 1),
        e_post=None if ep_out is None else np.swapaxes(ep_out, 0, 1),
        e_lower=None if lower_out is None else np.swapaxes(lower_out, 0, 1),
    )


def compiled_recursion(
    consts: SVSFConstants,
    state: SVSFState,
    z: np.ndarray,
    Gu: np.ndarray,
    store_states: bool,
    store_post_error: bool,
    store_lower: bool,
) -> tuple[SVSFState, SVSFOutput]:
    """Eq (4)-(12) over a chunk in the compiled kernel (one :func:`~.svsf_steps.svsf_step` per sample).

    Parameters
    ----------
    consts : SVSFConstants
        As :func:`kernel_constants` returns them (C-contiguous float arrays, empty for None).
    state, z, Gu, store_states, store_post_error, store_lower
        As :func:`numpy_recursion`.

    Returns
    -------
    (SVSFState, SVSFOutput)

    See Also
    --------
    numpy_recursion : the fallback without numba.
    """
    runs, K, m = z.shape
    PhiT, L, P, inv_psi, gamma, S_inv = consts
    assert L is not None and P is not None and inv_psi is not None  # (kernel_constants: empty arrays)
    n = PhiT.shape[0]
    # C-contiguous float arrays only, so that one compiled specialization serves every call
    c = np.ascontiguousarray
    z = c(z, dtype=float)
    Gu = c(Gu[None] if Gu.ndim == 2 else Gu, dtype=float)
    none = np.empty((0, 0, 0))
    e_out = np.empty((runs, K, m))
    x_out = np.empty((runs, K, n)) if store_states else none
    ep_out = np.empty((runs, K, m)) if store_post_error else none
    lower_out = np.empty((runs, K, n - m)) if (store_lower and n > m) else none
    y = np.array(state.y, dtype=float, order="C", copy=True)
    ep = np.array(state.e_post, dtype=float, order="C", copy=True)
    _svsf_kernel(z, Gu, PhiT, L, P, inv_psi, gamma, S_inv, y, ep, e_out, x_out, ep_out, lower_out)
    return SVSFState(y=y, e_post=ep, k=state.k + K), SVSFOutput(
        e_prior=e_out,
        x_post=x_out if store_states else None,
        e_post=ep_out if store_post_error else None,
        e_lower=lower_out if lower_out.shape[0] else None,
    )


def closed_form_errors(
    PhiT: np.ndarray,
    S_inv: np.ndarray,
    state: SVSFState,
    z: np.ndarray,
    Gu: np.ndarray,
    store_states: bool,
    store_post_error: bool,
) -> tuple[SVSFState, SVSFOutput]:
    """Eq (23) for the full-measurement ``sgn`` filter with ``e(k|k) = 0``, vectorized over time.

    ``e(k+1|k) = z(k+1) - Phi z(k) - G u(k)`` element-wise in a fixed order, so the bits do not
    depend on the chunking (see the Notes of :meth:`chatterspec.filters.svsf.SVSF.update`).

    Parameters
    ----------
    PhiT : (m, m) array
        Phi^T in measurement-aligned coordinates.
    S_inv : (m, m) array
        ``C^-1`` (for ``x(k|k) = C^-1 z(k)``).
    state, z, Gu, store_states, store_post_error
        As :func:`numpy_recursion`.

    Returns
    -------
    (SVSFState, SVSFOutput)
        ``e_post`` (when stored) is exactly zero.
    """
    runs, K, m = z.shape
    n = m
    shared_input = Gu.ndim == 2
    if not shared_input:
        Gu = np.broadcast_to(Gu, (runs, K, n))  # u given as (1, K, p) for every run
    # Element-wise, in a fixed order per element: (z_i - G_i u) - sum_j Phi_ij y_j, so the
    # bits do not depend on the chunking or on which memory layout is used below.
    time_major = z.strides[1] >= z.strides[0]
    if _jit.enabled():
        # the same operations, in the same order, in one compiled pass (no FMA contraction
        # without fastmath: bit-identical to the numpy branches below, tests/test_kernels.py);
        # the output has the numpy branch's memory layout, so later steps see the same strides
        store = np.empty((K, runs, m)) if time_major else np.empty((m, runs, K))
        e = np.swapaxes(store, 0, 1) if time_major else np.moveaxis(store, 0, 2)
        _closed_form_kernel(z, Gu if not shared_input else Gu[None], PhiT, state.y, e, time_major)
    elif time_major:
        # time-major storage (e.g. simulate() output): blocks of time steps, all runs
        zt = np.swapaxes(z, 0, 1)  # (K, runs, m)
        gt = Gu[:, None, :] if shared_input else np.swapaxes(Gu, 0, 1)  # (K, 1|runs, n)
        et = np.empty((K, runs, m))
        block = max(2, 65536 // max(runs * m, 1))
        for k0 in range(0, K, block):
            k1 = min(k0 + block, K)
            zb = zt[k0:k1]
            for i in range(m):
                acc = et[k0:k1, :, i]
                # e_i(k+1|k) = z_i(k+1) - G_i u(k) - sum_j Phi_ij y_j(k|k),  y(k|k) = z(k)
                np.subtract(zb[:, :, i], gt[k0:k1, :, i], out=acc)
                for j in range(n):
                    if k0 == 0:
                        acc[1:] -= PhiT[j, i] * zb[:-1, :, j]
                        acc[0] -= PhiT[j, i] * state.y[:, j]
                    else:
                        acc -= PhiT[j, i] * zt[k0 - 1 : k1 - 1, :, j]
        e = np.swapaxes(et, 0, 1)
    else:
        # realization-major storage: cache-sized blocks of runs, channel-major inside
        ec = np.empty((m, runs, K))
        block = max(1, 32768 // max(K, 1))
        for r0 in range(0, runs, block):
            r1 = min(r0 + block, runs)
            zc = np.ascontiguousarray(np.moveaxis(z[r0:r1], 2, 0))  # (m, b, K)
            gu = Gu.T if shared_input else np.moveaxis(Gu[r0:r1], 2, 0)  # (n, K) or (n, b, K)
            y0 = state.y[r0:r1]
            for i in range(m):
                acc = ec[i, r0:r1]
                np.subtract(zc[i], gu[i], out=acc)
                for j in range(n):
                    acc[:, 1:] -= PhiT[j, i] * zc[j, :, :-1]
                    acc[:, 0] -= PhiT[j, i] * y0[:, j]
        e = np.moveaxis(ec, 0, 2)
    x_post = None
    if store_states:
        x_post = rows_times(z, np.ascontiguousarray(S_inv.T))
    y_last = np.array(z[:, -1, :], dtype=float, copy=True)
    new_state = SVSFState(y=y_last, e_post=np.zeros((runs, m)), k=state.k + K)
    e_post = np.zeros((runs, K, m)) if store_post_error else None  # exactly zero (see update)
    return new_state, SVSFOutput(e_prior=e, x_post=x_post, e_post=e_post)


def kernel_constants(consts: SVSFConstants) -> SVSFConstants:
    """The constants as the compiled kernel takes them.

    C-contiguous float arrays (one compiled specialization serves every call), empty arrays for
    None (:mod:`chatterspec._jit` kernels take no None).

    Parameters
    ----------
    consts : SVSFConstants
        The filter's constants.

    Returns
    -------
    SVSFConstants
        What :func:`compiled_recursion` takes.
    """
    PhiT, L, P, inv_psi, gamma, S_inv = consts
    c, empty2 = np.ascontiguousarray, np.empty((0, 0))
    return SVSFConstants(
        c(PhiT, dtype=float),
        empty2 if L is None else c(L, dtype=float),
        empty2 if P is None else c(P, dtype=float),
        np.empty(0) if inv_psi is None else c(inv_psi, dtype=float),
        float(gamma),
        c(S_inv, dtype=float),
    )


def with_initial(out: SVSFOutput, state: SVSFState, S_inv: np.ndarray, single: bool) -> SVSFOutput:
    """A whole record's outputs: sample 0 (the initial values) before the chunk's K = T - 1 samples.

    Parameters
    ----------
    out : SVSFOutput
        Outputs for samples 1 .. T-1, shapes (runs, T - 1, .).
    state : SVSFState
        The initial state (sample 0).
    S_inv : (n, n) array
        Maps ``y(0|0)`` to ``x(0|0)``.
    single : bool
        Drop the runs axis (the record was given as one 2-D ``z``).

    Returns
    -------
    SVSFOutput
        T samples: ``e_prior[:, 0] = 0`` (no prediction of z(0)), ``x_post[:, 0] = x(0|0)``,
        ``e_post[:, 0] = e(0|0)``, ``e_lower[:, 0] = 0``.
    """
    runs, m = state.e_post.shape
    n = state.y.shape[1]
    T = out.e_prior.shape[1] + 1

    def with_first(arr: np.ndarray | None, first: np.ndarray) -> np.ndarray | None:
        if arr is None:
            return None
        full = np.empty((runs, T, arr.shape[2]))
        full[:, 0] = first
        full[:, 1:] = arr
        return full[0] if single else full

    zeros_m = np.zeros((runs, m))
    return SVSFOutput(
        e_prior=cast(np.ndarray, with_first(out.e_prior, zeros_m)),  # (always kept)
        x_post=with_first(out.x_post, state.y @ S_inv.T),
        e_post=with_first(out.e_post, state.e_post),
        e_lower=with_first(out.e_lower, np.zeros((runs, n - m))),
    )
