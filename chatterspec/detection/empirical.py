"""Empirical normalization spectrum and family-wise threshold, for models without a closed-form spectrum.

For a linear nominal model the healthy chattering spectrum ``E[S]`` is known in closed form
(eq 56; :func:`~chatterspec.detection.spectral.expected_spectrum`). For a nonlinear model
(:class:`~chatterspec.plants.nonlinear.NonlinearModel`) it is not, so it is *estimated* from
healthy runs (beyond the paper):

* ``normalization_spectrum``: the mean periodogram (eq 49) of ``P`` healthy "pilot" runs, then a
  moving average over ``2 h + 1`` neighbouring tested bins (the healthy spectrum is smooth; a
  periodogram bin has standard deviation about its mean, so the estimate's relative standard error
  is about ``1 / sqrt(P (2 h + 1))``). DC and Nyquist are kept unsmoothed (they are not tested).
* ``frame_normalization``: the same for STFT frames (mean over runs and frames).

The detector then tests ``S / E_hat`` against the empirical ``(1 - alpha)``-quantile of the
per-record maximum over tested bins, estimated on *other* healthy runs
(:func:`chatterspec.studies.calibration.thresholds.calibrate_empirical`). The false-alarm rate
of that family-wise threshold does not depend on how good ``E_hat`` is (it only shapes which
frequencies the detector is sensitive to); it is exact up to the order-statistic uncertainty
of the quantile, which the calibration reports as an interval.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import scipy.ndimage

from .._validate import finite_array, open_unit
from ..errors import ParameterError, ShapeError
from .spectral import STFTConfig, periodogram
from .spectral import spectrogram as stft_spectrogram
from .threshold_type import AlphaMeaning
from .thresholds import Threshold

__all__ = [
    "NORMALIZATION_SMOOTH_BINS",
    "empirical_family_wise_threshold",
    "frame_normalization",
    "normalization_spectrum",
    "smooth_spectrum",
]

NORMALIZATION_SMOOTH_BINS = 5  # h: half-width of the moving average (11 bins = 2.75 Hz at N = 4000, 1 ms)


def smooth_spectrum(mean_power: np.ndarray, half_width: int = NORMALIZATION_SMOOTH_BINS) -> np.ndarray:
    """Moving average over ``2 h + 1`` bins of the interior (tested) bins; DC and Nyquist unchanged.

    Parameters
    ----------
    mean_power : (bins, m) array
        Mean periodogram or frame spectrum (power units, e.g. Pa^2 for pressure).
    half_width : int
        ``h >= 0`` bins on each side; the ends are mirrored (a real signal's spectrum is even
        about DC and Nyquist).

    Returns
    -------
    (bins, m) ndarray
    """
    P = finite_array("mean_power", mean_power, ndim=2)
    h = int(half_width)
    if h < 0:
        raise ParameterError(f"half_width must be >= 0 bins; got {half_width}")
    out = P.copy()
    if h and P.shape[0] > 3:
        out[1:-1] = scipy.ndimage.uniform_filter1d(P[1:-1], 2 * h + 1, axis=0, mode="reflect")
    if np.any(out[1:-1] <= 0):
        raise ParameterError("the healthy chattering has zero power in some bin: cannot normalize by it")
    return out


def normalization_spectrum(
    records: Iterable[np.ndarray], dt: float, half_width: int = NORMALIZATION_SMOOTH_BINS
) -> tuple[np.ndarray, int]:
    """Estimated healthy periodogram ``E_hat[S]`` from chunks of healthy chattering.

    Parameters
    ----------
    records : iterable of (runs, N, m) arrays
        Healthy chattering chunks (same N and m).
    dt : float
        Sampling time in seconds.
    half_width : int
        Smoothing half-width in bins (:func:`smooth_spectrum`).

    Returns
    -------
    (E_hat (bins, m), runs)
    """
    total, runs = None, 0
    for x in records:
        S = periodogram(x, dt).power
        s = S.sum(axis=0)
        if total is not None and s.shape != total.shape:
            raise ShapeError(f"chunk spectrum {s.shape} differs from the first chunk's {total.shape}")
        total = s if total is None else total + s
        runs += S.shape[0]
    if total is None:
        raise ParameterError("no healthy chattering to estimate the normalization from")
    return smooth_spectrum(total / runs, half_width), runs


def frame_normalization(
    records: Iterable[np.ndarray],
    dt: float,
    config: STFTConfig,
    half_width: int = NORMALIZATION_SMOOTH_BINS,
) -> np.ndarray:
    """Estimated healthy STFT frame spectrum (mean over runs and frames, then smoothed).

    Parameters
    ----------
    records : iterable of (runs, N, m) arrays
        Healthy chattering chunks.
    dt : float
        Sampling time in seconds.
    config : STFTConfig
        Window length and hop (s) and taper.
    half_width : int
        Smoothing half-width in frame bins (:func:`smooth_spectrum`).

    Returns
    -------
    (fbins, m) ndarray
    """
    total, count = None, 0
    for x in records:
        P = stft_spectrogram(x, dt, config).power  # (runs, F, fb, m)
        s = P.sum(axis=(0, 1))
        total = s if total is None else total + s
        count += P.shape[0] * P.shape[1]
    if total is None or count == 0:
        raise ParameterError("no complete STFT frame to estimate the frame normalization from")
    return smooth_spectrum(total / count, half_width)


def empirical_family_wise_threshold(
    normalization: np.ndarray,
    freqs_hz: np.ndarray,
    tested: np.ndarray,
    factor: np.ndarray,
    alpha: float,
    meaning: AlphaMeaning = "family-wise",
) -> Threshold:
    """Threshold ``E_hat * q`` per channel (``kind="empirical"``).

    Parameters
    ----------
    normalization : (bins, m) array
        Estimated healthy spectrum ``E_hat`` (power units).
    freqs_hz : (bins,) array
        Bin frequencies in Hz.
    tested : (bins,) bool array
        Bins the detector tests (DC and Nyquist excluded).
    factor : (m,) array
        Empirical ``(1 - alpha)``-quantile of ``max_tested S / E_hat`` per channel.
    alpha : float
        Its nominal false-alarm probability in (0, 1).
    meaning : {"family-wise", "per-frame"}
        Record-level family-wise, or per STFT frame (family-wise over the frame's bins).

    Returns
    -------
    Threshold
    """
    alpha = open_unit("alpha", alpha)
    if meaning not in ("family-wise", "per-frame"):
        raise ParameterError(f"meaning must be 'family-wise' or 'per-frame'; got {meaning!r}")
    E = finite_array("normalization", normalization, ndim=2)
    q = finite_array("factor", factor, ndim=1)
    if q.shape[0] != E.shape[1]:
        raise ShapeError(f"factor needs one value per channel ({E.shape[1]}); got {q.shape}")
    tested = np.asarray(tested, dtype=bool)
    values = E * q
    ro = [np.array(a) for a in (values, freqs_hz, tested, np.where(tested, 2, 1), E)]
    for a in ro:
        a.setflags(write=False)
    return Threshold(
        values=ro[0],
        freqs_hz=ro[1],
        kind="empirical",
        alpha=alpha,
        alpha_meaning=meaning,
        correction="none",
        tested=ro[2],
        dof=ro[3],
        averaged=1,
        per_test_alpha=float("nan"),
        expected=ro[4],
    )
