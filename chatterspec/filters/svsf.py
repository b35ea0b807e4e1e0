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
Its recursion (steps, compiled loops, state) is :mod:`chatterspec.filters.svsf_recursion`.

Coordinates (eq 8-11)
---------------------
:func:`svsf_coordinates` gives ``S`` and ``Phi``: for full measurement ``S = C`` and
``Phi = C A C^-1`` (eq 8); for fewer measurements than states Luenberger's reduced-order form
(eq 9-11) with ``L = Phi22 Phi12^-1`` and ``P = Phi12^-1``; :func:`boundary_layer_inverse` the
per-coordinate ``1/psi``.

Nonlinear nominal model
-----------------------
The chattering paper defines the chattering for a linear model. With a nonlinear nominal model
``x(k+1) = f(x(k), u(k))`` (:class:`~chatterspec.plants.nonlinear.NonlinearModel`, full measurement:
``C`` square and invertible) only the prediction (eq 4) changes: ``x(k+1|k) = f(x(k|k), u(k))``;
the correction (eq 8, sgn) ``K = C^-1 (|e(k+1|k)| + gamma |e(k|k)|) o sgn(e(k+1|k))`` and the
update (eq 12) are the paper's (:class:`NonlinearSgnSVSF`). In measured coordinates ``y = C x``,
``y(k+1|k+1) = z(k+1) - e(k+1|k+1)`` with ``e(k+1|k+1) = e(k+1|k) - C K``; when ``e(k|k) = 0`` then
``C K = e`` exactly, so ``y(k+1|k+1) = z(k+1)`` bit for bit (eq 20-22, which do not use linearity).
With the default ``x(0|0) = C^-1 z(0)`` this holds at every sample, and the chattering has the
closed form ``e(k+1|k) = z(k+1) - C f(C^-1 z(k), u(k))`` (eq 23, nonlinear), which
:meth:`NonlinearSgnSVSF.update` evaluates vectorized over realizations *and* time
(:func:`nonlinear_chattering`); the recursion is used otherwise (``x0`` given), and both agree to
rounding. Beyond the paper: a nonlinear model has no closed-form spectrum (eq 56 uses linearity),
so its thresholds are estimated from healthy runs (:mod:`chatterspec.detection.thresholds`). The
reduced-order form (eq 9-11) needs the constant ``Phi`` of a linear model: full measurement only.

Healthy chattering variance (section II-III, Fig 2)
---------------------------------------------------
The SVSF chatters (eq 13) whenever ``|e_i(k|k-1)| > psi_i``. Under healthy conditions the auxiliary
(``sgn``) filter started at ``x(0|0) = C^-1 z(0)`` (or ``z(0)`` on the measured coordinates of the
reduced-order filter) is a *linear* filter: ``e(k|k) = 0`` for every k, the measured coordinates of
the a-posteriori estimate equal the measurements, and the unmeasured ones are corrected by
``L e(k+1|k)`` with ``L = Phi22 Phi12^-1`` (eq 10). With the error ``eps(k) = S x(k) - y(k|k)`` in
the filter's coordinates (``Phi = S A S^-1``, ``H = [I 0]``, ``J = [I; L]``)::

    eps(k+1)  = (I - J H) (Phi eps(k) + S v(k)) - J w(k+1)
    e(k+1|k)  = H Phi eps(k) + H S v(k) + w(k+1)

so the healthy chattering is zero-mean Gaussian with the stationary variance

    Var e = H Phi P Phi^T H^T + H S Q S^T H^T + R,
    P = F P F^T + (I - J H) S Q S^T (I - J H)^T + J R J^T,   F = (I - J H) Phi

(:func:`healthy_chattering_variance`). For full measurement ``F = 0`` and this is
``gamma0 = diag(C Q C^T + R + M R M^T)``, ``M = -C A C^-1`` (eq 23). For the reduced-order Fig 2
setup (f0 2 Hz, zeta 0, C = [1 0], q = (1e-10, 1e-8), r = 1e-8) the measured chattering is the
MA(2) sequence::

    e(k+2|k+1) = w(k+2) - (1 + A22) w(k+1) + (A22 - Ts A21) w(k)
                 + v1(k+1) - A22 v1(k) + Ts v2(k)

