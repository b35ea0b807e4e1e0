"""Linear discrete-time plant models and the paper's model factories.

The state-space form is eq (1)-(2) of Saeedzadeh et al. (2023)::

    x(k+1) = A x(k) + B u(k) + v(k),     v ~ N(0, Q)
    z(k)   = C x(k) + w(k),              w ~ N(0, R)

Factories build the under-damped second-order system of eq (30) and the
linear 3-state electro-hydraulic actuator (EHA) of eq (65)/(67), with the
index/sign corrections listed in ``docs/design.md`` (C2-C4).
Frequencies are given in **Hz** and converted to rad/s inside the factories
(w0 = 2 pi f0); times are in seconds.
"""

from __future__ import annotations

from typing import Literal, TypedDict

import numpy as np

from .._validate import nonnegative, positive
from ..errors import ParameterError
from .linear_model import (
    Discretization,
    LinearModel,
    OscillatoryMode,
    discretize,
    oscillatory_mode,
)
from .parameters import eha_parameter_map, second_order_parameter_map

__all__ = [
    "EHA_PARAMETERS",
    "Discretization",
    "EHAFault",
    "LinearModel",
    "OscillatoryMode",
    "discretize",
    "eha_linear",
    "eha_velocity_pressure_block",
    "oscillatory_mode",
    "second_order",
]


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
