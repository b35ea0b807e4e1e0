"""Smooth Variable Structure Filter (SVSF) and its auxiliary ``sgn`` variant.

Implements eq (4)-(12) of Saeedzadeh et al. (2023):

* prediction (4)-(5): ``x(k+1|k) = A x(k|k) + B u(k)``, ``z(k+1|k) = C x(k+1|k)``;
* output errors (6)-(7): ``e(k+1|k) = z(k+1) - z(k+1|k)``, ``e(k|k) = z(k) - C x(k|k)``;
* correction (8) for full measurement (C square and invertible)::

      K = C^-1 (|e(k+1|k)| + gamma |e(k|k)|) o sat(e(k+1|k) / psi)

* correction (9)-(11) for fewer measurements than states, through
  Luenberger's reduced-order form with ``Phi = T^-1 A T``::

      K_u = C1^-1 (|e(k+1|k)| + gamma |e(k|k)|) o sat(e(k+1|k) / psi_u)
      K_l = (|Phi22 Phi12^-1 e(k+1|k)| + gamma |Phi12^-1 e(k|k)|) o sat(Phi22 Phi12^-1 e(k+1|k) / psi_l)

* update (12): ``x(k+1|k+1) = x(k+1|k) + K``.

The auxiliary filter of section III replaces ``sat`` by ``sgn``; its a-priori
output error ``e(k|k-1)`` is the chattering signal (eq 17).

Implementation
--------------
The filter runs in measurement-aligned coordinates ``y = S x`` with
``S = [[C], [E_l]]`` (``E_l`` selects the states not used by ``C1``), so that
the first ``m`` coordinates *are* the measured outputs (``C S^-1 = [I 0]``).
For full measurement ``S = C`` and ``Phi = C A C^-1``; this is algebraically
identical to eq (4)-(12) and makes ``C1^-1`` the identity. There is one
kernel, :meth:`SVSF.update`, which advances any number of realizations
(leading axis) by a chunk of any length (1 sample for online use, the whole
record for batch use); :meth:`SVSF.run` is a thin loop-free wrapper around it.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array, open_unit
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel, require_linear
from ._conventions import svsf_store
from ._svsf_kernels import _closed_form_kernel, _rows_times, _svsf_kernel, _switch

__all__ = [
    "SVSF",
    "SVSFOutput",
    "SVSFState",
    "auxiliary_svsf",
    "boundary_layer_chattering",
    "chattering",
]

Switching = Literal["sat", "sgn"]


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


@dataclass(frozen=True, eq=False)
class SVSF:
    """SVSF with a smoothing boundary layer (``switching="sat"``) or the auxiliary ``sgn`` filter.

    Parameters
    ----------
    model : LinearModel
        Nominal model (A-hat, B-hat, C-hat).
    psi : float or array, optional
        Smoothing boundary layer (> 0), in output units. Length ``m`` for full
        measurement; for the reduced-order filter either ``m`` (measured part
        only; the unmeasured part then uses ``psi_lower``) or ``n`` values.
        Required for ``switching="sat"``, ignored for ``"sgn"``.
    gamma : float
        Convergence rate, ``0 < gamma < 1`` (eq 8).
    switching : {"sat", "sgn"}
        ``"sgn"`` gives the auxiliary filter of section III.
    psi_lower : float or array, optional
        Boundary layer of the unmeasured coordinates (reduced-order only).

    Raises
    ------
    ParameterError
        If ``psi <= 0`` or ``gamma`` is outside (0, 1).
    SingularMatrixError
        If the reduced-order transformation does not exist (``Phi12`` lacks
        full column rank, e.g. more unmeasured than measured states).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    model: LinearModel
    psi: float | np.ndarray | None = None
    gamma: float = 0.1
    switching: Switching = "sat"
    psi_lower: float | np.ndarray | None = None
    _S: np.ndarray = field(init=False, repr=False)
    _S_inv: np.ndarray = field(init=False, repr=False)
    _PhiT: np.ndarray = field(init=False, repr=False)
    _GT: np.ndarray = field(init=False, repr=False)
    _L: np.ndarray | None = field(init=False, repr=False)  # Phi22 Phi12^-1, (n-m, m)
    _P: np.ndarray | None = field(init=False, repr=False)  # Phi12^-1, (n-m, m)
    _inv_psi: np.ndarray | None = field(init=False, repr=False)
    _kernel_consts: tuple = field(
        init=False, repr=False
    )  # (PhiT, L, P, inv_psi, gamma, S_inv) for the kernel

    def __post_init__(self) -> None:
        if isinstance(self.model, NonlinearModel):  # a specific error, not a TypeError traceback
            require_linear(self.model, "the chattering SVSF (eq 8-11)")
        if not isinstance(self.model, LinearModel):
            raise TypeError(f"model must be a LinearModel; got {type(self.model).__name__}")
        object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        if self.switching not in ("sat", "sgn"):
            raise ParameterError(f"switching must be 'sat' or 'sgn'; got {self.switching!r}")
        model = self.model
        n, m = model.n_states, model.n_outputs
        if model.full_measurement:
            S = model.C.copy()
            S_inv = model.C_inv
        elif m == n:
            raise SingularMatrixError("C is square but singular: the SVSF needs C^-1 (eq 8)")
        else:
            S, S_inv = _reduced_order_transform(model.C)
        Phi = S @ model.A @ S_inv
        G = S @ model.B
        L = P = None
        if m < n:
            Phi12, Phi22 = Phi[:m, m:], Phi[m:, m:]
            if np.linalg.matrix_rank(Phi12) < n - m:
                raise SingularMatrixError(
                    f"reduced-order SVSF needs Phi12 ({m}x{n - m}) of full column rank "
                    f"{n - m} (eq 10): the unmeasured states must drive the measured ones "
                    "(and n - m <= m)"
                )
            P = np.linalg.pinv(Phi12)
            L = Phi22 @ P
        object.__setattr__(self, "_S", S)
        object.__setattr__(self, "_S_inv", S_inv)
        object.__setattr__(self, "_PhiT", np.ascontiguousarray(Phi.T))
        object.__setattr__(self, "_GT", np.ascontiguousarray(G.T))
        object.__setattr__(self, "_L", L)
        object.__setattr__(self, "_P", P)
        object.__setattr__(self, "_inv_psi", self._boundary_layer_inverse())
        # C-contiguous float constants of the compiled kernel (one specialization serves every call)
        c, empty2 = np.ascontiguousarray, np.empty((0, 0))
        consts = (
            c(self._PhiT, dtype=float),
            empty2 if L is None else c(L, dtype=float),
            empty2 if P is None else c(P, dtype=float),
            np.empty(0) if self._inv_psi is None else c(self._inv_psi, dtype=float),
            float(self.gamma),
            c(S_inv, dtype=float),
        )
        object.__setattr__(self, "_kernel_consts", consts)

    def _boundary_layer_inverse(self) -> np.ndarray | None:
        if self.switching == "sgn":
            return None
        n, m = self.model.n_states, self.model.n_outputs
        if self.psi is None:
            raise ParameterError("psi (smoothing boundary layer) is required for switching='sat'")
        psi = np.atleast_1d(finite_array("psi", self.psi, ndim=(0, 1)))
        if psi.size == 1:
            psi = np.full(m, psi[0])
        if m < n:
            if psi.size == m:
                lower = self.psi_lower
                if lower is None:
                    raise ParameterError(
                        "the reduced-order SVSF needs psi for all n states, or psi_lower for "
                        "the unmeasured ones"
                    )
                lower = np.atleast_1d(finite_array("psi_lower", lower, ndim=(0, 1)))
                psi = np.concatenate([psi, np.broadcast_to(lower, (n - m,))])
            if psi.size != n:
                raise ShapeError(f"psi must have 1, {m} or {n} entries; got {psi.size}")
        elif psi.size != m:
            raise ShapeError(f"psi must have 1 or {m} entries; got {psi.size}")
        if np.any(psi <= 0):
            raise ParameterError(f"psi must be > 0 (smoothing boundary layer); got {psi.tolist()}")
        return 1.0 / psi

    # ------------------------------------------------------------------ API
    @property
    def boundary_layer(self) -> np.ndarray | None:
        """The boundary layer psi per sat channel (measured first), or None for sgn."""
        return None if self._inv_psi is None else 1.0 / self._inv_psi

    def initialize(self, z0: np.ndarray, x0: np.ndarray | None = None) -> SVSFState:
        """Initial state from the first measurement ``z0`` of shape (runs, m) or (m,).

        With ``x0=None`` the measured coordinates start at ``z(0)`` (for full
        measurement ``x(0|0) = C^-1 z(0)``, zero initial output error, so the
        chattering equals eq 23 exactly) and the unmeasured ones at zero.
        ``x0`` of shape (n,) or (runs, n) overrides this.
        """
        m, n = self.model.n_outputs, self.model.n_states
        z0 = finite_array("z0", z0, ndim=(1, 2))
        if z0.ndim == 1:
            z0 = z0[None, :]
        if z0.shape[1] != m:
            raise ShapeError(f"z0 must have {m} channel(s); got shape {z0.shape}")
        runs = z0.shape[0]
        if x0 is None:
            y = np.zeros((runs, n))
            y[:, :m] = z0
        else:
            x0 = finite_array("x0", x0, ndim=(1, 2))
            if x0.shape[-1] != n or (x0.ndim == 2 and x0.shape[0] not in (1, runs)):
                raise ShapeError(f"x0 must have shape ({n},) or ({runs}, {n}); got {x0.shape}")
            y = np.broadcast_to(x0 @ self._S.T, (runs, n)).copy()
        return SVSFState(y=y, e_post=z0 - y[:, :m], k=0)

    def update(
        self,
        state: SVSFState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
        store_states: bool | None = None,
        store_post_error: bool | None = None,
        store_lower: bool | None = None,
        check: bool = True,
        closed_form: bool = True,
    ) -> tuple[SVSFState, SVSFOutput]:
        """Advance the filter over a chunk of K samples (the single SVSF kernel).

        Parameters
        ----------
        state : SVSFState
            State after sample ``k``.
        z : (runs, K, m) array
            Measurements ``z(k+1) .. z(k+K)``; ``(K, m)`` is accepted for one run.
        u : (K, p) or (runs, K, p) array, optional
            Inputs ``u(k) .. u(k+K-1)`` (the input that drives x(k) -> x(k+1)); None: zeros.
        store : collection of str, optional
            Also return ``"x_post"`` (``x(k|k)``), ``"e_post"`` (``e(k|k)``) and (reduced-order)
            ``"e_lower"`` per sample; ``e_prior`` (the chattering) is always returned.
        store_states, store_post_error, store_lower : bool, optional
            Deprecated spellings of ``store={"x_post"}``, ``{"e_post"}``, ``{"e_lower"}``
            (``DeprecationWarning``).
        check : bool
            Validate shapes and finiteness (turn off only in trusted hot loops).
        closed_form : bool
            Allow the closed-form evaluation of eq (22)-(23) described in Notes
            (default). ``False`` forces the sample-by-sample recursion; both
            give the same numbers up to rounding (tested to 1e-12 relative).

        Returns
        -------
        (SVSFState, SVSFOutput)

        Notes
        -----
        The measured coordinates are updated as ``y_u(k+1|k+1) = z(k+1) - e(k+1|k+1)``
        with ``e(k+1|k+1) = e(k+1|k) - K_u``, which is eq (12) rewritten with
        ``e(k+1|k) = z(k+1) - y_u(k+1|k)``. For the auxiliary ``sgn`` filter with
        full measurement this makes eq (20)-(22) exact in floating point: if
        ``e(k|k) = 0`` then ``K_u = |e| sgn(e) = e``, so ``e(k+1|k+1) = 0`` and
        ``y(k+1|k+1) = z(k+1)`` *exactly*, for every later sample. In that case
        (which the default initialization ``x(0|0) = C^-1 z(0)`` produces) the
        chunk is evaluated in closed form, vectorized over time as well as
        realizations (eq 23): ``e(k+1|k) = z(k+1) - Phi z(k) - G u(k)``, with
        element-wise arithmetic whose result does not depend on the chunk
        sizes, so batch and online processing agree bit for bit. Any other case
        (``sat``, reduced order, non-zero a-posteriori error) runs the
        recursion of eq (4)-(12) sample by sample: in the compiled kernel
        ``_svsf_kernel`` when :func:`chatterspec._jit.enabled` (numba
        installed, the ``fast`` extra), else in a numpy loop over samples,
        vectorized over realizations. Each path gives the same bits for any
        chunking; the two paths agree to rounding (1e-12 of the measurement
        scale, tests/test_kernels.py), since BLAS orders the sums of the
        numpy loop's matrix products differently.
        """
        if u is None:  # no input (docs/filters.md)
            u = np.zeros((np.shape(z)[-2], self.model.n_inputs))
        keep = svsf_store(store, store_states, store_post_error, store_lower, "SVSF")
        z, u = check_chunk(z, u, state.runs, self.model.n_outputs, self.model.n_inputs, check)
        Gu = _rows_times(u, self._GT)  # (K, n) or (runs, K, n): G u(k), element-wise
        return self._advance(state, z, Gu, *keep, closed_form)

    def _advance(
        self,
        state: SVSFState,
        z: np.ndarray,
        Gu: np.ndarray,
        store_states: bool = False,
        store_post_error: bool = False,
        store_lower: bool = False,
        closed_form: bool = True,
    ) -> tuple[SVSFState, SVSFOutput]:
        """:meth:`update` after its checks, from ``Gu`` = G u(k) ((K, n) or (runs, K, n), ``_rows_times``).

        ``z`` is a float (runs, K, m) array. The online monitor calls this directly with one ``Gu``
        for both its filters (same model, same G): the numbers are those of :meth:`update`.
        """
        m, n = self.model.n_outputs, self.model.n_states
        runs, K = z.shape[0], z.shape[1]
        if closed_form and self._inv_psi is None and self._L is None and not state.e_post.any():
            return self._update_closed_form(state, z, Gu, store_states, store_post_error)
        if _jit.enabled() and _jit.fits(n, m, vectors_only=True):
            return self._update_compiled(state, z, Gu, store_states, store_post_error, store_lower)
        # time-major working copies
        zt = np.ascontiguousarray(np.swapaxes(z, 0, 1))  # (K, runs, m)
        if Gu.ndim == 3:
            Gu = np.ascontiguousarray(np.swapaxes(np.broadcast_to(Gu, (runs, K, n)), 0, 1))
        e_out = np.empty((K, runs, m))
        x_out = np.empty((K, runs, n)) if store_states else None
        ep_out = np.empty((K, runs, m)) if store_post_error else None
        lower_out = np.empty((K, runs, n - m)) if (store_lower and n > m) else None

        PhiT, gamma = self._PhiT, self.gamma
        inv_psi = self._inv_psi
        inv_psi_u = None if inv_psi is None else inv_psi[:m]
        inv_psi_l = None if inv_psi is None else inv_psi[m:]
        reduced = self._L is not None
        LT = None if self._L is None else np.ascontiguousarray(self._L.T)
        PT = None if self._P is None else np.ascontiguousarray(self._P.T)
        S_invT = np.ascontiguousarray(self._S_inv.T)
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
            _switch(e, inv_psi_u, out=Ku)
            Ku *= mag
            if reduced:
                # eq (10): K_l = (|Phi22 Phi12^-1 e(k+1|k)| + gamma |Phi12^-1 e(k|k)|)
                #                o sat(Phi22 Phi12^-1 e(k+1|k), psi_l)
                Le = e @ LT
                mag_l = np.abs(Le)
                mag_l += gamma * np.abs(ep @ PT)
                if lower_out is not None:
                    lower_out[k] = Le
                Kl = _switch(Le, inv_psi_l)
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

    def _update_compiled(
        self,
        state: SVSFState,
        z: np.ndarray,
        Gu: np.ndarray,
        store_states: bool,
        store_post_error: bool,
        store_lower: bool,
    ) -> tuple[SVSFState, SVSFOutput]:
        """The recursion of eq (4)-(12) in the compiled kernel :func:`_svsf_kernel` (see :mod:`.._jit`)."""
        runs, K, m = z.shape
        n = self.model.n_states
        # C-contiguous float arrays only, so that one compiled specialization serves every call
        c = np.ascontiguousarray
        z = c(z, dtype=float)
        Gu = c(Gu[None] if Gu.ndim == 2 else Gu, dtype=float)
        none = np.empty((0, 0, 0))
        e_out = np.empty((runs, K, m))
        x_out = np.empty((runs, K, n)) if store_states else none
        ep_out = np.empty((runs, K, m)) if store_post_error else none
        lower_out = np.empty((runs, K, n - m)) if (store_lower and n > m) else none
        PhiT, L, P, inv_psi, gamma, S_inv = self._kernel_consts
        y = np.array(state.y, dtype=float, order="C", copy=True)
        ep = np.array(state.e_post, dtype=float, order="C", copy=True)
        _svsf_kernel(z, Gu, PhiT, L, P, inv_psi, gamma, S_inv, y, ep, e_out, x_out, ep_out, lower_out)
        return SVSFState(y=y, e_post=ep, k=state.k + K), SVSFOutput(
            e_prior=e_out,
            x_post=x_out if store_states else None,
            e_post=ep_out if store_post_error else None,
            e_lower=lower_out if lower_out.shape[0] else None,
        )

    def _update_closed_form(
        self, state: SVSFState, z: np.ndarray, Gu: np.ndarray, store_states: bool, store_post_error: bool
    ) -> tuple[SVSFState, SVSFOutput]:
        """Eq (23) for the sgn filter with e(k|k) = 0: vectorized over time (see :meth:`update`)."""
        runs, K, m = z.shape
        n = m
        PhiT = self._PhiT
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
            x_post = _rows_times(z, np.ascontiguousarray(self._S_inv.T))
        y_last = np.array(z[:, -1, :], dtype=float, copy=True)
        new_state = SVSFState(y=y_last, e_post=np.zeros((runs, m)), k=state.k + K)
        e_post = np.zeros((runs, K, m)) if store_post_error else None  # exactly zero (see update)
        return new_state, SVSFOutput(e_prior=e, x_post=x_post, e_post=e_post)

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray | None = None,
        store: Collection[str] | None = None,
        store_states: bool | None = None,
        store_post_error: bool | None = None,
        store_lower: bool | None = None,
    ) -> SVSFOutput:
        """Filter whole records (batch mode) with the same kernel as :meth:`update`.

        Parameters
        ----------
        z : (runs, T, m) or (T, m) array
            Measurements z(0) .. z(T-1).
        u : (T, p), (runs, T, p) or (T,) array, optional
            Inputs u(0) .. u(T-1) (the last one is not used); None: no input (zeros).
        x0 : array, optional
            Initial estimate x(0|0); default ``C^-1 z(0)`` (see :meth:`initialize`).
        store : collection of str, optional
            ``"x_post"``, ``"e_post"``, ``"e_lower"`` (see :meth:`update`).
        store_states, store_post_error, store_lower : bool, optional
            Deprecated spellings of ``store`` (see :meth:`update`).

        Returns
        -------
        SVSFOutput
            Arrays with T samples along axis 1. ``e_prior[:, 0]`` is 0 by
            convention (there is no prediction of z(0)); ``x_post[:, 0]`` is
            x(0|0) and ``e_post[:, 0]`` is e(0|0). A 2-D ``z`` gives 2-D outputs.
        """
        z = finite_array("z", z, ndim=(2, 3))
        single = z.ndim == 2
        if single:
            z = z[None]
        u = finite_array("u", np.zeros((z.shape[1], self.model.n_inputs)) if u is None else u, ndim=(1, 2, 3))
        if u.ndim == 1:
            u = u[:, None]
        T = z.shape[1]
        if u.shape[-2] != T:
            raise ShapeError(f"u must have {T} samples (like z) along its time axis; got {u.shape}")
        if T < 2:
            raise ShapeError(f"z needs at least 2 samples; got {T}")
        keep = svsf_store(store, store_states, store_post_error, store_lower, "SVSF")
        state = self.initialize(z[:, 0], x0)
        wanted = {f for f, k in zip(("x_post", "e_post", "e_lower"), keep, strict=True) if k}
        _, out = self.update(state, z[:, 1:], u[..., :-1, :], store=wanted, check=False)
        runs, m, n = z.shape[0], self.model.n_outputs, self.model.n_states

        def with_first(arr: np.ndarray | None, first: np.ndarray) -> np.ndarray | None:
            if arr is None:
                return None
            full = np.empty((runs, T, arr.shape[2]))
            full[:, 0] = first
            full[:, 1:] = arr
            return full[0] if single else full

        zeros_m = np.zeros((runs, m))
        return SVSFOutput(
            e_prior=with_first(out.e_prior, zeros_m),
            x_post=with_first(out.x_post, state.y @ self._S_inv.T),
            e_post=with_first(out.e_post, state.e_post),
            e_lower=with_first(out.e_lower, np.zeros((runs, n - m))),
        )


