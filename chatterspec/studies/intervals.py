"""Interval statistics: Clopper-Pearson rates and order-statistic quantile intervals."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.stats

from .._validate import open_unit, positive_int
from ..errors import ParameterError
from ..jsonout import fields_dict, finite_or_none

__all__ = [
    "QuantileEstimate",
    "RateEstimate",
    "clopper_pearson",
    "cluster_clopper_pearson",
    "quantile_ci_ranks",
]

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


def cluster_clopper_pearson(
    count: int, trials: int, clusters: int, count_sq: float, confidence: float = 0.99
) -> tuple[float, float, float]:
    """Interval for a rate whose trials come in independent clusters of dependent trials.

    The ~2000 bins of one record (or the overlapping frames of one record) are
    not independent trials; the records are. The rate's variance is therefore
    estimated from the per-record counts ``x_r`` (``r = 1..R``, ``R = clusters``,
    ``trials / R`` trials each): ``Var(p) = s^2 / (R (trials/R)^2)`` with ``s^2``
    the sample variance of ``x_r``. The Clopper-Pearson interval is then taken
    with the effective sample size ``n_eff = p (1 - p) / Var(p)`` (capped at
    ``trials``) and ``k_eff = p n_eff`` events: the Korn-Graubard (1998)
    interval for clustered samples, which reduces to :func:`clopper_pearson`
    when the trials are independent (design effect 1) and widens by the
    design effect ``trials / n_eff`` when neighbouring bins correlate.

    Parameters
    ----------
    count : int
        Events over all clusters, ``sum(x_r)``.
    trials : int
        Trials over all clusters (``R`` times the trials per cluster).
    clusters : int
        Independent clusters R (records). With ``R = 1`` the variance cannot be
        estimated and the whole record counts as one trial (a wide interval).
    count_sq : float
        ``sum(x_r ** 2)``, the sum of squared per-cluster counts.
    confidence : float
        Two-sided confidence level in (0, 1).

    Returns
    -------
    (low, high, n_eff) : tuple of float
        Interval of the rate and the effective number of independent trials.

    References
    ----------
    E. L. Korn and B. I. Graubard, "Confidence intervals for proportions with
    small expected number of positive counts estimated from survey data",
    Survey Methodology 24(2), 193-201, 1998.
    """
    trials = positive_int("trials", trials)
    clusters = positive_int("clusters", clusters)
    confidence = open_unit("confidence", confidence)
    if not 0 <= count <= trials:
        raise ParameterError(f"need 0 <= count <= trials; got count={count}, trials={trials}")
    if clusters > trials:
        raise ParameterError(f"need clusters <= trials; got clusters={clusters}, trials={trials}")
    p = count / trials
    n_eff = float(trials)
    if clusters < 2:
        n_eff = 1.0
    elif 0 < count < trials:
        s2 = max(0.0, (count_sq - count**2 / clusters) / (clusters - 1))
        var_p = s2 / (clusters * (trials / clusters) ** 2)
        if var_p > 0:
            n_eff = min(float(trials), p * (1.0 - p) / var_p)
    a = 1.0 - confidence
    k = p * n_eff
    lo = 0.0 if count == 0 else float(scipy.stats.beta.ppf(a / 2, k, n_eff - k + 1))
    hi = 1.0 if count == trials else float(scipy.stats.beta.ppf(1 - a / 2, k + 1, n_eff - k))
    return lo, hi, n_eff


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

    With ``clusters`` and ``count_sq`` the trials are taken as independent
    clusters (records) of dependent trials (bins or frames of one record) and
    the interval is :func:`cluster_clopper_pearson`'s; without them the trials
    are independent (:func:`clopper_pearson`).

    Attributes
    ----------
    count : int
        Number of events (e.g. false alarms), ``0 <= count <= trials``.
    trials : int
        Number of trials (>= 1): bins x channels x records, records, or frames.
    confidence : float
        Two-sided level in (0, 1) of the interval (see :func:`clopper_pearson`).
    clusters : int or None
        Independent clusters (records) the trials come in, or None for independent trials.
    count_sq : float or None
        Sum over clusters of the squared per-cluster count (needed with ``clusters``).
    rate : float
        ``count / trials`` (computed).
    ci_low, ci_high : float
        Clopper-Pearson interval of the rate (computed).
    effective_trials : float
        Independent trials the interval is worth (``trials`` without clusters).

    See Also
    --------
    QuantileEstimate : the interval of a quantile.
    """

    count: int
    trials: int
    confidence: float
    clusters: int | None = None
    count_sq: float | None = None
    rate: float = field(init=False)
    ci_low: float = field(init=False)
    ci_high: float = field(init=False)
    effective_trials: float = field(init=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "rate", self.count / self.trials)
        if self.clusters is None:
            lo, hi = clopper_pearson(self.count, self.trials, self.confidence)
            n_eff = float(self.trials)
        else:
            if self.count_sq is None:
                raise ParameterError("RateEstimate: clusters needs count_sq (sum of squared cluster counts)")
            lo, hi, n_eff = cluster_clopper_pearson(
                self.count, self.trials, self.clusters, self.count_sq, self.confidence
            )
        object.__setattr__(self, "ci_low", lo)
        object.__setattr__(self, "ci_high", hi)
        object.__setattr__(self, "effective_trials", n_eff)

    def contains(self, p: float) -> bool:
        """Whether the rate ``p`` lies in the confidence interval."""
        return self.ci_low <= p <= self.ci_high

    def to_dict(self) -> dict[str, float | int]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return fields_dict(self, ("rate", "ci_low", "ci_high", "count", "trials", "effective_trials"))


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

    See Also
    --------
    RateEstimate : the interval of a rate.
    """

    q: float
    value: float
    ci_low: float
    ci_high: float
    n: int
    confidence: float

    def contains(self, x: float) -> bool:
        """Whether ``x`` lies in the confidence interval."""
        return self.ci_low <= x <= self.ci_high

    def to_dict(self) -> dict[str, float | int | None]:
        """JSON-ready; an unbounded interval end (too few tail samples) is ``None``."""
        return {
            "q": self.q,
            "value": self.value,
            "ci_low": finite_or_none(self.ci_low),
            "ci_high": finite_or_none(self.ci_high),
            "n": self.n,
        }


def _none_to_inf(x: float | None, sign: float) -> float:
    return sign * np.inf if x is None else float(x)


def _quantile_from_top(
    top_desc: np.ndarray, n: int, q: float, confidence: float, n_eff: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point and CI from the largest values sorted in descending order along axis 0."""
    point, lo, hi = _pooled_ranks(n, n if n_eff is None else n_eff, q, confidence)
    need = n - max(lo, 1) + 1
    if top_desc.shape[0] < need:
        raise ParameterError(f"kept {top_desc.shape[0]} tail values; the interval needs {need}")
    shape = top_desc.shape[1:]
    low = np.full(shape, -np.inf) if lo < 1 else top_desc[n - lo]
    high = np.full(shape, np.inf) if hi > n else top_desc[n - hi]
    return top_desc[n - point], low, high
