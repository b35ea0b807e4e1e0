"""Gain design and stability of a PID position loop around a plant model.

The closed loop of :mod:`chatterspec.plants.controllers` around a linear model (or a nonlinear
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
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Unpack

import numpy as np

from .._validate import positive
from ..errors import ParameterError, UnstableLoopError
from .controllers import PIDController, PIDOptions, pid_coefficients
from .models import LinearModel
from .nonlinear import NonlinearModel

__all__ = [
    "GAINS",
    "LoopMode",
    "check_closed_loop",
    "closed_loop_matrix",
    "design_pi",
    "is_stable",
    "linear_part",
    "loop_mode",
    "rigid_body_gain",
    "spectral_radius",
    "stable_gain_ranges",
]

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
