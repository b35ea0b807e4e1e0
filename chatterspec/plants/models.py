"""Linear discrete-time plant models (:class:`LinearModel`, :func:`discretize`), what they share with
the nonlinear model (:class:`ModelBase`), and the paper's model factories.

The state-space form is eq (1)-(2) of Saeedzadeh et al. (2023)::

    x(k+1) = A x(k) + B u(k) + v(k),     v ~ N(0, Q)
    z(k)   = C x(k) + w(k),              w ~ N(0, R)

Factories build the under-damped second-order system of eq (30) and the
linear 3-state electro-hydraulic actuator (EHA) of eq (65)/(67), with the
index/sign corrections listed in ``docs/design.md`` (C2-C4).
Frequencies are given in **Hz** and converted to rad/s inside the factories
(w0 = 2 pi f0); times are in seconds.

What :class:`~chatterspec.plants.models.LinearModel` and
:class:`~chatterspec.plants.nonlinear.NonlinearModel` share: the checks of their common fields and
the interface the filters use.

Both models describe ``x(k+1) = f(x(k), u(k)) + v(k)``, ``z(k) = C x(k) + w(k)`` (eq 1-2 of the
chattering paper, ``f(x, u) = A x + B u`` for the linear model). The filters only need
``transition``, ``jacobian``, ``C``, ``Q``, ``R``, ``dt`` and the sizes; :class:`ModelBase` documents
that interface once and holds what both models compute the same way (outputs, the oscillatory mode's
frequency and damping, the array part of the fingerprint). The ``check_*`` functions validate the
fields both dataclasses carry, with the same messages for both.
"""

from __future__ import annotations

import hashlib
import warnings
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, TypedDict, Unpack

import numpy as np
import numpy.typing as npt

from .._repr import short_repr
from .._validate import finite_array, nonnegative, positive, readonly
from ..errors import ParameterError, ShapeError, SingularMatrixError, UnstableModelWarning
from .parameters import ParameterMap, eha_parameter_map, second_order_parameter_map

if TYPE_CHECKING:
    from .nonlinear import Model

__all__ = [
    "EHA_PARAMETERS",
    "Discretization",
    "EHAFault",
    "LinearModel",
    "ModelBase",
    "OscillatoryMode",
    "check_covariance",
    "check_labels",
    "check_measurement_matrix",
    "check_noise",
    "discretize",
    "eha_linear",
    "eha_velocity_pressure_block",
    "frozen",
    "hash_arrays",
    "oscillatory_mode",
    "second_order",
    "set_channel_labels",
    "state_units",
]


# What the linear and the nonlinear model share.

#: Time derivatives named after a measured state: their units follow from its unit (``m`` -> ``m/s``).
_DERIVATIVES = {"velocity": ("position", "/s"), "acceleration": ("position", "/s^2")}


def state_units(model: Model) -> tuple[str, ...]:
    """Units of a model's states: its ``state_units`` where it declares them (nonlinear models), else the
    unit of the output of the same name (a measured state), else for ``velocity`` / ``acceleration`` the
    unit of the ``position`` per second / per second squared; ``""`` where none of these says.

    Parameters
    ----------
    model : LinearModel or NonlinearModel

    Returns
    -------
    tuple of str
        One unit per state.
    """
    declared = tuple(getattr(model, "state_units", ()) or ())
    if any(declared):
        return declared
    by_name = dict(zip(model.output_names, model.output_units, strict=True))
    out = []
    for s in model.state_names:
        unit = by_name.get(s, "")
        if not unit and s in _DERIVATIVES:
            base, per = _DERIVATIVES[s]
            unit = f"{by_name[base]}{per}" if by_name.get(base) else ""
        out.append(unit)
    return tuple(out)


