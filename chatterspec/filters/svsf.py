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
from .._validate import open_unit
from ..errors import ParameterError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, NonlinearModel, require_linear
from .one_sample import OnlineSVSF
from .protocol import channel_rows, check_initial_rows, check_record, check_svsf_chunk, svsf_store
from .svsf_coordinates import boundary_layer_inverse, svsf_coordinates
from .svsf_recursion import (
    SVSFConstants,
    SVSFOutput,
    SVSFState,
    closed_form_errors,
    compiled_recursion,
    kernel_constants,
    numpy_recursion,
    with_initial,
)
from .svsf_steps import rows_times as _rows_times

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

    model: Model
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
    _consts: SVSFConstants = field(init=False, repr=False)
    _kernel_consts: SVSFConstants = field(
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
        coords = svsf_coordinates(self.model)
        S, S_inv, L, P = coords.S, coords.S_inv, coords.L, coords.P
        object.__setattr__(self, "_S", S)
        object.__setattr__(self, "_S_inv", S_inv)
        object.__setattr__(self, "_PhiT", np.ascontiguousarray(coords.Phi.T))
        object.__setattr__(self, "_GT", np.ascontiguousarray(coords.G.T))
        object.__setattr__(self, "_L", L)
        object.__setattr__(self, "_P", P)
        n, m = self.model.n_states, self.model.n_outputs
        inv_psi = boundary_layer_inverse(self.switching, self.psi, self.psi_lower, n, m)
        object.__setattr__(self, "_inv_psi", inv_psi)
        consts = SVSFConstants(self._PhiT, L, P, inv_psi, self.gamma, S_inv)
        object.__setattr__(self, "_consts", consts)
        consts = kernel_constants(consts)
        object.__setattr__(self, "_kernel_consts", consts)

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
        z0 = channel_rows("z0", z0, m)
        runs = z0.shape[0]
        if x0 is None:
            y = np.zeros((runs, n))
            y[:, :m] = z0
        else:
            x0 = check_initial_rows(x0, n, runs)
            y = np.broadcast_to(x0 @ self._S.T, (runs, n)).copy()
        return SVSFState(y=y, e_post=z0 - y[:, :m], k=0)

    def online(self, z0: np.ndarray, x0: np.ndarray | None = None) -> OnlineSVSF:
        """One realization advanced one sample per call: ``f = svsf.online(z0)``, ``x = f.step(z, u)``.

        Parameters
        ----------
        z0 : (m,) array
            The first measurement ``z(0)`` (see :meth:`initialize`).
        x0 : (n,) array, optional
            Initial estimate (default ``C^-1 z(0)`` in the measured coordinates).

        Returns
        -------
        OnlineSVSF
            Each step gives the numbers of :meth:`update` on that sample; its ``e_prior`` is the
            chattering (``docs/filters.md``).
        """
        return OnlineSVSF(self, self.initialize(np.reshape(z0, (1, -1)), x0))

    def update(
        self,
        state: SVSFState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
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
        ``filters._svsf_kernels._svsf_kernel`` when :func:`chatterspec._jit.enabled` (numba
        installed, the ``fast`` extra), else in a numpy loop over samples,
        vectorized over realizations. Each path gives the same bits for any
        chunking; the two paths agree to rounding (1e-12 of the measurement
        scale, tests/test_kernels.py), since BLAS orders the sums of the
        numpy loop's matrix products differently.
        """
        if u is None:  # no input (docs/filters.md)
            u = np.zeros((np.shape(z)[-2], self.model.n_inputs))
        keep = svsf_store(store, "SVSF")
        z, u = check_svsf_chunk(z, u, state.runs, self.model.n_outputs, self.model.n_inputs, check)
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
        if closed_form and self._inv_psi is None and self._L is None and not state.e_post.any():
            return closed_form_errors(self._PhiT, self._S_inv, state, z, Gu, store_states, store_post_error)
        if _jit.enabled() and _jit.fits(n, m, vectors_only=True):
            return compiled_recursion(
                self._kernel_consts, state, z, Gu, store_states, store_post_error, store_lower
            )
        return numpy_recursion(self._consts, state, z, Gu, store_states, store_post_error, store_lower)

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray | None = None,
        store: Collection[str] | None = None,
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

        Returns
        -------
        SVSFOutput
            Arrays with T samples along axis 1. ``e_prior[:, 0]`` is 0 by
            convention (there is no prediction of z(0)); ``x_post[:, 0]`` is
            x(0|0) and ``e_post[:, 0]`` is e(0|0). A 2-D ``z`` gives 2-D outputs.
        """
        if u is None:  # no input: zeros
            u = np.zeros((np.shape(z)[-2] if np.ndim(z) >= 2 else 0, self.model.n_inputs))
        z, u, single = check_record(z, u)
        keep = svsf_store(store, "SVSF")
        state = self.initialize(z[:, 0], x0)
        wanted = {f for f, k in zip(("x_post", "e_post", "e_lower"), keep, strict=True) if k}
        _, out = self.update(state, z[:, 1:], u[..., :-1, :], store=wanted, check=False)
        return with_initial(out, state, self._S_inv, single)


def auxiliary_svsf(model: Model, gamma: float = 0.1) -> SVSF:
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
