"""Short-time Fourier transform settings, :class:`STFTConfig`, and the STFT tapers (private module;
the public home of :class:`STFTConfig` is :mod:`chatterspec.detection.spectral`, which re-exports it).

It lives in the package's base so that a model file's ``[detector]`` table
(:mod:`chatterspec.plants.modelfile`) can check the settings without importing the spectra
module (:mod:`chatterspec.detection.spectral`), a layer above it.

Tapers without :mod:`scipy.signal`: importing it costs 0.3-0.6 s (it parses the docstrings of its
array-API wrappers), which the online monitor would pay at every start for one window. The cosine-sum
windows are computed here (:func:`get_window`) with the operations of
``scipy.signal.windows.general_cosine`` (periodic form: ``M + 1`` points of ``linspace(-pi, pi)``,
``w += a_k cos(k x)``, last point dropped), so they equal ``scipy.signal.get_window(name, M)`` bit for
bit (``tests/test_startup.py`` checks it); any other window name is handed to scipy.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft

from ._validate import positive, readonly
from .errors import ParameterError

__all__ = ["DEFAULT_STFT", "NATIVE_WINDOWS", "STFTConfig", "cached_taper", "get_window"]

#: Windows computed here: name -> Hamming coefficient ``alpha`` of ``alpha - (1 - alpha) cos``.
NATIVE_WINDOWS: dict[str, float] = {"hamming": 0.54, "hann": 0.5}


def get_window(name: str, n: int) -> np.ndarray:
    """The periodic (DFT-even) window ``name`` of ``n`` samples, as ``scipy.signal.get_window(name, n)``.

    Parameters
    ----------
    name : str
        Window name; ``hamming`` and ``hann`` are computed here, anything else by scipy.
    n : int
        Window length in samples (>= 1).
    """
    alpha = NATIVE_WINDOWS.get(name) if isinstance(name, str) else None
    if alpha is None or int(n) != n or n < 1:
        import scipy.signal

        return np.asarray(scipy.signal.get_window(name, n), dtype=float)
    if n == 1:
        return np.ones(1)
    M = int(n) + 1
    fac = np.linspace(-np.pi, np.pi, M, dtype=np.float64)
    w = np.zeros(M, dtype=np.float64)
    for k, a in enumerate(np.asarray([alpha, 1.0 - alpha], dtype=np.float64)):
        w += a * np.cos(k * fac)
    return w[:-1]


@dataclass(frozen=True)
class STFTConfig:
    """Short-time Fourier transform settings (paper section IV-C: 1 s Hamming window, 0.2 s hop).

    Parameters
    ----------
    window_s : float
        Window length in seconds (> 0). ``n_window(dt) = round(window_s / dt)`` samples.
    hop_s : float
        Hop between frame starts in seconds (> 0, at most ``window_s``).
    window : str
        Window name for :func:`scipy.signal.get_window` (periodic / DFT-even form).

    Raises
    ------
    ParameterError
        If a length is not positive, the hop exceeds the window or the window name is unknown.
    """

    window_s: float = 1.0
    hop_s: float = 0.2
    window: str = "hamming"

    def __post_init__(self) -> None:
        object.__setattr__(self, "window_s", positive("window_s", self.window_s, unit="s"))
        object.__setattr__(self, "hop_s", positive("hop_s", self.hop_s, unit="s"))
        if self.hop_s > self.window_s:
            raise ParameterError(
                f"hop_s ({self.hop_s} s) must not exceed window_s ({self.window_s} s): "
                "frames would skip samples"
            )
        if self.window not in NATIVE_WINDOWS:  # hamming / hann need no scipy.signal (0.3-0.6 s to import)
            import scipy.signal

            try:
                scipy.signal.get_window(self.window, 8)
            except (ValueError, TypeError) as exc:
                raise ParameterError(f"unknown window {self.window!r} for scipy.signal.get_window") from exc

    def n_window(self, dt: float) -> int:
        """Window length W in samples, ``round(window_s / dt)`` (at least 2)."""
        return _samples("window_s", self.window_s, dt, 2)

    def n_hop(self, dt: float) -> int:
        """Hop H in samples, ``round(hop_s / dt)`` (at least 1)."""
        return _samples("hop_s", self.hop_s, dt, 1)

    def taper(self, dt: float) -> np.ndarray:
        """The window samples ``w_k``, ``k = 0 .. W-1`` (read-only)."""
        return cached_taper(self.window, self.n_window(dt))

    def freqs_hz(self, dt: float) -> np.ndarray:
        """Frame frequencies ``n / (W dt)`` Hz, ``n = 0 .. W//2``."""
        return scipy.fft.rfftfreq(self.n_window(dt), dt)


#: The paper's STFT settings (1 s Hamming window, 0.2 s hop); the default of every STFT function.
DEFAULT_STFT = STFTConfig()


@lru_cache(maxsize=32)
def cached_taper(window: str, n: int) -> np.ndarray:
    """The read-only taper ``w_k`` of ``window`` at ``n`` samples (cached: never mutate it)."""
    return readonly(get_window(window, n))


def _samples(name: str, seconds: float, dt: float, least: int) -> int:
    """``round(seconds / dt)`` samples of the length ``name`` (s) at the sampling time ``dt`` (s).

    Raises
    ------
    ParameterError
        ``dt`` is not positive, or the length is shorter than ``least`` samples.
    """
    dt = positive("dt", dt, unit="s")
    n = round(seconds / dt)
    if n < least:
        what = "one sample" if least == 1 else f"{least} samples"
        raise ParameterError(f"{name} = {seconds} s is shorter than {what} at dt = {dt} s")
    return n
