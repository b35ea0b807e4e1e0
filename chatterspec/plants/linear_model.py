"""The linear discrete-time plant model, :class:`LinearModel`, and :func:`discretize`.

The state-space form is eq (1)-(2) of Saeedzadeh et al. (2023)::

    x(k+1) = A x(k) + B u(k) + v(k),     v ~ N(0, Q)
    z(k)   = C x(k) + w(k),              w ~ N(0, R)

Re-exported by :mod:`chatterspec.plants.models` (their documented home, with the paper's model
factories); times in seconds, frequencies in Hz.
"""

from __future__ import annotations

import hashlib
import warnings
from dataclasses import dataclass, field, replace
from typing import Literal, TypedDict, Unpack

import numpy as np

from .._repr import short_repr
from .._validate import finite_array, positive
from ..errors import ParameterError, ShapeError, SingularMatrixError, UnstableModelWarning
from .model_base import (
    ModelBase,
    check_measurement_matrix,
    check_noise,
    frozen,
    hash_arrays,
    set_channel_labels,
)
from .parameters import ParameterMap

__all__ = ["Discretization", "LinearModel", "OscillatoryMode", "discretize", "oscillatory_mode"]

Discretization = Literal["euler", "zoh"]


@dataclass(frozen=True)
class OscillatoryMode:
    """Natural frequency (Hz) and damping ratio of a continuous 2x2 block.

    For a block with characteristic polynomial ``s^2 + 2 zeta wn s + wn^2``:
    ``wn = sqrt(det)``, ``zeta = -trace / (2 wn)``; ``natural_frequency_hz = wn / (2 pi)``.

    Attributes
    ----------
    natural_frequency_hz : float
        Undamped natural frequency ``wn / (2 pi)`` in Hz (``wn`` in rad/s).
    damping_ratio : float
        Damping ratio ``zeta`` (dimensionless); negative for an unstable block.
    """

    natural_frequency_hz: float
    damping_ratio: float


def oscillatory_mode(block: np.ndarray) -> OscillatoryMode:
    """Natural frequency (Hz) and damping ratio of a continuous-time 2x2 matrix.

    Parameters
    ----------
    block : (2, 2) array_like
        Continuous-time system matrix (1/s), e.g. the EHA velocity-pressure block
        of :func:`eha_velocity_pressure_block`. Must be finite with a positive
        determinant (otherwise :class:`ParameterError`: no oscillatory mode).

    Returns
    -------
    OscillatoryMode
        ``wn = sqrt(det(block))`` (rad/s) reported in Hz, and
        ``zeta = -trace(block) / (2 wn)``.
    """
    block = finite_array("block", block, shape=(2, 2))
    det = float(np.linalg.det(block))
    if det <= 0:
        raise ParameterError(f"block has det = {det:g} <= 0: it has no oscillatory mode")
    wn = np.sqrt(det)
    return OscillatoryMode(float(wn / (2 * np.pi)), float(-np.trace(block) / (2 * wn)) + 0.0)


class ChannelLabels(TypedDict, total=False):
    """Channel names and output units, as keyword arguments of the model classes."""

    state_names: tuple[str, ...]
    output_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_units: tuple[str, ...]


class LinearModelLabels(ChannelLabels, total=False):
    """The optional keyword fields of :class:`LinearModel` (names, units, mode block, parameter map)."""

    oscillatory_block: np.ndarray | None
    name: str
    parameter_map: ParameterMap | None


