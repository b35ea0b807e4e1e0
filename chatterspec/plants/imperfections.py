"""Sensor imperfections: what a real measurement adds to a plant's noise-free output.

A model file says ``z(k) = C x(k) + w(k)`` with white Gaussian ``w ~ N(0, R)`` sampled exactly every
``dt``. Real sensors are not that: their noise is coloured or heavy-tailed, an ADC rounds, the mains
hum couples in, the offset drifts, the sampling instants jitter. Each effect here is a frozen
dataclass with

* ``init(runs, rng) -> state``: the effect's state for ``runs`` realizations (e.g. the last AR(1)
  value, the hum's phase), drawn from the ``numpy.random.Generator`` ``rng``;
* ``apply(y, t, rng, state) -> (y_out, state_out)``: the measurement of ``y`` (``(runs, K, m)``:
  realizations, samples, channels, in the channels' units) at the times ``t`` (``(K,)``, seconds),
  and the state after the last sample.

``apply`` is pure (it returns new arrays and a new state; the inputs are not modified) and
vectorized over the leading realizations axis and the channels (a recursion in time is one
:func:`scipy.signal.lfilter` call along the time axis, no Python loop over samples or
realizations). Applying a record in chunks, passing the state along, gives the same numbers as the
whole record at once when the same generator draws the same normals in the same order (the chunks
draw ``(runs, K, m)`` blocks one after another: the same numbers as one block only if the chunks
have the same ``runs`` and the generator is consumed in time order; the streams of the bench do
so). :class:`SensorChain` applies several in order (jitter on the noise-free output first, then
noise, hum and drift, then the ADC).

Every parameter is validated at construction (``ParameterError`` naming it and its unit). A
noise effect *replaces* the model's white measurement noise: simulate the plant with ``R = 0``
(e.g. ``dataclasses.replace(model, R=0 * model.R)``) and let the chain add the noise.

Effects (units: seconds, Hz, the channel's own units)
    :class:`WhiteNoise`
        ``w ~ N(0, R)``: the model's own noise (``R`` in channel units squared).
    :class:`AR1Noise`
        ``w(k) = rho w(k-1) + sqrt(1 - rho^2) L e(k)``, ``L L^T = R``, started stationary: the same
        covariance ``R`` as white noise, lag-``j`` correlation ``rho^j`` per channel.
    :class:`StudentTNoise`
        ``w = L t sqrt((nu - 2) / nu)`` with ``t`` independent Student-t with ``nu > 2`` degrees of
        freedom per channel: heavy tails, the same covariance ``R``.
    :class:`MainsHum`
        ``a_c sin(2 pi f t + phi_c)``, ``f`` in Hz (50 or 60), amplitude ``a_c`` per channel, phase
        uniform per realization and channel.
    :class:`BiasDrift`
        A first-order Gauss-Markov offset ``b(k) = g b(k-1) + sqrt(1 - g^2) sigma_c e(k)``,
        ``g = exp(-dt_s / tau)``: a slowly wandering bias of stationary standard deviation ``sigma_c``
        (channel units) and correlation time ``tau`` (s), started stationary.
    :class:`Quantization`
        An ADC of ``bits`` bits over ``[low_c, high_c]`` per channel (the sensor range, channel
        units): step ``q_c = (high_c - low_c) / 2^bits``, rounding to the nearest level, saturating
        at the range. When the signal spans many steps the error is uniform on ``[-q/2, q/2]``,
        variance ``q^2 / 12`` (Widrow).
    :class:`SampleJitter`
        Sampling instants ``t_k + d_k``, ``d_k ~ N(0, sigma_t^2)`` (s), the same for every channel
        of a sample (one ADC trigger): first order, ``y(t_k + d_k) = y_k + d_k (y_k - y_{k-1}) / dt_s``
        (the slope of the sampled trajectory over the last interval; exact for a signal linear
        between samples). The first sample of a record uses the slope of its first interval.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import scipy.signal

from .._validate import finite_array
from ..errors import ParameterError, ShapeError

__all__ = [
    "AR1Noise",
    "BiasDrift",
    "Imperfection",
    "MainsHum",
    "Quantization",
    "SampleJitter",
    "SensorChain",
    "StudentTNoise",
    "WhiteNoise",
]


class Imperfection(Protocol):
    """What every effect provides (see the module docstring)."""

    def init(self, runs: int, rng: np.random.Generator) -> Any:
        """The state for ``runs`` realizations."""
        ...

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: Any
    ) -> tuple[np.ndarray, Any]:
        """``y`` (runs, K, m) measured at times ``t`` (K,) s; the state after the last sample."""
        ...

    def describe(self) -> str:
        """A short description with the parameters and units."""
        ...


# --------------------------------------------------------------------------- validation helpers
def _covariance(R: Any, name: str = "R") -> np.ndarray:
    R = finite_array(name, R, ndim=(1, 2))
    if R.ndim == 1:
        R = np.diag(R)
    if R.shape[0] != R.shape[1] or not np.allclose(R, R.T, rtol=1e-10, atol=0.0):
        raise ParameterError(f"{name} must be a symmetric (m, m) covariance (channel units squared)")
    if np.linalg.eigvalsh(R).min() < -1e-12 * max(1.0, float(np.abs(R).max())):
        raise ParameterError(f"{name} must be positive semi-definite")
    return R


def _sqrt(R: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eigh(R)
    return V * np.sqrt(np.clip(w, 0.0, None))


def _per_channel(value: Any, name: str, unit: str, *, positive: bool = False) -> np.ndarray:
    v = np.atleast_1d(finite_array(name, value, ndim=(0, 1)))
    if np.any(v < 0) or (positive and np.any(v <= 0)):
        raise ParameterError(
            f"{name} must be {'> 0' if positive else '>= 0'} {unit} per channel; got {v.tolist()}"
        )
    return v


def _seconds(value: Any, name: str, what: str) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise ParameterError(f"{name} must be > 0 s ({what}); got {value!r}")
    return v


def _check_y(y: np.ndarray, t: np.ndarray, m: int | None) -> tuple[np.ndarray, np.ndarray]:
    y = np.asarray(y, dtype=float)
    t = np.asarray(t, dtype=float)
    if y.ndim != 3:
        raise ShapeError(f"y must be (runs, samples, channels); got shape {y.shape}")
    if t.shape != (y.shape[1],):
        raise ShapeError(f"t must hold one time (s) per sample, shape ({y.shape[1]},); got {t.shape}")
    if m is not None and y.shape[2] != m:
        raise ShapeError(f"y has {y.shape[2]} channels; this effect was made for {m}")
    return y, t


def _ar1(e: np.ndarray, g: float, prev: np.ndarray) -> np.ndarray:
    """``x(k) = g x(k-1) + sqrt(1 - g^2) e(k)`` along axis 1 from ``x(-1) = prev`` (runs, m)."""
    c = math.sqrt(1.0 - g * g)
    zi = (g * prev)[:, None, :]  # lfilter's state: the feedback of x(-1)
    out, _ = scipy.signal.lfilter([c], [1.0, -g], e, axis=1, zi=zi)
    return out


# --------------------------------------------------------------------------- noise
@dataclass(frozen=True, eq=False)
class _ScaledNoise:
    """Measurement noise ``L w`` of covariance ``R = L L^T`` (``R``: (m, m) or its diagonal, channel
    units^2), with ``w`` the unit-covariance noise of the subclass (:meth:`_unit`) carried over chunks
    by its state."""

    R: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "R", _covariance(self.R))

    def init(self, runs: int, rng: np.random.Generator) -> Any:
        """No state."""
        return None

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: Any
    ) -> tuple[np.ndarray, Any]:
        """``y + L w`` with ``w`` (runs, K, m) the unit noise of this kind (its state carried on)."""
        y, t = _check_y(y, t, self.R.shape[0])
        w, state = self._unit(y.shape, rng, state)
        return y + w @ _sqrt(self.R).T, state

    def _unit(self, shape: tuple[int, ...], rng: np.random.Generator, state: Any) -> tuple[np.ndarray, Any]:
        raise NotImplementedError


@dataclass(frozen=True, eq=False)
class WhiteNoise(_ScaledNoise):
    """White Gaussian measurement noise ``N(0, R)`` (``R``: (m, m) or its diagonal, channel units^2)."""

    def _unit(self, shape: tuple[int, ...], rng: np.random.Generator, state: None) -> tuple[np.ndarray, None]:
        """``e`` standard normal."""
        return rng.standard_normal(shape), None

    def describe(self) -> str:
        """A short description."""
        return f"white noise, std {np.sqrt(np.diag(self.R)).tolist()}"


@dataclass(frozen=True, eq=False)
class AR1Noise(_ScaledNoise):
    """AR(1) (coloured) measurement noise of covariance ``R``, lag-1 correlation ``rho`` in [0, 1)."""

    rho: float

    def __post_init__(self) -> None:
        super().__post_init__()
        rho = float(self.rho)
        if not (0.0 <= rho < 1.0):
            raise ParameterError(f"rho must lie in [0, 1) (lag-1 correlation of the noise); got {self.rho!r}")
        object.__setattr__(self, "rho", rho)

    def init(self, runs: int, rng: np.random.Generator) -> np.ndarray:
        """``w(-1)`` drawn from the stationary law ``N(0, I)`` (before ``L``)."""
        return rng.standard_normal((int(runs), self.R.shape[0]))

    def _unit(
        self, shape: tuple[int, ...], rng: np.random.Generator, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``w`` the unit AR(1) recursion along time from ``w(-1) = state``; the last ``w`` carried on."""
        w = _ar1(rng.standard_normal(shape), self.rho, state)
        return w, w[:, -1].copy() if w.shape[1] else state

    def describe(self) -> str:
        """A short description."""
        return f"AR(1) noise, rho {self.rho:g}, the model's covariance"


