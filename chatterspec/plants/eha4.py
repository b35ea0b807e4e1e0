"""The nonlinear 4-state electro-hydraulic actuator (EHA) of the estimator papers, and its fault modes.

States: ``x1`` position (m), ``x2`` velocity (m/s), ``x3`` acceleration (m/s^2), ``x4 = P1 - P2``
differential pressure (Pa); input: pump speed ``omega_p`` (rad/s). Eq (4.1)-(4.5) of the SMM
paper ([SMM]; = eq 34-38 of the IMM paper [IMM]; tags as in ``docs/design.md``), with the two
corrections derived in ``docs/design.md`` S1-S2::

    x1+ = x1 + T x2                                                                  (4.1)
    x2+ = x2 + T x3                                                                  (4.2)
    x3+ = [1 - T (a2 V0 + M be L)/(M V0)] x3 - T (A_E^2 + a2 L) be/(M V0) x2
          - T [2 a1 V0 x2 x3 + be L (a1 x2^2 + a3)]/(M V0) sgn(x2) + T A_E be/(M V0) u   (4.3)
    x4+ = [a2 x2 + (a1 x2^2 + a3) sgn(x2) + M x3] / A_E                              (4.4)
    u   = D_p omega_p - sgn(x4) Q_L0                        (flow, m^3/s)            (4.5)

Corrections: the printed ``1 - [T(...)] x3`` reads ``[1 - T(...)] x3`` (the IMM paper's eq 36 has
it right), and the input term carries ``u`` (the IMM paper's eq 36 drops it). Eq (4.3) is the
explicit Euler step of the jerk equation obtained by differentiating ``M x'' = A_E P - F_f(x')``
(``F_f = a2 v + (a1 v^2 + a3) sgn v``) and substituting ``(V0/be) P' = u - A_E x' - L P``. Eq (4.4)
is the algebraic force balance, printed with a one-step lag (it uses ``x2(k), x3(k)``); we keep
that as printed. ``sgn(0) = 0`` (``numpy.sign``), so at exactly ``v = 0`` the Coulomb term vanishes.

Jacobian (``sgn' = 0``; ``docs/design.md`` S1): ``J11 = J22 = 1``, ``J12 = J23 = T``,
``J32 = -T (A_E^2 + a2 L) be/(M V0) - T (2 a1 V0 x3 sgn x2 + 2 be L a1 |x2|)/(M V0)``,
``J33 = 1 - T (a2 V0 + M be L)/(M V0) - 2 T a1 |x2| / M``, ``J42 = (a2 + 2 a1 |x2|)/A_E``,
``J43 = M / A_E``; every other entry is 0 (``x4`` enters only through ``sgn(x4)``).

Parameters: SMM Table 2 (= IMM Table 1), in :data:`EHA4_PARAMETERS`. Fault modes in
:data:`EHA4_MODES`: the leakage rows of SMM Table 3 and the friction rows of IMM Table 2. **The IMM
paper's labels are swapped**: its leakage "Major" row (2.52e-11, 1.38e-5) is the SMM paper's
*minor* leakage, and its friction "Minor" row has the larger coefficients (larger friction force at
every speed) than its "Major" row. We name leakage modes by the SMM paper and keep the IMM
friction rows under their printed labels with an ``imm`` tag (``friction-imm-major`` is the row
printed as "Major friction", a1 = 1.162e6, a2 = -7440, a3 = 500).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache, partial
from typing import Literal, NamedTuple

import numpy as np

from .._jit import borrow, enabled, njit, step
from .._validate import finite_array, nonnegative, positive
from ..errors import ParameterError
from .nonlinear import Model, NonlinearModel

__all__ = [
    "EHA4_MODES",
    "EHA4_PARAMETERS",
    "EHA4Coefficients",
    "eha4",
    "eha4_jacobian",
    "eha4_mode_parameters",
    "eha4_step",
    "eha4_step_input",
    "eha4_step_jacobian",
    "eha4_transition",
]

#: SMM paper Table 2 (= IMM paper Table 1), SI units.
EHA4_PARAMETERS: dict[str, float] = {
    "piston_area": 1.52e-3,  # A_E, m^2
    "pump_displacement": 5.57e-7,  # D_p, m^3/rad
    "mass": 7.376,  # M, kg
    "volume": 1.08e-3,  # V0, m^3 (initial cylinder volume)
    "bulk_modulus": 2.07e8,  # beta_e, Pa
    "leakage": 4.78e-12,  # L, m^3/(s Pa)
    "flow_offset": 2.41e-6,  # Q_L0, m^3/s
    "a1": 6.589e4,  # quadratic friction, N s^2/m^2
    "a2": 2.144e3,  # viscous friction, N s/m
    "a3": 436.0,  # Coulomb friction, N
}

#: Fault modes: parameter overrides of :data:`EHA4_PARAMETERS` (see the module docstring for labels).
EHA4_MODES: dict[str, dict[str, float]] = {
    "normal": {},
    # SMM Table 3 "Minor leakage" (= IMM Table 3 row printed "Major")
    "leak-minor": {"leakage": 2.52e-11, "flow_offset": 1.38e-5},
    # SMM Table 3 "Major leakage" (= IMM Table 3 row printed "Minor")
    "leak-major": {"leakage": 6.01e-11, "flow_offset": 1.47e-5},
    # IMM Table 2 row printed "Major friction" (the smaller friction force of the two rows)
    "friction-imm-major": {"a1": 1.162e6, "a2": -7.440e3, "a3": 500.0},
    # IMM Table 2 row printed "Minor friction" (the larger friction force at every speed)
    "friction-imm-minor": {"a1": 4.462e6, "a2": 1.863e4, "a3": 551.0},
}

Measure = Literal["full", "position-pressure"]


def eha4_mode_parameters(mode: str = "normal", **overrides: float) -> dict[str, float]:
    """Parameters of a fault mode: :data:`EHA4_PARAMETERS` updated by ``EHA4_MODES[mode]`` and ``overrides``.

    Parameters
    ----------
    mode : str
        A key of :data:`EHA4_MODES` (``"normal"``, ``"leak-minor"``, ``"leak-major"``,
        ``"friction-imm-major"``, ``"friction-imm-minor"``).
    **overrides : float
        Individual parameters (keys of :data:`EHA4_PARAMETERS`, SI units) replacing the mode's.

    Returns
    -------
    dict
        All ten parameters, validated: physical constants > 0, ``leakage``, ``flow_offset``,
        ``a1`` and ``a3`` >= 0; ``a2`` may be negative (``friction-imm-major`` has a2 = -7440).

    Raises
    ------
    ParameterError
        On an unknown mode or a value out of range.
    TypeError
        On an unknown parameter name (like any unexpected keyword argument).
    """
    if mode not in EHA4_MODES:
        raise ParameterError(f"unknown EHA4 mode {mode!r}; valid modes: {', '.join(EHA4_MODES)}")
    unknown = set(overrides) - set(EHA4_PARAMETERS)
    if unknown:
        raise TypeError(
            f"got unexpected keyword argument(s) {', '.join(sorted(unknown))}; the EHA4 parameters are "
            f"{', '.join(EHA4_PARAMETERS)}"
        )
    p = {**EHA4_PARAMETERS, **EHA4_MODES[mode], **overrides}
    for k in ("piston_area", "pump_displacement", "mass", "volume", "bulk_modulus"):
        p[k] = positive(k, p[k])
    for k in ("leakage", "flow_offset", "a1", "a3"):
        p[k] = nonnegative(k, p[k])
    p["a2"] = float(finite_array("a2", p["a2"], ndim=0))
    return p


class EHA4Coefficients(NamedTuple):
    """Step coefficients of the corrected eq (4.3)-(4.5) at sampling time ``T`` (built by :func:`eha4`).

    Attributes
    ----------
    T : float
        Sampling time (s).
    c33 : float
        ``1 - T (a2 V0 + M be L)/(M V0)``, the x3 coefficient of (4.3).
    c32 : float
        ``T (A_E^2 + a2 L) be/(M V0)``, minus the x2 coefficient of (4.3).
    cxx : float
        ``2 T a1 / M``, the coefficient of ``x2 x3 sgn(x2)``.
    cl : float
        ``T be L/(M V0)``, the coefficient of ``(a1 x2^2 + a3) sgn(x2)``.
    cu : float
        ``T A_E be/(M V0)``, the coefficient of the flow u of (4.5).
    Dp : float
        Pump displacement (m^3/rad).
    QL0 : float
        Flow-rate offset (m^3/s).
    a1, a2, a3 : float
        Friction coefficients (N s^2/m^2, N s/m, N).
    M : float
        Mass (kg).
    A : float
        Piston area A_E (m^2).
    """

    T: float
    c33: float
    c32: float
    cxx: float
    cl: float
    cu: float
    Dp: float
    QL0: float
    a1: float
    a2: float
    a3: float
    M: float
    A: float


def _coefficients(T: float, p: dict[str, float]) -> EHA4Coefficients:
    A, M, V0, be, L = p["piston_area"], p["mass"], p["volume"], p["bulk_modulus"], p["leakage"]
    a1, a2, a3 = p["a1"], p["a2"], p["a3"]
    MV0 = M * V0
    return EHA4Coefficients(
        T=T,
        c33=1.0 - T * (a2 * V0 + M * be * L) / MV0,
        c32=T * (A * A + a2 * L) * be / MV0,
        cxx=T * 2.0 * a1 * V0 / MV0,
        cl=T * be * L / MV0,
        cu=T * A * be / MV0,
        Dp=p["pump_displacement"],
        QL0=p["flow_offset"],
        a1=a1,
        a2=a2,
        a3=a3,
        M=M,
        A=A,
    )


@step
def predict_step(prm: np.ndarray, x: np.ndarray, u: np.ndarray, xp: np.ndarray, n: int, p: int) -> None:
    """The EHA4 plant step: one Euler step of the corrected eq (4.1)-(4.5), one realization, into ``xp``.

    ``prm`` = the 13 :class:`EHA4Coefficients` in their order; ``u[0]`` is the pump speed (rad/s).
    The same operations in the same order as the numpy formulas of :func:`eha4_transition`.
    """
    T, c33, c32, cxx, cl, cu, Dp, QL0 = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5], prm[6], prm[7]
    a1, a2, a3, M, A = prm[8], prm[9], prm[10], prm[11], prm[12]
    x2 = x[1]
    x3 = x[2]
    x4 = x[3]
    s = 1.0 if x2 > 0 else (-1.0 if x2 < 0 else 0.0)
    s4 = 1.0 if x4 > 0 else (-1.0 if x4 < 0 else 0.0)
    fric = a1 * x2 * x2 + a3
    flow = Dp * u[0] - s4 * QL0
    xp[0] = x[0] + T * x2
    xp[1] = x2 + T * x3
    xp[2] = c33 * x3 - c32 * x2 - (cxx * x2 * x3 + cl * fric) * s + cu * flow
    xp[3] = (a2 * x2 + fric * s + M * x3) / A


@step
def jacobian_step(prm: np.ndarray, x: np.ndarray, u: np.ndarray, F: np.ndarray, n: int, p: int) -> None:
    """``F = d x+ / d x`` of :func:`predict_step` at ``x`` (``sgn' = 0``; every entry written)."""
    T, c33, c32, cxx, cl = prm[0], prm[1], prm[2], prm[3], prm[4]
    a1, a2, M, A = prm[8], prm[9], prm[11], prm[12]
    x2 = x[1]
    x3 = x[2]
    s = 1.0 if x2 > 0 else (-1.0 if x2 < 0 else 0.0)
    ax2 = abs(x2)
    for i in range(4):
        for j in range(4):
            F[i, j] = 0.0
    F[0, 0] = 1.0
    F[0, 1] = T
    F[1, 1] = 1.0
    F[1, 2] = T
    F[2, 1] = -c32 - cxx * x3 * s - 2.0 * cl * a1 * ax2
    F[2, 2] = c33 - cxx * ax2
    F[3, 1] = (a2 + 2.0 * a1 * ax2) / A
    F[3, 2] = M / A


@njit
def _step_kernel(x: np.ndarray, u: np.ndarray, out: np.ndarray, prm: np.ndarray) -> None:  # pragma: no cover
    """:func:`predict_step` for every row of ``x`` (runs, 4) with one input ``u`` (1,)."""
    x, u, out, prm = borrow(x), borrow(u), borrow(out), borrow(prm)
    for r in range(x.shape[0]):
        predict_step(prm, x[r], u, out[r], 4, 1)


@njit
def _jacobian_kernel(
    x: np.ndarray, u: np.ndarray, J: np.ndarray, prm: np.ndarray
) -> None:  # pragma: no cover
    """:func:`jacobian_step` for every row of ``x`` (runs, 4)."""
    x, u, J, prm = borrow(x), borrow(u), borrow(J), borrow(prm)
    for r in range(x.shape[0]):
        jacobian_step(prm, x[r], u, J[r], 4, 1)


def _batched(x: np.ndarray, u: np.ndarray) -> bool:
    """True for the compiled path: x (runs, 4) C-contiguous float, one input for all rows."""
    return u.ndim == 1 and x.ndim == 2 and x.dtype == np.float64 and x.flags.c_contiguous and enabled()


def eha4_transition(x: np.ndarray, u: np.ndarray, c: EHA4Coefficients) -> np.ndarray:
    """One Euler step of the corrected eq (4.1)-(4.5), batched.

    Parameters
    ----------
    x : (..., 4) array
        Position (m), velocity (m/s), acceleration (m/s^2), differential pressure (Pa).
    u : (..., 1) or (1,) array
        Pump speed ``omega_p`` in rad/s.
    c : EHA4Coefficients
        Step coefficients built by :func:`eha4` (``model.f.keywords["c"]``).

    Returns
    -------
    (..., 4) ndarray
        With numba, a 2-D ``x`` and one input for all rows take a compiled loop over the same
        formulas (tested equal to the numpy path).
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if _batched(x, u):
        out = np.empty(x.shape)
        _step_kernel(x, u, out, coefficient_vector(c))
        return out
    x2, x3, x4 = x[..., 1], x[..., 2], x[..., 3]
    s = np.sign(x2)
    fric = c.a1 * x2 * x2 + c.a3  # (a1 x2^2 + a3)
    flow = c.Dp * u[..., 0] - np.sign(x4) * c.QL0  # (4.5)
    x3n = c.c33 * x3 - c.c32 * x2 - (c.cxx * x2 * x3 + c.cl * fric) * s + c.cu * flow  # (4.3)
    x4n = (c.a2 * x2 + fric * s + c.M * x3) / c.A  # (4.4)
    out = np.empty((*np.broadcast_shapes(x.shape[:-1], u.shape[:-1]), 4))
    out[..., 0] = x[..., 0] + c.T * x2  # (4.1)
    out[..., 1] = x2 + c.T * x3  # (4.2)
    out[..., 2] = x3n
    out[..., 3] = x4n
    return out


def eha4_jacobian(x: np.ndarray, u: np.ndarray, c: EHA4Coefficients) -> np.ndarray:
    """Jacobian ``d x+ / d x`` of :func:`eha4_transition` (``sgn' = 0``), batched.

    Parameters
    ----------
    x : (..., 4) array
        States (SI units, as in :func:`eha4_transition`).
    u : (..., 1) or (1,) array
        Pump speed in rad/s (the Jacobian does not depend on it).
    c : EHA4Coefficients
        Step coefficients built by :func:`eha4`.

    Returns
    -------
    (..., 4, 4) ndarray
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)
    if _batched(x, u):
        J = np.empty((x.shape[0], 4, 4))
        _jacobian_kernel(x, u, J, coefficient_vector(c))
        return J
    x2, x3 = x[..., 1], x[..., 2]
    s = np.sign(x2)
    ax2 = np.abs(x2)
    J = np.zeros((*np.broadcast_shapes(x.shape[:-1], u.shape[:-1]), 4, 4))
    J[..., 0, 0] = 1.0
    J[..., 0, 1] = c.T
    J[..., 1, 1] = 1.0
    J[..., 1, 2] = c.T
    # d/dx2 of -(cxx x2 x3 + cl (a1 x2^2 + a3)) sgn(x2) = -cxx x3 sgn(x2) - 2 cl a1 |x2|
    J[..., 2, 1] = -c.c32 - c.cxx * x3 * s - 2.0 * c.cl * c.a1 * ax2
    J[..., 2, 2] = c.c33 - c.cxx * ax2
    J[..., 3, 1] = (c.a2 + 2.0 * c.a1 * ax2) / c.A
    J[..., 3, 2] = c.M / c.A
    return J


def coefficient_vector(c: EHA4Coefficients) -> np.ndarray:
    """The parameter vector ``prm`` of :func:`predict_step` / :func:`jacobian_step` (the 13 coefficients)."""
    return np.asarray(tuple(c), dtype=float)


def plant_steps(model: Model) -> tuple[Callable[..., None], Callable[..., None], bool, np.ndarray] | None:
    """``(predict, jacobian, constant_jacobian, prm)`` of a model built by :func:`eha4`, else None.

    A :class:`~chatterspec.plants.nonlinear.NonlinearModel` is recognized as the EHA4 when its ``f``
    and ``jac`` are :func:`eha4_transition` / :func:`eha4_jacobian` with one coefficient set (what
    :func:`eha4` builds), 4 states and one input; the compiled steps then reproduce its
    ``transition`` and ``jacobian`` exactly.
    """
    f, jac = getattr(model, "f", None), getattr(model, "jac", None)
    if not (
        isinstance(f, partial)
        and isinstance(jac, partial)
        and f.func is eha4_transition
        and jac.func is eha4_jacobian
        and not f.args
        and not jac.args
        and set(f.keywords) == {"c"}
        and set(jac.keywords) == {"c"}
        and f.keywords["c"] == jac.keywords["c"]
        and getattr(model, "n_states", None) == 4
        and getattr(model, "n_inputs", None) == 1
    ):
        return None
    return predict_step, jacobian_step, False, coefficient_vector(f.keywords["c"])


def _input_jacobian(x: np.ndarray, u: np.ndarray, c: EHA4Coefficients) -> np.ndarray:
    B = np.zeros((4, 1))
    B[2, 0] = c.cu * c.Dp  # T A_E be D_p / (M V0)
    return B


@lru_cache(maxsize=64)
def _cached_coefficients(dt: float, items: tuple[tuple[str, float], ...]) -> EHA4Coefficients:
    return _coefficients(dt, eha4_mode_parameters("normal", **dict(items)))


def eha4_step(x: np.ndarray, u: np.ndarray, *, dt: float, **parameters: float) -> np.ndarray:
    """:func:`eha4_transition` with the physical parameters as keywords (for model files).

    A model file names it as ``f = "chatterspec.plants.eha4:eha4_step"`` with the ten parameters of
    :data:`EHA4_PARAMETERS` in ``[dynamics.parameters]`` (SI units) and receives the file's ``dt`` (s);
    the step coefficients are those of :func:`eha4`, so the numbers are the catalogue model's.

    Parameters
    ----------
    x : (..., 4) array
        States (SI units).
    u : (..., 1) or (1,) array
        Pump speed in rad/s.
    dt : float
        Sampling time T in seconds.
    **parameters : float
        Keys of :data:`EHA4_PARAMETERS` (missing ones take the normal mode's value).

    See Also
    --------
    eha4_transition : the same step from precomputed coefficients.
    """
    return eha4_transition(x, u, _cached_coefficients(float(dt), tuple(sorted(parameters.items()))))


def eha4_step_jacobian(x: np.ndarray, u: np.ndarray, *, dt: float, **parameters: float) -> np.ndarray:
    """:func:`eha4_jacobian` with the physical parameters as keywords (see :func:`eha4_step`).

    Parameters
    ----------
    x : (..., 4) array
        States (SI units).
    u : (..., 1) or (1,) array
        Pump speed in rad/s (the Jacobian does not depend on it).
    dt : float
        Sampling time T in seconds.
    **parameters : float
        Keys of :data:`EHA4_PARAMETERS`.
    """
    return eha4_jacobian(x, u, _cached_coefficients(float(dt), tuple(sorted(parameters.items()))))


def eha4_step_input(x: np.ndarray, u: np.ndarray, *, dt: float, **parameters: float) -> np.ndarray:
    """``d f / d u`` (4, 1) with the physical parameters as keywords (see :func:`eha4_step`).

    Parameters
    ----------
    x : (4,) array
        State (SI units; the input enters affinely, so it does not matter).
    u : (1,) array
        Pump speed in rad/s.
    dt : float
        Sampling time T in seconds.
    **parameters : float
        Keys of :data:`EHA4_PARAMETERS`.
    """
    return _input_jacobian(x, u, _cached_coefficients(float(dt), tuple(sorted(parameters.items()))))


def eha4(
    mode: str = "normal",
    *,
    dt: float = 1e-3,
    measure: Measure = "full",
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
    **overrides: float,
) -> NonlinearModel:
    """The nonlinear 4-state EHA (corrected eq 4.1-4.5 of the SMM paper) in a given fault mode.

    Parameters
    ----------
    mode : str
        Fault mode, a key of :data:`EHA4_MODES` (default ``"normal"``).
    dt : float
        Sampling time T in seconds (SMM paper: 1 ms; IMM paper: 0.1 ms).
    measure : {"full", "position-pressure"}
        ``"full"``: C = I4 (SMM paper, R is 4x4); ``"position-pressure"``: C = [[1,0,0,0],[0,0,0,1]]
        (IMM paper's H).
    Q : (4, 4) array, optional
        Process-noise covariance per step; default ``1e-9 I4`` (SMM paper section 5).
    R : (m, m) array, optional
        Measurement-noise covariance; default ``1e-6 I_m`` (SMM paper section 5).
    **overrides : float
        Individual parameters (keys of :data:`EHA4_PARAMETERS`, SI units) replacing the mode's.

    Returns
    -------
    NonlinearModel
        Its linearization at rest reports the velocity-acceleration mode (39.08 Hz, zeta 0.594 for
        the normal mode; the chattering paper's linear EHA gives 39.07 Hz / 0.5936 with the rounded
        M = 7.38 kg and L = 4.8e-12).

    Raises
    ------
    ParameterError
        On an unknown mode or ``measure``, or out-of-range values.
    TypeError
        On an unknown parameter name.

    Notes
    -----
    Explicit Euler needs ``2 T a1 |v| / M < 1`` (|v| < 0.056 m/s for the normal a1 at 1 ms); beyond
    it the acceleration recursion diverges, and :func:`chatterspec.simulate` reports a
    ``NonFiniteError``.
    """
    p = eha4_mode_parameters(mode, **overrides)
    dt = positive("dt", dt, unit="s")
    if measure == "full":
        C = np.eye(4)
        outputs: tuple[str, ...] = ("position", "velocity", "acceleration", "pressure")
        units: tuple[str, ...] = ("m", "m/s", "m/s^2", "Pa")
    elif measure == "position-pressure":
        C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
        outputs, units = ("position", "pressure"), ("m", "Pa")
    else:
        raise ParameterError(f"measure must be 'full' or 'position-pressure'; got {measure!r}")
    c = _coefficients(dt, p)
    return NonlinearModel(
        f=partial(eha4_transition, c=c),
        jac=partial(eha4_jacobian, c=c),
        C=C,
        Q=1e-9 * np.eye(4) if Q is None else Q,
        R=1e-6 * np.eye(C.shape[0]) if R is None else R,
        dt=dt,
        n_inputs=1,
        input_jacobian=partial(_input_jacobian, c=c),
        state_names=("position", "velocity", "acceleration", "pressure"),
        state_units=("m", "m/s", "m/s^2", "Pa"),
        output_names=outputs,
        output_units=units,
        input_names=("pump_speed",),
        oscillatory_states=(1, 2),
        parameters=p,
        name=f"EHA4 {mode}" + ("".join(f" {k}={v:.4g}" for k, v in overrides.items())),
    )
