"""The time and frequency geometry of a recording: one time rule (:func:`to_ns`), the span a file's
spectrogram covers (:func:`record_span`, :func:`pad_columns`), the spectrogram's band
(:func:`default_band_hz`) and colour range (:data:`DB_RANGE`).

One time rule for everything logged: seconds are converted once to integer nanoseconds by
:func:`to_ns` (rounded to the nearest ns) and only integers reach Rerun, whether through
``send_columns`` or ``set_time``. (Rerun's own float paths differ: ``TimeColumn(duration=seconds)``
truncates, ``set_time(duration=seconds)`` rounds, which put a state logged "before" a frame 1 ns
after it.)
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor

__all__ = ["DB_RANGE", "default_band_hz", "pad_columns", "record_span", "to_ns"]

#: Colour range of the spectrogram, dB re the per-frame threshold (0 dB = threshold): healthy
#: frames (about -11 dB on average at alpha = 1e-3, Bonferroni over 499 bins) stay near black,
#: only excess lights up; fixed so that colours mean the same in every recording.
DB_RANGE = (-5.0, 30.0)


def to_ns(seconds: npt.ArrayLike) -> np.ndarray:
    """Seconds -> integer nanoseconds, rounded to the nearest ns: the one time rule of a recording.

    Parameters
    ----------
    seconds : float or array of float
        Times (s).

    Returns
    -------
    int64 array
        ``round(seconds * 1e9)`` (same shape; 0-d for a scalar).
    """
    return np.rint(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64)


def pad_columns(monitor: ChatteringMonitor) -> int:
    """Blank columns added on each side of a file's spectrogram so that it covers the whole record: the
    first frame's window starts about ``(W - H) / 2`` samples before the first column's left edge
    (2 columns for a 1 s window at a 0.2 s hop).

    Parameters
    ----------
    monitor : ChatteringMonitor

    Returns
    -------
    int
        ``round((W - 1 - H) / (2 H))`` (>= 0) for window ``W`` and hop ``H`` in samples.
    """
    return max(0, round((monitor.n_window - 1 - monitor.n_hop) / (2.0 * monitor.n_hop)))


def record_span(monitor: ChatteringMonitor, total: int, *, raw: bool) -> tuple[float, float] | None:
    """The time span (s) of a file recording: the columns of its spectrogram, padded by
    :func:`pad_columns` on each side, which covers the whole record; every time view shows exactly it.

    Parameters
    ----------
    monitor : ChatteringMonitor
        A fresh monitor (no sample pushed yet).
    total : int
        Samples that will be pushed.
    raw : bool
        Raw measurements (``z(0)`` initializes the filters) rather than chattering.

    Returns
    -------
    (start_s, stop_s) or None
        None if no frame fits or the monitor is not fresh.
    """
    if monitor.n_samples or monitor.n_frames:
        return None  # not a fresh monitor: the record's extent is not known
    n_chat = total - 1 if raw else total
    if n_chat < monitor.n_window:
        return None
    last = (n_chat - monitor.n_window) // monitor.n_hop
    t_chat0 = monitor.t0 + (monitor.dt if raw else 0.0)
    hop = monitor.n_hop * monitor.dt
    edge = hop / 2.0 + pad_columns(monitor) * hop
    centre = (monitor.n_window - 1) / 2.0
    first_c = t_chat0 + centre * monitor.dt
    last_c = t_chat0 + (last * monitor.n_hop + centre) * monitor.dt
    return (first_c - edge, last_c + edge)


def _nice_ceil(x: float) -> float:
    """Smallest multiple of half a decade's unit >= x (125 -> 150, 15 -> 15, 12.5 -> 15)."""
    step = 10.0 ** np.floor(np.log10(x)) / 2.0
    return float(np.ceil(x / step - 1e-9) * step)


def default_band_hz(monitor: ChatteringMonitor, factor: float = 3.0) -> tuple[float, float]:
    """Default spectrogram band: the bins the detector tests, capped where the model has no content.

    The cap is ``factor`` times the model's highest natural frequency ``|ln(lambda)| / (2 pi dt)``
    over the eigenvalues ``lambda`` of ``A`` (Hz), rounded up to a multiple of half a decade's unit
    (EHA: 3 x 41.8 Hz -> 150 Hz; second-order 5 Hz plant -> 15 Hz). Without an oscillatory or
    decaying mode (all eigenvalues 1) the band is the whole tested band.

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the model, the STFT frequencies and the tested bins of the threshold.
    factor : float
        Multiple of the highest natural frequency kept (> 0).

    Returns
    -------
    (lo_hz, hi_hz) : tuple of float
        Lowest and highest tested bin frequency inside the band (Hz).
    """
    if not factor > 0:
        raise ParameterError(f"factor must be > 0; got {factor!r}")
    f = monitor.threshold.freqs_hz[monitor.threshold.tested]
    if f.size == 0:
        f = monitor.freqs_hz
    lo, hi = float(f.min()), float(f.max())
    A = getattr(monitor.model, "A", None)
    if A is None:  # nonlinear model: the natural frequency of its linearization at rest (Hz)
        fn = float(getattr(monitor.model, "natural_frequency_hz", None) or 0.0)
    else:
        with np.errstate(divide="ignore"):
            s = np.log(np.linalg.eigvals(np.asarray(A, dtype=float)).astype(complex))
        fn = float(np.max(np.abs(s[np.isfinite(s)]), initial=0.0)) / (2 * np.pi * monitor.dt)
    if fn > 0:
        cap = _nice_ceil(factor * fn)
        inside = f[f <= cap]
        hi = float(inside.max()) if inside.size else hi
    return lo, hi
