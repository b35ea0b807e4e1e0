"""Threshold calibration, false-alarm statistics and detection power at Monte Carlo scale.

Three studies run on :mod:`chatterspec.montecarlo` (serial, local processes or
Dask, identical results for the same seed):

* :func:`calibrate` -- analytic thresholds (``paper``, ``exact`` per-bin,
  ``exact`` family-wise) beside empirical ones from healthy runs: per-bin and
  per-frame quantiles of the normalized power ``S / E[S]`` and the family-wise
  quantile of the maximum normalized bin, each with a distribution-free
  order-statistic confidence interval. The result saves to a calibration file
  (JSON or NPZ) that detection can load instead of the analytic threshold.
* :func:`false_alarm_study` -- per-bin, per-frame and family-wise false-alarm
  rates of every threshold kind with exact (Clopper-Pearson) intervals and a
  verdict against the nominal alpha.
* :func:`power_study` -- detection probability vs fault size and noise level
  for each threshold kind, and ROC curves (false-alarm vs detection rate as
  alpha varies).

Nothing here reimplements a periodogram or a threshold: spectra come from
:mod:`chatterspec.spectral`, thresholds from :mod:`chatterspec.thresholds`.

Statistics
----------
Clopper-Pearson interval for ``k`` events in ``n`` trials at confidence ``c``:
``[B^-1((1-c)/2; k, n-k+1), B^-1((1+c)/2; k+1, n-k)]`` (beta quantiles).
Order-statistic interval for the ``q``-quantile of ``n`` iid samples:
``[X_(l), X_(u)]`` with ``l = Binom^-1((1-c)/2; n, q)`` and
``u = Binom^-1((1+c)/2; n, q) + 1``; its coverage is at least ``c`` for any
continuous law. Pooling the bins of one record treats them as independent
trials; periodogram bins of the MA(1) chattering are nearly independent
(their correlation is O(1/N)). STFT frames that overlap are not: per-frame
quantile intervals count only the non-overlapping frames as independent
samples (approximate, conservative), and per-frame false-alarm intervals,
which pool overlapping frames, are approximate.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import scipy.stats

from ._validate import open_unit, positive_int, readonly
from .errors import CalibrationMismatchError, DataFileError, ParameterError
from .models import EHA_PARAMETERS, LinearModel, eha_linear, second_order
from .montecarlo import run_study
from .pipeline import iter_chattering
from .rng import SeedLike
from .scenarios import Scenario
from .scenarios import scenario as catalogue_scenario
from .signals import Chirp, Step
from .spectral import STFTConfig, expected_spectrum, periodogram, periodogram_freqs
from .spectral import spectrogram as stft_spectrogram
from .thresholds import Threshold, exact_threshold, frame_threshold, paper_threshold

__all__ = [
    "CALIBRATION_FORMAT",
    "POWER_FAMILIES",
    "Calibration",
    "FalseAlarmResult",
    "FalseAlarmStudy",
    "KindRates",
    "PowerResult",
    "QuantileEstimate",
    "RateEstimate",
    "calibrate",
    "clopper_pearson",
    "false_alarm_study",
    "load_calibration",
    "model_scenario",
    "power_scenario",
    "power_study",
    "quantile_ci_ranks",
    "resolve_scenario",
]

CALIBRATION_FORMAT = "chatterspec-calibration"
CALIBRATION_VERSION = 1

Verdict = Literal["consistent", "above", "below", "within", "exceeds"]


# --------------------------------------------------------------------------- statistics
def clopper_pearson(k: int, n: int, confidence: float = 0.99) -> tuple[float, float]:
    """Exact (Clopper-Pearson) interval for a binomial proportion ``k / n``.

    Parameters
    ----------
    k, n : int
        Events and trials (``0 <= k <= n``, ``n >= 1``).
    confidence : float
        Two-sided confidence level in (0, 1).

    Returns
    -------
    (low, high) : tuple of float
    """
    n = positive_int("n", n)
    confidence = open_unit("confidence", confidence)
    if not 0 <= k <= n:
        raise ParameterError(f"need 0 <= k <= n; got k={k}, n={n}")
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(scipy.stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(scipy.stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def quantile_ci_ranks(n: int, q: float, confidence: float = 0.99) -> tuple[int, int, int]:
    """1-based ascending ranks ``(point, low, high)`` of the order statistics for the ``q``-quantile.

    ``point = ceil(n q)`` (inverse empirical CDF); ``[X_(low), X_(high)]``
    covers the true quantile with probability >= ``confidence``. ``low = 0``
    or ``high = n + 1`` mean the interval is unbounded on that side (too few
    samples in the tail: the bound is -inf or +inf).
    """
    n = positive_int("n", n)
    a = 1.0 - open_unit("confidence", confidence)
    point = min(max(math.ceil(n * q), 1), n)
    lo = int(scipy.stats.binom.ppf(a / 2, n, q))
    hi = int(scipy.stats.binom.ppf(1 - a / 2, n, q)) + 1
    return point, min(max(lo, 0), n), min(max(hi, 1), n + 1)


def _pooled_ranks(n: int, n_eff: int, q: float, confidence: float) -> tuple[int, int, int]:
    """Ranks for ``n`` pooled, dependent samples worth ``n_eff`` independent ones.

    The interval ranks are computed for ``n_eff`` samples and rescaled to ``n``
    (the binomial spread of the count below the quantile is inflated by
    ``n / n_eff``); ``n_eff = n`` gives :func:`quantile_ci_ranks`.
    """
    point = min(max(math.ceil(n * q), 1), n)
    _, lo, hi = quantile_ci_ranks(n_eff, q, confidence)
    if n_eff == n:
        return point, lo, hi
    lo_n = 0 if lo == 0 else math.floor(n * (lo - 1) / n_eff) + 1
    hi_n = n + 1 if hi > n_eff else math.ceil(n * hi / n_eff)
    return point, min(max(lo_n, 0), n), min(max(hi_n, 1), n + 1)


def _top_needed(n: int, q: float, confidence: float, n_eff: int | None = None) -> int:
    """How many of the largest values must be kept to read the ``q``-quantile interval."""
    _, lo, _ = _pooled_ranks(n, n if n_eff is None else n_eff, q, confidence)
    return n - max(lo, 1) + 1


@dataclass(frozen=True)
class RateEstimate:
    """``count`` events in ``trials`` with a Clopper-Pearson interval.

    Attributes
    ----------
    count : int
        Number of events (e.g. false alarms), ``0 <= count <= trials``.
    trials : int
        Number of trials (>= 1): bins x channels x records, records, or frames.
    confidence : float
        Two-sided level in (0, 1) of the interval (see :func:`clopper_pearson`).
    rate : float
        ``count / trials`` (computed).
    ci_low, ci_high : float
        Clopper-Pearson interval of the rate (computed).
    """

    count: int
    trials: int
    confidence: float
    rate: float = field(init=False)
    ci_low: float = field(init=False)
    ci_high: float = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate", self.count / self.trials)
        lo, hi = clopper_pearson(self.count, self.trials, self.confidence)
        object.__setattr__(self, "ci_low", lo)
        object.__setattr__(self, "ci_high", hi)

    def contains(self, p: float) -> bool:
        return self.ci_low <= p <= self.ci_high

    def to_dict(self) -> dict[str, float | int]:
        return {
            "rate": self.rate,
            "ci_low": self.ci_low,
            "ci_high": self.ci_high,
            "count": self.count,
            "trials": self.trials,
        }


@dataclass(frozen=True)
class QuantileEstimate:
    """Empirical ``q``-quantile with a distribution-free order-statistic interval.

    Used for the empirical thresholds of :func:`calibrate`: quantiles of the
    normalized power ``S / E[S]`` (dimensionless) of healthy runs.

    Attributes
    ----------
    q : float
        Quantile level in (0, 1), e.g. ``1 - alpha``.
    value : float
        Point estimate, the order statistic of rank ``ceil(n q)``.
    ci_low, ci_high : float
        Order-statistic interval (ranks from :func:`quantile_ci_ranks`, or
        pooled ranks for dependent STFT frames); ``-inf`` / ``+inf`` when the
        tail holds too few samples to bound that side.
    n : int
        Number of samples the quantile was read from (records, or records x frames).
    confidence : float
        Coverage level in (0, 1) of the interval.
    """

    q: float
    value: float
    ci_low: float
    ci_high: float
    n: int
    confidence: float

    def contains(self, x: float) -> bool:
        return self.ci_low <= x <= self.ci_high

    def to_dict(self) -> dict[str, float | int | None]:
        """JSON-ready; an unbounded interval end (too few tail samples) is ``None``."""
        return {
            "q": self.q,
            "value": self.value,
            "ci_low": _finite_or_none(self.ci_low),
            "ci_high": _finite_or_none(self.ci_high),
            "n": self.n,
        }


def _finite_or_none(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def _none_to_inf(x: float | None, sign: float) -> float:
    return sign * np.inf if x is None else float(x)


def _quantile_from_top(
    top_desc: np.ndarray, n: int, q: float, confidence: float, n_eff: int | None = None
) -> tuple[np.ndarray, ...]:
    """Point and CI from the largest values sorted in descending order along axis 0."""
    point, lo, hi = _pooled_ranks(n, n if n_eff is None else n_eff, q, confidence)
    need = n - max(lo, 1) + 1
    if top_desc.shape[0] < need:
        raise ParameterError(f"kept {top_desc.shape[0]} tail values; the interval needs {need}")
    shape = top_desc.shape[1:]
    low = np.full(shape, -np.inf) if lo < 1 else top_desc[n - lo]
    high = np.full(shape, np.inf) if hi > n else top_desc[n - hi]
    return top_desc[n - point], low, high


# --------------------------------------------------------------------------- scenarios
@dataclass(frozen=True)
class _ZeroInput:
    """u(t) = 0 on ``channels`` inputs (healthy chattering of a matched linear model does not depend on u)."""

    channels: int = 1

    def sample(self, t: np.ndarray) -> np.ndarray:
        return np.zeros((np.size(t), self.channels))

    def describe(self) -> dict[str, object]:
        return {"kind": "zero", "channels": self.channels}


def model_scenario(model: LinearModel, duration: float = 4.0, name: str | None = None) -> Scenario:
    """A healthy scenario for a user model: zero input, the model as nominal and true plant.

    The input is zero on every channel: the healthy chattering of a matched
    linear model does not depend on u.

    Parameters
    ----------
    model : LinearModel
        Nominal model, also used as the true plant (no fault windows).
    duration : float
        Record length in seconds (default 4 s, the paper's record).
    name : str, optional
        Scenario name; default ``model.name``, or ``"user-model"`` if that is empty.

    Returns
    -------
    Scenario
        Family ``"user"``, healthy.
    """
    return Scenario(
        name=name or model.name or "user-model",
        nominal=model,
        input=_ZeroInput(model.n_inputs),
        duration=duration,
        description="user model, healthy, zero input",
        family="user",
    )


def resolve_scenario(source: str | Scenario | LinearModel | Path, duration: float = 4.0) -> Scenario:
    """A catalogue name, a TOML model file (``.toml``), a Scenario or a LinearModel -> Scenario.

    Parameters
    ----------
    source : str, Scenario, LinearModel or Path
        A :class:`Scenario` is returned unchanged; a :class:`LinearModel` or a
        path ending in ``.toml`` (read with :func:`~chatterspec.modelfile.load_model`)
        becomes a healthy zero-input scenario (:func:`model_scenario`, named
        after the file stem); any other string is looked up in the scenario catalogue.
    duration : float
        Record length in seconds for model and model-file sources; ignored for
        catalogue names and Scenario objects, which carry their own duration.

    Returns
    -------
    Scenario

    Raises
    ------
    UnknownScenarioError
        A string that is neither a ``.toml`` path nor a catalogue name.
    """
    if isinstance(source, Scenario):
        return source
    if isinstance(source, LinearModel):
        return model_scenario(source, duration)
    text = str(source)
    if text.endswith(".toml"):
        from .modelfile import load_model

        spec = load_model(text)
        return model_scenario(spec.model, duration, name=Path(text).stem)
    return catalogue_scenario(text)


# --------------------------------------------------------------------------- summaries
def _merge_top(a: np.ndarray, b: np.ndarray, k: int) -> np.ndarray:
    both = np.concatenate([a, b], axis=0)
    if both.shape[0] <= k:
        return both
    return np.partition(both, both.shape[0] - k, axis=0)[both.shape[0] - k :]


def _reduce_dict(acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray], k_top: dict[str, int]):
    if acc is None:
        return dict(part)
    out = {}
    for key, val in part.items():
        if key.startswith("top_"):
            out[key] = _merge_top(acc[key], val, k_top[key])
        elif key.startswith("runs_"):
            out[key] = np.concatenate([acc[key], val], axis=0)
        else:
            out[key] = acc[key] + val
    return out


def _keep_top(x: np.ndarray, k: int) -> np.ndarray:
    """The ``k`` largest values along axis 0 (unsorted)."""
    if k <= 0:
        return x[:0]
    if x.shape[0] <= k:
        return x
    return np.partition(x, x.shape[0] - k, axis=0)[x.shape[0] - k :]


@dataclass(frozen=True, eq=False)
class HealthyStudy:
    """Chunk function of calibration and false-alarm studies (picklable; see :mod:`chatterspec.montecarlo`).

    Thresholds are passed as stacked arrays so that workers do not rebuild them.
    Each chunk simulates healthy chattering, takes its periodogram (and STFT
    frames if ``config`` and ``fthr_values`` are set) and counts exceedances.
    Exported as ``FalseAlarmStudy``.

    Attributes
    ----------
    scenario : Scenario
        Healthy scenario to simulate.
    thr_values : (K, bins, m) array
        Power thresholds of the K record-level kinds, in the squared output
        units of the periodogram (e.g. Pa^2 for pressure).
    thr_tested : (K, bins) bool array
        Bins each kind tests (DC and Nyquist excluded).
    expected : (bins, m) array
        Expected healthy periodogram E[S] (eq 56), used to normalize ``S / E[S]``.
    tested : (bins,) bool array
        Bins over which the normalized per-record maximum is taken.
    config : STFTConfig, optional
        STFT settings of the per-frame kinds; None skips the frame statistics.
    fthr_values : (Kf, fbins, m) array, optional
        Per-frame thresholds of the Kf frame kinds.
    fthr_tested : (Kf, fbins) bool array, optional
        Frame bins each frame kind tests.
    fexpected : (fbins, m) array, optional
        Expected healthy frame spectrum; needed only when ``kf_top > 0``.
    k_top : int
        Largest normalized bin powers to keep (for the empirical per-bin
        quantile interval); 0 keeps none.
    kf_top : int
        Largest normalized frame powers to keep (empirical per-frame quantile).
    keep_max : bool
        Keep each record's normalized maximum over ``tested`` bins (for the
        empirical family-wise threshold).
    """

    scenario: Scenario
    thr_values: np.ndarray  # (K, bins, m)
    thr_tested: np.ndarray  # (K, bins)
    expected: np.ndarray  # (bins, m)
    tested: np.ndarray  # (bins,) bins of the normalized maximum
    config: STFTConfig | None = None
    fthr_values: np.ndarray | None = None  # (Kf, fbins, m)
    fthr_tested: np.ndarray | None = None  # (Kf, fbins)
    fexpected: np.ndarray | None = None  # (fbins, m)
    k_top: int = 0
    kf_top: int = 0
    keep_max: bool = False

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        acc = None
        for rec in iter_chattering(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run):
            acc = self.reduce(acc, self._summarize(rec.values, rec.dt))
        return acc

    def _summarize(self, x: np.ndarray, dt: float) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {"runs": np.array(x.shape[0])}
        S = periodogram(x, dt).power  # (r, bins, m)
        exc = S[None] > self.thr_values[:, None]  # (K, r, bins, m)
        out["bin_exceed"] = exc.sum(axis=1)
        masked = exc & self.thr_tested[:, None, :, None]
        n_false = masked.sum(axis=2)  # (K, r, m)
        out["false_bins"] = n_false.sum(axis=1)
        out["false_bins_sq"] = (n_false.astype(np.int64) ** 2).sum(axis=1)
        fw = n_false > 0
        out["fw"] = fw.sum(axis=1)  # (K, m)
        out["fw_any"] = fw.any(axis=-1).sum(axis=1)  # (K,)
        Y = S / self.expected
        if self.keep_max:
            out["runs_max"] = Y[:, self.tested].max(axis=1)  # (r, m)
        if self.k_top:
            out["top_bin"] = _keep_top(Y, self.k_top)
        if self.config is not None and self.fthr_values is not None:
            P = stft_spectrogram(x, dt, self.config).power  # (r, F, fb, m)
            out["frames"] = np.array(P.shape[0] * P.shape[1])
            fexc = P[None] > self.fthr_values[:, None, None]  # (Kf, r, F, fb, m)
            out["frame_bin_exceed"] = fexc.sum(axis=(1, 2))  # (Kf, fb, m)
            flags = (fexc & self.fthr_tested[:, None, None, :, None]).any(axis=3)  # (Kf, r, F, m)
            out["frame_flag"] = flags.sum(axis=(1, 2))  # (Kf, m)
            out["frame_flag_any"] = flags.any(axis=-1).sum(axis=(1, 2))  # (Kf,)
            if self.kf_top:
                Yf = (P / self.fexpected).reshape(-1, *P.shape[-2:])
                out["top_frame"] = _keep_top(Yf, self.kf_top)
                if self.keep_max:  # per frame: the largest normalized tested bin (frame family-wise)
                    out["top_frame_max"] = _keep_top(Yf[:, self.fthr_tested[0]].max(axis=1), self.kf_top)
        return out

    def reduce(self, acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return _reduce_dict(
            acc, part, {"top_bin": self.k_top, "top_frame": self.kf_top, "top_frame_max": self.kf_top}
        )


def _analytic_thresholds(
    model: LinearModel, n_samples: int, alpha: float
) -> tuple[np.ndarray, dict[str, Threshold]]:
    freqs = periodogram_freqs(n_samples, model.dt)
    return freqs, {
        "paper": paper_threshold(model, freqs, alpha),
        "exact": exact_threshold(model, freqs, n_samples, alpha, correction="none"),
        "exact-bonferroni": exact_threshold(model, freqs, n_samples, alpha, correction="bonferroni"),
        "exact-sidak": exact_threshold(model, freqs, n_samples, alpha, correction="sidak"),
    }


def _frame_thresholds(
    model: LinearModel, config: STFTConfig, alpha: float
) -> tuple[np.ndarray, dict[str, Threshold]]:
    freqs = config.freqs_hz(model.dt)
    return freqs, {
        "frame": frame_threshold(model, freqs, config, model.dt, alpha, correction="none"),
        "frame-bonferroni": frame_threshold(model, freqs, config, model.dt, alpha, correction="bonferroni"),
    }


def _check_alphas(alpha: float | Sequence[float]) -> tuple[float, ...]:
    alphas = (alpha,) if np.isscalar(alpha) else tuple(alpha)
    if not alphas:
        raise ParameterError("alpha: give at least one value")
    return tuple(open_unit("alpha", a) for a in alphas)


def _n_frames(n_samples: int, config: STFTConfig, dt: float) -> int:
    W, H = config.n_window(dt), config.n_hop(dt)
    return max(0, (n_samples - W) // H + 1)


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
    """

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
        and the family-wise check per channel.
        """
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
    def check(
        self, model: LinearModel, n_samples: int | None = None, config: STFTConfig | None = None
    ) -> None:
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
        """The empirical threshold as a :class:`chatterspec.thresholds.Threshold` (``kind="empirical"``).

        Parameters
        ----------
        meaning : {"family-wise", "per-bin", "per-frame", "frame-family-wise"}
            ``family-wise``: ``E[S] * q_max`` (per channel) on the record
            periodogram; ``per-bin``: the per-bin quantiles; ``per-frame``: the
            pooled per-frame quantiles on STFT frames (per bin, not corrected);
            ``frame-family-wise``: ``E_frame * q_frame_max`` per channel, the
            live monitor's per-frame detector (``alpha_meaning="per-frame"``).
        """
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

    # ---- serialization
    def to_dict(self, arrays: bool = False) -> dict[str, Any]:
        """JSON-ready summary; ``arrays=True`` adds every array (the calibration file content)."""
        ag = self.agreement()
        t = self.tested
        d: dict[str, Any] = {
            "format": CALIBRATION_FORMAT,
            "version": CALIBRATION_VERSION,
            "scenario": self.scenario,
            "model_name": self.model_name,
            "model_fingerprint": self.model_fingerprint,
            "dt": self.dt,
            "n_samples": self.n_samples,
            "stft": self.stft,
            "alpha": self.alpha,
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "channels": list(self.channels),
            "analytic_factor": {
                "exact_per_bin": float(np.median(self.exact_factor[t])),
                "family_wise_bonferroni": self.family_wise_analytic["bonferroni"],
                "family_wise_sidak": self.family_wise_analytic["sidak"],
                "paper_over_expected_min_max": [
                    float(np.min(self.analytic["paper"][t] / self.expected[t])),
                    float(np.max(self.analytic["paper"][t] / self.expected[t])),
                ],
            },
            "empirical": {
                "per_bin_factor_median": [float(v) for v in np.median(self.per_bin[t], axis=0)],
                "per_frame_factor_median": [
                    float(v) for v in np.median(self.per_frame[self.frame_tested], axis=0)
                ],
                "family_wise": [q.to_dict() for q in self.family_wise],
                "frame_family_wise": [q.to_dict() for q in self.frame_family_wise],
            },
            "agreement": ag,
        }
        if arrays:
            d["arrays"] = {k: np.where(np.isfinite(v), v, None).tolist() for k, v in self._arrays().items()}
        return d

    def _arrays(self) -> dict[str, np.ndarray]:
        a = {
            "freqs_hz": self.freqs_hz,
            "tested": self.tested.astype(np.int8),
            "expected": self.expected,
            "per_bin": self.per_bin,
            "per_bin_low": self.per_bin_low,
            "per_bin_high": self.per_bin_high,
            "frame_freqs_hz": self.frame_freqs_hz,
            "frame_tested": self.frame_tested.astype(np.int8),
            "frame_expected": self.frame_expected,
            "per_frame": self.per_frame,
            "per_frame_low": self.per_frame_low,
            "per_frame_high": self.per_frame_high,
        }
        a.update({f"analytic:{k}": v for k, v in self.analytic.items()})
        a.update({f"frame_analytic:{k}": v for k, v in self.frame_analytic.items()})
        return a

    def save(self, path: str | Path) -> Path:
        """Write the calibration file: ``.npz`` (arrays + JSON metadata) or JSON otherwise."""
        path = Path(path)
        meta = self.to_dict(arrays=False)
        meta.pop("agreement", None)
        meta["family_wise"] = [q.to_dict() for q in self.family_wise]
        meta["frame_family_wise"] = [q.to_dict() for q in self.frame_family_wise]
        meta["family_wise_analytic"] = self.family_wise_analytic
        if path.suffix == ".npz":
            np.savez(path, _meta=np.array(json.dumps(meta)), **self._arrays())
        else:
            meta["arrays"] = {
                k: np.where(np.isfinite(v), v, None).tolist() for k, v in self._arrays().items()
            }
            path.write_text(json.dumps(meta))
        return path


def _ro(a: np.ndarray) -> np.ndarray:
    return readonly(np.array(a))  # a copy: the caller's arrays stay writable


def _stft_dict(config: STFTConfig) -> dict[str, Any]:
    return {"window_s": float(config.window_s), "hop_s": float(config.hop_s), "window": str(config.window)}


def _json_array(key: str, value: object) -> np.ndarray:
    a = np.asarray(value, dtype=object)
    sign = -1.0 if key.endswith("_low") else 1.0
    return np.where(a == None, sign * np.inf, a).astype(float)  # noqa: E711


def load_calibration(
    path: str | Path,
    model: LinearModel | None = None,
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
    path = Path(path)
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(str(z["_meta"]))
                arrays = {k: np.array(z[k]) for k in z.files if k != "_meta"}
        else:
            meta = json.loads(path.read_text())
            arrays = {k: _json_array(k, v) for k, v in meta.pop("arrays").items()}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataFileError(f"{path}: cannot read calibration file ({type(exc).__name__}: {exc})") from None
    if meta.get("format") != CALIBRATION_FORMAT:
        raise DataFileError(f"{path}: not a chatterspec calibration file (format {meta.get('format')!r})")
    if meta.get("version") != CALIBRATION_VERSION:
        raise DataFileError(f"{path}: calibration file version {meta.get('version')} is not supported")
    conf = float(meta["confidence"])

    def quantiles(key: str) -> tuple[QuantileEstimate, ...]:
        return tuple(
            QuantileEstimate(
                q["q"], q["value"], _none_to_inf(q["ci_low"], -1), _none_to_inf(q["ci_high"], 1), q["n"], conf
            )
            for q in meta.get(key, ())
        )

    fw = quantiles("family_wise")
    cal = Calibration(
        scenario=meta["scenario"],
        model_name=meta["model_name"],
        model_fingerprint=meta["model_fingerprint"],
        dt=float(meta["dt"]),
        n_samples=int(meta["n_samples"]),
        stft=dict(meta["stft"]),
        alpha=float(meta["alpha"]),
        runs=int(meta["runs"]),
        seed=meta["seed"],
        confidence=conf,
        channels=tuple(meta["channels"]),
        freqs_hz=_ro(arrays["freqs_hz"].astype(float)),
        tested=_ro(arrays["tested"].astype(bool)),
        expected=_ro(arrays["expected"].astype(float)),
        analytic={
            k.split(":", 1)[1]: _ro(v.astype(float)) for k, v in arrays.items() if k.startswith("analytic:")
        },
        per_bin=_ro(arrays["per_bin"].astype(float)),
        per_bin_low=_ro(arrays["per_bin_low"].astype(float)),
        per_bin_high=_ro(arrays["per_bin_high"].astype(float)),
        family_wise=fw,
        family_wise_analytic={k: float(v) for k, v in meta["family_wise_analytic"].items()},
        frame_freqs_hz=_ro(arrays["frame_freqs_hz"].astype(float)),
        frame_tested=_ro(arrays["frame_tested"].astype(bool)),
        frame_expected=_ro(arrays["frame_expected"].astype(float)),
        frame_analytic={
            k.split(":", 1)[1]: _ro(v.astype(float))
            for k, v in arrays.items()
            if k.startswith("frame_analytic:")
        },
        per_frame=_ro(arrays["per_frame"].astype(float)),
        per_frame_low=_ro(arrays["per_frame_low"].astype(float)),
        per_frame_high=_ro(arrays["per_frame_high"].astype(float)),
        frame_family_wise=quantiles("frame_family_wise"),
    )
    if model is not None:
        cal.check(model, n_samples, config)
    return cal


def calibrate(
    source: str | Scenario | LinearModel | Path,
    alpha: float = 1e-2,
    runs: int = 1000,
    seed: SeedLike = 0,
    *,
    config: STFTConfig | None = None,
    confidence: float = 0.99,
    workers: int = 1,
    scheduler: str | None = None,
    chunk_runs: int | None = None,
    progress: bool | None = None,
) -> Calibration:
    """Calibrate thresholds on healthy Monte Carlo runs and compare them with the analytic ones.

    Parameters
    ----------
    source : str, Scenario, LinearModel or path
        A healthy catalogue scenario name, a scenario, a user model or a TOML model file.
    alpha : float
        False-alarm probability in (0, 1) (per bin, per frame or family-wise, by threshold).
    runs : int
        Healthy realizations (>= 1). The family-wise quantile needs ``runs * alpha``
        well above 1 to be informative.
    seed : int
        Root seed (identical results whatever ``workers``/``scheduler``).
    config : STFTConfig, optional
        STFT settings of the per-frame calibration (default 1 s Hamming, 0.2 s hop).
    confidence : float
        Level of the order-statistic intervals.
    workers, scheduler, chunk_runs, progress
        Execution (see :func:`chatterspec.montecarlo.run_study`).

    Returns
    -------
    Calibration

    Raises
    ------
    ParameterError
        alpha outside (0, 1), runs < 1, or a scenario that is not healthy.
    """
    alpha = open_unit("alpha", alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    sc = resolve_scenario(source)
    if not sc.is_healthy:
        raise ParameterError(
            f"calibrate needs a healthy scenario; {sc.name!r} has faults at {sc.fault_intervals}"
        )
    config = STFTConfig() if config is None else config
    model = sc.nominal
    N = sc.n_samples - 1
    freqs, thr = _analytic_thresholds(model, N, alpha)
    ffreqs, fthr = _frame_thresholds(model, config, alpha)
    E = thr["exact"].expected
    Ef = fthr["frame"].expected
    n_frames = _n_frames(N, config, model.dt)
    if n_frames < 1:
        raise ParameterError(f"records of {N} samples are shorter than one STFT window")
    k_top = _top_needed(runs, 1 - alpha, confidence)
    # overlapping frames are dependent: count only non-overlapping ones as independent samples
    frames_eff = max(1, (N - config.n_window(model.dt)) // config.n_window(model.dt) + 1)
    kf_top = _top_needed(runs * n_frames, 1 - alpha, confidence, runs * frames_eff)
    study = HealthyStudy(
        scenario=sc,
        thr_values=np.stack([t.values for t in thr.values()]),
        thr_tested=np.stack([t.tested for t in thr.values()]),
        expected=E,
        tested=thr["exact"].tested,
        config=config,
        fthr_values=np.stack([t.values for t in fthr.values()]),
        fthr_tested=np.stack([t.tested for t in fthr.values()]),
        fexpected=Ef,
        k_top=k_top,
        kf_top=kf_top,
        keep_max=True,
    )
    out = run_study(
        study,
        runs,
        seed,
        workers=workers,
        scheduler=scheduler,
        chunk_runs=chunk_runs,
        progress=progress,
        label=f"calibrate {sc.name}",
    )
    q = 1 - alpha
    top = -np.sort(-out["top_bin"], axis=0)
    pb, pb_lo, pb_hi = _quantile_from_top(top, runs, q, confidence)
    topf = -np.sort(-out["top_frame"], axis=0)
    pf, pf_lo, pf_hi = _quantile_from_top(topf, runs * n_frames, q, confidence, runs * frames_eff)
    mx = -np.sort(-out["runs_max"], axis=0)
    mv, mlo, mhi = _quantile_from_top(mx, runs, q, confidence)
    fmx = -np.sort(-out["top_frame_max"], axis=0)
    fv, flo, fhi = _quantile_from_top(fmx, runs * n_frames, q, confidence, runs * frames_eff)
    n_tested = thr["exact"].n_tested
    fw = tuple(
        QuantileEstimate(q, float(mv[c]), float(mlo[c]), float(mhi[c]), runs, confidence)
        for c in range(E.shape[1])
    )
    return Calibration(
        scenario=sc.name,
        model_name=model.name,
        model_fingerprint=model.fingerprint(),
        dt=model.dt,
        n_samples=N,
        stft=_stft_dict(config),
        alpha=alpha,
        runs=runs,
        seed=int(seed) if isinstance(seed, int | np.integer) else None,
        confidence=confidence,
        channels=tuple(model.output_names),
        freqs_hz=_ro(freqs),
        tested=_ro(thr["exact"].tested),
        expected=_ro(E),
        analytic={k: _ro(t.values) for k, t in thr.items()},
        per_bin=_ro(pb),
        per_bin_low=_ro(pb_lo),
        per_bin_high=_ro(pb_hi),
        family_wise=fw,
        family_wise_analytic={
            "bonferroni": float(scipy.stats.chi2.isf(thr["exact-bonferroni"].per_test_alpha, 2) / 2),
            "sidak": float(scipy.stats.chi2.isf(thr["exact-sidak"].per_test_alpha, 2) / 2),
            "n_tested": n_tested,
        },
        frame_freqs_hz=_ro(ffreqs),
        frame_tested=_ro(fthr["frame"].tested),
        frame_expected=_ro(Ef),
        frame_analytic={k: _ro(t.values) for k, t in fthr.items()},
        per_frame=_ro(pf),
        per_frame_low=_ro(pf_lo),
        per_frame_high=_ro(pf_hi),
        frame_family_wise=tuple(
            QuantileEstimate(q, float(fv[c]), float(flo[c]), float(fhi[c]), runs * n_frames, confidence)
            for c in range(E.shape[1])
        ),
    )


# --------------------------------------------------------------------------- false alarms
@dataclass(frozen=True)
class KindRates:
    """False-alarm statistics of one threshold kind at one alpha.

    Attributes
    ----------
    kind : str
        ``paper``, ``exact`` (per-bin), ``exact-bonferroni`` (the default
        detector), ``exact-sidak``, ``empirical-*`` (from a calibration file),
        ``frame`` (per-bin on STFT frames) or ``frame-bonferroni`` (the STFT detector).
    alpha : float
    alpha_meaning : str
        ``per-bin``, ``family-wise`` or ``per-frame``.
    nominal_per_bin : float
        Per-bin level the threshold aims at (alpha, or alpha / n for Bonferroni).
    per_bin : RateEstimate
        Exceedances over tested bins x channels x records (or x frames).
    per_bin_by_channel : tuple of RateEstimate
    family_wise : tuple of RateEstimate or None
        Per channel, records with any tested bin above (record kinds only).
    family_wise_any : RateEstimate or None
        Records with any channel above.
    per_frame : tuple of RateEstimate or None
        Per channel, frames with any tested bin above (frame kinds only).
    per_frame_any : RateEstimate or None
    mean_false_bins : tuple of float
        Mean number of false-alarm bins per record (or frame) and channel.
    verdict : str
        For per-bin kinds ``consistent`` if nominal_per_bin lies in the per-bin
        interval, else ``above``/``below``; for family-wise and per-frame kinds
        ``within`` if the interval's lower end is <= alpha, else ``exceeds``.
    rate_vs_freq : (bins, m) array
        Per-bin exceedance rate per frequency (the plot of per-bin rate vs frequency).
    freqs_hz : (bins,) array
    """

    kind: str
    alpha: float
    alpha_meaning: str
    nominal_per_bin: float
    per_bin: RateEstimate
    per_bin_by_channel: tuple[RateEstimate, ...]
    family_wise: tuple[RateEstimate, ...] | None
    family_wise_any: RateEstimate | None
    per_frame: tuple[RateEstimate, ...] | None
    per_frame_any: RateEstimate | None
    mean_false_bins: tuple[float, ...]
    verdict: str
    rate_vs_freq: np.ndarray = field(repr=False, compare=False)
    freqs_hz: np.ndarray = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "kind": self.kind,
            "alpha": self.alpha,
            "alpha_meaning": self.alpha_meaning,
            "nominal_per_bin": self.nominal_per_bin,
            "per_bin": self.per_bin.to_dict(),
            "per_bin_by_channel": [r.to_dict() for r in self.per_bin_by_channel],
            "mean_false_bins_per_record": list(self.mean_false_bins),
            "verdict": self.verdict,
        }
        if self.family_wise is not None:
            d["family_wise"] = [r.to_dict() for r in self.family_wise]
            d["family_wise_any_channel"] = self.family_wise_any.to_dict() if self.family_wise_any else None
        if self.per_frame is not None:
            d["per_frame"] = [r.to_dict() for r in self.per_frame]
            d["per_frame_any_channel"] = self.per_frame_any.to_dict() if self.per_frame_any else None
        return d


@dataclass(frozen=True)
class FalseAlarmResult:
    """Result of :func:`false_alarm_study`: one :class:`KindRates` per (alpha, kind).

    Attributes
    ----------
    scenario : str
        Name of the healthy scenario simulated.
    runs : int
        Healthy realizations (records).
    seed : int or None
        Root seed if it was an integer, else None.
    confidence : float
        Level of every Clopper-Pearson interval.
    channels : tuple of str
        Output channel names (order of the per-channel rates).
    n_frames : int
        STFT frames per record (0 when frames were not tested).
    rates : tuple of KindRates
        One entry per (alpha, threshold kind), alphas in the order given.
    """

    scenario: str
    runs: int
    seed: int | None
    confidence: float
    channels: tuple[str, ...]
    n_frames: int
    rates: tuple[KindRates, ...]

    def get(self, kind: str, alpha: float | None = None) -> KindRates:
        """The rates of ``kind`` (at ``alpha``, default the first alpha)."""
        for r in self.rates:
            if r.kind == kind and (alpha is None or math.isclose(r.alpha, alpha)):
                return r
        raise ParameterError(f"no rates for kind {kind!r} at alpha {alpha}; have {self.kinds}")

    @property
    def kinds(self) -> tuple[str, ...]:
        return tuple(dict.fromkeys(r.kind for r in self.rates))

    def to_dict(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "channels": list(self.channels),
            "frames_per_record": self.n_frames,
            "rates": [r.to_dict() for r in self.rates],
        }


FalseAlarmStudy = HealthyStudy


def _verdict(meaning: str, nominal: float, alpha: float, est: RateEstimate) -> str:
    if meaning == "per-bin":
        if est.contains(nominal):
            return "consistent"
        return "above" if est.ci_low > nominal else "below"
    return "within" if est.ci_low <= alpha else "exceeds"


def false_alarm_study(
    source: str | Scenario | LinearModel | Path,
    alpha: float | Sequence[float] = 1e-2,
    runs: int = 1000,
    seed: SeedLike = 0,
    *,
    calibration: Calibration | None = None,
    config: STFTConfig | None = None,
    frames: bool = True,
    confidence: float = 0.99,
    workers: int = 1,
    scheduler: str | None = None,
    chunk_runs: int | None = None,
    progress: bool | None = None,
) -> FalseAlarmResult:
    """False-alarm rates of every threshold kind on healthy runs, with Clopper-Pearson intervals.

    Parameters
    ----------
    source : str, Scenario, LinearModel or path
        Healthy scenario (name), scenario, user model or TOML model file.
    alpha : float or sequence of float
        Nominal level(s) in (0, 1); all share the same simulated runs.
    runs : int
        Healthy realizations (>= 1).
    seed : int
        Root seed.
    calibration : Calibration, optional
        Adds ``empirical-per-bin`` and ``empirical-family-wise`` kinds (its own
        alpha); checked against the model (:class:`CalibrationMismatchError`).
        Use a calibration made with another seed, or the rates are optimistic.
    config : STFTConfig, optional
        STFT settings of the per-frame kinds.
    frames : bool
        Also test the STFT detector (per-frame rates).
    confidence : float
        Level of the Clopper-Pearson intervals.
    workers, scheduler, chunk_runs, progress
        Execution (see :func:`chatterspec.montecarlo.run_study`).

    Returns
    -------
    FalseAlarmResult
    """
    alphas = _check_alphas(alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    sc = resolve_scenario(source)
    if not sc.is_healthy:
        raise ParameterError(f"false-alarm study needs a healthy scenario; {sc.name!r} has faults")
    model = sc.nominal
    N = sc.n_samples - 1
    config = STFTConfig() if config is None else config
    kinds: list[tuple[str, float, Threshold]] = []
    fkinds: list[tuple[str, float, Threshold]] = []
    freqs = periodogram_freqs(N, model.dt)
    for a in alphas:
        _, thr = _analytic_thresholds(model, N, a)
        kinds += [(k, a, t) for k, t in thr.items()]
        if frames:
            _, fthr = _frame_thresholds(model, config, a)
            fkinds += [(k, a, t) for k, t in fthr.items()]
    if calibration is not None:
        calibration.check(model, N, config if frames else None)
        for meaning in ("per-bin", "family-wise"):
            kinds.append((f"empirical-{meaning}", calibration.alpha, calibration.threshold(meaning)))
        if frames:
            fkinds.append(("empirical-per-frame", calibration.alpha, calibration.threshold("per-frame")))
    E = expected_spectrum(model, freqs, N, form="exact")
    n_frames = _n_frames(N, config, model.dt) if frames else 0
    if frames and n_frames < 1:
        raise ParameterError(f"records of {N} samples are shorter than one STFT window; pass frames=False")
    study = HealthyStudy(
        scenario=sc,
        thr_values=np.stack([t.values for _, _, t in kinds]),
        thr_tested=np.stack([t.tested for _, _, t in kinds]),
        expected=E,
        tested=kinds[1][2].tested,
        config=config if frames else None,
        fthr_values=np.stack([t.values for _, _, t in fkinds]) if frames else None,
        fthr_tested=np.stack([t.tested for _, _, t in fkinds]) if frames else None,
        fexpected=None,
    )
    out = run_study(
        study,
        runs,
        seed,
        workers=workers,
        scheduler=scheduler,
        chunk_runs=chunk_runs,
        progress=progress,
        label=f"far {sc.name}",
    )
    m = model.n_outputs
    rates: list[KindRates] = []
    for i, (name, a, t) in enumerate(kinds):
        tested = t.tested
        nt = int(np.count_nonzero(tested))
        counts = out["bin_exceed"][i]  # (bins, m)
        per_ch = tuple(RateEstimate(int(counts[tested, c].sum()), runs * nt, confidence) for c in range(m))
        pooled = RateEstimate(int(counts[tested].sum()), runs * nt * m, confidence)
        meaning = t.alpha_meaning
        nominal = t.per_test_alpha if np.isfinite(t.per_test_alpha) else a
        fw = tuple(RateEstimate(int(out["fw"][i, c]), runs, confidence) for c in range(m))
        fw_any = RateEstimate(int(out["fw_any"][i]), runs, confidence)
        ref = pooled if meaning == "per-bin" else _worst(fw)
        rates.append(
            KindRates(
                kind=name,
                alpha=a,
                alpha_meaning=meaning,
                nominal_per_bin=float(nominal),
                per_bin=pooled,
                per_bin_by_channel=per_ch,
                family_wise=fw,
                family_wise_any=fw_any,
                per_frame=None,
                per_frame_any=None,
                mean_false_bins=tuple(float(v) / runs for v in out["false_bins"][i]),
                verdict=_verdict(meaning, nominal, a, ref),
                rate_vs_freq=_ro(counts / runs),
                freqs_hz=_ro(t.freqs_hz),
            )
        )
    n_fr = runs * n_frames
    for i, (name, a, t) in enumerate(fkinds):
        tested = t.tested
        nt = int(np.count_nonzero(tested))
        counts = out["frame_bin_exceed"][i]
        per_ch = tuple(RateEstimate(int(counts[tested, c].sum()), n_fr * nt, confidence) for c in range(m))
        pooled = RateEstimate(int(counts[tested].sum()), n_fr * nt * m, confidence)
        pf = tuple(RateEstimate(int(out["frame_flag"][i, c]), n_fr, confidence) for c in range(m))
        pf_any = RateEstimate(int(out["frame_flag_any"][i]), n_fr, confidence)
        meaning = t.alpha_meaning
        nominal = t.per_test_alpha if np.isfinite(t.per_test_alpha) else a
        ref = pooled if meaning == "per-bin" else _worst(pf)
        rates.append(
            KindRates(
                kind=name,
                alpha=a,
                alpha_meaning=meaning,
                nominal_per_bin=float(nominal),
                per_bin=pooled,
                per_bin_by_channel=per_ch,
                family_wise=None,
                family_wise_any=None,
                per_frame=pf,
                per_frame_any=pf_any,
                mean_false_bins=tuple(float(counts[tested, c].sum()) / n_fr for c in range(m)),
                verdict=_verdict(meaning, nominal, a, ref),
                rate_vs_freq=_ro(counts / n_fr),
                freqs_hz=_ro(t.freqs_hz),
            )
        )
    return FalseAlarmResult(
        scenario=sc.name,
        runs=runs,
        seed=int(seed) if isinstance(seed, int | np.integer) else None,
        confidence=confidence,
        channels=tuple(model.output_names),
        n_frames=n_frames,
        rates=tuple(rates),
    )


def _worst(ests: Iterable[RateEstimate]) -> RateEstimate:
    return max(ests, key=lambda r: r.ci_low)


# --------------------------------------------------------------------------- power
#: Fault families of :func:`power_study`: default sizes (first = healthy), noise levels (R multipliers),
#: the fault channel and the unit of the size.
POWER_FAMILIES: dict[str, dict[str, Any]] = {
    "leakage": {
        "sizes": (EHA_PARAMETERS["leakage"], 1e-11, 2e-11, 3e-11, 6e-11, 9e-11),
        "noise": (1.0, 10.0),
        "channel": "pressure",
        "unit": "m^3/(s Pa)",
    },
    "bulk-modulus": {
        "sizes": (1.0, 0.95, 0.9, 0.75, 0.5),
        "noise": (1.0, 10.0),
        "channel": "pressure",
        "unit": "x nominal",
    },
    "friction": {
        "sizes": (EHA_PARAMETERS["friction"], 3000.0, 4000.0, 7000.0),
        "noise": (1.0, 10.0),
        "channel": "velocity",
        "unit": "N s/m",
    },
    "f0": {
        "sizes": (10.0, 10.25, 10.5, 11.0, 12.0),
        "noise": (1.0, 100.0),
        "channel": "velocity",
        "unit": "Hz (true f0, nominal 10 Hz)",
    },
}

_SO_Q = np.diag([1e-8, 1e-6])
_SO_R = np.diag([1e-8, 1e-6])


def power_scenario(family: str, size: float, noise: float = 1.0) -> Scenario:
    """The scenario of one point of a power sweep.

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
    size : float
        Leakage coefficient, bulk-modulus factor, friction coefficient or true f0 (Hz).
    noise : float
        Multiplier of the measurement noise covariance R (nominal and true plant):
        EHA ``R = noise * diag(1e-6, 1e-6, 1e6)``; second order ``noise * diag(1e-8, 1e-6)``
        (100 = the catalogue's "high" noise).
    """
    if family not in POWER_FAMILIES:
        raise ParameterError(f"unknown fault family {family!r}; valid: {', '.join(POWER_FAMILIES)}")
    size, noise = float(size), float(noise)
    if not (np.isfinite(size) and size > 0 and np.isfinite(noise) and noise > 0):
        raise ParameterError(f"fault size and noise level must be finite and > 0; got {size}, {noise}")
    if family == "f0":
        R = noise * _SO_R
        nominal = second_order(10.0, 0.1, Q=_SO_Q, R=R)
        plant = second_order(size, 0.1, Q=_SO_Q, R=R)
        inp: Any = Step(0.0)
    else:
        R = noise * np.diag([1e-6, 1e-6, 1e6])
        nominal = eha_linear(R=R)
        key = {"leakage": "leakage", "bulk-modulus": "bulk_modulus", "friction": "friction"}[family]
        value = size * EHA_PARAMETERS["bulk_modulus"] if family == "bulk-modulus" else size
        plant = eha_linear(R=R, **{key: value})
        inp = Chirp(10.0, 100.0, 4.0, 300.0)
    return Scenario(
        name=f"power-{family}-{size:g}-noise{noise:g}",
        nominal=nominal,
        plant=plant,
        input=inp,
        duration=4.0,
        family="second-order" if family == "f0" else "eha",
        fault=family,
        fault_channel=POWER_FAMILIES[family]["channel"],
    )


@dataclass(frozen=True, eq=False)
class PowerStudyChunks:
    """Chunk function of :func:`power_study`: detection counts per (point, kind, alpha, channel)."""

    scenarios: tuple[Scenario, ...]
    thr_values: tuple[np.ndarray, ...]  # per point: (K, A, bins, m)
    thr_tested: np.ndarray  # (K, bins)

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        det, det_any = [], []
        for sc, thr in zip(self.scenarios, self.thr_values, strict=True):
            rec = next(iter_chattering(sc, runs, seed, chunk_runs=runs, first_run=first_run))
            S = periodogram(rec.values, rec.dt).power  # (r, bins, m)
            d = np.empty((thr.shape[0], thr.shape[1], runs, S.shape[-1]), dtype=bool)
            for k in range(thr.shape[0]):
                St = S[:, self.thr_tested[k]]  # (r, bt, m)
                d[k] = (St[None] > thr[k][:, None, self.thr_tested[k]]).any(axis=2)  # (A, r, m)
            det.append(d.sum(axis=2))
            det_any.append(d.any(axis=-1).sum(axis=2))
        return {"det": np.stack(det), "det_any": np.stack(det_any)}

    def reduce(self, acc: dict[str, np.ndarray] | None, part: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return _reduce_dict(acc, part, {})


@dataclass(frozen=True, eq=False)
class PowerResult:
    """Detection probability per (noise, size, kind, alpha), with Clopper-Pearson intervals.

    Attributes
    ----------
    family : str
    sizes, noise : tuple of float
        Grid (``sizes[0]`` is the healthy value: its "detection" rate is the false-alarm rate).
    kinds : tuple of str
        ``paper`` (per-bin alpha, the paper's rule), ``exact`` (per-bin), ``exact-bonferroni`` (default).
    alphas : (A,) array
        Alpha grid of the ROC; ``alpha`` is the reporting level.
    runs : int
        Realizations per (noise, size) grid point (common random numbers).
    seed : int or None
        Root seed if it was an integer, else None.
    confidence : float
        Level of the Clopper-Pearson intervals.
    channel : str
        Fault channel used for the verdict.
    channels : tuple of str
        All output channel names (last axis of ``counts``).
    counts : (noise, sizes, kinds, A, m) int array
        Records detected (any tested bin above the threshold) per channel.
    counts_any : (noise, sizes, kinds, A) int array
        Records detected on any channel.
    """

    family: str
    sizes: tuple[float, ...]
    noise: tuple[float, ...]
    kinds: tuple[str, ...]
    alphas: np.ndarray
    alpha: float
    runs: int
    seed: int | None
    confidence: float
    channel: str
    channels: tuple[str, ...]
    counts: np.ndarray
    counts_any: np.ndarray

    def _ia(self, alpha: float | None) -> int:
        a = self.alpha if alpha is None else alpha
        return int(np.argmin(np.abs(np.log(self.alphas) - np.log(a))))

    def detection(self, kind: str = "exact-bonferroni", alpha: float | None = None) -> np.ndarray:
        """(noise, sizes) detection probability on the fault channel."""
        c = self.channels.index(self.channel)
        return self.counts[:, :, self.kinds.index(kind), self._ia(alpha), c] / self.runs

    def estimate(self, i_noise: int, i_size: int, kind: str, alpha: float | None = None) -> RateEstimate:
        c = self.channels.index(self.channel)
        k = int(self.counts[i_noise, i_size, self.kinds.index(kind), self._ia(alpha), c])
        return RateEstimate(k, self.runs, self.confidence)

    def roc(self, i_noise: int, i_size: int, kind: str = "exact-bonferroni") -> tuple[np.ndarray, np.ndarray]:
        """``(false_alarm_rate, detection_rate)`` over the alpha grid (healthy = ``sizes[0]``)."""
        c = self.channels.index(self.channel)
        k = self.kinds.index(kind)
        far = self.counts[i_noise, 0, k, :, c] / self.runs
        det = self.counts[i_noise, i_size, k, :, c] / self.runs
        return far, det

    def to_dict(self) -> dict[str, Any]:
        points = []
        for i, nz in enumerate(self.noise):
            for j, sz in enumerate(self.sizes):
                points.append(
                    {
                        "noise": nz,
                        "size": sz,
                        "healthy": j == 0,
                        "detection": {k: self.estimate(i, j, k).to_dict() for k in self.kinds},
                    }
                )
        roc = []
        for i, nz in enumerate(self.noise):
            for j, sz in enumerate(self.sizes[1:], start=1):
                far, det = self.roc(i, j)
                roc.append(
                    {
                        "noise": nz,
                        "size": sz,
                        "false_alarm_rate": far.tolist(),
                        "detection_rate": det.tolist(),
                    }
                )
        return {
            "family": self.family,
            "unit": POWER_FAMILIES[self.family]["unit"],
            "channel": self.channel,
            "alpha": self.alpha,
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "points": points,
            "roc": {"kind": "exact-bonferroni", "alphas": self.alphas.tolist(), "curves": roc},
        }


def power_study(
    family: str,
    sizes: Sequence[float] | None = None,
    noise: Sequence[float] | None = None,
    alpha: float = 1e-3,
    runs: int = 200,
    seed: SeedLike = 0,
    *,
    alphas: Sequence[float] | None = None,
    confidence: float = 0.99,
    workers: int = 1,
    scheduler: str | None = None,
    chunk_runs: int | None = None,
    progress: bool | None = None,
) -> PowerResult:
    """Detection power vs fault size and noise level, and ROC curves.

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
        Fault family (:data:`POWER_FAMILIES`).
    sizes : sequence of float, optional
        Fault sizes; the family's healthy value is prepended if missing.
    noise : sequence of float, optional
        Measurement-noise multipliers (see :func:`power_scenario`).
    alpha : float
        Reporting level in (0, 1).
    runs : int
        Realizations per grid point (common random numbers across points).
    seed : int
    alphas : sequence of float, optional
        ROC alpha grid (default 1e-5 .. 0.5 log-spaced, plus ``alpha``).
    confidence : float
        Level of the Clopper-Pearson intervals.
    workers, scheduler, chunk_runs, progress
        Execution (see :func:`chatterspec.montecarlo.run_study`).

    Returns
    -------
    PowerResult
    """
    if family not in POWER_FAMILIES:
        raise ParameterError(f"unknown fault family {family!r}; valid: {', '.join(POWER_FAMILIES)}")
    alpha = open_unit("alpha", alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    spec = POWER_FAMILIES[family]
    healthy = spec["sizes"][0]
    sizes_t = tuple(float(s) for s in (spec["sizes"] if sizes is None else sizes))
    if not sizes_t or not math.isclose(sizes_t[0], healthy):
        sizes_t = (healthy, *(s for s in sizes_t if not math.isclose(s, healthy)))
    noise_t = tuple(float(s) for s in (spec["noise"] if noise is None else noise))
    grid = np.geomspace(1e-5, 0.5, 15) if alphas is None else np.asarray(alphas, dtype=float)
    grid = np.unique(np.append([open_unit("alpha", a) for a in grid], alpha))
    kinds = ("paper", "exact", "exact-bonferroni")
    scenarios, thr_values = [], []
    tested = None
    for nz in noise_t:
        for sz in sizes_t:
            sc = power_scenario(family, sz, nz)
            model, N = sc.nominal, sc.n_samples - 1
            per_alpha = [_analytic_thresholds(model, N, a)[1] for a in grid]
            thr_values.append(np.stack([np.stack([t[k].values for t in per_alpha]) for k in kinds]))
            tested = np.stack([per_alpha[0][k].tested for k in kinds])
            scenarios.append(sc)
    study = PowerStudyChunks(tuple(scenarios), tuple(thr_values), tested)
    out = run_study(
        study,
        runs,
        seed,
        workers=workers,
        scheduler=scheduler,
        chunk_runs=chunk_runs,
        progress=progress,
        label=f"power {family}",
    )
    shape = (len(noise_t), len(sizes_t))
    return PowerResult(
        family=family,
        sizes=sizes_t,
        noise=noise_t,
        kinds=kinds,
        alphas=_ro(grid),
        alpha=alpha,
        runs=runs,
        seed=int(seed) if isinstance(seed, int | np.integer) else None,
        confidence=confidence,
        channel=spec["channel"],
        channels=tuple(scenarios[0].nominal.output_names),
        counts=_ro(out["det"].reshape(*shape, *out["det"].shape[1:])),
        counts_any=_ro(out["det_any"].reshape(*shape, *out["det_any"].shape[1:])),
    )
