"""The estimator settings a paper prints for a scenario (filter Q, R, P0, gamma, psi, Lambda, modes, ...).

A :class:`FilterSettings` rides on a :class:`~chatterspec.plants.scenarios.Scenario`
(``scenario.filter_settings``) so that the estimators (KF/EKF, SVSF with covariance, the second-order
SVSF, SMM-SVSF, IMM) find the paper's tuning next to the plant, instead of each command
re-typing it. Every field is optional: ``None`` means "the paper does not say; use the filter's own
default or the nominal model's value". Sources and resolutions are in
``docs/design.md`` (section 13) and ``docs/paper-notes.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .._validate import finite_array, nonnegative, open_unit, readonly
from ..errors import ParameterError, ShapeError
from .model_base import check_covariance
from .nonlinear import same_dynamics

if TYPE_CHECKING:  # pragma: no cover
    from .scenario_types import Scenario

__all__ = ["MAPPINGS", "FilterSettings", "StateMapping"]

#: State-correction mappings for fewer measurements than states (``docs/design.md`` §7.4).
StateMapping = Literal["full", "pinv", "cov", "luen"]
MAPPINGS: tuple[StateMapping, ...] = ("full", "pinv", "cov", "luen")


def _opt_array(name: str, value: Any, ndim: int) -> np.ndarray | None:
    if value is None:
        return None
    return readonly(np.array(finite_array(name, value, ndim=ndim), dtype=float))


def _opt_tuple(name: str, value: Any, *, positive: bool = True) -> tuple[float, ...] | None:
    if value is None:
        return None
    arr = finite_array(name, np.atleast_1d(np.asarray(value, dtype=float)), ndim=1)
    if positive and np.any(arr <= 0):
        raise ParameterError(f"{name} must be > 0 in every channel; got {arr.tolist()}")
    return tuple(float(v) for v in arr)


@dataclass(frozen=True, eq=False)
class FilterSettings:
    """Filter tuning printed (or resolved) for a scenario; every field optional.

    Attributes
    ----------
    Q : (n, n) array or None
        Filter process-noise covariance per step (None: the nominal model's ``Q``).
    R : (m, m) array or None
        Filter measurement-noise covariance (None: the nominal model's ``R``).
    P0 : (n, n) array or None
        Initial estimation-error covariance.
    x0 : (n,) array or None
        Initial state estimate (None: zeros, as in all three estimator papers).
    gamma : float or None
        SVSF convergence-rate memory gamma, in (0, 1).
    psi : tuple of float or None
        First-order SVSF boundary layer per measured channel (output units).
    psi_lower : tuple of float or None
        Boundary layer of the unmeasured states for the reduced-order (``luen``) mapping.
    cutoff_lambda : tuple of float or None
        Diagonal of Lambda of the dynamic second-order SVSF (DETC eq 17: ``lambda = 1/(1 + c)``),
        each in (0, 1); one value per measured channel (a single value is broadcast by the filter).
    mapping : str or None
        State-correction mapping for ``m < n``: one of :data:`MAPPINGS`.
    modes : tuple of str
        Names of the candidate modes of a multiple-model filter (SMM-SVSF, IMM), in bank order.
    mode_models : tuple of models
        The model of each mode (``LinearModel`` or ``NonlinearModel``), same length as ``modes``.
    mu0 : tuple of float or None
        Initial mode probabilities (sum 1); None means uniform.
    transition_matrix : (r, r) array or None
        Mode transition probabilities per step, ``pi[i, j] = P(mode j at k | mode i at k-1)``
        (rows sum to 1).
    weight_floor : float or None
        Floor of the SMM mode weights, in [0, 1/r).
    source : str
        Where the values come from (paper, table, equation, or chatterspec's resolution).
    """

    Q: np.ndarray | None = None
    R: np.ndarray | None = None
    P0: np.ndarray | None = None
    x0: np.ndarray | None = None
    gamma: float | None = None
    psi: tuple[float, ...] | None = None
    psi_lower: tuple[float, ...] | None = None
    cutoff_lambda: tuple[float, ...] | None = None
    mapping: StateMapping | None = None
    modes: tuple[str, ...] = ()
    mode_models: tuple[Any, ...] = ()
    mu0: tuple[float, ...] | None = None
    transition_matrix: np.ndarray | None = None
    weight_floor: float | None = None
    source: str = ""

    def __post_init__(self) -> None:
        for name in ("Q", "R", "P0"):
            val = _opt_array(name, getattr(self, name), 2)
            if val is not None:
                if val.shape[0] != val.shape[1]:
                    raise ShapeError(f"filter {name} must be square; got {val.shape}")
                check_covariance(f"filter {name}", val)
            object.__setattr__(self, name, val)
        object.__setattr__(self, "x0", _opt_array("x0", self.x0, 1))
        if self.gamma is not None:
            object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        object.__setattr__(self, "psi", _opt_tuple("psi", self.psi))
        object.__setattr__(self, "psi_lower", _opt_tuple("psi_lower", self.psi_lower))
        lam = _opt_tuple("cutoff_lambda", self.cutoff_lambda)
        if lam is not None and any(v >= 1 for v in lam):
            raise ParameterError(
                "cutoff_lambda must lie in (0, 1) (lambda = 1 puts a residual root on the unit "
                f"circle); got {lam}"
            )
        object.__setattr__(self, "cutoff_lambda", lam)
        if self.mapping is not None and self.mapping not in MAPPINGS:
            raise ParameterError(f"mapping must be one of {', '.join(MAPPINGS)}; got {self.mapping!r}")
        modes = tuple(str(s) for s in self.modes)
        models = tuple(self.mode_models)
        if len(models) != len(modes):
            raise ShapeError(f"mode_models has {len(models)} entries; modes has {len(modes)}")
        if len(set(modes)) != len(modes):
            raise ParameterError(f"mode names must be distinct; got {modes}")
        object.__setattr__(self, "modes", modes)
        object.__setattr__(self, "mode_models", models)
        r = len(modes)
        mu0 = _opt_tuple("mu0", self.mu0, positive=False)
        if mu0 is not None:
            if len(mu0) != r:
                raise ShapeError(f"mu0 must have one entry per mode ({r}); got {len(mu0)}")
            if min(mu0) < 0 or abs(sum(mu0) - 1.0) > 1e-12:
                raise ParameterError(f"mu0 must be non-negative and sum to 1; got {mu0}")
        object.__setattr__(self, "mu0", mu0)
        pi = _opt_array("transition_matrix", self.transition_matrix, 2)
        if pi is not None:
            if pi.shape != (r, r):
                raise ShapeError(f"transition_matrix must be ({r}, {r}) (one row per mode); got {pi.shape}")
            if np.any(pi < 0) or not np.allclose(pi.sum(axis=1), 1.0, rtol=0, atol=1e-12):
                raise ParameterError("transition_matrix must be non-negative with rows summing to 1")
        object.__setattr__(self, "transition_matrix", pi)
        if self.weight_floor is not None:
            floor = nonnegative("weight_floor", self.weight_floor)
            if r and not floor < 1.0 / r:
                raise ParameterError(f"weight_floor must lie in [0, 1/{r}); got {floor}")
            object.__setattr__(self, "weight_floor", floor)

    def check_dimensions(self, n: int, m: int) -> None:
        """Check the array sizes against a model with ``n`` states and ``m`` outputs.

        Parameters
        ----------
        n : int
            Number of states.
        m : int
            Number of measured outputs.

        Raises
        ------
        ShapeError
            Naming the first field of the wrong size.
        """
        want = {"Q": (n, n), "R": (m, m), "P0": (n, n), "x0": (n,)}
        for name, shape in want.items():
            val = getattr(self, name)
            if val is not None and val.shape != shape:
                raise ShapeError(f"filter_settings.{name} must have shape {shape}; got {val.shape}")
        if self.psi is not None and len(self.psi) not in (1, m):
            raise ShapeError(f"filter_settings.psi must have 1 or {m} entries; got {len(self.psi)}")
        if self.cutoff_lambda is not None and len(self.cutoff_lambda) not in (1, m):
            raise ShapeError(f"filter_settings.cutoff_lambda must have 1 or {m} entries")
        for name, model in zip(self.modes, self.mode_models, strict=True):
            if (model.n_states, model.n_outputs) != (n, m):
                raise ShapeError(f"mode {name!r}: its model must have {n} states and {m} outputs")

    def mode_index(self, scenario: Scenario, t: np.ndarray | None = None) -> np.ndarray:
        """Index into :attr:`modes` of the true plant at each sample time (-1 where none matches).

        A segment's true model matches a mode when they have the same dynamics and measurement
        (:func:`~chatterspec.plants.nonlinear.same_dynamics`; noise covariances are ignored).

        Parameters
        ----------
        scenario : Scenario
            The scenario whose ``segments`` are matched.
        t : (T,) array, optional
            Sample times in seconds (default ``scenario.time``).

        Returns
        -------
        (T,) int ndarray
        """
        seg_mode = []
        for seg in scenario.segments:
            hit = [i for i, m in enumerate(self.mode_models) if same_dynamics(m, seg.model)]
            seg_mode.append(hit[0] if hit else -1)
        return np.asarray(seg_mode, dtype=int)[scenario.segment_index(t)]

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (arrays as nested lists)."""

        def arr(a: np.ndarray | None) -> object:
            return None if a is None else a.tolist()

        return {
            "Q": arr(self.Q),
            "R": arr(self.R),
            "P0": arr(self.P0),
            "x0": arr(self.x0),
            "gamma": self.gamma,
            "psi": None if self.psi is None else list(self.psi),
            "psi_lower": None if self.psi_lower is None else list(self.psi_lower),
            "cutoff_lambda": None if self.cutoff_lambda is None else list(self.cutoff_lambda),
            "mapping": self.mapping,
            "modes": list(self.modes),
            "mu0": None if self.mu0 is None else list(self.mu0),
            "transition_matrix": arr(self.transition_matrix),
            "weight_floor": self.weight_floor,
            "source": self.source,
        }
