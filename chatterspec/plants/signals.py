"""Input signals u(t) for the scenarios.

Each signal is a frozen dataclass with a ``sample(t)`` method that maps a
time vector in seconds of shape ``(T,)`` to input values of shape ``(T,)``
(single-input plants; stack several signals for more inputs).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from .._validate import finite_array, nonnegative, positive

__all__ = [
    "Chirp",
    "Constant",
    "HeldUniform",
    "Repeat",
    "Signal",
    "Sine",
    "SquareWave",
    "Step",
    "Sum",
    "ZeroInput",
]


@runtime_checkable
class Signal(Protocol):
    """Anything with ``sample(t) -> ndarray`` and a ``describe()`` string."""

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at times ``t`` (s), one row per time."""
        ...

    def describe(self) -> str:
        """A short description for reports and recordings."""
        ...


def _times(t: npt.ArrayLike) -> np.ndarray:
    return finite_array("t", t, ndim=1)


@dataclass(frozen=True)
class Constant:
    """u(t) = value for all t (the paper's "constant unit input", Fig 8a).

    Attributes
    ----------
    value : float
        The input level (input units; default 1).
    """

    value: float = 1.0

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        return np.full(_times(t).shape, float(self.value))

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"constant {self.value:g}"


@dataclass(frozen=True)
class Step:
    """u(t) = initial for t < time, amplitude for t >= time (seconds).

    ``Step(0.0)`` is the paper's unit step applied at the start of the record.

    Attributes
    ----------
    time : float
        Switching time in seconds (>= 0).
    amplitude : float
        Level from ``time`` on (input units; default 1).
    initial : float
        Level before ``time`` (default 0).
    """

    time: float = 0.0
    amplitude: float = 1.0
    initial: float = 0.0

    def __post_init__(self) -> None:
        nonnegative("time", self.time)

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        # a tiny tolerance so that t = k*dt hits the step on the intended sample
        return np.where(t >= self.time - 1e-12, float(self.amplitude), float(self.initial))

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"step {self.initial:g} -> {self.amplitude:g} at t = {self.time:g} s"


@dataclass(frozen=True)
class Chirp:
    """Linear chirp ``amplitude * cos(2 pi (f0 t + k t^2 / 2) + phase)`` sweeping ``f0 -> f1``.

    ``k = (f_stop_hz - f_start_hz) / sweep_time``. With the default
    ``phase_deg = 0`` the chirp is a cosine, so ``u(0) = amplitude``: the input
    jumps from rest to its full value at ``t = 0`` and adds a start-up transient;
    ``phase_deg = -90`` gives a sine chirp that starts at ``u(0) = 0``. The EHA
    scenarios use 10 -> 100 Hz over the 4 s record at 300 rad/s (amplitude and
    phase unspecified in the paper; ``docs/design.md`` C9; the phase choice is
    documented where the scenarios are defined, ``plants/scenarios.py``).

    Attributes
    ----------
    f_start_hz, f_stop_hz : float
        Start and stop frequency in Hz (> 0).
    sweep_time : float
        Time in s at which ``f_stop_hz`` is reached (> 0).
    amplitude : float
        Peak value (input units, e.g. rad/s of pump speed for the EHA).
    phase_deg : float
        Phase offset in degrees: 0 = cosine chirp (default), -90 = sine chirp.
    """

    f_start_hz: float = 10.0
    f_stop_hz: float = 100.0
    sweep_time: float = 4.0
    amplitude: float = 300.0
    phase_deg: float = 0.0

    def __post_init__(self) -> None:
        positive("f_start_hz", self.f_start_hz, unit="Hz")
        positive("f_stop_hz", self.f_stop_hz, unit="Hz")
        positive("sweep_time", self.sweep_time, unit="s")
        finite_array("phase_deg", np.asarray(self.phase_deg, dtype=float), ndim=0)

    @classmethod
    def sine(
        cls,
        f_start_hz: float = 10.0,
        f_stop_hz: float = 100.0,
        sweep_time: float = 4.0,
        amplitude: float = 300.0,
    ) -> Chirp:
        """The sine chirp (``phase_deg = -90``, ``u(0) = 0``), no step at ``t = 0``.

        Parameters
        ----------
        f_start_hz, f_stop_hz, sweep_time, amplitude : float
            As the attributes of the same name (Hz, Hz, s, input units).
        """
        return cls(f_start_hz, f_stop_hz, sweep_time, amplitude, phase_deg=-90.0)

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        import scipy.signal  # on demand: listing the catalogue must not wait for scipy.signal

        t = _times(t)
        return self.amplitude * scipy.signal.chirp(
            t, f0=self.f_start_hz, t1=self.sweep_time, f1=self.f_stop_hz, method="linear", phi=self.phase_deg
        )

    def describe(self) -> str:
        """A short description for reports and recordings."""
        text = (
            f"linear chirp {self.f_start_hz:g}->{self.f_stop_hz:g} Hz over {self.sweep_time:g} s, "
            f"amplitude {self.amplitude:g}"
        )
        if self.phase_deg == -90.0:
            return text + ", sine (u(0) = 0)"
        if self.phase_deg != 0.0:
            return text + f", phase {self.phase_deg:g} deg"
        return text


