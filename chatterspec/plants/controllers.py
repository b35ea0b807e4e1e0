"""A discrete PID position controller with input saturation and anti-windup, as a pure step.

The controller closes the loop around an actuator model (the linear EHA of eq 65/67 of the core
paper or the nonlinear 4-state EHA of the SMM paper's eq 4.1-4.5): it reads the measured position
``y(k)`` (m) and the reference ``r(k)`` (m) and commands the pump speed ``u(k)`` (rad/s), which is
applied to the plant for ``x(k) -> x(k+1)``. Neither paper has a controller; this is chatterspec's
extension for the core paper's open problem (its section VI: detection inside a closed loop).

The law, at sample ``k`` (``dt`` in s)::

    e(k)   = r(k) - y(k)                                          position error, m
    D(k)   = a D(k-1) - kd / (Tf + dt) (y(k) - y(k-1)),  a = Tf / (Tf + dt)
    v(k)   = kp (b r(k) - y(k)) + I(k) + D(k) + d(k)              unsaturated command, rad/s
    u(k)   = min(max(v(k), -u_max), u_max)                        applied pump speed, rad/s
    I(k+1) = I(k) + g(k) ki dt e(k) + (dt / Tt) (u(k) - v(k))

The derivative acts on the measurement (no kick on reference steps) through a first-order filter
of time constant ``Tf`` (backward Euler); ``b`` weights the reference in the proportional term;
``d(k)`` is an optional input dither (rad/s, added before the saturation, so the applied ``u``
never leaves ``[-u_max, u_max]``). Anti-windup is either **back-calculation** (``g = 1``, the
integrator is pulled towards the saturated value with tracking time ``Tt``) or **clamping**
(conditional integration: ``g = 0`` while the command is saturated and the error would drive it
further, ``Tt`` unused).

:func:`pid_step` is written with scalar arithmetic only: numba compiles it for one realization
(``chatterspec.plants.simulate_closed_loop``'s compiled loop) and the same Python function runs
vectorized over realizations on the numpy path, doing the same correctly rounded operations in the
same order (the two paths give the same bits).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal, NamedTuple, TypedDict

import numpy as np

from .._jit import step
from .._validate import finite_scalar, nonnegative, positive
from ..errors import ParameterError
from ..jsonout import fields_dict

__all__ = [
    "AntiWindup",
    "PIDCoefficients",
    "PIDController",
    "PIDOptions",
    "pid_coefficients",
    "pid_step",
]

AntiWindup = Literal["back-calculation", "clamping"]


class PIDOptions(TypedDict, total=False):
    """The optional arguments of :class:`PIDController` (what ``design_pi`` passes on)."""

    kd: float
    derivative_filter_s: float
    anti_windup: AntiWindup
    tracking_time_s: float | None
    setpoint_weight: float


_ANTI_WINDUP: tuple[str, ...] = ("back-calculation", "clamping")


@dataclass(frozen=True)
class PIDController:
    """Discrete PID position controller with saturation and anti-windup (parameters in SI units).

    Parameters
    ----------
    kp : float
        Proportional gain in rad/s per m of position error (>= 0).
    ki : float
        Integral gain in rad/s per (m s) (>= 0).
    saturation : float
        Largest pump speed magnitude ``u_max`` in rad/s (> 0): ``u`` is clipped to ``[-u_max, u_max]``.
    kd : float
        Derivative gain in rad/s per (m/s) (>= 0; default 0: a PI controller).
    derivative_filter_s : float
        Time constant ``Tf`` (s, > 0) of the derivative's first-order filter.
    anti_windup : {"back-calculation", "clamping"}
        How the integrator is kept from winding up while ``u`` saturates (module docstring).
    tracking_time_s : float, optional
        Back-calculation tracking time ``Tt`` in s (> 0); default ``kp / ki`` (the integral time),
        or 1 s without integral action.
    setpoint_weight : float
        Weight ``b`` of the reference in the proportional term, in [0, 1] (1: error feedback).

    Raises
    ------
    ParameterError
        On a negative gain, a saturation that is not positive, an unknown anti-windup scheme, a
        non-positive time constant or ``b`` outside [0, 1]; the message names the parameter.

    See Also
    --------
    chatterspec.plants.loop_design.design_pi : gains for a damping target on a linear model.
    chatterspec.plants.loop_design.check_closed_loop : stability of the loop and the stable gain ranges.
    """

    kp: float
    ki: float
    saturation: float
    kd: float = 0.0
    derivative_filter_s: float = 0.005
    anti_windup: AntiWindup = "back-calculation"
    tracking_time_s: float | None = None
    setpoint_weight: float = 1.0

    def __post_init__(self) -> None:
        for name in ("kp", "ki", "kd"):
            object.__setattr__(self, name, nonnegative(name, getattr(self, name)))
        try:
            sat = finite_scalar("saturation", self.saturation)
        except ParameterError:
            raise ParameterError(
                f"saturation must be a finite pump speed > 0 rad/s; got {self.saturation!r}"
            ) from None
        if not sat > 0:
            raise ParameterError(
                f"saturation must be > 0 rad/s (the largest pump speed magnitude); got {sat!r}"
            )
        object.__setattr__(self, "saturation", sat)
        object.__setattr__(
            self, "derivative_filter_s", positive("derivative_filter_s", self.derivative_filter_s, unit="s")
        )
        if self.anti_windup not in _ANTI_WINDUP:
            raise ParameterError(
                f"anti_windup must be one of {', '.join(_ANTI_WINDUP)}; got {self.anti_windup!r}"
            )
        if self.tracking_time_s is not None:
            object.__setattr__(
                self, "tracking_time_s", positive("tracking_time_s", self.tracking_time_s, unit="s")
            )
        b = finite_scalar("setpoint_weight", self.setpoint_weight)
        if not 0.0 <= b <= 1.0:
            raise ParameterError(f"setpoint_weight must lie in [0, 1]; got {b!r}")
        object.__setattr__(self, "setpoint_weight", b)

    @property
    def tracking_time(self) -> float:
        """Back-calculation tracking time ``Tt`` in s (the integral time ``kp / ki`` by default)."""
        if self.tracking_time_s is not None:
            return self.tracking_time_s
        if self.ki > 0 and self.kp > 0:
            return self.kp / self.ki
        return 1.0

    def with_gains(self, **gains: float) -> PIDController:
        """A copy with some of ``kp``, ``ki``, ``kd`` replaced (validated again)."""
        unknown = set(gains) - {"kp", "ki", "kd"}
        if unknown:
            raise ParameterError(f"unknown gain(s) {', '.join(sorted(unknown))}; the gains are kp, ki, kd")
        kp, ki, kd = (gains.get(g, getattr(self, g)) for g in ("kp", "ki", "kd"))
        return replace(self, kp=kp, ki=ki, kd=kd)

    def describe(self) -> str:
        """One line with the gains in engineering units (rad/s per mm, ...)."""
        text = f"PI{'D' if self.kd > 0 else ''} kp {self.kp * 1e-3:.4g} rad/s/mm, "
        text += f"ki {self.ki * 1e-3:.4g} rad/s/(mm s)"
        if self.kd > 0:
            text += f", kd {self.kd * 1e-3:.4g} rad/s/(mm/s) (filter {self.derivative_filter_s * 1e3:g} ms)"
        aw = "back-calculation" if self.anti_windup == "back-calculation" else "clamping"
        text += f", |u| <= {self.saturation:g} rad/s, {aw} anti-windup"
        if self.setpoint_weight != 1.0:
            text += f", setpoint weight {self.setpoint_weight:g}"
        return text

    def to_dict(self) -> dict[str, object]:
        """The constructor's arguments (SI units), JSON-ready: every field, in declaration order."""
        return fields_dict(self)


