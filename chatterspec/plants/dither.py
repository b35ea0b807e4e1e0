"""Dither signals: small deterministic excitation added to a closed loop's input or reference.

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

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .._validate import finite_array, finite_scalar, positive
from ..errors import ParameterError

__all__ = ["PRBS", "PRBS_TAPS", "Multisine"]


def _times(t: npt.ArrayLike) -> np.ndarray:
    return finite_array("t", t, ndim=1)


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