class LinearModelFields(LinearModelLabels, total=False):
    """Any fields of :class:`LinearModel` (what :meth:`LinearModel.replace` takes)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    dt: float


@dataclass(frozen=True, eq=False)
class LinearModel(ModelBase):
    """A validated linear discrete-time state-space model (eq 1-2).

    Parameters
    ----------
    A : (n, n) array
        State transition matrix.
    B : (n, p) array or None
        Input matrix (a 1-D array of length n is taken as one input); None for a model without
        input (one zero input column, so the filters' ``u`` may be omitted).
    C : (m, n) array
        Measurement matrix.
    Q : (n, n) array
        Process-noise covariance (symmetric positive semi-definite).
    R : (m, m) array
        Measurement-noise covariance (symmetric positive semi-definite).
    dt : float
        Sampling time in seconds (> 0).
    state_names, output_names, input_names : tuple of str, optional
        Channel names; default ``x1..xn``, ``z1..zm``, ``u1..up``.
    output_units : tuple of str, optional
        Units of the measured channels (for reports and the viewer).
    oscillatory_block : (2, 2) array, optional
        Continuous-time block whose natural frequency/damping the model reports
        (the velocity-pressure block for the EHA, the whole matrix for the
        second-order system).
    name : str
        Short human-readable description.
    parameter_map : ParameterMap, optional
        How named physical parameters enter A and B (:mod:`chatterspec.plants.parameters`),
        for fault identification; checked against A and B when identification uses it.

    Raises
    ------
    ShapeError, NonFiniteError, ParameterError
        On inconsistent shapes, non-finite entries, ``dt <= 0`` or invalid covariances.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    A: np.ndarray
    B: np.ndarray  # None accepted (no input): a zero column
    C: np.ndarray
    Q: np.ndarray
    R: np.ndarray
    dt: float
    state_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    input_names: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()
    oscillatory_block: np.ndarray | None = None
    name: str = "linear model"
    parameter_map: ParameterMap | None = field(default=None, repr=False)
    _cinv: np.ndarray | None = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        A = finite_array("A", self.A, ndim=2)
        n = A.shape[0]
        if A.shape != (n, n):
            raise ShapeError(f"A must be square; got shape {A.shape}")
        B = np.zeros((n, 1)) if self.B is None else finite_array("B", self.B, ndim=(1, 2))
        if B.ndim == 1:
            B = B[:, None]
        if B.shape[0] != n:
            raise ShapeError(f"B must have {n} rows (one per state); got shape {B.shape}")
        C = check_measurement_matrix(self.C, n)
        m = C.shape[0]
        Q, R = check_noise(self.Q, self.R, n, m)
        dt = positive("dt", self.dt, unit="s")
        p = B.shape[1]
        set_channel_labels(self, n, m, p)
        block = self.oscillatory_block
        if block is not None:
            block = frozen(finite_array("oscillatory_block", block, shape=(2, 2)))
        object.__setattr__(self, "oscillatory_block", block)
        object.__setattr__(self, "dt", dt)
        for attr, val in (("A", A), ("B", B), ("C", C), ("Q", Q), ("R", R)):
            object.__setattr__(self, attr, frozen(val))
        cinv = None
        if m == n and np.linalg.cond(C) <= 1e12:
            cinv = frozen(np.linalg.inv(C))
        object.__setattr__(self, "_cinv", cinv)

    # -- sizes ---------------------------------------------------------------
    @property
    def n_states(self) -> int:
        """Number of states."""
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        """Number of inputs."""
        return self.B.shape[1]

    @property
    def full_measurement(self) -> bool:
        """True when C is square and invertible (eq 8 applies); else eq 9-11."""
        return self._cinv is not None

    @property
    def C_inv(self) -> np.ndarray:
        """Inverse of C (full measurement only).

        Raises
        ------
        SingularMatrixError
            If C is not square or is singular.
        """
        if self._cinv is None:
            if self.n_outputs != self.n_states:
                raise SingularMatrixError(
                    f"C is {self.n_outputs}x{self.n_states}: C^-1 exists only for full "
                    "measurement; use the reduced-order SVSF (eq 9-11)"
                )
            raise SingularMatrixError("C is singular (condition number > 1e12); C^-1 is needed")
        return self._cinv

    # -- dynamics ------------------------------------------------------------
    @property
    def spectral_radius(self) -> float:
        """Largest ``|eigenvalue|`` of ``A`` (< 1: stable)."""
        return float(np.max(np.abs(np.linalg.eigvals(self.A))))

    @property
    def mode(self) -> OscillatoryMode | None:
        """Natural frequency (Hz) and damping of the continuous oscillatory block, if any."""
        if self.oscillatory_block is None:
            return None
        return oscillatory_mode(self.oscillatory_block)

    def warn_if_unstable(self, tolerance: float = 1e-3) -> bool:
        """Warn (``UnstableModelWarning``) if the spectral radius exceeds ``1 + tolerance``."""
        rho = self.spectral_radius
        if rho > 1.0 + tolerance:
            warnings.warn(
                f"{self.name}: spectral radius of A is {rho:.6f} > 1; the nominal model is unstable",
                UnstableModelWarning,
                stacklevel=2,
            )
            return True
        return False

    def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``A x + B u`` (eq 1), batched: see :meth:`ModelBase.transition`."""
        return x @ self.A.T + np.asarray(u, dtype=float) @ self.B.T

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``A``, a read-only view broadcast to ``(..., n, n)`` (``u`` unused): :meth:`ModelBase.jacobian`."""
        return np.broadcast_to(self.A, np.shape(x)[:-1] + self.A.shape)

    def replace(self, **changes: Unpack[LinearModelFields]) -> LinearModel:
        """Return a copy with fields replaced (validated again)."""
        return replace(self, **changes)

    def fingerprint(self) -> str:
        """SHA-256 of the matrices and dt: identifies the model in saved calibrations."""
        h = hashlib.sha256()
        hash_arrays(h, (self.A, self.B, self.C, self.Q, self.R, np.array([self.dt])))
        return h.hexdigest()

    def to_dict(self) -> dict[str, object]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {
            "name": self.name,
            "dt": self.dt,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "C": self.C.tolist(),
            "Q": self.Q.tolist(),
            "R": self.R.tolist(),
            "state_names": list(self.state_names),
            "output_names": list(self.output_names),
            "input_names": list(self.input_names),
            "output_units": list(self.output_units),
        }

    @classmethod
    def from_continuous(
        cls,
        Ac: np.ndarray,
        Bc: np.ndarray,
        C: np.ndarray,
        Q: np.ndarray,
        R: np.ndarray,
        dt: float,
        *,
        discretization: Discretization = "euler",
        **kwargs: Unpack[LinearModelLabels],
    ) -> LinearModel:
        """Discretize continuous matrices (see :func:`discretize`) and build a model.

        ``Q`` and ``R`` are the *discrete* noise covariances.
        """
        A, B = discretize(Ac, Bc, dt, discretization)
        return cls(A=A, B=B, C=C, Q=Q, R=R, dt=dt, **kwargs)


def discretize(
    Ac: np.ndarray, Bc: np.ndarray, dt: float, method: Discretization = "euler"
) -> tuple[np.ndarray, np.ndarray]:
    """Discretize ``x' = Ac x + Bc u`` with sampling time ``dt`` (s).

    ``"euler"`` is the paper's explicit Euler (A = I + dt Ac, B = dt Bc, as in
    eq 30 and eq 67); ``"zoh"`` is the exact zero-order hold (matrix exponential).

    Parameters
    ----------
    Ac : (n, n) array_like
        Continuous-time state matrix (1/s).
    Bc : (n,) or (n, p) array_like
        Continuous-time input matrix; a 1-D array is taken as a single input.
    dt : float
        Sampling time in seconds (> 0).
    method : {"euler", "zoh"}
        ``"euler"`` (default, the paper's choice) or exact zero-order hold;
        anything else raises :class:`ParameterError`.

    Returns
    -------
    A : (n, n) ndarray
        Discrete state transition matrix.
    B : (n, p) ndarray
        Discrete input matrix.
    """
    dt = positive("dt", dt, unit="s")
    Ac = finite_array("Ac", Ac, ndim=2)
    n = Ac.shape[0]
    if Ac.shape != (n, n):
        raise ShapeError(f"Ac must be square; got {Ac.shape}")
    Bc = finite_array("Bc", Bc, ndim=(1, 2))
    if Bc.ndim == 1:
        Bc = Bc[:, None]
    if Bc.shape[0] != n:
        raise ShapeError(f"Bc must have {n} rows; got {Bc.shape}")
    if method == "euler":
        return np.eye(n) + dt * Ac, dt * Bc
    if method == "zoh":
        p = Bc.shape[1]
        big = np.zeros((n + p, n + p))
        big[:n, :n] = Ac
        big[:n, n:] = Bc
        import scipy.linalg  # on demand: listing the catalogue must not wait for scipy

        e = scipy.linalg.expm(big * dt)
        return e[:n, :n], e[:n, n:]
    raise ParameterError(f"discretization must be 'euler' or 'zoh'; got {method!r}")
