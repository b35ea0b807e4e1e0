"""Overshoot and settling time of a closed-loop scenario's moves (noise-free response).

For each move of a :class:`~chatterspec.plants.references.StepSequence` or
:class:`~chatterspec.plants.references.SCurve` reference, from the level ``r0`` to ``r1``:

* **overshoot**: the largest excursion of the position beyond ``r1`` after the reference has
  arrived (the move's end), in % of the step ``|r1 - r0|``;
* **settling time**: from the reference's arrival to the last time the position is outside
  ``r1 +- band |r1 - r0|`` before the next move starts (0 if it never leaves the band; ``inf`` if
  it has not settled when the next move starts).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..errors import ParameterError
from .references import SCurve, StepSequence
from .simulate_closed_loop import loop_response

if TYPE_CHECKING:  # pragma: no cover
    from .scenario_types import Scenario

__all__ = ["MoveMetrics", "move_metrics"]


@dataclass(frozen=True)
class MoveMetrics:
    """The response to one move of the reference.

    Attributes
    ----------
    start_s, end_s : float
        When the reference starts and stops moving (s; equal for a step).
    step_m : float
        ``r1 - r0`` in m.
    overshoot_pct : float
        Overshoot in % of ``|step_m|`` (0 when the position stays short of ``r1``).
    settling_s : float
        Settling time into the band after ``end_s`` (s).
    peak_u : float
        Largest ``|u|`` (rad/s) between this move's start and the next one's.
    saturated : bool
        Whether ``u`` reached the saturation during the move.
    """

    start_s: float
    end_s: float
    step_m: float
    overshoot_pct: float
    settling_s: float
    peak_u: float
    saturated: bool

    def to_dict(self) -> dict[str, float | bool]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {
            "start_s": self.start_s,
            "end_s": self.end_s,
            "step_mm": self.step_m * 1e3,
            "overshoot_pct": self.overshoot_pct,
            "settling_s": self.settling_s,
            "peak_u": self.peak_u,
            "saturated": self.saturated,
        }


def move_metrics(scenario: Scenario, band: float = 0.02) -> list[MoveMetrics]:
    """Overshoot and settling time of every move of a closed-loop scenario's reference (no noise).

    Parameters
    ----------
    scenario : Scenario
        A closed-loop scenario whose reference is a ``StepSequence`` or an ``SCurve`` (no dither
        on the reference).
    band : float
        Settling band as a fraction of the step (default 2 %).

    Returns
    -------
    list of MoveMetrics
        One per move that ends inside the record.
    """
    loop = getattr(scenario, "closed_loop", None)
    if loop is None:
        raise ParameterError(f"{getattr(scenario, 'name', '?')!r} is not a closed-loop scenario")
    ref = loop.reference
    if not isinstance(ref, StepSequence | SCurve):
        raise ParameterError(
            f"move metrics need a StepSequence or SCurve reference; got {type(ref).__name__}"
        )
    move_time = ref.move_time if isinstance(ref, SCurve) else 0.0
    t, _, x, u = loop_response(scenario)
    y = x[:, loop.output]
    levels = (ref.initial, *ref.levels)
    out = []
    for j, start in enumerate(ref.times):
        r0, r1 = levels[j], levels[j + 1]
        step = r1 - r0
        end = start + move_time
        nxt = ref.times[j + 1] if j + 1 < len(ref.times) else t[-1] + scenario.dt
        after = (t >= end - 1e-9) & (t < nxt - 1e-9)
        during = (t >= start - 1e-9) & (t < nxt - 1e-9)
        if step == 0 or not after.any():  # no move, or it ends after the record
            continue
        over = float(np.max((y[after] - r1) * np.sign(step)) / abs(step) * 100.0)
        outside = np.abs(y[after] - r1) > band * abs(step)
        if not outside.any():
            settle = 0.0
        elif outside[-1]:
            settle = float("inf")
        else:
            settle = float(t[after][np.flatnonzero(outside)[-1] + 1] - end)
        peak = float(np.abs(u[during]).max())
        out.append(
            MoveMetrics(
                start_s=float(start),
                end_s=float(end),
                step_m=float(step),
                overshoot_pct=max(over, 0.0),
                settling_s=settle,
                peak_u=peak,
                saturated=bool(peak >= loop.controller.saturation),
            )
        )
    return out