class PIDCoefficients(NamedTuple):
    """The per-sample constants of :func:`pid_step` at sampling time ``dt`` (from :func:`pid_coefficients`).

    Attributes
    ----------
    kp : float
        Proportional gain (rad/s per m).
    kpb : float
        ``kp * b`` (reference weight in the proportional term).
    ki_dt : float
        ``ki * dt`` (rad/s per m per sample).
    a_d : float
        Derivative filter pole ``Tf / (Tf + dt)``.
    kd_f : float
        ``kd / (Tf + dt)`` (rad/s per m of measurement change).
    u_max : float
        Saturation (rad/s).
    k_t : float
        Back-calculation gain ``dt / Tt`` (0 for clamping).
    clamp : float
        1.0 for clamping (conditional integration), 0.0 for back-calculation.
    """

    kp: float
    kpb: float
    ki_dt: float
    a_d: float
    kd_f: float
    u_max: float
    k_t: float
    clamp: float


def pid_coefficients(controller: PIDController, dt: float) -> PIDCoefficients:
    """The constants of :func:`pid_step` for ``controller`` at sampling time ``dt`` (s).

    Parameters
    ----------
    controller : PIDController
    dt : float
        Sampling time in seconds (> 0).

    Returns
    -------
    PIDCoefficients
    """
    dt = positive("dt", dt, unit="s")
    c = controller
    tf = c.derivative_filter_s
    clamping = c.anti_windup == "clamping"
    return PIDCoefficients(
        kp=c.kp,
        kpb=c.kp * c.setpoint_weight,
        ki_dt=c.ki * dt,
        a_d=tf / (tf + dt),
        kd_f=c.kd / (tf + dt),
        u_max=c.saturation,
        k_t=0.0 if clamping else dt / c.tracking_time,
        clamp=1.0 if clamping else 0.0,
    )


@step
def pid_step(
    kp: float,
    kpb: float,
    ki_dt: float,
    a_d: float,
    kd_f: float,
    u_max: float,
    k_t: float,
    clamp: float,
    integ: float,
    deriv: float,
    y_prev: float,
    r: float,
    y: float,
    d: float,
) -> tuple[float, float, float]:  # pragma: no cover - compiled (its Python form runs on the numpy path)
    """One controller sample: ``(u(k), I(k+1), D(k))`` from ``I(k), D(k-1), y(k-1), r(k), y(k), d(k)``.

    The first eight arguments are :class:`PIDCoefficients` in order. Scalars (one realization,
    compiled) or arrays of realizations (numpy path): the same operations in the same order.

    Returns
    -------
    u : float or ndarray
        Applied (saturated) pump speed in rad/s.
    integ : float or ndarray
        Integrator state ``I(k+1)`` in rad/s.
    deriv : float or ndarray
        Filtered derivative term ``D(k)`` in rad/s (the next call's ``deriv``).
    """
    e = r - y
    deriv = a_d * deriv - kd_f * (y - y_prev)
    v = ((kpb * r - kp * y) + integ + deriv) + d
    u = np.minimum(np.maximum(v, -u_max), u_max)
    gate = 1.0 - clamp * (e * (v - u) > 0.0)
    integ = (integ + gate * (ki_dt * e)) + k_t * (u - v)
    return u, integ, deriv