whose variance is ``r (1 + 4 + (1 + Ts^2 w0^2)^2) + 2 q1 + Ts^2 q2 = 6.02e-8``. Eq (34) keeps only
``w(k) - w(k-1)`` and one ``v1`` pair and prints ``2.02e-8`` (``docs/design.md`` C7); the paper's
"0.067" after eq (35) is a percentage, not a probability. The Monte Carlo estimate
(``estimate_boundary_layer``: ``psi = sigma * Phi^-1(1 - p/2)`` for a target per-sample chattering
probability ``p``) and the Fig 2 study (``boundary_layer_study``) are in
:mod:`chatterspec.studies.boundary_layer`.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import numpy.typing as npt

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array, open_unit
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, NonlinearModel, require_linear, require_linear_measurement
from .one_sample import OnlineSVSF
from .protocol import (
    channel_rows,
    check_initial_rows,
    check_record,
    check_svsf_chunk,
    require_finite,
    store_flags,
    svsf_store,
)
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
from .svsf_recursion import rows_times as _rows_times

__all__ = [
    "SVSF",
    "NonlinearSVSFOutput",
    "NonlinearSVSFState",
    "NonlinearSgnSVSF",
    "SVSFCoordinates",
    "SVSFOutput",
    "SVSFState",
    "auxiliary_svsf",
    "boundary_layer_chattering",
    "boundary_layer_inverse",
    "chattering",
    "healthy_chattering_variance",
    "nonlinear_chattering",
    "reduced_order_transform",
    "svsf_coordinates",
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
        """One realization advanced one sample per call: ``f = online(z0)``, ``x = f.step(z, u)``.

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
        ``filters.svsf_recursion._svsf_kernel`` when :func:`chatterspec._jit.enabled` (numba
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
        :func:`nonlinear_chattering` (eq 23 with the nonlinear
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
    nonlinear_chattering : the nonlinear model's chattering.
    """
    if u is None:  # no input (docs/filters.md)
        u = np.zeros((np.shape(z)[-2], model.n_inputs))
    if isinstance(model, NonlinearModel):
        return nonlinear_chattering(model, z, u, gamma=gamma, x0=x0)
    return auxiliary_svsf(model, gamma).run(z, u, x0=x0).e_prior


# ----------------------------------------------------------------------------- coordinates
@dataclass(frozen=True, eq=False)
class SVSFCoordinates:
    """The SVSF's model in measurement-aligned coordinates ``y = S x`` (eq 8-11).

    Attributes
    ----------
    S, S_inv : (n, n) arrays
        The transformation and its inverse.
    Phi : (n, n) array
        ``S A S^-1``.
    G : (n, p) array
        ``S B``.
    L : (n - m, m) array or None
        ``Phi22 Phi12^-1`` (eq 10); None for full measurement.
    P : (n - m, m) array or None
        ``Phi12^-1`` (pseudo-inverse, eq 10); None for full measurement.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    S: np.ndarray
    S_inv: np.ndarray
    Phi: np.ndarray
    G: np.ndarray
    L: np.ndarray | None
    P: np.ndarray | None


def svsf_coordinates(model: LinearModel) -> SVSFCoordinates:
    """The SVSF's coordinates for ``model``: ``S = C`` (full measurement) or Luenberger's form.

    Parameters
    ----------
    model : LinearModel
        Nominal model (A-hat, B-hat, C-hat of eq 3).

    Returns
    -------
    SVSFCoordinates

    Raises
    ------
    SingularMatrixError
        ``C`` square but singular, or ``Phi12`` without full column rank (eq 10: the unmeasured
        states must drive the measured ones, and ``n - m <= m``).
    """
    n, m = model.n_states, model.n_outputs
    if model.full_measurement:
        S = model.C.copy()
        S_inv = model.C_inv
    elif m == n:
        raise SingularMatrixError("C is square but singular: the SVSF needs C^-1 (eq 8)")
    else:
        S, S_inv = reduced_order_transform(model.C)
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
    return SVSFCoordinates(S=S, S_inv=S_inv, Phi=Phi, G=G, L=L, P=P)


def boundary_layer_inverse(
    switching: str, psi: npt.ArrayLike | None, psi_lower: npt.ArrayLike | None, n: int, m: int
) -> np.ndarray | None:
    """``1 / psi`` per switching channel (measured first), or None for ``sgn`` (eq 8-10).

    Parameters
    ----------
    switching : {"sat", "sgn"}
        ``"sgn"`` needs no boundary layer.
    psi : float or array or None
        Boundary layer (> 0, output units): 1 or ``m`` values, or ``n`` for the reduced order.
    psi_lower : float or array or None
        Boundary layer of the ``n - m`` unmeasured coordinates when ``psi`` has ``m`` values.
    n, m : int
        States and outputs.

    Returns
    -------
    (m,) or (n,) array or None

    Raises
    ------
    ParameterError
        ``psi`` missing for ``sat``, or not > 0; ``psi_lower`` missing where needed.
    ShapeError
        ``psi`` with a number of entries that fits neither ``m`` nor ``n``.
    """
    if switching == "sgn":
        return None
    if psi is None:
        raise ParameterError("psi (smoothing boundary layer) is required for switching='sat'")
    psi = np.atleast_1d(finite_array("psi", psi, ndim=(0, 1)))
    if psi.size == 1:
        psi = np.full(m, psi[0])
    if m < n:
        if psi.size == m:
            lower = psi_lower
            if lower is None:
                raise ParameterError(
                    "the reduced-order SVSF needs psi for all n states, or psi_lower for the unmeasured ones"
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


def reduced_order_transform(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Luenberger transformation ``S = [[C], [E_l]]`` for eq (9)-(11).

    ``E_l`` selects the states left out of ``C1`` (the m columns of C chosen by pivoted QR, i.e. the
    best-conditioned square sub-block). Measured coordinates come first.

    Parameters
    ----------
    C : (m, n) array
        Output matrix, m < n.

    Returns
    -------
    (S, S_inv) : tuple of (n, n) arrays

    Raises
    ------
    SingularMatrixError
        No square invertible ``C1`` block exists in ``C``.
    """
    import scipy.linalg  # on first use: importing the SVSF does not import scipy.linalg

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


# ----------------------------------------------------------------------------- nonlinear nominal model
@dataclass(frozen=True, eq=False)
class NonlinearSVSFState:
    """Filter state after sample ``k`` (one row per realization).

    Attributes
    ----------
    y : (runs, m) array
        Measured coordinates ``C x(k|k)`` (equal to ``z(k)`` while ``e(k|k) = 0``).
    e_post : (runs, m) array
        A posteriori output error ``e(k|k)`` (eq 7).
    k : int
        Index of the last processed sample.
    """

    y: np.ndarray
    e_post: np.ndarray
    k: int = 0

    @property
    def runs(self) -> int:
        """Number of realizations."""
        return self.y.shape[0]


@dataclass(frozen=True, eq=False)
class NonlinearSVSFOutput:
    """Per-sample outputs of :meth:`NonlinearSgnSVSF.update` / :meth:`NonlinearSgnSVSF.run`.

    Attributes
    ----------
    e_prior : (runs, K, m) array
        A priori output error ``e(k|k-1)``: the chattering (eq 17), in output units.
    x_post : (runs, K, n) array or None
        ``x(k|k)`` if requested.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    e_prior: np.ndarray
    x_post: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class NonlinearSgnSVSF:
    """Auxiliary ``sgn`` SVSF (eq 4-8, 12, 17) of a nonlinear (or linear) nominal model, full measurement.

    Parameters
    ----------
    model : NonlinearModel or LinearModel
        Nominal model; only ``transition(x, u)``, ``C``, ``n_inputs`` and the sizes are used.
    gamma : float
        Convergence rate in (0, 1) (eq 8); without effect while ``e(k|k) = 0``.

    Raises
    ------
    SingularMatrixError
        If ``C`` is not square and invertible (only full measurement is supported).
    ParameterError
        If ``gamma`` is outside (0, 1).
    """

    model: NonlinearModel | LinearModel
    gamma: float = 0.1
    _CT: np.ndarray = field(init=False, repr=False)
    _CinvT: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        require_linear_measurement(self.model, "the chattering SVSF")
        if not isinstance(self.model, NonlinearModel | LinearModel):
            raise ParameterError(
                f"model must be a NonlinearModel or LinearModel; got {type(self.model).__name__}"
            )
        object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        if not self.model.full_measurement:
            raise SingularMatrixError(
                f"the nonlinear sgn-SVSF needs full measurement (C square and invertible, eq 8); "
                f"{self.model.name!r} measures {self.model.n_outputs} of {self.model.n_states} states"
            )
        object.__setattr__(self, "_CT", np.ascontiguousarray(self.model.C.T))
        object.__setattr__(self, "_CinvT", np.ascontiguousarray(self.model.C_inv.T))

    def initialize(self, z0: np.ndarray, x0: np.ndarray | None = None) -> NonlinearSVSFState:
        """Initial state from the first measurement ``z0`` (runs, m) or (m,).

        Parameters
        ----------
        z0 : (runs, m) or (m,) array
            Measurement z(0).
        x0 : (n,) or (runs, n) array, optional
            Initial estimate x(0|0); default ``C^-1 z(0)`` (zero initial output error, so the
            chattering is the closed form of the module docstring).

        Returns
        -------
        NonlinearSVSFState
        """
        m = self.model.n_outputs
        z0 = channel_rows("z0", z0, m)
        runs = z0.shape[0]
        if x0 is None:
            y = z0.copy()
        else:
            x0 = check_initial_rows(x0, m, runs)
            y = np.broadcast_to(_rows_times(x0, self._CT), (runs, m)).copy()
        return NonlinearSVSFState(y=y, e_post=z0 - y, k=0)

    def update(
        self,
        state: NonlinearSVSFState,
        z: np.ndarray,
        u: np.ndarray,
        *,
        store: Collection[str] | None = None,
        closed_form: bool = True,
        check: bool = True,
    ) -> tuple[NonlinearSVSFState, NonlinearSVSFOutput]:
        """Advance all realizations by a chunk of K samples (online: K = 1; batch: the record).

        Parameters
        ----------
        state : NonlinearSVSFState
            State after sample ``k``.
        z : (runs, K, m) or (K, m) array
            Measurements ``z(k+1) .. z(k+K)``.
        u : (K, p) or (runs, K, p) array
            Inputs ``u(k) .. u(k+K-1)``.
        store : collection of str, optional
            ``{"x_post"}``: also return ``x(k|k)`` per sample (``e_prior`` is always returned).
        closed_form : bool
            Allow the closed form (eq 23, nonlinear) when ``e(k|k) = 0``; ``False`` forces the
            sample-by-sample recursion (same numbers up to rounding).
        check : bool
            Validate finiteness (turn off only in trusted hot loops); shapes are always checked.

        Returns
        -------
        (NonlinearSVSFState, NonlinearSVSFOutput)
            The chattering of every sample depends only on ``z(k)``, ``z(k+1)`` and ``u(k)``,
            evaluated element-wise, so any chunking gives the same bits.
        """
        (store_states,) = store_flags(
            store, ("x_post",), frozenset({"x_post"}), "NonlinearSgnSVSF", "e_prior is always returned"
        )
        m = self.model.n_outputs
        runs = state.runs
        z, u = check_svsf_chunk(z, u, runs, m, self.model.n_inputs, check)
        K = z.shape[1]
        if closed_form and not np.any(state.e_post):
            y_prev = np.concatenate([state.y[:, None, :], z[:, :-1, :]], axis=1)  # y(j|j) = z(j)
            x_prev = _rows_times(y_prev, self._CinvT)
            with np.errstate(over="ignore", invalid="ignore"):  # checked just below
                x_pred = np.asarray(self.model.transition(x_prev, u), dtype=float)  # eq 4
                e = z - _rows_times(x_pred, self._CT)  # eq 6
            require_finite(type(self).__name__, (e,), {"e_prior": e}, state.k, K)
            x_post = _rows_times(z, self._CinvT) if store_states else None
            new = NonlinearSVSFState(y=z[:, -1, :].copy(), e_post=np.zeros((runs, m)), k=state.k + K)
            return new, NonlinearSVSFOutput(e_prior=e, x_post=x_post)
        e_out = np.empty((runs, K, m))
        x_out = np.empty((runs, K, m)) if store_states else None
        y, ep = state.y.copy(), state.e_post.copy()
        for k in range(K):
            uk = u[..., k, :]
            x_pred = np.asarray(self.model.transition(_rows_times(y, self._CinvT), uk), dtype=float)
            e = z[:, k] - _rows_times(x_pred, self._CT)  # eq 6
            CK = (np.abs(e) + self.gamma * np.abs(ep)) * np.sign(e)  # C K of eq 8 (sgn)
            ep = e - CK  # e(k+1|k+1)
            y = z[:, k] - ep  # eq 12 in measured coordinates
            e_out[:, k] = e
            if x_out is not None:
                x_out[:, k] = _rows_times(y, self._CinvT)
        require_finite(type(self).__name__, (y, e_out), {"e_prior": e_out}, state.k, K)
        new = NonlinearSVSFState(y=y, e_post=ep, k=state.k + K)
        return new, NonlinearSVSFOutput(e_prior=e_out, x_post=x_out)

    def run(self, z: np.ndarray, u: np.ndarray, *, x0: np.ndarray | None = None) -> NonlinearSVSFOutput:
        """Filter whole records (batch): ``e_prior[:, 0] = 0`` (no prediction of z(0)).

        Parameters
        ----------
        z : (runs, T, m) or (T, m) array
            Measurements z(0) .. z(T-1).
        u : (T, p), (runs, T, p) or (T,) array
            Inputs u(0) .. u(T-1) (the last one is not used).
        x0 : array, optional
            Initial estimate x(0|0); default ``C^-1 z(0)``.

        Returns
        -------
        NonlinearSVSFOutput
            ``e_prior`` with T samples (2-D for a 2-D ``z``).
        """
        z, u, single = check_record(z, u)
        state = self.initialize(z[:, 0], x0)
        _, out = self.update(state, z[:, 1:], u[..., :-1, :])
        e = np.zeros(z.shape)
        e[:, 1:] = out.e_prior
        return NonlinearSVSFOutput(e_prior=e[0] if single else e)


def nonlinear_chattering(
    model: NonlinearModel | LinearModel,
    z: np.ndarray,
    u: np.ndarray,
    *,
    gamma: float = 0.1,
    x0: np.ndarray | None = None,
) -> np.ndarray:
    """Chattering ``e(k|k-1)`` (eq 17) of the auxiliary sgn-SVSF of a nonlinear nominal model.

    Parameters
    ----------
    model : NonlinearModel or LinearModel
        Nominal model (full measurement).
    z : (runs, T, m) or (T, m) array
        Measurements.
    u : (T, p), (runs, T, p) or (T,) array
        Inputs.
    gamma : float
        Convergence rate in (0, 1) (eq 8).
    x0 : array, optional
        Initial estimate; default ``C^-1 z(0)``.

    Returns
    -------
    ndarray, same shape as ``z``
        ``out[..., k, :] = e(k|k-1)`` for k >= 1; ``out[..., 0, :] = 0``.
    """
    return NonlinearSgnSVSF(model, gamma).run(z, u, x0=x0).e_prior


# ----------------------------------------------------------------------------- healthy chattering variance
def _filter_matrices(model: LinearModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(S, Phi, L)`` of the SVSF in measurement-aligned coordinates (L is (n-m, m), maybe empty)."""
    aux = auxiliary_svsf(model)  # validates C / Phi12 and builds the transformation
    S = aux._S
    Phi = aux._PhiT.T
    m, n = model.n_outputs, model.n_states
    L = np.zeros((n - m, m)) if aux._L is None else aux._L
    return S, Phi, L


def healthy_chattering_variance(model: LinearModel) -> tuple[np.ndarray, np.ndarray]:
    """Stationary variance of the auxiliary SVSF's chattering when the plant equals ``model``.

    Parameters
    ----------
    model : LinearModel
        Nominal model, which is also the true plant (healthy case); full or
        reduced-order measurement.

    Returns
    -------
    (var_measured, var_lower) : tuple of ndarray
        ``var_measured`` (m,): variance of ``e_i(k+1|k)`` (output units squared);
        ``var_lower`` (n - m,): variance of ``L e(k+1|k)``, the argument of the
        unmeasured coordinates' switching term (eq 10); empty for full measurement.
        See the module docstring for the derivation (the error dynamics of the
        sgn filter are linear and, for full measurement, memoryless).
    """
    S, Phi, L = _filter_matrices(model)
    m, n = model.n_outputs, model.n_states
    H = np.hstack([np.eye(m), np.zeros((m, n - m))])
    J = np.vstack([np.eye(m), L])
    IJH = np.eye(n) - J @ H
    F = IJH @ Phi
    SQS = S @ model.Q @ S.T
    W = IJH @ SQS @ IJH.T + J @ model.R @ J.T
    import scipy.linalg  # on first use: importing the SVSF does not import scipy.linalg

    P = scipy.linalg.solve_discrete_lyapunov(F, W)
    HPhi = H @ Phi
    cov = HPhi @ P @ HPhi.T + H @ SQS @ H.T + model.R
    return np.diag(cov).copy(), np.diag(L @ cov @ L.T).copy()
