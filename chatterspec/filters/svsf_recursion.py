"""The SVSF's recursion: its per-sample steps, the compiled loops built from them, its state and outputs,
and the three ways to advance it (eq 4-12 and eq 23 of the core paper).

:meth:`chatterspec.filters.svsf.SVSF.update` checks its input and picks one of these paths; each
gives the same bits for any chunking:

* :func:`closed_form_errors`: the auxiliary ``sgn`` filter with full measurement and
  ``e(k|k) = 0``, eq (23) vectorized over time (compiled loop or numpy, the same bits);
* :func:`compiled_recursion`: eq (4)-(12) sample by sample in the compiled kernel (numba);
* :func:`numpy_recursion`: eq (4)-(12) sample by sample in numpy, vectorized over realizations
  (the fallback without numba; BLAS orders the sums of its matrix products differently, so it
  agrees with the compiled kernel to rounding, 1e-12 of the measurement scale).

The filter's constants (:class:`SVSFConstants`) are in measurement-aligned coordinates ``y = S x``
(see :func:`chatterspec.filters.svsf.svsf_coordinates`).

**Steps.** Public because every loop that runs the SVSF is built from them: the batch kernels here
(:func:`_svsf_kernel`, :func:`_closed_form_kernel`, the one-sample :func:`_svsf_one`), the online
monitor's push (:mod:`chatterspec.online.monitor`) and the fused simulate-and-chatter loop
(:mod:`chatterspec.detection.pipeline`). The steps (:func:`chatterspec._jit.step`) are inlined by
numba into every loop that calls them and run as plain Python without numba:

* :func:`svsf_step`: one sample of the recursion of eq (4)-(12) (sat or sgn, full or reduced order);
* :func:`closed_form_step`: one channel of the auxiliary filter's closed form, eq (23);
* :func:`rows_times_step`, :func:`matvec_step`: the products ``G u(k)`` and ``S^-1 y`` summed in a
  fixed order.

The numpy helpers :func:`rows_times` (``a @ M^T`` in the order of :func:`rows_times_step`, so that
chunked and whole-record processing agree bit for bit) and :func:`switch` (``sat`` or ``sgn``, eq 8)
serve the numpy path. Every step is checked against eq (8)-(12) written out by hand
(``tests/test_steps.py``); the compiled loops against the numpy formulation (``tests/test_kernels.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from .protocol import finite_sample

__all__ = [
    "SVSFConstants",
    "SVSFOutput",
    "SVSFState",
    "closed_form_errors",
    "closed_form_step",
    "compiled_recursion",
    "copy_pair_step",
    "kernel_constants",
    "matvec_step",
    "numpy_recursion",
    "rows_times",
    "rows_times_step",
    "svsf_one_kernel",
    "svsf_one_offsets",
    "svsf_step",
    "switch",
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
        ``G u(k)`` per sample (:func:`rows_times`).
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
    """Eq (4)-(12) over a chunk in the compiled kernel (one :func:`svsf_step` per sample).

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


# ----------------------------------------------------------------------------- steps
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
def copy_pair_step(a: np.ndarray, b: np.ndarray, a2: np.ndarray, b2: np.ndarray, na: int, nb: int) -> None:
    """``a2 = a`` (``na`` entries), ``b2 = b`` (``nb``): a run's state into a loop's stack copy, and back."""
    for i in range(na):
        a2[i] = a[i]
    for i in range(nb):
        b2[i] = b[i]


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


# ----------------------------------------------------------------------------- compiled loops
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
        copy_pair_step(y[r], ep[r], yc, epc, n, m)
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
        copy_pair_step(yc, epc, y[r], ep[r], n, m)


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