def check_chunk(
    z: np.ndarray, u: np.ndarray, runs: int, m: int, p: int, check: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Measurements ``z`` as (runs, K, m) and inputs ``u`` as (K, p) or (runs, K, p) of an SVSF update.

    Validates finiteness when ``check``; a 2-D ``z`` is one run, a 1-D ``u`` one input channel.

    Raises
    ------
    ShapeError
        Shapes that do not match the filter.
    NonFiniteError
        NaN or inf (with ``check``).
    """
    if check:
        z = finite_array("z", z, ndim=(2, 3))
        u = finite_array("u", u, ndim=(1, 2, 3))
    if z.ndim == 2:
        z = z[None]
    if z.shape[0] != runs or z.shape[2] != m:
        raise ShapeError(f"z must have shape ({runs}, K, {m}); got {z.shape}")
    K = z.shape[1]
    if u.ndim == 1:
        u = u[:, None]
    if u.shape[-2] != K or u.shape[-1] != p or (u.ndim == 3 and u.shape[0] not in (1, runs)):
        raise ShapeError(f"u must have shape ({K}, {p}) or ({runs}, {K}, {p}); got {u.shape}")
    return z, u


def auxiliary_svsf(model: LinearModel, gamma: float = 0.1) -> SVSF:
    """The auxiliary filter of section III: the SVSF with ``sgn`` instead of ``sat`` (eq 17).

    Parameters
    ----------
    model : LinearModel
        Nominal model (A-hat, B-hat, C-hat of eq 3).
    gamma : float
        Convergence rate in (0, 1) (eq 8); with ``x(0|0) = C^-1 z(0)`` it has no
        effect on the chattering (eq 21-23).

    Returns
    -------
    SVSF
        ``SVSF(model, gamma=gamma, switching="sgn")``.
    """
    return SVSF(model, gamma=gamma, switching="sgn")


def boundary_layer_chattering(e: np.ndarray, psi: float | np.ndarray) -> np.ndarray:
    """Chattering of the smoothing-boundary-layer SVSF, eq (13).

    ``(|e| - psi) sgn(e)`` where ``|e| > psi`` and 0 elsewhere, per channel
    (``psi`` broadcasts along the last axis).

    Parameters
    ----------
    e : array (..., m)
        Output errors, in output units.
    psi : float or (m,) array
        Smoothing boundary layer (> 0), in output units.

    Returns
    -------
    array like ``e``
        The part of ``e`` outside the boundary layer.

    See Also
    --------
    chattering : the auxiliary ``sgn`` filter's chattering (eq 17).
    """
    e = np.asarray(e, dtype=float)
    psi = np.asarray(psi, dtype=float)
    if np.any(psi <= 0):
        raise ParameterError(f"psi must be > 0; got {psi.tolist()}")
    excess = np.abs(e) - psi
    return np.where(excess > 0, excess * np.sign(e), 0.0)


def chattering(
    model: LinearModel | NonlinearModel,
    z: np.ndarray,
    u: np.ndarray | None = None,
    *,
    gamma: float = 0.1,
    x0: np.ndarray | None = None,
) -> np.ndarray:
    """Chattering of the auxiliary (sgn) SVSF, eq (17): ``e(k|k-1)``.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        Nominal model used by the filter. A
        :class:`~chatterspec.plants.nonlinear.NonlinearModel` (full measurement) goes to
        :func:`~chatterspec.filters.nonlinear_svsf.nonlinear_chattering` (eq 23 with the nonlinear
        prediction), as :func:`chatterspec.simulate` accepts such models too.
    z : (runs, T, m) or (T, m) array
        Measurements.
    u : (T, p), (runs, T, p) or (T,) array, optional
        Inputs; None: no input (zeros).
    gamma : float
        Convergence rate in (0, 1); with the default initialization it has no
        effect after the first step (e(k|k) = 0).
    x0 : array, optional
        Initial estimate; default ``C^-1 z(0)``.

    Returns
    -------
    ndarray, same leading shape as ``z``
        ``out[..., k, :] = e(k|k-1)`` for k >= 1; ``out[..., 0, :] = 0``.
        Spectral analysis uses samples 1..T-1 (N = T - 1 samples).

    Raises
    ------
    DivergenceError
        A nonlinear ``f`` returned NaN/inf (the message names the first such sample).

    See Also
    --------
    chatterspec.filters.nonlinear_svsf.nonlinear_chattering : the nonlinear model's chattering.
    """
    if u is None:  # no input (docs/filters.md)
        u = np.zeros((np.shape(z)[-2], model.n_inputs))
    if isinstance(model, NonlinearModel):
        from .nonlinear_svsf import nonlinear_chattering

        return nonlinear_chattering(model, z, u, gamma=gamma, x0=x0)
    return auxiliary_svsf(model, gamma).run(z, u, x0=x0).e_prior


def _reduced_order_transform(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Luenberger transformation ``S = [[C], [E_l]]`` for eq (9)-(11).

    ``E_l`` selects the states left out of ``C1`` (the m columns of C chosen
    by pivoted QR, i.e. the best-conditioned square sub-block). Measured
    coordinates come first. Returns ``(S, S^-1)``.
    """
    import scipy.linalg

    m, n = C.shape
    _, _, piv = scipy.linalg.qr(C, pivoting=True, mode="economic")
    measured = sorted(piv[:m].tolist())
    lower = [j for j in range(n) if j not in measured]
    E = np.zeros((n - m, n))
    E[np.arange(n - m), lower] = 1.0
    S = np.vstack([C, E])
    if np.linalg.cond(S) > 1e12:
        raise SingularMatrixError("no square invertible C1 block exists in C (eq 9)")
    return S, np.linalg.inv(S)
