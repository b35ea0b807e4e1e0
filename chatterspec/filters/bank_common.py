"""What the multiple-model banks share: checks, state and output containers, ``update`` and ``run``.

SMM-SVSF (:mod:`chatterspec.filters.smm_svsf`) and IMM (:mod:`chatterspec.filters.imm`) take the
same data, keep the same state (:class:`MultipleModelState`) and return the same outputs
(:class:`MultipleModelOutput`); :class:`BankFilter` checks an update's data once for both.

See Also
--------
chatterspec.filters.smm_svsf : SMM-SVSF, its equations and readings.
chatterspec.filters.imm : IMM, its cycle and the corrections to the printed equations.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np
import numpy.typing as npt

from .._repr import short_repr
from .._validate import finite_array, nonnegative
from ..errors import ParameterError, ShapeError
from ..plants.nonlinear import Model
from ._base import check_model
from ._conventions import bank_store, default_input
from .one_sample import OnlineBank
from .protocol import FilterState, initial_estimate

__all__ = [
    "BankFilter",
    "MultipleModelOutput",
    "MultipleModelState",
    "check_bank_data",
    "check_bank_models",
    "check_mode_probabilities",
    "check_transition_matrix",
    "check_weight_floor",
    "initial_bank_state",
    "initial_mode_probabilities",
    "mode_names",
]


def check_mode_probabilities(name: str, mu: npt.ArrayLike, r: int) -> np.ndarray:
    """Mode probabilities: ``r`` non-negative entries summing to 1 (within 1e-9).

    Parameters
    ----------
    name : str
        Name used in error messages.
    mu : (r,) or (runs, r) array_like
        Probabilities.
    r : int
        Number of modes.

    Returns
    -------
    ndarray of float

    Raises
    ------
    ShapeError
        Wrong number of entries.
    ParameterError
        A negative entry or a sum other than 1.
    """
    arr = finite_array(name, mu, ndim=(1, 2))
    if arr.shape[-1] != r:
        raise ShapeError(f"{name} must have one entry per mode ({r}); got shape {arr.shape}")
    if np.any(arr < 0):
        raise ParameterError(f"{name} must be non-negative (probabilities); got min {arr.min():.3g}")
    if not np.allclose(arr.sum(axis=-1), 1.0, rtol=0, atol=1e-9):
        raise ParameterError(f"{name} must sum to 1 over the modes; got sum {arr.sum(axis=-1)}")
    return np.array(arr, dtype=float)


def initial_mode_probabilities(mu0: npt.ArrayLike | None, r: int) -> np.ndarray:
    """A bank's ``mu0``: ``r`` probabilities (:func:`check_mode_probabilities`), uniform when None.

    Raises
    ------
    ShapeError
        Not of shape (r,) (one set for every realization).
    """
    mu = np.full(r, 1.0 / r) if mu0 is None else check_mode_probabilities("mu0", mu0, r)
    if mu.ndim != 1:
        raise ShapeError(f"mu0 must have shape ({r},); got {mu.shape}")
    return mu


def check_transition_matrix(pi: npt.ArrayLike, r: int) -> np.ndarray:
    """Mode transition matrix per step, ``pi[i, j] = P(mode j at k | mode i at k-1)``.

    Parameters
    ----------
    pi : (r, r) array_like
        Non-negative, rows summing to 1 (within 1e-9).
    r : int
        Number of modes.

    Returns
    -------
    (r, r) ndarray

    Raises
    ------
    ShapeError
        Not (r, r).
    ParameterError
        A negative entry or a row not summing to 1 (the message names the rows).
    """
    arr = finite_array("transition_matrix", pi, ndim=2)
    if arr.shape != (r, r):
        raise ShapeError(f"transition_matrix must be ({r}, {r}) (one row per mode); got {arr.shape}")
    if np.any(arr < 0):
        raise ParameterError(
            f"transition_matrix must be non-negative (probabilities); min entry {arr.min():.3g}"
        )
    sums = arr.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > 1e-9)
    if bad.size:
        raise ParameterError(
            f"every row of transition_matrix must sum to 1 (row i = P(next mode | mode i)); rows "
            f"{bad.tolist()} sum to {sums[bad].tolist()}"
        )
    return np.array(arr, dtype=float)


def check_weight_floor(floor: float, r: int) -> float:
    """SMM weight floor in ``[0, 1/r)`` ([SMM] Table 1 step 3, ``docs/design.md`` S4).

    Parameters
    ----------
    floor : float
        Lower bound of every mode weight.
    r : int
        Number of modes.

    Returns
    -------
    float

    Raises
    ------
    ParameterError
        Outside ``[0, 1/r)`` (at ``1/r`` every weight would be pinned to uniform).
    """
    value = nonnegative("weight_floor", floor)
    if not value < 1.0 / r:
        raise ParameterError(
            f"weight_floor must lie in [0, 1/{r}) = [0, {1.0 / r:.4g}) for {r} modes (at 1/r every "
            f"weight is pinned to uniform); got {value}"
        )
    return value


def check_bank_models(models: Sequence[Model]) -> tuple[int, int]:
    """``(n, m)`` of a bank's mode models, which must all have the same state, output and input sizes.

    Parameters
    ----------
    models : sequence of models
        One per mode, at least one.

    Returns
    -------
    (int, int)
        States ``n`` and outputs ``m``.

    Raises
    ------
    ParameterError
        No mode.
    ShapeError
        Modes of different sizes (they filter the same data).
    """
    if len(models) < 1:
        raise ParameterError("a multiple-model filter needs at least one mode")
    for mdl in models:
        check_model(mdl)
    dims = [(int(mdl.n_states), int(mdl.n_outputs), int(mdl.n_inputs)) for mdl in models]
    if len(set(dims)) != 1:
        raise ShapeError(
            "every mode must have the same numbers of states, measurements and inputs (they filter the "
            f"same data); got (n, m, p) = {dims}"
        )
    return dims[0][0], dims[0][1]


@dataclass(frozen=True, eq=False)
class MultipleModelState:
    """State of a multiple-model filter after sample ``k`` (every realization).

    Attributes
    ----------
    x : (runs, n) array
        Combined posterior ``x(k|k)`` (SMM Table 1: the one SVSF's posterior).
    P : (runs, n, n) array
        Combined posterior covariance.
    mu : (runs, r) array
        Mode probabilities / weights after sample ``k``.
    e_post : (runs, m) array
        Posterior residual ``z(k) - C x(k|k)`` of the combined estimate.
    z_last : (runs, m) array
        Last measurement ``z(k)`` (IMM: residual of each mixed estimate, ``docs/design.md`` I4).
    mode_states : tuple of FilterState
        Mode-matched filter states (IMM and the SMM bank reading; empty for Table 1).
    k : int
        Index of the last processed sample.
    e_prev : (runs, m) array or None
        Residual one step earlier, ``e(k-1|k-1)`` (SMM Table 1; None = zeros).
    """

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    e_post: np.ndarray
    z_last: np.ndarray
    mode_states: tuple[FilterState, ...] = ()
    k: int = 0
    e_prev: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class MultipleModelOutput:
    """Per-sample outputs of a multiple-model filter (sample j belongs to time ``k + 1 + j``).

    Attributes
    ----------
    x_post : (runs, K, n) array
        Combined posterior estimate.
    mu : (runs, K, r) array
        Mode probabilities after each sample.
    loglik : (runs, K, r) array
        Log-likelihood of each mode's innovation (natural log).
    modes : tuple of str
        Mode names in bank order.
    P_post : (runs, K, n, n) array or None
        Combined posterior covariance (only with ``store={"P_post"}``).
    mode_x_post : (runs, K, r, n) array or None
        Mode-conditioned posteriors (IMM / bank; only with ``store={"mode_x_post"}``).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    x_post: np.ndarray
    mu: np.ndarray
    loglik: np.ndarray
    modes: tuple[str, ...]
    P_post: np.ndarray | None = None
    mode_x_post: np.ndarray | None = None

    @property
    def argmax_mode(self) -> np.ndarray:
        """Index of the most probable mode per run and sample, ``(runs, K)``."""
        return np.argmax(self.mu, axis=-1)


def mode_names(modes: Sequence[str] | None, r: int) -> tuple[str, ...]:
    """The bank's mode names: ``modes`` checked to name each of the ``r`` modes, or ``mode0, mode1, ...``."""
    if modes is None:
        return tuple(f"mode{j}" for j in range(r))
    names = tuple(str(s) for s in modes)
    if len(names) != r:
        raise ShapeError(f"modes must name each of the {r} modes; got {len(names)} names")
    return names


def initial_bank_state(
    n: int, r: int, x0: npt.ArrayLike, P0: npt.ArrayLike, runs: int | None, mu0: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """``(runs, x, P, mu)`` at k = 0 from a bank's ``initialize`` arguments (checked as any filter's).

    Parameters
    ----------
    n, r : int
        States and modes.
    x0, P0, runs
        As :meth:`chatterspec.filters.protocol.Filter.initialize`.
    mu0 : (r,) array
        Initial mode probabilities.

    Returns
    -------
    (int, (runs, n), (runs, n, n), (runs, r))
    """
    runs, x, P0a = initial_estimate(n, x0, P0, runs)
    P = np.array(np.broadcast_to(P0a, (runs, n, n)), dtype=float)
    mu = np.array(np.broadcast_to(mu0, (runs, r)), dtype=float)
    return runs, x, P, mu


def check_bank_data(
    z: npt.ArrayLike, u: npt.ArrayLike | None, runs: int, m: int, p: int
) -> tuple[np.ndarray, np.ndarray]:
    """``z`` as (runs, K, m) and ``u`` as (1 | runs, K, p) float arrays of a bank's update (None: no input).

    Raises
    ------
    ShapeError
        Shapes that do not match the bank.
    NonFiniteError
        NaN or inf.
    """
    z = finite_array("z", z, ndim=(2, 3))
    if z.ndim == 2:
        z = z[None]
    if z.shape[0] != runs or z.shape[2] != m:
        raise ShapeError(f"z must have shape ({runs}, K, {m}) (runs, samples, outputs); got {z.shape}")
    K = z.shape[1]
    u = finite_array("u", default_input(u, K, p), ndim=(1, 2, 3))
    if u.ndim == 1:
        u = u[:, None] if p == 1 else u[None, :]
    if u.ndim == 2:
        u = u[None]
    if u.shape[1] != K or u.shape[2] != p or u.shape[0] not in (1, runs):
        raise ShapeError(
            f"u must have shape ({K}, {p}) or ({runs}, {K}, {p}) (samples like z); got {u.shape}"
        )
    return z, u


class BankFilter:
    """What SMM-SVSF and IMM share: their options, start, outputs and the checks of :meth:`update`.

    A subclass provides ``initialize``, ``_sensor_model()`` (the model whose sizes the data must
    match) and ``_advance(state, z, u, store_covariance, store_modes)`` (the recursion on checked data),
    and has the fields ``mu0``, ``weight_floor`` and ``modes`` (checked by :meth:`_check_bank`).
    """

    if TYPE_CHECKING:  # what the subclasses define (fields, then methods)
        mu0: np.ndarray | None
        weight_floor: float
        modes: Sequence[str] | None

        def initialize(
            self, x0: np.ndarray, P0: np.ndarray, *, runs: int | None = None
        ) -> MultipleModelState: ...

        def _sensor_model(self) -> Model: ...

        def _advance(
            self,
            state: MultipleModelState,
            z: np.ndarray,
            u: np.ndarray,
            store_covariance: bool,
            store_modes: bool,
        ) -> tuple[MultipleModelState, MultipleModelOutput]: ...

    def _check_bank(self, models: Sequence[Model]) -> tuple[int, int]:
        """Check the mode models (:func:`check_bank_models`) and set ``mu0``, ``weight_floor``, ``modes``.

        Returns
        -------
        (int, int)
            States ``n`` and outputs ``m`` of every mode.
        """
        n, m = check_bank_models(models)
        r = len(models)
        object.__setattr__(self, "mu0", initial_mode_probabilities(self.mu0, r))
        object.__setattr__(self, "weight_floor", check_weight_floor(self.weight_floor, r))
        object.__setattr__(self, "modes", mode_names(self.modes, r))
        return n, m

    def _initial_estimate(
        self, x0: npt.ArrayLike, P0: npt.ArrayLike, runs: int | None
    ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """``(runs, x, P, mu)`` at k = 0 (:func:`initial_bank_state` with the bank's sizes and ``mu0``)."""
        n = int(self._sensor_model().n_states)
        modes, mu0 = cast(tuple[str, ...], self.modes), cast(np.ndarray, self.mu0)  # set by _check_bank
        return initial_bank_state(n, len(modes), x0, P0, runs, mu0)

    def _initial_state(
        self, x: np.ndarray, P: np.ndarray, mu: np.ndarray, mode_states: tuple[FilterState, ...]
    ) -> MultipleModelState:
        """The state at k = 0: ``e(0|0) = 0`` and ``z(0) = 0`` (no measurement yet)."""
        zero = np.zeros((x.shape[0], int(self._sensor_model().n_outputs)))
        return MultipleModelState(
            x=x, P=P, mu=mu, e_post=zero, z_last=zero.copy(), mode_states=mode_states, k=0
        )

    def _output(self, res: dict[str, np.ndarray | None]) -> MultipleModelOutput:
        """The bank's output from the per-sample arrays ``x, mu, ll, P, mx`` (None: not kept)."""
        x, mu, ll = res["x"], res["mu"], res["ll"]
        assert x is not None and mu is not None and ll is not None  # always kept
        return MultipleModelOutput(x, mu, ll, tuple(cast(tuple[str, ...], self.modes)), res["P"], res["mx"])

    def online(self, x0: np.ndarray, P0: np.ndarray, **initial: object) -> OnlineBank:
        """One realization advanced one sample per call: ``f = bank.online(x0, P0)``, ``x = f.step(z, u)``.

        Parameters
        ----------
        x0 : (n,) array
            ``x(0|0)``.
        P0 : (n, n) array
            ``P(0|0)``.
        **initial
            IMM: ``mode_x0``, ``mode_P0`` (see :meth:`IMM.initialize`).

        Returns
        -------
        OnlineBank
            Each step gives the numbers of :meth:`update` on that sample (``docs/filters.md``).
        """
        return OnlineBank(self, self.initialize(x0, P0, runs=1, **initial))

    def update(
        self,
        state: MultipleModelState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        """Advance every realization over K samples (``z(k+1..k+K)``, ``u(k..k+K-1)``).

        Parameters
        ----------
        state : MultipleModelState
            From :meth:`initialize` or a previous update.
        z : (runs, K, m) array
            Measurements.
        u : (K, p) or (runs, K, p) array, optional
            Inputs (``u(k)`` drives ``x(k) -> x(k+1)``); None: no input (zeros).
        store : collection of str, optional
            ``"P_post"``: keep the combined posterior covariance per sample (memory ``runs K n^2``);
            ``"mode_x_post"``: the mode-conditioned posteriors per sample (IMM and the SMM bank
            reading; SMM's Table 1 reading keeps the mode predictions).

        Returns
        -------
        (MultipleModelState, MultipleModelOutput)
        """
        if not isinstance(state, MultipleModelState):
            raise TypeError(f"state must be a MultipleModelState; got {type(state).__name__}")
        mdl0 = self._sensor_model()
        m, p = int(mdl0.n_outputs), int(mdl0.n_inputs)
        store_covariance, store_modes = bank_store(store, type(self).__name__)
        z, u = check_bank_data(z, u, state.x.shape[0], m, p)
        return self._advance(state, z, u, store_covariance, store_modes)

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray,
        P0: np.ndarray,
        store: Collection[str] | None = None,
        **initial: object,
    ) -> MultipleModelOutput:
        """Filter whole records: :meth:`initialize` then one :meth:`update`.

        Parameters
        ----------
        z : (runs, T, m) array
            Measurements ``z(1) .. z(T)``.
        u : (T, p) or (runs, T, p) array, optional
            Inputs ``u(0) .. u(T-1)``; None: no input (zeros).
        x0 : (n,) or (runs, n) array
            ``x(0|0)``.
        P0 : (n, n) or (runs, n, n) array
            ``P(0|0)``.
        store : collection of str, optional
            See :meth:`update`.
        **initial
            IMM: ``mode_x0``, ``mode_P0`` (per-mode starts, see :meth:`IMM.initialize`).

        Returns
        -------
        MultipleModelOutput
        """
        zz = finite_array("z", z, ndim=(2, 3))
        runs = 1 if zz.ndim == 2 else zz.shape[0]
        state = self.initialize(x0, P0, runs=runs, **initial)
        keep = bank_store(store, type(self).__name__)
        store = {n for n, k in zip(("P_post", "mode_x_post"), keep, strict=True) if k}
        return self.update(state, zz, u, store=store)[1]