@dataclass(frozen=True)
class SquareWave:
    """Square wave of frequency ``frequency_hz`` between ``-amplitude`` and ``+amplitude`` (plus offset).

    Sampled with :func:`scipy.signal.square`, so the wave starts high at ``t = 0``.

    Attributes
    ----------
    frequency_hz : float
        Fundamental frequency in Hz (> 0).
    amplitude : float
        Half the peak-to-peak swing (input units, e.g. rad/s of pump speed for the EHA).
    offset : float
        Constant added to the wave.
    duty : float
        Fraction of each period spent at ``offset + amplitude``, in the open
        interval (0, 1); 0.5 (default) gives a symmetric wave.
    """

    frequency_hz: float = 1.0
    amplitude: float = 1.0
    offset: float = 0.0
    duty: float = 0.5

    def __post_init__(self) -> None:
        positive("frequency_hz", self.frequency_hz, unit="Hz")
        if not 0.0 < self.duty < 1.0:
            from ..errors import ParameterError

            raise ParameterError(f"duty must lie in (0, 1); got {self.duty!r}")

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        import scipy.signal

        t = _times(t)
        return self.offset + self.amplitude * scipy.signal.square(
            2 * np.pi * self.frequency_hz * t, duty=self.duty
        )

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"square wave {self.frequency_hz:g} Hz, amplitude {self.amplitude:g}"


@dataclass(frozen=True)
class Sine:
    """u(t) = offset + amplitude * sin(2 pi frequency_hz t + phase).

    The nonlinear EHA scenarios drive the pump with ``94.25 sin(2 pi 0.5 t)`` rad/s
    (``docs/design.md`` S6).

    Attributes
    ----------
    amplitude : float
        Peak value (input units, e.g. rad/s of pump speed).
    frequency_hz : float
        Frequency in Hz (> 0).
    phase : float
        Phase at t = 0 in radians.
    offset : float
        Constant added to the sine.
    """

    amplitude: float = 1.0
    frequency_hz: float = 1.0
    phase: float = 0.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        positive("frequency_hz", self.frequency_hz, unit="Hz")

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        return self.offset + self.amplitude * np.sin(2 * np.pi * self.frequency_hz * t + self.phase)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"sine {self.frequency_hz:g} Hz, amplitude {self.amplitude:g}"


@dataclass(frozen=True)
class HeldUniform:
    """A seeded i.i.d. uniform(low, high) sequence held for ``hold_time`` seconds (zero-order hold).

    Value ``j`` is held on ``[j hold_time, (j + 1) hold_time)``; the values are the first draws
    of ``numpy.random.Generator(PCG64(SeedSequence(seed))).uniform(low, high)``, so the input is a
    deterministic function of ``t`` (the same for every realization and whatever time vector is
    asked for). The DETC2015 scenarios use U(-1, 1) per 1 ms sample.

    Attributes
    ----------
    low, high : float
        Bounds of the uniform law (low < high).
    hold_time : float
        Hold time in seconds (> 0), normally the sampling time.
    seed : int
        Non-negative seed of the sequence (part of the scenario definition).
    """

    low: float = -1.0
    high: float = 1.0
    hold_time: float = 1e-3
    seed: int = 0

    def __post_init__(self) -> None:
        positive("hold_time", self.hold_time, unit="s")
        if not float(self.low) < float(self.high):
            from ..errors import ParameterError

            raise ParameterError(f"need low < high; got [{self.low}, {self.high}]")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            from ..errors import ParameterError

            raise ParameterError(f"seed must be a non-negative integer; got {self.seed!r}")

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _nonnegative_times(t)
        j = np.floor(t / self.hold_time + 1e-9).astype(np.int64)
        if j.size == 0:
            return np.zeros(0)
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(self.seed)))
        values = rng.uniform(float(self.low), float(self.high), size=int(j.max()) + 1)
        return values[j]

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"uniform({self.low:g}, {self.high:g}) held {self.hold_time:g} s, seed {self.seed}"


def _nonnegative_times(t: npt.ArrayLike) -> np.ndarray:
    """Finite 1-D sample times that are all >= 0 (seconds)."""
    t = _times(t)
    if t.size and t.min() < 0:
        from ..errors import ParameterError

        raise ParameterError(f"sample times must be >= 0 s; got min {t.min():g}")
    return t


@dataclass(frozen=True)
class Sum:
    """The sum of several signals, e.g. a random sequence superimposed on a step (DETC2015).

    Attributes
    ----------
    terms : tuple of Signal
        The signals to add (at least one).
    """

    terms: tuple[Signal, ...] = ()

    def __post_init__(self) -> None:
        if not self.terms:
            from ..errors import ParameterError

            raise ParameterError("Sum needs at least one signal")
        object.__setattr__(self, "terms", tuple(self.terms))

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        t = _times(t)
        return np.sum([s.sample(t) for s in self.terms], axis=0)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return " + ".join(s.describe() for s in self.terms)


@dataclass(frozen=True)
class Repeat:
    """A signal repeated with a period: ``signal.sample(t mod period_s)`` (e.g. the 4 s EHA chirp for hours).

    Attributes
    ----------
    signal : Signal
        The signal over one period.
    period_s : float
        The period in s (> 0).
    """

    signal: Signal
    period_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "period_s", positive("period_s", self.period_s, unit="s"))

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        return self.signal.sample(np.mod(_nonnegative_times(t), self.period_s))

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"{self.signal.describe()}, repeated every {self.period_s:g} s"


@dataclass(frozen=True)
class ZeroInput:
    """u(t) = 0 on ``channels`` inputs: the input of healthy scenarios made for a user model.

    The healthy chattering of a matched linear model does not depend on u.

    Parameters
    ----------
    channels : int
        Number of input channels (the model's ``n_inputs``).

    See Also
    --------
    Constant : one constant value on a single input.
    """

    channels: int = 1

    def sample(self, t: np.ndarray) -> np.ndarray:
        """``(len(t), channels)`` zeros (t in seconds)."""
        return np.zeros((np.size(t), self.channels))

    def describe(self) -> str:
        """``"zero"`` (on every input)."""
        return "zero"