@dataclass(frozen=True, eq=False)
class StudentTNoise(_ScaledNoise):
    """Student-t measurement noise with ``nu > 2`` degrees of freedom, scaled to covariance ``R``."""

    nu: float

    def __post_init__(self) -> None:
        super().__post_init__()
        nu = float(self.nu)
        if not (math.isfinite(nu) and nu > 2.0):
            raise ParameterError(f"nu must be > 2 (a finite variance); got {self.nu!r}")
        object.__setattr__(self, "nu", nu)

    def _unit(self, shape: tuple[int, ...], rng: np.random.Generator, state: None) -> tuple[np.ndarray, None]:
        """``t sqrt((nu - 2) / nu)``, ``t`` Student-t."""
        return rng.standard_t(self.nu, size=shape) * math.sqrt((self.nu - 2.0) / self.nu), None

    def describe(self) -> str:
        """A short description."""
        return f"Student-t noise, nu {self.nu:g}, the model's covariance"


# --------------------------------------------------------------------------- disturbances
@dataclass(frozen=True, eq=False)
class MainsHum:
    """A sinusoid of ``frequency_hz`` (Hz) and ``amplitude`` per channel (channel units), random phase."""

    amplitude: np.ndarray
    frequency_hz: float = 50.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "amplitude", _per_channel(self.amplitude, "amplitude", "(channel units)"))
        f = float(self.frequency_hz)
        if not (math.isfinite(f) and f > 0):
            raise ParameterError(f"frequency_hz must be > 0 Hz; got {self.frequency_hz!r}")
        object.__setattr__(self, "frequency_hz", f)

    def init(self, runs: int, rng: np.random.Generator) -> np.ndarray:
        """The phase (rad) per realization and channel, uniform on [0, 2 pi)."""
        return rng.uniform(0.0, 2.0 * np.pi, (int(runs), self.amplitude.size))

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``y + a sin(2 pi f t + phi)``."""
        y, t = _check_y(y, t, None)
        a = np.broadcast_to(self.amplitude, (y.shape[2],))
        hum = a * np.sin(2.0 * np.pi * self.frequency_hz * t[None, :, None] + state[:, None, :])
        return y + hum, state

    def describe(self) -> str:
        """A short description."""
        return f"{self.frequency_hz:g} Hz hum, amplitude {self.amplitude.tolist()}"


@dataclass(frozen=True, eq=False)
class BiasDrift:
    """A first-order Gauss-Markov offset: stationary std ``sigma`` per channel, correlation time ``tau_s``
    (s), sampled every ``dt_s`` (s)."""

    sigma: np.ndarray
    tau_s: float
    dt_s: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "sigma", _per_channel(self.sigma, "sigma", "(channel units)"))
        tau = float(self.tau_s)
        if not (math.isfinite(tau) and tau > 0):
            raise ParameterError(f"tau_s must be > 0 s (the drift's correlation time); got {self.tau_s!r}")
        object.__setattr__(self, "tau_s", tau)
        object.__setattr__(self, "dt_s", _seconds(self.dt_s, "dt_s", "the sampling interval"))

    def init(self, runs: int, rng: np.random.Generator) -> np.ndarray:
        """``b(-1) / sigma`` drawn from the stationary law ``N(0, 1)``."""
        return rng.standard_normal((int(runs), self.sigma.size))

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """``y + sigma b`` with ``b`` the unit recursion, ``g = exp(-dt_s / tau_s)``."""
        y, t = _check_y(y, t, None)
        g = math.exp(-self.dt_s / self.tau_s)
        b = _ar1(rng.standard_normal((y.shape[0], y.shape[1], self.sigma.size)), g, state)
        return y + b * self.sigma, b[:, -1].copy() if b.shape[1] else state

    def describe(self) -> str:
        """A short description."""
        return f"bias drift, std {self.sigma.tolist()}, correlation time {self.tau_s:g} s"


# --------------------------------------------------------------------------- sampling
@dataclass(frozen=True, eq=False)
class Quantization:
    """An ADC of ``bits`` bits over the sensor range ``[low, high]`` per channel (channel units)."""

    bits: int
    low: np.ndarray
    high: np.ndarray

    def __post_init__(self) -> None:
        bits = int(self.bits)
        if bits != self.bits or not 1 <= bits <= 32:
            raise ParameterError(f"bits must be an integer in [1, 32]; got {self.bits!r}")
        lo = np.atleast_1d(finite_array("low", self.low, ndim=(0, 1)))
        hi = np.atleast_1d(finite_array("high", self.high, ndim=(0, 1)))
        if lo.shape != hi.shape or np.any(hi <= lo):
            raise ParameterError(f"the sensor range needs low < high per channel; got low {lo}, high {hi}")
        object.__setattr__(self, "bits", bits)
        object.__setattr__(self, "low", lo)
        object.__setattr__(self, "high", hi)

    @property
    def step(self) -> np.ndarray:
        """The quantization step ``q = (high - low) / 2^bits`` per channel (channel units)."""
        return (self.high - self.low) / 2.0**self.bits

    def init(self, runs: int, rng: np.random.Generator) -> None:
        """No state."""
        return None

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: None
    ) -> tuple[np.ndarray, None]:
        """The nearest of the ``2^bits`` levels ``low + q j`` (saturating at the range)."""
        y, t = _check_y(y, t, None)
        q = self.step
        j = np.clip(np.rint((y - self.low) / q), 0, 2**self.bits - 1)
        return self.low + q * j, None

    def describe(self) -> str:
        """A short description."""
        return (
            f"{self.bits}-bit ADC over [{self.low.tolist()}, {self.high.tolist()}], step {self.step.tolist()}"
        )


@dataclass(frozen=True, eq=False)
class SampleJitter:
    """Sampling instants jittered by ``N(0, std_s^2)`` seconds (first order in the jitter), nominal
    sampling interval ``dt_s`` (s)."""

    std_s: float
    dt_s: float

    def __post_init__(self) -> None:
        s = float(self.std_s)
        if not (math.isfinite(s) and s >= 0):
            raise ParameterError(
                f"std_s must be >= 0 s (the jitter's standard deviation); got {self.std_s!r}"
            )
        object.__setattr__(self, "std_s", s)
        object.__setattr__(self, "dt_s", _seconds(self.dt_s, "dt_s", "the sampling interval"))

    def init(self, runs: int, rng: np.random.Generator) -> None:
        """The previous sample (None before the first)."""
        return None

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """``y_k + d_k (y_k - y_{k-1}) / dt``; ``state`` is ``y_{-1}`` (runs, m) or None."""
        y, t = _check_y(y, t, None)
        if y.shape[1] == 0:
            return y, state
        if state is None:  # the first sample: the slope of the first interval (zero for one sample)
            prev = y[:, :1] - (y[:, 1:2] - y[:, :1]) if y.shape[1] > 1 else y[:, :1]
        else:
            prev = state[:, None, :]
        slope = np.diff(np.concatenate([prev, y], axis=1), axis=1) / self.dt_s
        d = rng.standard_normal((y.shape[0], y.shape[1], 1)) * self.std_s
        return y + d * slope, y[:, -1].copy()

    def describe(self) -> str:
        """A short description."""
        return f"sampling jitter, std {1e6 * self.std_s:g} us"


# --------------------------------------------------------------------------- chains
@dataclass(frozen=True, eq=False)
class SensorChain:
    """Effects applied in order to a noise-free output.

    Attributes
    ----------
    effects : tuple
        The effects, first applied first (e.g. jitter, noise, hum, drift, then the ADC).
    """

    effects: tuple[Any, ...] = ()

    def init(self, runs: int, rng: np.random.Generator) -> tuple[Any, ...]:
        """Every effect's state."""
        return tuple(e.init(runs, rng) for e in self.effects)

    def apply(
        self, y: np.ndarray, t: np.ndarray, rng: np.random.Generator, state: tuple[Any, ...]
    ) -> tuple[np.ndarray, tuple[Any, ...]]:
        """The measurement of ``y`` (runs, K, m) at ``t`` (K,) s through every effect; the new states."""
        out = []
        for e, s in zip(self.effects, state, strict=True):
            y, s = e.apply(y, t, rng, s)
            out.append(s)
        return y, tuple(out)

    def describe(self) -> str:
        """A short description."""
        return "; ".join(e.describe() for e in self.effects) or "ideal sensor"
