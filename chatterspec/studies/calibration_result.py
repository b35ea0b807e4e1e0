"""The result of a threshold calibration, :class:`Calibration`.

:func:`chatterspec.studies.calibration.calibrate` computes it (analytic thresholds; empirical ones in
:mod:`~chatterspec.studies.empirical_calibration`). Its file format (``.npz`` arrays with a JSON
header, or JSON) is :mod:`~chatterspec.studies.calibration_file`: :meth:`Calibration.save` writes it,
:func:`load_calibration` reads it. Both names are re-exported by :mod:`chatterspec.studies.calibration`,
their documented home.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import scipy.stats

from .._repr import short_repr
from ..detection.alarms.calibration import RuleCalibration
from ..detection.spectral import STFTConfig
from ..detection.thresholds import Correction, Threshold
from ..errors import CalibrationMismatchError, ParameterError
from ..plants.nonlinear import Model
from .calibration_file import CALIBRATION_FORMAT, _ro, calibration_dict, read_calibration, save_calibration
from .intervals import QuantileEstimate

__all__ = [
    "CALIBRATION_FORMAT",
    "Calibration",
    "load_calibration",
]


# --------------------------------------------------------------------------- calibration
@dataclass(frozen=True, eq=False)
class Calibration:
    """Analytic and empirical thresholds of one healthy model (result of :func:`calibrate`).

    Thresholds on the power are ``E[S] * factor``; the arrays below are the
    factors (normalized thresholds) unless stated otherwise.

    Attributes
    ----------
    scenario, model_name, model_fingerprint : str
        What was calibrated (the fingerprint guards :meth:`check`).
    dt : float
    n_samples : int
        Record length N of the periodogram.
    stft : dict
        ``window_s``, ``hop_s``, ``window`` of the per-frame calibration.
    alpha : float
    runs : int
    seed : int or None
    confidence : float
        Level of every interval.
    channels : tuple of str
    freqs_hz : (bins,) array
    tested : (bins,) bool array
        Bins of the detector (DC and Nyquist excluded).
    expected : (bins, m) array
        Exact expected healthy spectrum.
    analytic : dict of str -> (bins, m) array
        ``paper``, ``exact`` (per-bin), ``exact-bonferroni``, ``exact-sidak`` thresholds (power units).
    per_bin, per_bin_low, per_bin_high : (bins, m) arrays
        Empirical per-bin ``(1 - alpha)``-quantile of ``S / E[S]`` and its interval.
    family_wise : tuple of QuantileEstimate
        Per channel: ``(1 - alpha)``-quantile of ``max_tested S / E[S]``.
    family_wise_analytic : dict of str -> float
        Bonferroni and Sidak factors ``chi2.isf(a, 2) / 2``.
    frame_freqs_hz, frame_tested, frame_expected, frame_analytic, per_frame, per_frame_low, per_frame_high
        The same for STFT frames (quantiles pooled over frames).
    frame_family_wise : tuple of QuantileEstimate
        Per channel: ``(1 - alpha)``-quantile over frames of ``max_tested S / E[S]``
        (the empirical per-frame threshold of the live monitor, family-wise over
        the bins of one frame); its interval counts only non-overlapping frames
        as independent.
    normalization : {"analytic", "empirical"}
        ``expected``/``frame_expected`` are the closed-form spectrum (linear model, eq 56) or an
        estimate from healthy pilot runs (nonlinear model; :mod:`~.empirical_calibration`; then
        ``analytic``, ``frame_analytic`` and ``family_wise_analytic`` are empty).
    normalization_info : dict
        How an empirical normalization was estimated (pilot runs, smoothing); empty otherwise.
    tails : dict
        How the empirical quantiles were read: ``method`` ``"exact"`` (order statistics of the
        kept top-k tails) or ``"histogram"`` (bounded memory, :mod:`~.tail_histogram`, with
        ``pilot_runs``, ``fine_rel_width``, ``outside_window``); ``budget_bytes`` and the
        ``exact_bytes`` the exact tails would need. Empty for files of older versions.
    alarm : RuleCalibration or None
        The monitor's alarm rule calibrated for a false-alarm budget (rule, threshold, budget,
        frames per hour; :mod:`chatterspec.studies.alarm_budget`), when made with ``--rule``.
    source : dict
        Where the healthy data came from when they were recorded, not simulated
        (:mod:`~chatterspec.studies.recorded_calibration`: data file name and SHA-256, time span,
        samples, frames, records); empty for a simulated calibration.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    scenario: str
    model_name: str
    model_fingerprint: str
    dt: float
    n_samples: int
    stft: dict[str, Any]
    alpha: float
    runs: int
    seed: int | None
    confidence: float
    channels: tuple[str, ...]
    freqs_hz: np.ndarray
    tested: np.ndarray
    expected: np.ndarray
    analytic: dict[str, np.ndarray]
    per_bin: np.ndarray
    per_bin_low: np.ndarray
    per_bin_high: np.ndarray
    family_wise: tuple[QuantileEstimate, ...]
    family_wise_analytic: dict[str, float]
    frame_freqs_hz: np.ndarray
    frame_tested: np.ndarray
    frame_expected: np.ndarray
    frame_analytic: dict[str, np.ndarray]
    per_frame: np.ndarray
    per_frame_low: np.ndarray
    per_frame_high: np.ndarray
    frame_family_wise: tuple[QuantileEstimate, ...] = ()
    normalization: str = "analytic"
    normalization_info: dict[str, Any] = field(default_factory=dict)
    tails: dict[str, Any] = field(default_factory=dict)
    alarm: RuleCalibration | None = None
    source: dict[str, Any] = field(default_factory=dict)

    # ---- derived
    @property
    def exact_factor(self) -> np.ndarray:
        """Analytic exact per-bin factor ``chi2.isf(alpha, nu) / nu`` per bin and channel."""
        return self.analytic["exact"] / self.expected

    def agreement(self) -> dict[str, Any]:
        """Does the analytic exact threshold fall inside the empirical intervals?

        Returns per-bin coverage (fraction of tested bins/channels whose
        analytic factor lies in the empirical interval), the number of misses
        and the largest miss count consistent with intervals of level
        ``confidence`` (binomial 0.999 quantile, bins treated as independent),
        and the family-wise check per channel. Empty for an empirical normalization.
        """
        if self.normalization == "empirical":
            return {}
        t = self.tested
        f = self.exact_factor[t]
        inside = (self.per_bin_low[t] <= f) & (f <= self.per_bin_high[t])
        n = inside.size
        misses = int(n - np.count_nonzero(inside))
        allowed = int(scipy.stats.binom.ppf(0.999, n, 1 - self.confidence))
        fw = [q.contains(self.family_wise_analytic["sidak"]) for q in self.family_wise]
        ft = self.frame_tested
        ff = (self.frame_analytic["frame"] / self.frame_expected)[ft]
        f_in = (self.per_frame_low[ft] <= ff) & (ff <= self.per_frame_high[ft])
        return {
            "per_bin_coverage": float(np.mean(inside)),
            "per_bin_misses": misses,
            "per_bin_tests": n,
            "per_bin_misses_allowed": allowed,
            "per_bin_agrees": misses <= allowed,
            "per_bin_median_ratio": float(np.median(self.per_bin[t] / self.exact_factor[t])),
            "family_wise_agrees": fw,
            "per_frame_coverage": float(np.mean(f_in)),
            "per_frame_median_ratio": float(
                np.median(self.per_frame[ft] / (self.frame_analytic["frame"] / self.frame_expected)[ft])
            ),
        }

    # ---- use as a threshold
    def check(self, model: Model, n_samples: int | None = None, config: STFTConfig | None = None) -> None:
        """Raise :class:`CalibrationMismatchError` (with the reason) unless this calibration fits.

        Checks the model fingerprint (matrices, noise covariances, dt), the
        record length and the STFT settings.
        """
        if model.fingerprint() != self.model_fingerprint:
            raise CalibrationMismatchError(
                f"calibration was made for model {self.model_name!r} (fingerprint "
                f"{self.model_fingerprint[:12]}); the model in use ({model.name!r}, fingerprint "
                f"{model.fingerprint()[:12]}) differs in A, B, C, Q, R or dt -- recalibrate it"
            )
        if not math.isclose(model.dt, self.dt, rel_tol=1e-12):
            raise CalibrationMismatchError(f"calibration dt = {self.dt} s; the model has dt = {model.dt} s")
        if n_samples is not None and int(n_samples) != self.n_samples:
            raise CalibrationMismatchError(
                f"calibration is for records of N = {self.n_samples} samples; got N = {n_samples}"
            )
        if config is not None:
            want = _stft_dict(config)
            if want != self.stft:
                raise CalibrationMismatchError(f"calibration STFT settings {self.stft} differ from {want}")

    def threshold(
        self, meaning: Literal["per-bin", "family-wise", "per-frame", "frame-family-wise"] = "family-wise"
    ) -> Threshold:
        """The empirical threshold as a :class:`~.thresholds.Threshold` (``kind="empirical"``).

        Parameters
        ----------
        meaning : {"family-wise", "per-bin", "per-frame", "frame-family-wise"}
            ``family-wise``: ``E[S] * q_max`` (per channel) on the record
            periodogram; ``per-bin``: the per-bin quantiles; ``per-frame``: the
            pooled per-frame quantiles on STFT frames (per bin, not corrected);
            ``frame-family-wise``: ``E_frame * q_frame_max`` per channel, the
            live monitor's per-frame detector (``alpha_meaning="per-frame"``).
        """
        correction: Correction
        if meaning == "family-wise":
            factor = np.array([q.value for q in self.family_wise])
            values, freqs, tested, E = self.expected * factor, self.freqs_hz, self.tested, self.expected
            correction = "none"
        elif meaning == "per-bin":
            values, freqs, tested, E = self.expected * self.per_bin, self.freqs_hz, self.tested, self.expected
            correction = "none"
        elif meaning == "per-frame":
            values = self.frame_expected * self.per_frame
            freqs, tested, E = self.frame_freqs_hz, self.frame_tested, self.frame_expected
            correction = "none"
        elif meaning == "frame-family-wise":
            if not self.frame_family_wise:
                raise CalibrationMismatchError(
                    "this calibration has no per-frame family-wise quantile (made by an older "
                    "chatterspec): recalibrate it"
                )
            factor = np.array([q.value for q in self.frame_family_wise])
            values = self.frame_expected * factor
            freqs, tested, E = self.frame_freqs_hz, self.frame_tested, self.frame_expected
            correction = "none"
        else:
            raise ParameterError(
                f"meaning must be per-bin, family-wise, per-frame or frame-family-wise; got {meaning!r}"
            )
        dof = np.where(tested, 2, 1)
        return Threshold(
            values=_ro(values),
            freqs_hz=_ro(freqs),
            kind="empirical",
            alpha=self.alpha,
            alpha_meaning="per-frame" if meaning == "frame-family-wise" else meaning,
            correction=correction,
            tested=_ro(tested),
            dof=_ro(dof),
            averaged=1,
            per_test_alpha=self.alpha if meaning == "per-bin" else float("nan"),
            expected=_ro(E),
        )

    # ---- the file format (chatterspec.studies.calibration_file)
    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """JSON-ready summary; ``arrays=True`` adds every array (the calibration file content).

        See Also
        --------
        chatterspec.studies.calibration_file.calibration_dict : the same as a function.
        """
        return calibration_dict(self, arrays)

    def save(self, path: str | Path) -> Path:
        """Write the calibration file: ``.npz`` (arrays + JSON metadata) or JSON otherwise.

        See Also
        --------
        load_calibration : reads it back.
        """
        return save_calibration(self, path)


def _stft_dict(config: STFTConfig) -> dict[str, Any]:
    return {"window_s": float(config.window_s), "hop_s": float(config.hop_s), "window": str(config.window)}


def load_calibration(
    path: str | Path,
    model: Model | None = None,
    n_samples: int | None = None,
    config: STFTConfig | None = None,
) -> Calibration:
    """Read a calibration file written by :meth:`Calibration.save`.

    With ``model`` (and optionally ``n_samples``, ``config``) the calibration
    is checked against them (:meth:`Calibration.check`).

    Parameters
    ----------
    path : str or Path
        Calibration file: ``.npz`` (arrays plus JSON metadata), otherwise JSON.
    model : LinearModel, optional
        Model the calibration will be used with; its fingerprint must match.
    n_samples : int, optional
        Periodogram record length N (samples) it will be used with.
    config : STFTConfig, optional
        STFT settings (window and hop in seconds, taper) of the per-frame detector.

    Returns
    -------
    Calibration

    Raises
    ------
    DataFileError
        The file is missing or is not a chatterspec calibration.
    CalibrationMismatchError
        It was made for another model, record length or STFT setting.
    """
    cal = Calibration(**read_calibration(path))
    if model is not None:
        cal.check(model, n_samples, config)
    return cal
