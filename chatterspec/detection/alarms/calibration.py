"""Thresholds of alarm rules for a false-alarm budget in alarm starts per hour.

A budget of ``X`` false alarms per hour means: on healthy data, the whole monitor (all
channels together) raises on average ``X`` alarm **starts** per hour. The rules of
:mod:`chatterspec.detection.alarms.streams` renew after every alarm, so starts on a long healthy
stream are close to a Poisson process of rate ``X`` (Garwood intervals below).

Three ways to a threshold (:attr:`RuleCalibration.method`)
    ``law``
        The frame rule on a p-value score (``score = -log p`` with ``P(p <= x) <= x`` under
        the healthy law, e.g. :mod:`chatterspec.detection.verdicts` with the exact law):
        a step exceeds ``h`` with probability at most ``exp(-h)`` and starts are at most
        exceedances, so ``h = log(steps_per_hour * channels / X)`` keeps the rate at or below
        ``X`` with no simulation. It is an upper bound: overlapping frames make exceedances
        come in clusters (measured on the EHA with 1 s / 0.2 s frames: about 0.9 starts per
        exceedance at ``h`` 8-14), so the realized rate is about ``0.9 X``.
    ``counted``
        Healthy score streams of ``T`` hours hold enough starts at the budget (``X T >=``
        :data:`MIN_COUNT`): starts are counted on a grid of thresholds and ``h`` is where
        ``log(count)`` (linear between grid points) crosses ``log(X T)``.
    ``extrapolated``
        The budget is rarer than ``T`` hours resolve. For a renewal rule the mean time to a
        false alarm grows exponentially in ``h`` once alarms are rare compared with the rule's
        memory (CUSUM: ``log ARL0 ~ theta h`` with ``theta`` the root of
        ``E exp(theta (s - drift)) = 1`` for independent increments, Siegmund 1985; the same
        large-deviation form for weakly dependent scores; single-step and k-of-n rules: the
        exponential tail of the score), so ``log(starts per hour)`` is linear in ``h`` there.
        It is fitted (Poisson weights) over the grid points with between :data:`MIN_COUNT`
        starts and a start rate of :data:`MAX_RATE_PER_STEP` per channel step (the rare-alarm
        regime), and solved for ``X``. Measured on 160 h of healthy EHA frame scores (1 s /
        0.2 s frames): below 5e-4 starts per channel step the slope is constant to the noise
        down to 1 per day (CUSUM drift 3: -0.46 to -0.49 per unit of ``h``; 3-of-5 persistence:
        -1.9; frame: -0.97); at higher rates the CUSUM's is steeper (-0.53 at 2e-3, Siegmund's
        ``e^x - x - 1`` shape), and a fit reaching up to 2e-3 put the 1-per-day threshold 0.5-1
        too low (1.6 false alarms per day realized). With the 5e-4 limit, thresholds from 4 h
        and 24 h of streams were unbiased against the 160 h count (CUSUM: 20.98 +- 1.62 from 4 h,
        20.99 +- 1.08 from 24 h, against about 21.0) and their 95 % intervals covered it in
        0.94-1.0 of the cases.

Uncertainty
    The streams are cut into :data:`BATCHES` batches of consecutive steps and the fit (or the
    interpolation) is repeated with each batch left out (jackknife): the standard error of
    ``h`` gives :attr:`RuleCalibration.threshold_interval` and the matching interval of the
    realized rate at ``h`` (``rate_interval``, per hour). This accounts for the dependence
    between the counts at neighbouring thresholds (the same alarms) and between steps; the
    interval is ``h +- t SE`` with Student's ``t`` at ``B - 1`` degrees of freedom (measured
    coverage of the exact threshold of iid scores at 95 %: 0.95 and 1.0 over 40 seeds for a
    counted and an extrapolated budget).

Public interface (stable; additions only)
    :func:`poisson_interval`, :func:`poisson_count_interval`, :class:`RuleCalibration`
    (``to_dict`` / ``from_dict``), :func:`calibrate_rule`, :func:`law_frame_rule`,
    :func:`starts_on_grid`, :class:`MonitorSettings`.

Monitor settings
    :class:`MonitorSettings`, the detector settings of the online monitor (STFT, per-frame alpha,
    alarm rule and its calibration). In the detection layer because the alarm studies
    (:mod:`chatterspec.studies.alarm_budget`, :mod:`chatterspec.studies.alarm_budget`, the
    diagnosis routes) compute with the same settings without the online monitor;
    :mod:`chatterspec.online.monitor` re-exports it (its documented home).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal, cast

import numpy as np
import scipy.special  # not scipy.stats: the monitor imports this module at start-up

from ... import _jit
from ..._validate import finite_array, open_unit, positive
from ...errors import ParameterError, ShapeError
from ...jsonout import finite_or_none
from ..spectral import STFTConfig
from ..thresholds import Threshold, check_detector
from .rules import AlarmRule, FrameRule, is_rule, rule_from_dict, rule_spec
from .streams import ring_length, rule_vector

__all__ = [
    "BATCHES",
    "MAX_RATE_PER_STEP",
    "MIN_COUNT",
    "MonitorSettings",
    "RuleCalibration",
    "calibrate_rule",
    "check_budget",
    "law_frame_rule",
    "poisson_count_interval",
    "poisson_interval",
    "starts_on_grid",
]


#: Fewest starts at a grid point used for counting or fitting.
MIN_COUNT = 20
#: Highest start rate per channel step of a grid point in the extrapolation fit (rare-alarm regime).
MAX_RATE_PER_STEP = 5e-4
#: Batches of the jackknife.
BATCHES = 8
#: Thresholds of the grid.
GRID_POINTS = 48

Method = Literal["law", "counted", "extrapolated"]


def check_budget(
    false_alarms_per_hour: float | str,
    option: str = "false_alarms_per_hour",
    *,
    steps_per_hour: float | None = None,
    channels: int | None = None,
) -> float:
    """A budget in false alarms per hour: a finite number > 0 (``ParameterError`` naming ``option``).

    With ``steps_per_hour`` and ``channels``, also one that some threshold can meet: an alarm
    starts on a step over the threshold after a step that was not in alarm, so no rule raises more
    than ``steps_per_hour * channels / 2`` starts per hour; a larger budget has no threshold (it
    would be set at or below the lowest score, one alarm that never ends).

    Parameters
    ----------
    false_alarms_per_hour : float or str
        The budget (alarm starts per hour).
    option : str
        How the caller names it in the error message (e.g. ``--false-alarms-per-hour``).
    steps_per_hour : float, optional
        Steps (frames) per hour of one channel.
    channels : int, optional
        Channels sharing the budget.
    """
    try:
        x = float(false_alarms_per_hour)
    except (TypeError, ValueError):
        raise ParameterError(f"{option} must be a number > 0; got {false_alarms_per_hour!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ParameterError(f"{option} must be positive and finite (alarm starts per hour); got {x!r}")
    if steps_per_hour is not None and channels is not None:
        most = steps_per_hour * channels / 2.0
        if x > most:
            raise ParameterError(
                f"no alarm threshold meets {x:g} false alarms per hour: {channels} channel(s) at "
                f"{steps_per_hour:g} steps per hour raise at most {most:g} alarm starts per hour (one per "
                "two steps per channel); give a smaller budget"
            )
    return x


def _poisson_ppf(q: float, mu: float) -> int:
    """The smallest count ``k`` with ``P(N <= k) >= q`` for ``N`` ~ Poisson(``mu``) (scipy.stats' rule)."""
    k = math.ceil(scipy.special.pdtrik(q, mu))
    below = max(k - 1, 0)
    return below if scipy.special.pdtr(below, mu) >= q else k


def poisson_interval(count: int, confidence: float = 0.99) -> tuple[float, float]:
    """Exact two-sided interval (Garwood) for the mean of a Poisson count.

    ``[chi2.ppf(a/2, 2k) / 2, chi2.ppf(1 - a/2, 2k + 2) / 2]`` with ``a = 1 - confidence``
    (lower end 0 for ``k = 0``).

    Parameters
    ----------
    count : int
        Observed count ``k >= 0``.
    confidence : float
        Two-sided level in (0, 1).
    """
    k = int(count)
    if k < 0:
        raise ParameterError(f"count must be >= 0; got {count!r}")
    a = 1.0 - open_unit("confidence", confidence)
    lo = 0.0 if k == 0 else float(scipy.special.gammaincinv(k, a / 2))
    hi = float(scipy.special.gammaincinv(k + 1, 1 - a / 2))
    return lo, hi


def poisson_count_interval(mean: float, confidence: float = 0.99) -> tuple[int, int]:
    """Two-sided interval of counts of a Poisson law with ``mean``: the ``a/2`` and ``1 - a/2`` quantiles.

    A count ``k`` with ``lo <= k <= hi`` is consistent with ``mean`` at level ``confidence``
    (each tail has probability at most ``a/2``).
    """
    mu = positive("mean", mean)
    a = 1.0 - open_unit("confidence", confidence)
    lo = _poisson_ppf(a / 2, mu)
    hi = _poisson_ppf(1 - a / 2, mu)
    # ppf gives the smallest k with cdf >= q: keep P(K < lo) <= a/2 and P(K > hi) <= a/2
    if lo > 0 and scipy.special.pdtr(lo - 1, mu) > a / 2:  # pragma: no cover - ppf's definition
        lo -= 1
    return lo, hi


@dataclass(frozen=True)
class RuleCalibration:
    """A rule's threshold for a false-alarm budget, and how it was obtained.

    Attributes
    ----------
    rule : AlarmRule
        The rule with its calibrated ``threshold``.
    false_alarms_per_hour : float
        The budget ``X``: alarm starts per hour of healthy data, all channels together.
    steps_per_hour : float
        Steps (frames or samples) per hour of one stream.
    channels : int
        Channels sharing the budget (one threshold for all of them).
    method : {"law", "counted", "extrapolated"}
        See the module docstring.
    hours : float
        Healthy stream time the threshold was calibrated on (0 for ``law``).
    threshold_interval : (float, float)
        Confidence interval of the threshold that meets the budget.
    rate_interval : (float, float)
        Confidence interval of the realized false-alarm rate (starts per hour) at ``threshold``
        (``law``: ``(0, X)``, an upper bound).
    confidence : float
        Level of both intervals.
    seed : int or None
        Seed of the healthy streams (None for ``law`` or when unknown).
    fit : dict
        ``counted`` / ``extrapolated``: the grid (``h``, ``starts``), ``hours``, and for
        ``extrapolated`` ``slope`` and ``intercept`` of ``log(starts per hour) = intercept +
        slope h`` and the ``h`` range fitted.
    """

    rule: AlarmRule
    false_alarms_per_hour: float
    steps_per_hour: float
    channels: int
    method: Method
    hours: float
    threshold_interval: tuple[float, float]
    rate_interval: tuple[float, float]
    confidence: float = 0.95
    seed: int | None = None
    fit: Mapping[str, Any] = field(default_factory=dict)

    @property
    def threshold(self) -> float:
        """The calibrated rule's threshold (score units)."""
        return self.rule.threshold

    def describe(self) -> str:
        """A short description for reports and recordings."""
        how = {
            "law": "from the healthy law (an upper bound on the rate)",
            "counted": f"counted on {self.hours:.3g} h of healthy streams",
            "extrapolated": f"extrapolated (log rate linear in h) from {self.hours:.3g} h of healthy streams",
        }[self.method]
        lo, hi = self.rate_interval
        return (
            f"{self.rule.name} rule, threshold {self.threshold:.4g} for {self.false_alarms_per_hour:g} false "
            f"alarm(s) per hour over {self.channels} channel(s), {how}; realized rate "
            f"{lo:.3g}-{hi:.3g} per hour ({100 * self.confidence:g} %)"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``from_dict`` reads it back)."""
        return {
            "rule": self.rule.to_dict(),
            "false_alarms_per_hour": self.false_alarms_per_hour,
            "steps_per_hour": self.steps_per_hour,
            "channels": self.channels,
            "method": self.method,
            "hours": self.hours,
            "threshold_interval": [finite_or_none(v) for v in self.threshold_interval],
            "rate_interval": [finite_or_none(v) for v in self.rate_interval],
            "confidence": self.confidence,
            "seed": self.seed,
            "fit": _jsonable(dict(self.fit)),
        }

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RuleCalibration:
        """Rebuild the object from the output of ``to_dict``."""
        try:
            return cls(
                rule=rule_from_dict(d["rule"]),
                false_alarms_per_hour=float(d["false_alarms_per_hour"]),
                steps_per_hour=float(d["steps_per_hour"]),
                channels=int(d["channels"]),
                method=cast(Method, str(d["method"])),  # (as to_dict wrote it)
                hours=float(d["hours"]),
                threshold_interval=cast(tuple[float, float], tuple(_den(v) for v in d["threshold_interval"])),
                rate_interval=cast(tuple[float, float], tuple(_den(v) for v in d["rate_interval"])),
                confidence=float(d.get("confidence", 0.95)),
                seed=d.get("seed"),
                fit=dict(d.get("fit", {})),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"not a rule calibration ({type(exc).__name__}: {exc})") from None


def _den(x: float | None) -> float:
    return float("inf") if x is None else float(x)


def _jsonable(d: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, np.ndarray):
            v = v.tolist()
        if isinstance(v, float) and not math.isfinite(v):
            v = None
        out[k] = v
    return out


def law_frame_rule(
    steps_per_hour: float, channels: int, false_alarms_per_hour: float, confidence: float = 0.95
) -> RuleCalibration:
    """The frame rule on a p-value score from the law alone: ``h = log(steps_per_hour * channels / X)``.

    Valid for scores ``-log p`` with ``P(p <= x) <= x`` on healthy data (the chattering frame
    score with the exact law); the realized rate is at most ``X`` (module docstring).

    Parameters
    ----------
    steps_per_hour : float
        Frames per hour of one channel.
    channels : int
        Channels sharing the budget.
    false_alarms_per_hour : float
        The budget ``X`` (> 0).
    confidence : float
        Recorded level (the bound holds surely).
    """
    F = positive("steps_per_hour", steps_per_hour)
    m = int(channels)
    if m < 1:
        raise ParameterError(f"channels must be >= 1; got {channels!r}")
    X = check_budget(false_alarms_per_hour, steps_per_hour=F, channels=m)
    h = math.log(F * m / X)
    return RuleCalibration(
        rule=FrameRule(threshold=max(h, 0.0)),
        false_alarms_per_hour=X,
        steps_per_hour=F,
        channels=m,
        method="law",
        hours=0.0,
        threshold_interval=(h, h),
        rate_interval=(0.0, X),
        confidence=open_unit("confidence", confidence),
    )


# --------------------------------------------------------------------------- counting on a grid
def starts_on_grid(rule: AlarmRule, scores: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Alarm starts of ``rule`` at each threshold of ``thresholds``, per stream and channel.

    Parameters
    ----------
    rule : AlarmRule
        Its other parameters are used; its threshold is replaced by each grid value.
    scores : (..., steps, channels) array
        Healthy score streams (each started from the rule's initial state).
    thresholds : (G,) array

    Returns
    -------
    (G, ..., channels) int array
        Identical to ``count_starts(rule.with_threshold(h), scores)`` for each ``h``.
    """
    s = np.asarray(scores, dtype=float)
    if s.ndim < 2:
        raise ShapeError(f"scores must be (..., steps, channels); got shape {s.shape}")
    hs = np.asarray(thresholds, dtype=float).ravel()
    lead, K, C = s.shape[:-2], s.shape[-2], s.shape[-1]
    R = int(np.prod(lead, dtype=np.int64))
    s3 = np.ascontiguousarray(s.reshape(R, K, C))
    G = hs.size
    steps = rule_spec(rule).load_steps()
    p, W = rule_vector(rule), ring_length(rule, steps)
    if steps.grid_starts is not None:
        out = steps.grid_starts(s3, hs)
    elif _jit.enabled():
        out = np.zeros((G, R, C), dtype=np.int64)
        act, sa, en = (np.empty((R, K, C), dtype=np.bool_) for _ in range(3))
        st = np.empty((R, K, C))
        for i, h in enumerate(hs):
            steps.kernel(
                s3, float(h), p, np.zeros((R, C), dtype=np.bool_), np.zeros((R, C)),
                np.zeros((R, C), dtype=np.int64), np.zeros((R, C, W), dtype=np.bool_),
                np.zeros(1, dtype=np.int64), act, st, sa, en,
            )  # fmt: skip
            out[i] = sa.sum(axis=1)
    else:  # one pass over the steps for every threshold at once
        out = np.zeros((G, R, C), dtype=np.int64)
        steps.numpy(
            s3, hs[:, None, None], p, 0, np.zeros((G, R, C), dtype=np.bool_), np.zeros((G, R, C)),
            np.zeros((G, R, C), dtype=np.int64), np.zeros((G, R, C, W), dtype=np.bool_), None, out,
        )  # fmt: skip
    return out.reshape(G, *lead, C)


def _grid(rule: AlarmRule, s3: np.ndarray, points: int) -> np.ndarray:
    """Thresholds from where alarms are frequent to where none occurs in the streams (the range of the
    rule's statistic, :attr:`~chatterspec.detection.alarms.steps.RuleSteps.statistic_range`)."""
    lo, hi = rule_spec(rule).load_steps().statistic_range(s3, rule_vector(rule))
    if not (math.isfinite(hi) and hi > lo):
        raise ParameterError(
            f"the healthy scores give no alarm range for the {rule.name} rule (largest statistic "
            f"{hi:g}); check that the scores vary"
        )
    return np.linspace(lo, hi, points + 1)[1:]


# --------------------------------------------------------------------------- calibration
def calibrate_rule(
    rule: AlarmRule,
    scores: np.ndarray,
    steps_per_hour: float,
    false_alarms_per_hour: float,
    *,
    confidence: float = 0.95,
    seed: int | None = None,
    batches: int = BATCHES,
) -> RuleCalibration:
    """Threshold of ``rule`` giving ``false_alarms_per_hour`` starts on healthy score streams.

    Parameters
    ----------
    rule : AlarmRule
        The rule and its other parameters (its threshold is ignored).
    scores : (..., steps, channels) array
        Healthy score streams; each is run from the rule's initial state. The total time is
        ``streams * steps / steps_per_hour`` hours; all channels share the budget and one threshold.
    steps_per_hour : float
        Steps per hour of one stream (frames per hour: ``3600 / hop_s``).
    false_alarms_per_hour : float
        The budget ``X`` (> 0, finite): starts per hour, all channels together.
    confidence : float
        Level of the intervals (two-sided).
    seed : int, optional
        Recorded with the result (the seed of the healthy streams).
    batches : int
        Jackknife batches (>= 2).

    Returns
    -------
    RuleCalibration
        ``method`` ``counted`` or ``extrapolated`` (see the module docstring).

    Raises
    ------
    ParameterError
        Bad budget, or streams too short to resolve even the frequent alarms (fewer than
        :data:`MIN_COUNT` starts at two grid points in the rare-alarm regime).
    """
    F = positive("steps_per_hour", steps_per_hour)
    conf = open_unit("confidence", confidence)
    s = np.asarray(scores, dtype=float)
    if s.ndim < 2 or s.shape[-2] < 2:
        raise ShapeError(f"scores must be (..., steps >= 2, channels); got shape {s.shape}")
    if np.isnan(s).any():
        raise ParameterError("healthy scores contain NaN")
    C = s.shape[-1]
    X = check_budget(false_alarms_per_hour, steps_per_hour=F, channels=C)
    s3 = s.reshape(-1, s.shape[-2], C)
    K = s3.shape[1]
    B = max(2, min(int(batches), K // 2))
    # batches of consecutive steps, each run from the initial state (the budget counts renewals)
    edges = np.linspace(0, K, B + 1).astype(int)
    parts = [s3[:, a:b] for a, b in itertools.pairwise(edges)]
    steps = np.array([p.shape[0] * p.shape[1] for p in parts], dtype=float)  # per batch, one channel
    hours = float(steps.sum() / F)
    coarse = _grid(rule, s3, GRID_POINTS)
    total = starts_on_grid(rule, s3, coarse).reshape(coarse.size, -1).sum(axis=1)
    if X * hours > total.max():  # the budget is above every rate the rule reaches: no threshold meets it
        i = int(np.argmax(total))
        raise ParameterError(
            f"no threshold of the {rule.name} rule meets {X:g} false alarms per hour: on {hours:.3g} h of "
            f"healthy streams it raises at most {total[i] / hours:.4g} alarm starts per hour (at threshold "
            f"{coarse[i]:.4g}; lower thresholds merge the alarms); give a smaller budget"
        )
    # a finer grid where it matters: from the last threshold still above the rare-alarm rate (or the
    # budget) to the first one with too few starts to count
    top = min(MAX_RATE_PER_STEP * steps.sum() * C, max(X * hours, MIN_COUNT))
    i_lo = int(np.flatnonzero(total > top)[-1]) if np.any(total > top) else 0
    i_hi = int(np.flatnonzero(total < MIN_COUNT)[0]) if np.any(total < MIN_COUNT) else coarse.size - 1
    fine = np.linspace(coarse[i_lo], coarse[max(i_hi, i_lo)], GRID_POINTS // 2)
    grid = np.unique(np.concatenate([coarse, fine]))
    counts = np.stack([starts_on_grid(rule, p, grid).reshape(grid.size, -1).sum(axis=1) for p in parts])

    def solve(cnt: np.ndarray, n_steps: float) -> tuple[float, Method, dict[str, Any]]:
        T = n_steps / F
        target = X * T
        rate = cnt / (n_steps * C)
        if target >= MIN_COUNT and cnt.max() >= target:
            i = int(np.flatnonzero(cnt >= target)[-1])  # last grid point still at or above the target
            if i + 1 < grid.size and cnt[i + 1] > 0:
                l0, l1 = math.log(cnt[i]), math.log(cnt[i + 1])
                step = grid[i + 1] - grid[i]
                h = grid[i] + (math.log(target) - l0) / (l1 - l0) * step if l1 < l0 else grid[i]
            else:
                h = float(grid[i])
            return float(h), "counted", {}
        ok = (cnt >= MIN_COUNT) & (rate <= MAX_RATE_PER_STEP)
        # a slope needs a range of counts: at least a factor e^1 between the ends of the fit
        if np.count_nonzero(ok) < 2 or cnt[ok].max() < math.e * cnt[ok].min():
            raise ParameterError(
                f"{T:.3g} h of healthy streams are too short to calibrate the {rule.name} rule for "
                f"{X:g} false alarms per hour: the thresholds with >= {MIN_COUNT} alarm starts at rare-alarm "
                f"rates span less than a factor e of starts; simulate more hours"
            )
        hh, cc = grid[ok], cnt[ok]
        w = cc.astype(float)  # Poisson: var(log count) ~ 1 / count
        A = np.stack([np.ones_like(hh), hh], axis=1)
        coef = np.linalg.lstsq(A * np.sqrt(w)[:, None], np.log(cc / T) * np.sqrt(w), rcond=None)[0]
        a, b = float(coef[0]), float(coef[1])
        if not b < 0:
            raise ParameterError(f"the {rule.name} rule's false-alarm rate does not fall with its threshold")
        h = (math.log(X) - a) / b
        info = {"slope": b, "intercept": a, "h_fitted": [float(hh[0]), float(hh[-1])]}
        return float(h), "extrapolated", info

    h, method, fit = solve(counts.sum(axis=0), float(steps.sum()))
    # jackknife over batches (same method as the full data where possible)
    hs = []
    for j in range(B):
        keep = np.arange(B) != j
        try:
            hj, _, _ = solve(counts[keep].sum(axis=0), float(steps[keep].sum()))
        except ParameterError:
            continue
        hs.append(hj)
    if len(hs) >= 2:
        hjs = np.array(hs)
        se = float(math.sqrt((len(hjs) - 1) / len(hjs) * np.sum((hjs - hjs.mean()) ** 2)))
    else:  # pragma: no cover - every leave-one-out fit failed
        se = float("inf")
    # the jackknife over B batches: Student t with B - 1 degrees of freedom
    z = float(-scipy.special.stdtrit(max(1, len(hs) - 1), (1 - conf) / 2))
    th_int = (h - z * se, h + z * se)
    slope = fit.get("slope")
    if slope is None:  # counted: local slope of log(count) around h
        i = int(np.clip(np.searchsorted(grid, h), 1, grid.size - 1))
        c0, c1 = counts.sum(axis=0)[i - 1], counts.sum(axis=0)[i]
        slope = (math.log(max(c1, 0.5)) - math.log(max(c0, 0.5))) / (grid[i] - grid[i - 1])
    spread = min(700.0, abs(slope) * z * se) if math.isfinite(se) else 700.0
    rate_int = (X * math.exp(-spread), X * math.exp(spread))
    total = counts.sum(axis=0).tolist()
    fit = {**fit, "h": grid.tolist(), "starts": total, "hours": hours, "jackknife_se": se}
    return RuleCalibration(
        rule=rule.with_threshold(h),
        false_alarms_per_hour=X,
        steps_per_hour=F,
        channels=C,
        method=method,
        hours=hours,
        threshold_interval=th_int,
        rate_interval=(min(rate_int), max(rate_int)),
        confidence=conf,
        seed=seed,
        fit=fit,
    )


@dataclass(frozen=True)
class MonitorSettings:
    """Detector settings of the online monitor.

    Parameters
    ----------
    stft : STFTConfig
        Window and hop (default 1 s Hamming, 0.2 s hop).
    alpha : float
        Per-frame false-alarm probability (0 < alpha < 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise correction over the tested bins of a frame.
    gamma : float
        SVSF convergence rate (both filters).
    psi : tuple of float, optional
        Smoothing boundary layer per output. When given, the ``sat`` SVSF runs
        too (its estimate is reported and the boundary drawn next to the
        chattering); ``None`` runs only the auxiliary filter.
    threshold : Threshold, optional
        Per-frame threshold to use instead of the analytic
        :func:`~chatterspec.detection.thresholds.frame_threshold`, e.g. the empirical one of
        a saved calibration, ``load_calibration(...).threshold("frame-family-wise")``
        (then ``alpha`` and ``correction`` are ignored). It must cover the STFT
        frequencies of ``stft``.
    band : (float, float), optional
        The tested band ``(lo, hi)`` in Hz: test only the frame bins with ``lo <= f <= hi`` (beyond the
        paper, see :mod:`chatterspec.detection.thresholds`); the correction counts only
        them. With ``threshold`` given, that threshold is restricted to the band
        (:meth:`~chatterspec.detection.thresholds.Threshold.restricted`: its level is then
        conservative). ``None`` (default): every bin but DC and Nyquist.
    rule : AlarmRule, optional
        The alarm rule (:mod:`chatterspec.detection.alarms.streams`) that turns the frame score
        (``-log`` of the frame's p-value, :mod:`chatterspec.detection.verdicts`) into
        fault-start / fault-end events, with its threshold set (e.g. by
        :func:`chatterspec.studies.alarm_budget.alarm_settings` for a false-alarm budget).
        ``None`` (default): the per-frame rule at ``alpha``, events where the per-frame
        verdict (``FrameBlock.flags``) changes, as before the alarm layer.
    budget : RuleCalibration, optional
        How ``rule``'s threshold was set for a budget in false alarms per hour (reported in
        events, summaries and recordings); its ``rule`` must be ``rule``.
    """

    stft: STFTConfig = field(default_factory=STFTConfig)
    alpha: float = 1e-3
    correction: Literal["none", "bonferroni", "sidak"] = "bonferroni"
    gamma: float = 0.1
    psi: tuple[float, ...] | None = None
    threshold: Threshold | None = None
    band: tuple[float, float] | None = None
    rule: AlarmRule | None = None
    budget: RuleCalibration | None = None

    def __post_init__(self) -> None:
        if self.rule is not None and not is_rule(self.rule):
            raise ParameterError(f"rule must be an alarm rule; got {type(self.rule).__name__}")
        if self.budget is not None:
            if not isinstance(self.budget, RuleCalibration):
                raise ParameterError(f"budget must be a RuleCalibration; got {type(self.budget).__name__}")
            if self.budget.rule != self.rule:
                raise ParameterError(
                    f"budget was calibrated for {self.budget.rule.to_dict()}; the rule is "
                    f"{None if self.rule is None else self.rule.to_dict()}"
                )
        checked = check_detector(self.alpha, self.correction, self.band)
        for name, value in zip(("alpha", "correction", "band"), checked, strict=True):
            object.__setattr__(self, name, value)
        if not isinstance(self.stft, STFTConfig):
            raise ParameterError(f"stft must be an STFTConfig; got {type(self.stft).__name__}")
        object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        if self.threshold is not None and not isinstance(self.threshold, Threshold):
            raise ParameterError(f"threshold must be a Threshold; got {type(self.threshold).__name__}")
        if self.psi is not None:
            psi = tuple(float(p) for p in np.atleast_1d(finite_array("psi", self.psi, ndim=(0, 1))))
            if any(p <= 0 for p in psi):
                raise ParameterError(f"psi must be > 0; got {list(psi)}")
            object.__setattr__(self, "psi", psi)

    @classmethod
    def from_detector(
        cls,
        detector: Mapping[str, Any],
        *,
        gamma: float = 0.1,
        psi: Sequence[float] | None = None,
        alpha: float | None = None,
        band: tuple[float, float] | None = None,
    ) -> MonitorSettings:
        """The settings a model file's ``[detector]`` table gives the monitor (no alarm rule yet).

        Parameters
        ----------
        detector : mapping
            ``ModelSpec.detector``: ``window_s``, ``hop_s`` (s), ``window``, ``alpha``, ``correction``,
            ``band`` (Hz); missing keys take the defaults (1 s Hamming, 0.2 s hop, 0.001, Bonferroni).
        gamma : float
            SVSF convergence rate (the file's ``[svsf] gamma``).
        psi : sequence of float, optional
            Boundary layer per output (None: the auxiliary filter only).
        alpha : float, optional
            Per-frame level overriding the table's.
        band : (float, float), optional
            Tested band (Hz) overriding the table's.
        """
        stft = STFTConfig(
            window_s=float(detector.get("window_s", 1.0)),
            hop_s=float(detector.get("hop_s", 0.2)),
            window=str(detector.get("window", "hamming")),
        )
        return cls(
            stft=stft,
            alpha=float(alpha if alpha is not None else detector.get("alpha", 1e-3)),
            correction=cast(
                Literal["none", "bonferroni", "sidak"], str(detector.get("correction", "bonferroni"))
            ),  # checked by __post_init__
            gamma=gamma,
            psi=None if psi is None else tuple(float(x) for x in psi),
            band=band or detector.get("band"),
        )

    @property
    def false_alarms_per_hour(self) -> float | None:
        """The budget of :attr:`budget` (alarm starts per hour, all channels), or None."""
        return None if self.budget is None else self.budget.false_alarms_per_hour

    def same_frame_threshold(self, other: MonitorSettings) -> bool:
        """Whether ``other`` has this per-frame threshold: the same given threshold (the same object),
        STFT, ``alpha``, correction and band (what :func:`~chatterspec.detection.thresholds.monitor_threshold`
        reads). A caller that computed it for ``other`` may pass it on for these settings; adding an alarm
        rule keeps it, except the frame and persistence rules, which draw the verdict at their own
        per-step level (another ``alpha``)."""
        return self.threshold is other.threshold and all(
            getattr(self, k) == getattr(other, k) for k in ("stft", "alpha", "correction", "band")
        )