def check_covariance(name: str, M: np.ndarray) -> None:
    """Raise :class:`ParameterError` unless ``M`` is symmetric positive semi-definite.

    Parameters
    ----------
    name : str
        The covariance's name, for the message (``"Q"``, ``"R"``).
    M : (k, k) ndarray
        A finite square matrix.
    """
    d = np.diag(M)
    if np.any(d < 0):  # a variance: never negative (the relative eigenvalue tolerance would let it pass)
        i = int(np.flatnonzero(d < 0)[0])
        raise ParameterError(f"{name} must be positive semi-definite: diagonal entry {i} is {d[i]:g} < 0")
    if not np.allclose(M, M.T, rtol=1e-10, atol=0.0):
        raise ParameterError(f"{name} must be symmetric")
    eig = np.linalg.eigvalsh(M)
    if eig.min() < -1e-12 * max(1.0, abs(eig.max())):
        raise ParameterError(f"{name} must be positive semi-definite; smallest eigenvalue {eig.min():g}")


def check_measurement_matrix(C: npt.ArrayLike, n: int | None = None, *, full_rank: bool = True) -> np.ndarray:
    """``C`` as a finite (m, n) array with ``m <= n`` (a 1-D array is one measured channel).

    Parameters
    ----------
    C : array_like
        The measurement matrix.
    n : int, optional
        The number of states ``C`` must have as columns (None: any).
    full_rank : bool
        Require full row rank (independent measured channels).

    Raises
    ------
    ShapeError, NonFiniteError, SingularMatrixError
    """
    C = finite_array("C", C, ndim=(1, 2))
    if C.ndim == 1:
        C = C[None, :]
    if n is not None and C.shape[1] != n:
        raise ShapeError(f"C must have {n} columns (one per state); got shape {C.shape}")
    m, n = C.shape
    if m > n:
        raise ShapeError(f"C has more rows ({m}) than states ({n})")
    if full_rank and np.linalg.matrix_rank(C) < m:
        raise SingularMatrixError(f"C must have full row rank {m}; its rows are dependent")
    return C


