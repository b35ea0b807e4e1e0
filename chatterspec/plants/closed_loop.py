"""The closed loop: a PID position controller, its gain design, position references, dither and
:class:`ClosedLoop`, a scenario's input when the controller closes the loop.

A scenario's input when a controller closes the loop: controller, position reference and dither.

Open-loop scenarios drive the plant with a chosen signal (a chirp, a sine). A real actuator runs
under its position controller: the pump speed is whatever the controller commands from the
measured position. :class:`ClosedLoop` is what a :class:`~chatterspec.plants.scenarios.Scenario`
takes as its ``input`` in that case; the simulation
(:mod:`chatterspec.plants.simulate`) computes ``u(k)`` per realization from ``z(k)``
and returns it as ``Simulation.u`` of shape ``(runs, T, 1)``. The filters then run the open-loop
nominal model with that measured (saturated) ``u``, as a monitor on the real actuator would.

With an exactly known linear model the healthy chattering (eq 23 of the core paper) is
``v(k) + w(k+1) - C A C^-1 w(k)``: it does not involve ``u`` at all, so the analytic thresholds hold
in closed loop as they do open loop (``chatterspec detect eha-cl-healthy --runs 1000`` measures it).

A discrete PID position controller with input saturation and anti-windup, as a pure step.

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
(``chatterspec.plants.simulate``'s compiled loop) and the same Python function runs
vectorized over realizations on the numpy path, doing the same correctly rounded operations in the
same order (the two paths give the same bits).

Gain design and stability of a PID position loop around a plant model.

The closed loop of the PID controller around a linear model (or a nonlinear
model's linearization at rest), without saturation or noise, is linear in the augmented state
``s(k) = [x(k), I(k), D(k-1), y(k-1)]`` (plant state, integrator, filtered derivative, last measured
position): ``s(k+1) = Acl s(k) + (reference terms)``. The loop is stable when every eigenvalue of
``Acl`` lies strictly inside the unit circle (:func:`closed_loop_matrix`, :func:`is_stable`).

:func:`stable_gain_ranges` gives, for each gain with the other two held, the intervals of values
that keep the loop stable (a scan over 22 decades refined by bisection), and
:func:`check_closed_loop` raises :class:`~chatterspec.errors.UnstableLoopError` with those ranges
when the gains destabilize the plant. :func:`design_pi` chooses PI gains by pole placement on the
actuator's rigid-body approximation (an integrator, ``y' = Kv u``) for a damping target, and
:func:`loop_mode` reports the damping and frequency the full model actually gets.

Position references for a closed loop: holds, step sequences and smooth point-to-point moves.

Each reference is a frozen dataclass with ``sample(t) -> (T,)`` (position in metres at the times
``t`` in seconds), ``describe()`` and ``peak`` (the largest ``|r(t)|`` in m), so it plugs in wherever
a :class:`chatterspec.plants.signals.Signal` does. A reference says where the actuator should be;
:class:`chatterspec.plants.closed_loop.ClosedLoop` turns it into the pump speed through a controller.

* :class:`Hold` -- the position held still (the hard case for fault detection: nothing moves, so a
  leak or a friction change has nothing to act on).
* :class:`StepSequence` -- jumps to new levels at given times (rich in frequency content, and the
  classic test of a controller's overshoot and settling time).
* :class:`SCurve` -- the same levels reached by smooth minimum-jerk moves
  ``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5`` (position, velocity and acceleration continuous; peak
  velocity ``1.875 |step| / move_time``), the way point-to-point motion is commanded in practice.

Dither signals: small deterministic excitation added to a closed loop's input or reference.

Under a position controller an actuator that holds still excites nothing, and the chattering of a
fault that acts through the motion (a leak needs pressure, friction needs velocity) stays at the
noise floor (the persistent-excitation problem of the core paper's section VI). A dither is a small
known signal added to the pump-speed command (amplitude in rad/s) or to the position reference (in
m); it costs tracking accuracy and buys detection power (``chatterspec power leakage --closed-loop
--dither LEVELS`` measures both).

Both signals are the same for every realization (a deterministic function of time, like every
:mod:`chatterspec.plants.signals` input) and report ``peak``, the largest value they can take, which
:class:`chatterspec.plants.closed_loop.ClosedLoop` checks against the controller's saturation.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Literal, NamedTuple, TypedDict, Unpack

import numpy as np
import numpy.typing as npt

from .._jit import step
from .._validate import finite_array, finite_scalar, nonnegative, positive
from ..errors import ParameterError, UnstableLoopError
from ..jsonout import fields_dict
from .models import LinearModel
from .nonlinear import NonlinearModel
from .signals import Chirp, Constant, Signal, Sine, SquareWave

__all__ = [
    "GAINS",
    "PRBS",
    "PRBS_TAPS",
    "AntiWindup",
    "ClosedLoop",
    "DitherAt",
    "Hold",
    "LoopMode",
    "Multisine",
    "PIDCoefficients",
    "PIDController",
    "PIDOptions",
    "SCurve",
    "StepSequence",
    "check_closed_loop",
    "closed_loop_matrix",
    "design_pi",
    "is_stable",
    "linear_part",
    "loop_mode",
    "pid_coefficients",
    "pid_step",
    "rigid_body_gain",
    "signal_peak",
    "spectral_radius",
    "stable_gain_ranges",
]


# The discrete PID controller (a pure step).

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
    chatterspec.plants.closed_loop.design_pi : gains for a damping target on a linear model.
    chatterspec.plants.closed_loop.check_closed_loop : stability of the loop and the stable gain ranges.
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


# Gain design and stability of the loop.

#: The gains whose stable ranges are reported, with their SI units.
GAINS: dict[str, str] = {"kp": "rad/s per m", "ki": "rad/s per (m s)", "kd": "rad/s per (m/s)"}

#: Largest spectral radius counted as stable (strictly inside the unit circle, with a margin for rounding).
_RHO_STABLE = 1.0 - 1e-12


def linear_part(model: LinearModel | NonlinearModel) -> LinearModel:
    """``model`` itself if linear, else its linearization at rest (``NonlinearModel.linearize()``)."""
    return model if isinstance(model, LinearModel) else model.linearize()


def _output_row(model: LinearModel, output: int) -> np.ndarray:
    if not 0 <= output < model.n_outputs:
        raise ParameterError(
            f"position output index {output} is out of range: the model has {model.n_outputs} output(s) "
            f"({', '.join(model.output_names)})"
        )
    if model.n_inputs != 1:
        raise ParameterError(f"a position loop drives one input; the model has {model.n_inputs}")
    return np.asarray(model.C[output], dtype=float)


def closed_loop_matrix(
    model: LinearModel | NonlinearModel, controller: PIDController, output: int = 0
) -> np.ndarray:
    """The linear closed-loop transition ``Acl`` (``(n + 3, n + 3)``) on ``[x, I, D(k-1), y(k-1)]``.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The plant (a nonlinear one is linearized at rest); one input (pump speed, rad/s).
    controller : PIDController
        Gains; saturation and anti-windup play no part in the linear loop.
    output : int
        Index of the measured position among the model's outputs.

    Returns
    -------
    (n + 3, n + 3) ndarray
    """
    lin = linear_part(model)
    cp = _output_row(lin, output)
    c = pid_coefficients(controller, lin.dt)
    n = lin.n_states
    A, B = lin.A, lin.B[:, 0]
    dx = -c.kd_f * cp  # D(k) = a_d D(k-1) - kd_f (Cp x - y(k-1))
    ux = -c.kp * cp + dx  # u = -kp Cp x + I + D(k)   (reference 0)
    M = np.zeros((n + 3, n + 3))
    M[:n, :n] = A + np.outer(B, ux)
    M[:n, n] = B
    M[:n, n + 1] = B * c.a_d
    M[:n, n + 2] = B * c.kd_f
    M[n, :n] = -c.ki_dt * cp
    # without integral action I keeps its initial value 0 (a decoupled state, not an unstable mode)
    M[n, n] = 1.0 if c.ki_dt > 0 else 0.0
    M[n + 1, :n] = dx
    M[n + 1, n + 1] = c.a_d
    M[n + 1, n + 2] = c.kd_f
    M[n + 2, :n] = cp
    return M


def spectral_radius(model: LinearModel | NonlinearModel, controller: PIDController, output: int = 0) -> float:
    """Largest eigenvalue magnitude of :func:`closed_loop_matrix` (< 1: stable).

    Parameters
    ----------
    model, controller, output
        As in :func:`closed_loop_matrix`.
    """
    return float(np.abs(np.linalg.eigvals(closed_loop_matrix(model, controller, output))).max())


def is_stable(model: LinearModel | NonlinearModel, controller: PIDController, output: int = 0) -> bool:
    """Whether ``controller`` closing the loop on ``model``'s position ``output`` is asymptotically stable.

    That is :func:`spectral_radius` ``< 1`` (strictly, with a 1e-12 margin for rounding).
    """
    return spectral_radius(model, controller, output) < _RHO_STABLE


def _rho_with(lin: LinearModel, controller: PIDController, output: int, gain: str, value: float) -> float:
    return spectral_radius(lin, controller.with_gains(**{gain: value}), output)


def stable_gain_ranges(
    model: LinearModel | NonlinearModel, controller: PIDController, output: int = 0
) -> dict[str, tuple[tuple[float, float], ...]]:
    """For each gain, the intervals of values that keep the loop stable with the other gains held.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The plant (linearized at rest if nonlinear).
    controller : PIDController
        The other gains held at their values here.
    output : int
        Index of the measured position.

    Returns
    -------
    dict
        ``{"kp": ((lo, hi), ...), "ki": ..., "kd": ...}`` in SI units (:data:`GAINS`); ``hi`` may be
        ``inf``; an empty tuple when no value of that gain stabilizes the loop. Found on a grid of
        0 and 20 values per decade over 1e-6 .. 1e16, each edge refined by 60 bisection steps; an
        interval narrower than the grid spacing (12 %) can be missed.
    """
    lin = linear_part(model)
    grid = np.concatenate([[0.0], np.geomspace(1e-6, 1e16, 22 * 20 + 1)])
    out: dict[str, tuple[tuple[float, float], ...]] = {}
    for gain in GAINS:
        ok = np.array([_rho_with(lin, controller, output, gain, g) < _RHO_STABLE for g in grid])
        intervals = []
        i = 0
        while i < grid.size:
            if not ok[i]:
                i += 1
                continue
            j = i
            while j + 1 < grid.size and ok[j + 1]:
                j += 1
            lo = grid[i] if i == 0 else _edge(lin, controller, output, gain, grid[i - 1], grid[i])
            hi = np.inf if j + 1 == grid.size else _edge(lin, controller, output, gain, grid[j + 1], grid[j])
            intervals.append((float(lo), float(hi)))
            i = j + 1
        out[gain] = tuple(intervals)
    return out


def _edge(
    lin: LinearModel, controller: PIDController, output: int, gain: str, bad: float, good: float
) -> float:
    """Bisection (geometric where both ends are > 0) from an unstable to a stable value; the stable end."""
    for _ in range(60):
        mid = np.sqrt(bad * good) if bad > 0 and good > 0 else 0.5 * (bad + good)
        if _rho_with(lin, controller, output, gain, mid) < _RHO_STABLE:
            good = mid
        else:
            bad = mid
    return good


def _fmt_ranges(gain: str, intervals: tuple[tuple[float, float], ...]) -> str:
    if not intervals:
        return "no value"
    parts = []
    for lo, hi in intervals:
        left = f"0 <= {gain}" if lo == 0 else f"{lo:.4g} < {gain}"
        parts.append(left + ("" if np.isinf(hi) else f" < {hi:.4g}"))
    return " or ".join(parts)


def check_closed_loop(
    model: LinearModel | NonlinearModel,
    controller: PIDController,
    output: int = 0,
    *,
    what: str = "the plant",
) -> float:
    """Raise :class:`~chatterspec.errors.UnstableLoopError` when ``controller`` destabilizes ``model``.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The plant (linearized at rest if nonlinear).
    controller : PIDController
    output : int
        Index of the measured position.
    what : str
        How the message names the plant (e.g. ``"the true plant on [2, 4) s"``).

    Returns
    -------
    float
        The closed loop's spectral radius (< 1).

    Raises
    ------
    UnstableLoopError
        Naming each gain with its current value and the range that would be stable with the other
        gains held (:func:`stable_gain_ranges`).
    """
    rho = spectral_radius(model, controller, output)
    if rho < _RHO_STABLE:
        return rho
    ranges = stable_gain_ranges(model, controller, output)
    parts = []
    for gain, unit in GAINS.items():
        text = _fmt_ranges(gain, ranges[gain])
        parts.append(f"{gain} = {getattr(controller, gain):.4g} ({unit}; stable for {text})")
    raise UnstableLoopError(
        f"the PID position loop is unstable on {what} (spectral radius {rho:.6g} >= 1 at "
        f"dt = {model.dt:g} s, "
        f"linear loop without saturation); change one gain, the others held: " + "; ".join(parts)
    )


def rigid_body_gain(model: LinearModel | NonlinearModel, output: int = 0) -> float:
    """``Kv``: the low-frequency velocity gain of the measured position per unit input (m/s per rad/s).

    The actuator integrates its input (position = integral of velocity): at low frequency
    ``y(z) ~ Kv dt / (z - 1) u(z)``, so ``Kv = lim_{z -> 1} (z - 1) / dt * Cp (zI - A)^-1 B``
    (evaluated at ``z = exp(j 1e-6 / dt)``). For the linear EHA ``Kv = Dp / (Ac + L a / Ac)``.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The plant (linearized at rest if nonlinear).
    output : int
        Index of the measured position among the model's outputs.

    Raises
    ------
    ParameterError
        If the plant does not integrate its input (no eigenvalue at 1).
    """
    lin = linear_part(model)
    cp = _output_row(lin, output)
    z = np.exp(1j * 1e-6)
    G = cp @ np.linalg.solve(z * np.eye(lin.n_states) - lin.A, lin.B[:, 0])
    kv = float(np.abs(G * (z - 1.0) / lin.dt))
    if not np.isfinite(kv) or kv < 1e-300 or np.min(np.abs(np.linalg.eigvals(lin.A) - 1.0)) > 1e-6:
        raise ParameterError(
            f"{lin.name}: the position {lin.output_names[output]!r} does not integrate the input (no "
            "eigenvalue of A at 1), so the rigid-body PI design does not apply; give the gains directly"
        )
    return kv


def design_pi(
    model: LinearModel | NonlinearModel,
    bandwidth_hz: float,
    saturation: float,
    *,
    damping: float = 1.0,
    output: int = 0,
    **options: Unpack[PIDOptions],
) -> PIDController:
    """PI gains by pole placement on the rigid-body approximation, checked on the full model.

    On ``y' = Kv u`` (:func:`rigid_body_gain`) the PI loop ``u = kp e + ki int e`` has the
    characteristic polynomial ``s^2 + Kv kp s + Kv ki``; matching ``s^2 + 2 zeta wc s + wc^2`` gives
    ``kp = 2 zeta wc / Kv`` and ``ki = wc^2 / Kv`` with ``wc = 2 pi bandwidth_hz``. Valid while ``wc``
    is well below the actuator's hydraulic mode (EHA: 39 Hz); :func:`loop_mode` reports what the
    full model gets, and :func:`check_closed_loop` is applied.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The plant (linearized at rest if nonlinear).
    bandwidth_hz : float
        Natural frequency of the designed closed-loop pair in Hz (> 0).
    saturation : float
        Pump speed limit in rad/s (> 0).
    damping : float
        Damping ratio of the designed pair (> 0; 1 = critically damped).
    output : int
        Index of the measured position.
    **options
        Other :class:`PIDController` arguments (``anti_windup``, ``setpoint_weight``, ...).

    Returns
    -------
    PIDController
    """
    wc = 2 * np.pi * positive("bandwidth_hz", bandwidth_hz, unit="Hz")
    zeta = positive("damping", damping)
    kv = rigid_body_gain(model, output)
    ctrl = PIDController(kp=2 * zeta * wc / kv, ki=wc * wc / kv, saturation=saturation, **options)
    check_closed_loop(
        model, ctrl, output, what=f"{linear_part(model).name} (designed at {bandwidth_hz:g} Hz)"
    )
    return ctrl


@dataclass(frozen=True)
class LoopMode:
    """The slowest closed-loop mode of a linear loop (continuous equivalent ``s = ln(z) / dt``).

    Attributes
    ----------
    natural_frequency_hz : float
        ``|s| / (2 pi)`` in Hz.
    damping_ratio : float
        ``-Re(s) / |s|`` (1 for a real pole).
    time_constant_s : float
        ``-1 / Re(s)`` in s.
    spectral_radius : float
        Largest ``|z|`` of the loop.
    """

    natural_frequency_hz: float
    damping_ratio: float
    time_constant_s: float
    spectral_radius: float

    def to_dict(self) -> dict[str, float]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return asdict(self)


def loop_mode(model: LinearModel | NonlinearModel, controller: PIDController, output: int = 0) -> LoopMode:
    """The dominant (slowest-decaying) mode of the closed loop and the loop's spectral radius.

    Eigenvalues at 0 and the derivative filter's pole (when ``kd = 0`` it is decoupled) are skipped.

    Parameters
    ----------
    model, controller, output
        As in :func:`closed_loop_matrix`.

    Returns
    -------
    LoopMode
    """
    lin = linear_part(model)
    M = closed_loop_matrix(lin, controller, output)
    z = np.linalg.eigvals(M)
    c = pid_coefficients(controller, lin.dt)
    keep = np.abs(z) > 1e-9
    if controller.kd == 0:
        keep &= np.abs(z - c.a_d) > 1e-9
    z = z[keep]
    s = np.log(z.astype(complex)) / lin.dt
    i = int(np.argmax(s.real))
    si = s[i]
    wn = float(abs(si))
    return LoopMode(
        natural_frequency_hz=wn / (2 * np.pi),
        damping_ratio=float(-si.real / wn) if wn > 0 else 1.0,
        time_constant_s=float(-1.0 / si.real) if si.real < 0 else float("inf"),
        spectral_radius=float(np.abs(np.linalg.eigvals(M)).max()),
    )


# Position references.


def _times(t: npt.ArrayLike) -> np.ndarray:
    return finite_array("t", t, ndim=1)


def _mm(x: float) -> str:
    return f"{x * 1e3:g} mm"


@dataclass(frozen=True)
class Hold:
    """r(t) = position for all t: the actuator held still.

    Attributes
    ----------
    position : float
        Held position in m.
    """

    position: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", finite_scalar("position", self.position))

    @property
    def peak(self) -> float:
        """Largest ``|r|`` in m."""
        return abs(self.position)

    @property
    def moves(self) -> int:
        """Number of moves (0)."""
        return 0

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        return np.full(_times(t).shape, self.position)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"hold at {_mm(self.position)}"


def _levels(
    times: npt.ArrayLike, levels: npt.ArrayLike, name: str
) -> tuple[tuple[float, ...], tuple[float, ...]]:
    tt = finite_array(f"{name} times", times, ndim=1)
    ll = finite_array(f"{name} levels", levels, ndim=1)
    if tt.size == 0 or tt.shape != ll.shape:
        raise ParameterError(
            f"{name} needs as many levels as times (at least one); got {tt.size} times, {ll.size} levels"
        )
    if tt[0] < 0 or np.any(np.diff(tt) <= 0):
        raise ParameterError(f"{name} times must be >= 0 s and increasing; got {tt.tolist()}")
    return tuple(float(x) for x in tt), tuple(float(x) for x in ll)


class _Moves:
    """What :class:`StepSequence` and :class:`SCurve` share: moves at ``times`` (s) to ``levels`` (m)
    from ``initial`` (m), checked and normalized in place when the frozen dataclass is built."""

    times: tuple[float, ...]
    levels: tuple[float, ...]
    initial: float

    def __post_init__(self) -> None:
        tt, ll = _levels(self.times, self.levels, type(self).__name__)
        object.__setattr__(self, "times", tt)
        object.__setattr__(self, "levels", ll)
        object.__setattr__(self, "initial", finite_scalar("initial", self.initial))

    @property
    def peak(self) -> float:
        """Largest ``|r|`` in m (a step or a minimum-jerk move does not overshoot its end points)."""
        return max(abs(self.initial), *(abs(x) for x in self.levels))

    @property
    def moves(self) -> int:
        """Number of steps or moves."""
        return len(self.times)


@dataclass(frozen=True)
class StepSequence(_Moves):
    """r(t) = levels[j] from times[j] on (``initial`` before the first time).

    Attributes
    ----------
    times : tuple of float
        Step times in s, increasing, >= 0.
    levels : tuple of float
        Position after each step, in m.
    initial : float
        Position before the first step, in m.
    """

    times: tuple[float, ...]
    levels: tuple[float, ...]
    initial: float = 0.0

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        # a tiny tolerance so that t = k dt hits the step on the intended sample (as signals.Step)
        j = np.searchsorted(np.asarray(self.times), t + 1e-12, side="right") - 1
        values = np.asarray((self.initial, *self.levels))
        return values[j + 1]

    def describe(self) -> str:
        """A short description for reports and recordings."""
        steps = ", ".join(f"{_mm(x)} at {s:g} s" for s, x in zip(self.times, self.levels, strict=True))
        return f"steps from {_mm(self.initial)}: {steps}"


@dataclass(frozen=True)
class SCurve(_Moves):
    """Minimum-jerk moves: from ``times[j]`` the position goes to ``levels[j]`` in ``move_time`` s.

    ``r = r0 + (r1 - r0) s(tau)``, ``s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5``, ``tau = (t - t_j) /
    move_time`` in [0, 1]: position, velocity and acceleration are continuous, the peak velocity is
    ``1.875 |r1 - r0| / move_time`` (m/s) and the peak acceleration ``5.77 |r1 - r0| / move_time^2``.

    Attributes
    ----------
    times : tuple of float
        Start of each move in s, increasing, >= 0; a move must end before the next starts.
    levels : tuple of float
        Target position of each move, in m.
    move_time : float
        Duration of every move in s (> 0).
    initial : float
        Position before the first move, in m.
    """

    times: tuple[float, ...]
    levels: tuple[float, ...]
    move_time: float
    initial: float = 0.0

    def __post_init__(self) -> None:
        super().__post_init__()
        mt = positive("move_time", self.move_time, unit="s")
        object.__setattr__(self, "move_time", mt)
        gaps = np.diff(self.times)
        if gaps.size and gaps.min() < mt - 1e-12:
            raise ParameterError(
                f"SCurve moves overlap: move_time {mt:g} s is longer than the shortest gap between "
                f"move starts ({gaps.min():g} s)"
            )

    @property
    def peak_velocity(self) -> float:
        """Largest reference speed in m/s (``1.875 max |step| / move_time``)."""
        steps = np.diff(np.asarray((self.initial, *self.levels)))
        return float(1.875 * np.abs(steps).max() / self.move_time)

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        starts = np.asarray(self.times)
        values = np.asarray((self.initial, *self.levels))
        j = np.searchsorted(starts, t + 1e-12, side="right") - 1  # the move that started last (-1: none)
        r0, r1 = values[np.maximum(j, 0)], values[j + 1]
        tau = np.clip((t - starts[np.maximum(j, 0)]) / self.move_time, 0.0, 1.0)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        return np.where(j < 0, self.initial, r0 + (r1 - r0) * s)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        moves = ", ".join(f"to {_mm(x)} at {s:g} s" for s, x in zip(self.times, self.levels, strict=True))
        return f"S-curve moves ({self.move_time:g} s each) from {_mm(self.initial)}: {moves}"


# Dither signals.


def _amplitude(value: float) -> float:
    a = finite_scalar("amplitude", value)
    if a < 0:
        raise ParameterError(f"amplitude must be >= 0 (input or reference units); got {a!r}")
    return a


@dataclass(frozen=True)
class Multisine:
    """Sum of sines of equal amplitude with Schroeder phases (a low crest factor).

    ``d(t) = amplitude * sum_k cos(2 pi f_k t + phi_k)``, ``phi_k = -pi k (k - 1) / K`` for the
    ``K`` tones ``k = 1..K`` (Schroeder 1970), so the tones do not line up at ``t = 0``.

    Attributes
    ----------
    amplitude : float
        Amplitude of **each** tone (input units, rad/s for the EHA pump; m for a reference dither), >= 0.
    frequencies_hz : tuple of float
        Tone frequencies in Hz (> 0, distinct).

    Notes
    -----
    ``peak`` is the bound ``K * amplitude`` (reached only if the tones align); the actual maximum
    of a Schroeder multisine is lower (2.63 amplitudes for the default 20, 30, 40 Hz tones).
    """

    amplitude: float
    frequencies_hz: tuple[float, ...] = (20.0, 30.0, 40.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude", _amplitude(self.amplitude))
        f = finite_array("frequencies_hz", self.frequencies_hz, ndim=1)
        if f.size == 0 or np.any(f <= 0) or np.unique(f).size != f.size:
            raise ParameterError(f"frequencies_hz must be distinct and > 0 Hz; got {f.tolist()}")
        object.__setattr__(self, "frequencies_hz", tuple(float(x) for x in f))

    @property
    def phases(self) -> np.ndarray:
        """Schroeder phases ``-pi k (k - 1) / K`` in rad, k = 1..K."""
        K = len(self.frequencies_hz)
        k = np.arange(1, K + 1)
        return -np.pi * k * (k - 1) / K

    @property
    def peak(self) -> float:
        """Upper bound of ``|d(t)|``: ``K * amplitude``."""
        return self.amplitude * len(self.frequencies_hz)

    @property
    def rms(self) -> float:
        """Root mean square ``amplitude * sqrt(K / 2)``."""
        return float(self.amplitude * np.sqrt(len(self.frequencies_hz) / 2.0))

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        f = np.asarray(self.frequencies_hz)
        return self.amplitude * np.cos(2 * np.pi * f[:, None] * t[None, :] + self.phases[:, None]).sum(axis=0)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        tones = ", ".join(f"{x:g}" for x in self.frequencies_hz)
        return f"multisine {tones} Hz, {self.amplitude:g} per tone"


#: Feedback taps (1-based bit positions) of a maximal-length Fibonacci LFSR, by register length.
PRBS_TAPS: dict[int, tuple[int, ...]] = {
    2: (2, 1),
    3: (3, 2),
    4: (4, 3),
    5: (5, 3),
    6: (6, 5),
    7: (7, 6),
    8: (8, 6, 5, 4),
    9: (9, 5),
    10: (10, 7),
    11: (11, 9),
    12: (12, 6, 4, 1),
    13: (13, 4, 3, 1),
    14: (14, 5, 3, 1),
    15: (15, 14),
    16: (16, 15, 13, 4),
}


@dataclass(frozen=True)
class PRBS:
    """Pseudo-random binary sequence ``+-amplitude``, one bit per ``clock_s``, from a maximal-length LFSR.

    The sequence repeats every ``2^order - 1`` clocks; its power spectrum is flat within 3 dB up to
    about ``0.44 / clock_s`` Hz. Bit ``j`` holds on ``[j clock_s, (j + 1) clock_s)``.

    Attributes
    ----------
    amplitude : float
        Level of the sequence (input units), >= 0.
    clock_s : float
        Bit duration in s (> 0), normally a multiple of the sampling time.
    order : int
        LFSR length, a key of :data:`PRBS_TAPS` (2..16).
    seed : int
        Initial register state in ``1 .. 2^order - 1`` (part of the signal's definition).
    """

    amplitude: float
    clock_s: float = 0.005
    order: int = 10
    seed: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude", _amplitude(self.amplitude))
        object.__setattr__(self, "clock_s", positive("clock_s", self.clock_s, unit="s"))
        if isinstance(self.order, bool) or self.order not in PRBS_TAPS:
            raise ParameterError(f"order must be an integer in 2..16; got {self.order!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 < self.seed < 2**self.order:
            raise ParameterError(f"seed must be an integer in 1..{2**self.order - 1}; got {self.seed!r}")

    @property
    def peak(self) -> float:
        """``|d(t)|`` is always ``amplitude``."""
        return self.amplitude

    @property
    def period(self) -> int:
        """Clocks per repetition, ``2^order - 1``."""
        return 2**self.order - 1

    def bits(self) -> np.ndarray:
        """One period of the sequence as 0/1 (``int8``), the register's output bit per clock."""
        taps = PRBS_TAPS[self.order]
        state = self.seed
        out = np.empty(self.period, dtype=np.int8)
        for j in range(self.period):
            out[j] = state & 1
            fb = 0
            for tap in taps:
                fb ^= (state >> (self.order - tap)) & 1
            state = (state >> 1) | (fb << (self.order - 1))
        return out

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        j = np.floor(t / self.clock_s + 1e-9).astype(np.int64) % self.period
        return self.amplitude * (2.0 * self.bits()[j] - 1.0)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"PRBS +-{self.amplitude:g}, {self.clock_s * 1e3:g} ms clock, order {self.order}"


# The closed loop as a scenario's input.

DitherAt = Literal["input", "reference"]


def signal_peak(signal: object) -> float | None:
    """The largest ``|value|`` a signal can take, if it is known (``peak`` attribute or a simple signal)."""
    peak = getattr(signal, "peak", None)
    if peak is not None:
        return float(peak)
    if isinstance(signal, Sine | SquareWave):
        return abs(signal.amplitude) + abs(signal.offset)
    if isinstance(signal, Chirp):
        return abs(signal.amplitude)
    if isinstance(signal, Constant):
        return abs(signal.value)
    return None


@dataclass(frozen=True)
class ClosedLoop:
    """A position controller closing the loop around a scenario's plant.

    Parameters
    ----------
    controller : PIDController
        Gains, saturation (rad/s) and anti-windup.
    reference : Signal
        Position reference ``r(t)`` in m (:mod:`chatterspec.plants.closed_loop`: ``Hold``,
        ``StepSequence``, ``SCurve``; any signal works).
    dither : Signal, optional
        A small known excitation (:mod:`chatterspec.plants.closed_loop`: ``Multisine``, ``PRBS``): added to
        the pump-speed command before the saturation (``dither_at="input"``, rad/s) or to the
        reference (``dither_at="reference"``, m).
    dither_at : {"input", "reference"}
        Where the dither enters.
    output : int
        Index of the measured position among the plant's outputs (EHA: 0).

    Raises
    ------
    ParameterError
        If ``dither_at`` is unknown, the dither's peak is unknown, or the dither alone would reach
        the saturation: an input dither's peak must stay below ``saturation``, a reference dither's
        below ``saturation / kp``; the message gives the allowed range.
    """

    controller: PIDController
    reference: Signal
    dither: Signal | None = None
    dither_at: DitherAt = "input"
    output: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.controller, PIDController):
            raise ParameterError(f"controller must be a PIDController; got {type(self.controller).__name__}")
        if self.dither_at not in ("input", "reference"):
            raise ParameterError(f"dither_at must be 'input' or 'reference'; got {self.dither_at!r}")
        if isinstance(self.output, bool) or not isinstance(self.output, int | np.integer) or self.output < 0:
            raise ParameterError(f"output must be a non-negative output index; got {self.output!r}")
        if self.dither is not None:
            self._check_dither()

    def _check_dither(self) -> None:
        peak = signal_peak(self.dither)
        if peak is None:
            raise ParameterError(
                f"the dither {type(self.dither).__name__} does not report its peak; use Multisine, PRBS, "
                "Sine or a signal with a 'peak' attribute (the peak is checked against the saturation)"
            )
        sat = self.controller.saturation
        if self.dither_at == "input" and not peak < sat:
            raise ParameterError(
                f"input dither peak {peak:g} rad/s is not below the saturation {sat:g} rad/s: the command "
                f"would sit on the limit; the dither amplitude (peak) must lie in [0, {sat:g}) rad/s"
            )
        if self.dither_at == "reference" and not peak * self.controller.kp < sat:
            limit = sat / self.controller.kp if self.controller.kp > 0 else np.inf
            raise ParameterError(
                f"reference dither peak {peak * 1e3:g} mm times kp = {self.controller.kp:g} rad/s per m "
                "gives "
                f"{peak * self.controller.kp:g} rad/s, not below the saturation {sat:g} rad/s; the reference "
                f"dither amplitude (peak) must lie in [0, {limit * 1e3:.4g}) mm"
            )

    def with_dither(self, dither: Signal | None, at: DitherAt = "input") -> ClosedLoop:
        """A copy with another dither (validated again); ``None`` removes it."""
        return replace(self, dither=dither, dither_at=at)

    def signals(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(r, d)`` at the times ``t`` (s): reference (m, reference dither added), input dither (rad/s)."""
        t = np.asarray(t, dtype=float)
        r = np.asarray(self.reference.sample(t), dtype=float).reshape(t.shape)
        d = np.zeros(t.shape)
        if self.dither is not None:
            values = np.asarray(self.dither.sample(t), dtype=float).reshape(t.shape)
            if self.dither_at == "reference":
                r = r + values
            else:
                d = values
        return np.ascontiguousarray(r), np.ascontiguousarray(d)

    def check(self, model: LinearModel | NonlinearModel, what: str = "the plant") -> float:
        """Check that the loop is stable on ``model`` (linearized at rest if nonlinear); its spectral radius.

        Raises
        ------
        UnstableLoopError
            With each gain's stable range (:func:`~chatterspec.plants.closed_loop.check_closed_loop`).
        ParameterError
            If ``output`` is not an output of the model or the model has more than one input.
        """
        return check_closed_loop(model, self.controller, self.output, what=what)

    def sample(self, t: np.ndarray) -> np.ndarray:
        """Not available: the input of a closed loop depends on each realization's measurements."""
        raise ParameterError(
            "this scenario runs in closed loop: its input (the pump speed) is computed by the controller "
            "from each realization's measurements during the simulation; use simulate(...).u "
            "(shape (runs, T, 1)) instead of sampling the scenario's input"
        )

    def describe(self) -> str:
        """A short description for reports and recordings."""
        text = f"closed loop: {self.controller.describe()}; reference {self.reference.describe()}"
        if self.dither is not None:
            where = "pump-speed command" if self.dither_at == "input" else "reference"
            text += f"; dither on the {where}: {self.dither.describe()}"
        return text

    def to_dict(self) -> dict[str, object]:
        """JSON-ready description (controller arguments in SI units)."""
        return {
            "controller": self.controller.to_dict(),
            "reference": self.reference.describe(),
            "dither": None if self.dither is None else self.dither.describe(),
            "dither_at": self.dither_at,
            "output": int(self.output),
        }
