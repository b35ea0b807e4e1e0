"""Position references for a closed loop: holds, step sequences and smooth point-to-point moves.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .._validate import finite_array, finite_scalar, positive
from ..errors import ParameterError

__all__ = ["Hold", "SCurve", "StepSequence"]


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
