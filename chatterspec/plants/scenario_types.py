"""The scenario types: :class:`Scenario` (a nominal model, a time-segmented true plant, an input and
a duration) and :class:`Segment` (one fault window).

Re-exported by :mod:`chatterspec.plants.scenarios` (their documented home, with the catalogue); the
catalogue's builders (:mod:`~chatterspec.plants.scenarios_estimators`,
:mod:`~chatterspec.plants.scenarios_closed_loop`) build them without importing the catalogue.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._repr import short_repr
from .._validate import finite_array, positive, readonly
from ..errors import ParameterError
from .closed_loop import ClosedLoop
from .filter_settings import FilterSettings
from .models import LinearModel
from .nonlinear import NonlinearModel, same_dynamics
from .signals import Signal

__all__ = ["Scenario", "Segment"]


@dataclass(frozen=True, eq=False)
class Segment:
    """The true plant on the half-open time window ``[start, stop)`` (seconds).

    Attributes
    ----------
    start : float
        Window start in seconds (finite, >= 0); samples with ``t >= start`` belong to it.
    stop : float
        Window end in seconds (finite, > ``start``); samples with ``t < stop`` belong to it.
    model : LinearModel or NonlinearModel
        The true plant simulated inside the window (e.g. a faulty EHA or a
        mismatched second-order system); the filters keep using the nominal model.
    label : str
        Human-readable description of the window (e.g. ``"w0 = 8 Hz"``), used in
        listings and plot annotations; empty by default.
    """

    start: float
    stop: float
    model: LinearModel | NonlinearModel
    label: str = ""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.start) and np.isfinite(self.stop)) or not self.stop > self.start:
            raise ParameterError(f"segment needs start < stop; got [{self.start}, {self.stop})")
        if self.start < 0:
            raise ParameterError(f"segment start must be >= 0 s; got {self.start}")


@dataclass(frozen=True, eq=False)
class Scenario:
    """A simulation scenario.

    Parameters
    ----------
    name : str
        Catalogue name (e.g. ``"eha-leak-major"``).
    nominal : LinearModel or NonlinearModel
        The model the filters use (A-hat, B-hat, C-hat of eq 3; for a nonlinear plant the
        filter's f and Jacobian).
    input : Signal or ClosedLoop
        Input u(t), or a :class:`~chatterspec.plants.closed_loop.ClosedLoop` (controller, position
        reference, dither) that computes u per realization from the measurements; its gains must
        keep the loop stable on the nominal model and on every true-plant segment (linearized at
        rest if nonlinear), else :class:`~chatterspec.errors.UnstableLoopError`.
    duration : float
        Record length in seconds; the simulation has ``round(duration/dt) + 1``
        samples at ``t = 0, dt, ..., duration``.
    plant : LinearModel or NonlinearModel, optional
        The true plant outside the fault windows (default: the nominal model). The
        simulation draws its noise from the true plant's ``Q`` and ``R`` (per segment).
    windows : tuple of Segment
        Time windows in which the true plant differs (non-overlapping).
    description, family, fault, level : str
        Metadata for listings; ``fault_channel`` names the output on which the
        fault shows (``docs/design.md`` §5, from eq 68-70).
    x0 : array, optional
        Initial true state (default zeros).
    psi : tuple of float, optional
        Smoothing boundary layer for the SVSF on this scenario (per sat channel);
        ``None`` lets :mod:`chatterspec.filters.svsf` derive it from statistics.
    filter_settings : FilterSettings, optional
        The estimator tuning the source paper prints for this scenario (filter Q, R, P0,
        gamma, psi, Lambda, modes, ...); ``None`` for the chattering-paper scenarios.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    name: str
    nominal: LinearModel | NonlinearModel
    input: Signal | ClosedLoop
    duration: float
    plant: LinearModel | NonlinearModel | None = None
    windows: tuple[Segment, ...] = ()
    description: str = ""
    family: str = ""
    fault: str = "healthy"
    level: str = ""
    fault_channel: str | None = None
    x0: np.ndarray = None  # type: ignore[assignment]  # None: zeros (set by __post_init__)
    psi: tuple[float, ...] | None = None
    filter_settings: FilterSettings | None = None
    _segments: tuple[Segment, ...] = field(default=(), init=False, repr=False)

    def __post_init__(self) -> None:
        duration = positive("duration", self.duration, unit="s")
        object.__setattr__(self, "duration", duration)
        plant = self.plant if self.plant is not None else self.nominal
        object.__setattr__(self, "plant", plant)
        models = [plant, *(w.model for w in self.windows)]
        for m in models:
            if (m.n_states, m.n_outputs, m.n_inputs) != (
                self.nominal.n_states,
                self.nominal.n_outputs,
                self.nominal.n_inputs,
            ) or m.dt != self.nominal.dt:
                raise ParameterError(
                    f"scenario {self.name!r}: every true-plant model must have the nominal "
                    "model's dimensions and dt"
                )
        windows = tuple(sorted(self.windows, key=lambda w: w.start))
        for a, b in itertools.pairwise(windows):
            if b.start < a.stop:
                raise ParameterError(f"scenario {self.name!r}: fault windows overlap")
        object.__setattr__(self, "windows", windows)
        x0 = np.zeros(self.nominal.n_states) if self.x0 is None else self.x0
        x0 = finite_array("x0", x0, shape=(self.nominal.n_states,))
        object.__setattr__(self, "x0", readonly(x0))
        # full partition of [0, duration)
        segs: list[Segment] = []
        t = 0.0
        for w in windows:
            if w.start >= duration:
                break
            if w.start > t:
                segs.append(Segment(t, w.start, plant, "nominal plant"))
            segs.append(Segment(w.start, min(w.stop, duration), w.model, w.label))
            t = min(w.stop, duration)
        if t < duration:
            segs.append(Segment(t, duration, plant, "nominal plant" if plant is self.nominal else self.fault))
        object.__setattr__(self, "_segments", tuple(segs))
        if self.filter_settings is not None:
            self.filter_settings.check_dimensions(self.nominal.n_states, self.nominal.n_outputs)
        if isinstance(self.input, ClosedLoop):
            self.input.check(self.nominal, what=f"the nominal model of scenario {self.name!r}")
            for sg in segs:
                if sg.model is not self.nominal:
                    self.input.check(
                        sg.model,
                        what=f"the true plant of scenario {self.name!r} on "
                        f"[{sg.start:g}, {sg.stop:g}) s ({sg.label or sg.model.name})",
                    )

    @property
    def closed_loop(self) -> ClosedLoop | None:
        """The controller closing the loop (the ``input`` of a closed-loop scenario), else None."""
        return self.input if isinstance(self.input, ClosedLoop) else None

    @property
    def dt(self) -> float:
        """Sampling time (s) of the nominal model."""
        return self.nominal.dt

    @property
    def n_samples(self) -> int:
        """Number of samples ``T = round(duration / dt) + 1``."""
        return round(self.duration / self.dt) + 1

    @property
    def time(self) -> np.ndarray:
        """Sample times ``k dt`` (s), ``k = 0 .. n_samples - 1``."""
        return np.arange(self.n_samples) * self.dt

    @property
    def segments(self) -> tuple[Segment, ...]:
        """The true plant as a partition of ``[0, duration)`` into segments."""
        return self._segments

    def segment_index(self, t: np.ndarray | None = None) -> np.ndarray:
        """Index into :attr:`segments` of the true model that advances x(k) -> x(k+1) at each time."""
        t = self.time if t is None else np.asarray(t, dtype=float)
        starts = np.array([s.start for s in self.segments])
        return np.clip(np.searchsorted(starts, t + 1e-9 * self.dt, side="right") - 1, 0, None)

    @property
    def fault_intervals(self) -> tuple[tuple[float, float], ...]:
        """Time windows (s) in which the true plant differs from the nominal model."""
        return tuple((s.start, s.stop) for s in self.segments if self.deviates(s))

    def deviates(self, segment: Segment) -> bool:
        """True where ``segment``'s true plant differs from the nominal model (A, B or C).

        Parameters
        ----------
        segment : Segment
            One of :attr:`segments`.
        """
        return not _same_model(segment.model, self.nominal)

    @property
    def is_healthy(self) -> bool:
        """True when the scenario has no fault window."""
        return not self.fault_intervals

    @property
    def is_linear(self) -> bool:
        """True when the nominal model and every true-plant model are ``LinearModel`` s."""
        return all(isinstance(s.model, LinearModel) for s in self.segments) and isinstance(
            self.nominal, LinearModel
        )

    @property
    def plant_kind(self) -> str:
        """``"linear"`` or ``"nonlinear"`` (nonlinear if any model of the scenario is)."""
        return "linear" if self.is_linear else "nonlinear"

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary (used by ``chatterspec scenarios --json``)."""
        return {
            "name": self.name,
            "description": self.description,
            "plant": self.family,
            "plant_kind": self.plant_kind,
            "fault": self.fault,
            "level": self.level,
            "fault_channel": self.fault_channel,
            "duration_s": self.duration,
            "dt_s": self.dt,
            "input": self.input.describe(),
            "closed_loop": None if self.closed_loop is None else self.closed_loop.to_dict(),
            "nominal": _mode_dict(self.nominal),
            "segments": [
                {
                    "start_s": s.start,
                    "stop_s": s.stop,
                    "label": s.label,
                    "matches_nominal": not self.deviates(s),
                    **_mode_dict(s.model),
                }
                for s in self.segments
            ],
            "filter_settings": None if self.filter_settings is None else self.filter_settings.describe(),
        }


def _mode_dict(model: LinearModel | NonlinearModel) -> dict[str, object]:
    # a nonlinear model reports its linearization at rest (NonlinearModel.mode), flagged as such
    return {
        "natural_frequency_hz": model.natural_frequency_hz,
        "damping_ratio": model.damping_ratio,
        "linearized": isinstance(model, NonlinearModel),
    }


def _same_model(a: LinearModel | NonlinearModel, b: LinearModel | NonlinearModel) -> bool:
    return same_dynamics(a, b)
