"""A scenario's input when a controller closes the loop: controller, position reference and dither.

Open-loop scenarios drive the plant with a chosen signal (a chirp, a sine). A real actuator runs
under its position controller: the pump speed is whatever the controller commands from the
measured position. :class:`ClosedLoop` is what a :class:`~chatterspec.plants.scenarios.Scenario`
takes as its ``input`` in that case; the simulation
(:mod:`chatterspec.plants.simulate_closed_loop`) computes ``u(k)`` per realization from ``z(k)``
and returns it as ``Simulation.u`` of shape ``(runs, T, 1)``. The filters then run the open-loop
nominal model with that measured (saturated) ``u``, as a monitor on the real actuator would.

With an exactly known linear model the healthy chattering (eq 23 of the core paper) is
``v(k) + w(k+1) - C A C^-1 w(k)``: it does not involve ``u`` at all, so the analytic thresholds hold
in closed loop as they do open loop (``chatterspec detect eha-cl-healthy --runs 1000`` measures it).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from ..errors import ParameterError
from .controllers import PIDController
from .loop_design import check_closed_loop
from .models import LinearModel
from .nonlinear import NonlinearModel
from .signals import Chirp, Constant, Signal, Sine, SquareWave

__all__ = ["ClosedLoop", "DitherAt", "signal_peak"]

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
        Position reference ``r(t)`` in m (:mod:`chatterspec.plants.references`: ``Hold``,
        ``StepSequence``, ``SCurve``; any signal works).
    dither : Signal, optional
        A small known excitation (:mod:`chatterspec.plants.dither`: ``Multisine``, ``PRBS``): added to
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
            With each gain's stable range (:func:`~chatterspec.plants.loop_design.check_closed_loop`).
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