def check_noise(Q: npt.ArrayLike, R: npt.ArrayLike, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The process- and measurement-noise covariances ``Q`` (n, n) and ``R`` (m, m), checked.

    Raises
    ------
    ShapeError, NonFiniteError, ParameterError
        On a wrong shape, a non-finite entry or a matrix that is not symmetric PSD.
    """
    Q = finite_array("Q", Q, shape=(n, n))
    R = finite_array("R", R, shape=(m, m))
    check_covariance("Q", Q)
    check_covariance("R", R)
    return Q, R


def check_labels(attr: str, given: Iterable[object], size: int, prefix: str | None) -> tuple[str, ...]:
    """Channel names or units: ``given`` as strings, ``size`` entries; defaults when ``given`` is empty.

    Parameters
    ----------
    attr : str
        The field's name, for the message (``"state_names"``, ``"output_units"``).
    given : iterable
        The labels given (empty: the defaults).
    size : int
        How many channels there are.
    prefix : str or None
        Prefix of the default names ``prefix1..prefixN`` (``"x"``, ``"z"``, ``"u"``); None for units,
        whose default is the empty string.

    Raises
    ------
    ShapeError
        If ``given`` has another number of entries.
    """
    labels = tuple(str(s) for s in given)
    if not labels:
        labels = ("",) * size if prefix is None else tuple(f"{prefix}{i + 1}" for i in range(size))
    if len(labels) != size:
        raise ShapeError(f"{attr} must have {size} entries; got {len(labels)}")
    return labels


def set_channel_labels(model: ModelBase, n: int, m: int, p: int) -> None:
    """Set the checked channel names and units of a frozen model in place.

    ``state_names``, ``output_names``, ``input_names`` (default ``x1..xn``, ``z1..zm``, ``u1..up``),
    then ``state_units`` (if the model has that field) and ``output_units`` (default empty).

    Parameters
    ----------
    model : frozen dataclass
        The model being built (its ``__post_init__``).
    n, m, p : int
        Numbers of states, outputs and inputs.
    """
    names = (("state_names", n, "x"), ("output_names", m, "z"), ("input_names", p, "u"))
    units = (("state_units", n, None), ("output_units", m, None))
    for attr, size, prefix in (*names, *units):
        if hasattr(model, attr):
            object.__setattr__(model, attr, check_labels(attr, getattr(model, attr), size, prefix))


def frozen(value: npt.ArrayLike) -> np.ndarray:
    """A read-only float copy of ``value`` (what the model dataclasses store)."""
    return readonly(np.array(value, dtype=float))


def hash_arrays(h: hashlib._Hash, arrays: Iterable[np.ndarray]) -> None:
    """Feed arrays to a hash as little-endian float64 bytes, each followed by its shape.

    Parameters
    ----------
    h : hashlib hash object
        Updated in place (e.g. ``hashlib.sha256()``).
    arrays : iterable of ndarray
        The arrays, in a fixed order.
    """
    for arr in arrays:
        h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
        h.update(str(arr.shape).encode())


class ModelBase:
    """The plant interface the filters use, and what the linear and nonlinear models share.

    A subclass is a frozen dataclass with the fields ``C`` (m, n), ``Q``, ``R``, ``dt`` (s) and the
    sizes ``n_states``/``n_inputs``, and defines :meth:`transition`, :meth:`jacobian` and ``mode``.
    """

    C: np.ndarray

    if TYPE_CHECKING:  # each model defines it (a property)

        @property
        def mode(self) -> OscillatoryMode | None: ...

    @property
    def n_outputs(self) -> int:
        """Number of outputs."""
        return self.C.shape[0]

    @property
    def natural_frequency_hz(self) -> float | None:
        """Natural frequency (Hz) of the oscillatory mode, or None (see ``mode``)."""
        mode = self.mode
        return None if mode is None else mode.natural_frequency_hz

    @property
    def damping_ratio(self) -> float | None:
        """Damping ratio of the oscillatory mode, or None (see ``mode``)."""
        mode = self.mode
        return None if mode is None else mode.damping_ratio

    def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """One step of the noise-free dynamics ``f(x, u)``, batched.

        Parameters
        ----------
        x : (..., n) array
            States.
        u : (..., p) or (p,) array
            Inputs (broadcast against ``x``'s leading axes).

        Returns
        -------
        (..., n) array
        """
        raise NotImplementedError

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Jacobian ``F = df/dx`` of :meth:`transition` at ``(x, u)``, batched.

        Parameters
        ----------
        x, u : arrays
            As in :meth:`transition`.

        Returns
        -------
        (..., n, n) array
        """
        raise NotImplementedError


# The linear model.

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


# The paper's model factories.


#: Table 1 of the core paper (SI units).
class EHAFault(TypedDict, total=False):
    """Physical parameters of the linear EHA that a fault changes (:func:`eha_linear`'s first three)."""

    leakage: float
    friction: float
    bulk_modulus: float


EHA_PARAMETERS: dict[str, float] = {
    "piston_area": 1.52e-3,  # Ac, m^2
    "pump_displacement": 5.57e-7,  # Dp, m^3/rad
    "mass": 7.38,  # M, kg
    "leakage": 4.8e-12,  # L, m^3/(s Pa)
    "friction": 2144.0,  # a, N s/m
    "bulk_modulus": 2.07e8,  # be, Pa
    "volume": 1.08e-3,  # V0, m^3
}


def second_order(
    f0_hz: float,
    zeta: float,
    b: float = 100.0,
    dt: float = 1e-3,
    *,
    measure: Literal["full", "position"] = "full",
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
    discretization: Discretization = "euler",
) -> LinearModel:
    """Second-order system of eq (30) (corrected per ``docs/design.md`` C2).

    Continuous form ``x1' = x2``, ``x2' = -w0^2 x1 - 2 zeta w0 x2 + b u`` with
    ``w0 = 2 pi f0_hz`` (rad/s). Explicit Euler gives eq (30)::

        A = [[1, Ts], [-Ts w0^2, 1 - 2 Ts zeta w0]],  B = [0, Ts b]^T

    (eq 63 prints the 10 Hz / zeta 0.1 matrix as A21 = -3.9478, A22 = 0.98743).

    Parameters
    ----------
    f0_hz : float
        Natural frequency in Hz (> 0).
    zeta : float
        Damping ratio (>= 0). ``zeta = 0`` with Euler grows slowly
        (|lambda| = sqrt(1 + Ts^2 w0^2)); this is the paper's model.
    b : float
        Input gain.
    dt : float
        Sampling time in seconds (paper: 1 ms).
    measure : {"full", "position"}
        ``"full"``: C = I (spectral sections); ``"position"``: C = [1 0] (Fig 2).
    Q, R : arrays, optional
        Discrete noise covariances; defaults are the paper's low-noise values
        Q = diag(1e-8, 1e-6), R = diag(1e-8, 1e-6) (R = [[1e-8]] for ``"position"``).
    discretization : {"euler", "zoh"}
    """
    f0 = positive("f0_hz", f0_hz, unit="Hz")
    zeta = nonnegative("zeta", zeta)
    w0 = 2.0 * np.pi * f0
    Ac = np.array([[0.0, 1.0], [-(w0**2), -2.0 * zeta * w0]])
    Bc = np.array([[0.0], [float(b)]])
    if measure == "full":
        C = np.eye(2)
        R_default = np.diag([1e-8, 1e-6])
        outputs: tuple[str, ...] = ("position", "velocity")
    elif measure == "position":
        C = np.array([[1.0, 0.0]])
        R_default = np.array([[1e-8]])
        outputs = ("position",)
    else:
        raise ParameterError(f"measure must be 'full' or 'position'; got {measure!r}")
    return LinearModel.from_continuous(
        Ac,
        Bc,
        C,
        np.diag([1e-8, 1e-6]) if Q is None else Q,
        R_default if R is None else R,
        dt,
        discretization=discretization,
        state_names=("position", "velocity"),
        output_names=outputs,
        input_names=("u",),
        oscillatory_block=Ac,
        name=f"second-order f0={f0:g} Hz zeta={zeta:g}",
        # the formulas are those of explicit Euler; a ZOH model has no closed-form entries
        parameter_map=second_order_parameter_map(f0, zeta) if discretization == "euler" else None,
    )


def eha_velocity_pressure_block(
    leakage: float = EHA_PARAMETERS["leakage"],
    friction: float = EHA_PARAMETERS["friction"],
    bulk_modulus: float = EHA_PARAMETERS["bulk_modulus"],
    *,
    piston_area: float = EHA_PARAMETERS["piston_area"],
    mass: float = EHA_PARAMETERS["mass"],
    volume: float = EHA_PARAMETERS["volume"],
    leakage_sign: float = 1.0,
) -> np.ndarray:
    """Continuous velocity-pressure block of the linear EHA (eq 65, corrected).

    ``[[-a/M, Ac/M], [-be Ac/V0, -leakage_sign * be L/V0]]``. The physical model
    has ``leakage_sign = +1`` (leakage dissipates pressure). The paper's Table 2
    natural frequencies and damping ratios are reproduced digit for digit only
    with ``leakage_sign = -1`` (``docs/design.md`` C4); that option exists to document
    the discrepancy, not for use.

    Parameters
    ----------
    leakage : float
        Leakage coefficient L in m^3/(s Pa) (Table 1: 4.8e-12; Table 2 faults:
        3e-11, 6e-11, 9e-11).
    friction : float
        Viscous friction coefficient a in N s/m (Table 1: 2144).
    bulk_modulus : float
        Effective bulk modulus be in Pa (Table 1: 2.07e8).
    piston_area : float
        Piston area Ac in m^2 (Table 1: 1.52e-3).
    mass : float
        Moving mass M in kg (Table 1: 7.38).
    volume : float
        System volume V0 in m^3 (Table 1: 1.08e-3).
    leakage_sign : float
        Sign applied to the leakage term; ``+1`` is physical, ``-1``
        reproduces the paper's Table 2 (see above).

    Returns
    -------
    (2, 2) ndarray
        Continuous-time block (1/s) acting on (velocity, pressure). No input
        validation is done here; :func:`eha_linear` validates its arguments.
    """
    a, M, Ac, V0, be, L = friction, mass, piston_area, volume, bulk_modulus, leakage
    return np.array([[-a / M, Ac / M], [-be * Ac / V0, -leakage_sign * be * L / V0]])


def eha_linear(
    leakage: float = EHA_PARAMETERS["leakage"],
    friction: float = EHA_PARAMETERS["friction"],
    bulk_modulus: float = EHA_PARAMETERS["bulk_modulus"],
    *,
    piston_area: float = EHA_PARAMETERS["piston_area"],
    pump_displacement: float = EHA_PARAMETERS["pump_displacement"],
    mass: float = EHA_PARAMETERS["mass"],
    volume: float = EHA_PARAMETERS["volume"],
    dt: float = 1e-3,
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
    discretization: Discretization = "euler",
) -> LinearModel:
    """Linear 3-state electro-hydraulic actuator, eq (65)/(67) corrected (``docs/design.md`` C3).

    States: position (m), velocity (m/s), differential pressure (Pa); input:
    pump speed (rad/s); C = I. Continuous dynamics::

        x1' = x2
        x2' = -a/M x2 + Ac/M x3
        x3' = -be Ac/V0 x2 - be L/V0 x3 + be Dp/V0 u

    The model reports the natural frequency (Hz) and damping of the
    velocity-pressure block (healthy: 39.07 Hz, 0.5936).

    Parameters
    ----------
    leakage : float
        Leakage coefficient L in m^3/(s Pa), >= 0 (Table 1: 4.8e-12; the
        Table 2 leakage faults use 3e-11, 6e-11 and 9e-11).
    friction : float
        Viscous friction coefficient a in N s/m, >= 0 (Table 1: 2144; Table 2
        friction faults: 4000 and 7000).
    bulk_modulus : float
        Effective bulk modulus be in Pa, > 0 (Table 1: 2.07e8; Table 2 scales
        it by 0.5, 0.75, 1.25 and 1.5).
    piston_area : float
        Piston area Ac in m^2, > 0 (Table 1: 1.52e-3).
    pump_displacement : float
        Pump displacement Dp in m^3/rad, > 0 (Table 1: 5.57e-7).
    mass : float
        Moving mass M in kg, > 0 (Table 1: 7.38).
    volume : float
        System volume V0 in m^3, > 0 (Table 1: 1.08e-3).
    dt : float
        Sampling time Ts in seconds (paper: 1 ms).
    Q, R : (3, 3) arrays, optional
        Discrete process- and measurement-noise covariances; default eq (66):
        Q = diag(1e-12, 1e-6, 1), R = diag(1e-6, 1e-6, 1e6).
    discretization : {"euler", "zoh"}
        How the continuous dynamics are discretized (see :func:`discretize`);
        ``"euler"`` gives the paper's eq (67).

    Returns
    -------
    LinearModel
        Outputs position (m), velocity (m/s) and pressure (Pa); input
        ``pump_speed`` (rad/s).
    """
    params = {
        "leakage": nonnegative("leakage", leakage),
        "friction": nonnegative("friction", friction),
        "bulk_modulus": positive("bulk_modulus", bulk_modulus, unit="Pa"),
        "piston_area": positive("piston_area", piston_area, unit="m^2"),
        "pump_displacement": positive("pump_displacement", pump_displacement, unit="m^3/rad"),
        "mass": positive("mass", mass, unit="kg"),
        "volume": positive("volume", volume, unit="m^3"),
    }
    block = eha_velocity_pressure_block(
        params["leakage"],
        params["friction"],
        params["bulk_modulus"],
        piston_area=params["piston_area"],
        mass=params["mass"],
        volume=params["volume"],
    )
    Ac = np.zeros((3, 3))
    Ac[0, 1] = 1.0
    Ac[1:, 1:] = block
    Bc = np.array([[0.0], [0.0], [params["bulk_modulus"] * params["pump_displacement"] / params["volume"]]])
    return LinearModel.from_continuous(
        Ac,
        Bc,
        np.eye(3),
        np.diag([1e-12, 1e-6, 1.0]) if Q is None else Q,
        np.diag([1e-6, 1e-6, 1e6]) if R is None else R,
        dt,
        discretization=discretization,
        state_names=("position", "velocity", "pressure"),
        output_names=("position", "velocity", "pressure"),
        input_names=("pump_speed",),
        output_units=("m", "m/s", "Pa"),
        oscillatory_block=block,
        name=(f"EHA L={params['leakage']:.3g} a={params['friction']:.4g} be={params['bulk_modulus']:.4g}"),
        # the formulas are those of explicit Euler; a ZOH model has no closed-form entries
        parameter_map=eha_parameter_map(**params) if discretization == "euler" else None,
    )
