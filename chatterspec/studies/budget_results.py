"""Results of the diagnosis at one false-alarm budget (``chatterspec diagnose``): one record per route.

:class:`RouteBudget` holds, for one route under one rule whose threshold was calibrated on healthy
runs to the budget: the false alarms realized on the diagnosed runs' healthy time with their
two-sided Poisson interval, the detection delay per onset (median, 90th percentile), missed onsets,
isolation, cost, and the delay-against-false-alarms curve (thresholds swept on the same
realizations). :func:`summarize_route` builds it from the merged sweep of
:mod:`chatterspec.studies.route_sweep`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarms.calibration import poisson_interval
from ..jsonout import finite_or_none
from .intervals import clopper_pearson

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.rules import AlarmRule
    from .route_sweep import RouteGeometry
    from .routes import Route

__all__ = ["OnsetFigures", "RouteBudget", "summarize_route"]


def _clean(x: Any) -> Any:
    """JSON-ready copy: arrays to lists, NaN and inf to None (recursively)."""
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, list | tuple | np.ndarray):
        return [_clean(v) for v in x]
    if isinstance(x, float | np.floating):
        return finite_or_none(float(x))
    if isinstance(x, np.integer):
        return int(x)
    return x


_BIG = 1e300


def _quantiles(delays: np.ndarray) -> tuple[float, float]:
    """Median and 90th percentile over *all* runs, a missed onset (NaN) counting as an infinite delay.

    (numpy's linear interpolation; a quantile that touches a missed run is ``inf``.)
    """
    d = np.asarray(delays, dtype=float)
    if not d.size:
        return float("nan"), float("nan")
    q = np.quantile(np.where(np.isfinite(d), d, _BIG), [0.5, 0.9])
    median, p90 = (float(v) if v < _BIG / 2 else float("inf") for v in q)
    return median, p90


@dataclass(frozen=True, eq=False)
class OnsetFigures:
    """Detection of one fault onset by one route at the calibrated threshold.

    Attributes
    ----------
    onset_s : float
        Onset time (s).
    detected : int
        Runs not in alarm before the onset that are in alarm at some step of its window.
    missed : int
        Runs not in alarm before the onset and never in alarm in its window.
    in_alarm_at_onset : int
        Runs already in alarm on the last step before the onset: the onset is no new detection for
        them (no delay).
    delay_median_s, delay_p90_s : float
        Median and 90th percentile of the delay (s) over the runs not in alarm before the onset: time
        of the first step in alarm minus the onset; a missed onset counts as an infinite delay (NaN:
        every run was in alarm before).
    true_label : str or None
        The new mode (mode routes) a correct isolation names.
    isolated : dict
        Label at the detection -> runs.
    correct, correct_ci : int, tuple of float
        Runs isolating the true label at detection, with the 99 % Clopper-Pearson interval of the
        fraction over detected runs (mode routes only).
    isolation_median_s, isolation_p90_s : float
        Delay to the first step in alarm whose label is the true one (mode routes; never: infinite).
    """

    onset_s: float
    detected: int
    missed: int
    in_alarm_at_onset: int
    delay_median_s: float
    delay_p90_s: float
    true_label: str | None
    isolated: dict[str, int]
    correct: int | None
    correct_ci: tuple[float, float] | None
    isolation_median_s: float
    isolation_p90_s: float

    def describe(self) -> dict[str, Any]:
        """A short description for reports and recordings."""
        return {
            "onset_s": self.onset_s,
            "detected": self.detected,
            "missed": self.missed,
            "in_alarm_at_onset": self.in_alarm_at_onset,
            "delay_median_s": finite_or_none(self.delay_median_s),
            "delay_p90_s": finite_or_none(self.delay_p90_s),
            "true_label": self.true_label,
            "isolated": dict(self.isolated),
            "correct_isolation": self.correct,
            "correct_isolation_ci99": None if self.correct_ci is None else list(self.correct_ci),
            "isolation_delay_median_s": finite_or_none(self.isolation_median_s),
            "isolation_delay_p90_s": finite_or_none(self.isolation_p90_s),
        }


@dataclass(frozen=True, eq=False)
class RouteBudget:
    """One route at one false-alarm budget.

    Attributes
    ----------
    method : str
    rule : dict
        The alarm rule with its calibrated threshold (``rule.to_dict()``).
    budget_per_hour : float
        The false-alarm budget the threshold was calibrated to (alarm starts per hour).
    score : dict
        What the route's score is (and its parameters).
    runs : int
        Diagnosed realizations.
    healthy_hours : float
        Healthy time of the diagnosed runs the rule watched (before the first onset, after the
        warm-up), all runs together.
    false_alarms : int
        Alarm starts on that healthy time.
    rate_per_hour, rate_ci : float, tuple of float
        ``false_alarms / healthy_hours`` and its two-sided Poisson (Garwood) interval.
    budget_inside : bool
        Whether the budget lies inside that interval.
    confidence : float
        Level of the interval.
    calibration : dict
        Healthy hours, starts and rate of the calibration streams at the threshold, and how the
        threshold was found.
    onsets : tuple of OnsetFigures
    steps_per_second : float
        Realization-samples per second of the route's scores on the diagnosed runs.
    curve : dict
        ``thresholds``, ``far_per_hour`` (calibration streams), ``far_count``, and per onset
        ``delay_median_s``, ``delay_p90_s``, ``missed`` at each threshold.
    route : route object
        The route as diagnosed (e.g. an innovation route with its healthy NIS scale).
    timings : dict
        Seconds (summed over worker processes) per stage: ``healthy_scores_s`` (the route's scores on
        the calibration streams), ``calibrate_s`` (the layer's calibration), ``curve_s`` (starts at
        every threshold of the grid), ``scores_s`` (scores of the diagnosed runs), ``sweep_s`` (the rule
        at every threshold on them).
    """

    method: str
    rule: dict[str, Any]
    budget_per_hour: float
    score: dict[str, Any]
    runs: int
    healthy_hours: float
    false_alarms: int
    rate_per_hour: float
    rate_ci: tuple[float, float]
    budget_inside: bool
    confidence: float
    calibration: dict[str, Any]
    onsets: tuple[OnsetFigures, ...]
    steps_per_second: float
    curve: dict[str, Any] = field(repr=False)
    timings: dict[str, float] = field(default_factory=dict)
    route: Any = field(default=None, repr=False)

    def describe(self) -> dict[str, Any]:
        """JSON-ready summary (NaN and inf -> None: a missed onset's delay, an uncalibrated threshold)."""
        return _clean(
            {
                "method": self.method,
                "rule": dict(self.rule),
                "budget_per_hour": self.budget_per_hour,
                "score": dict(self.score),
                "runs": self.runs,
                "healthy_hours": self.healthy_hours,
                "false_alarms": self.false_alarms,
                "false_alarm_rate_per_hour": self.rate_per_hour,
                f"false_alarm_rate_ci{round(100 * self.confidence)}": list(self.rate_ci),
                "budget_inside_interval": self.budget_inside,
                "calibration": dict(self.calibration),
                "onsets": [o.describe() for o in self.onsets],
                "steps_per_second": self.steps_per_second,
                "timings_s": dict(self.timings),
                "curve": dict(self.curve),
            }
        )


def _delays(first: np.ndarray, geo: RouteGeometry, i: int) -> np.ndarray:
    """Delays (s) of the first-in-alarm steps ``first`` (G, runs) of onset ``i`` (NaN: none)."""
    t = geo.times
    k = geo.lo[i] + np.maximum(first, 0)
    d = t[np.minimum(k, t.size - 1)] - geo.onsets[i]
    return np.where(first >= 0, np.maximum(d, 0.0), np.nan)


def _quantiles_fresh(d: np.ndarray, before: np.ndarray) -> tuple[float, float]:
    """:func:`_quantiles` of the delays of the runs not in alarm before the onset (NaN if none)."""
    fresh = d[~before]
    return _quantiles(fresh) if fresh.size else (float("nan"), float("nan"))


def summarize_route(
    route: Route,
    geo: RouteGeometry,
    sweep: dict[str, Any],
    *,
    rule: AlarmRule,
    budget: float,
    thresholds: np.ndarray,
    far_count: np.ndarray,
    calibration_hours: float,
    calibration: dict[str, Any],
    seconds: float,
    samples: int,
    confidence: float,
    timings: dict[str, float] | None = None,
) -> RouteBudget:
    """:class:`RouteBudget` from the merged sweep (the last threshold is the calibrated one).

    Parameters
    ----------
    route : route object
        Gives ``method``, ``labels`` and ``describe()``.
    geo : RouteGeometry
    sweep : dict
        :func:`~chatterspec.studies.route_sweep.merge_sweeps` over the diagnosed runs, thresholds
        ``thresholds``.
    rule : alarm rule
        At the calibrated threshold.
    budget : float
        Alarm starts per hour.
    thresholds : (G,) array
        The swept thresholds; the last one is the calibrated threshold.
    far_count : (G,) int array
        Alarm starts of the calibration streams at each threshold.
    calibration_hours : float
        Healthy hours of the calibration streams.
    calibration : dict
        Provenance of the threshold.
    seconds : float
        Time spent computing the route's scores on the diagnosed runs.
    samples : int
        Realization-samples diagnosed.
    confidence : float
        Level of the Poisson interval.
    timings : dict, optional
        Seconds per stage (:attr:`RouteBudget.timings`).
    """
    runs = sweep["runs"]
    G = len(thresholds)
    hours = runs * geo.healthy_steps * geo.step_s / 3600.0
    fa = int(sweep["healthy_starts"][-1])
    if hours > 0:
        lo, hi = poisson_interval(fa, confidence)
        rate, ci = fa / hours, (lo / hours, hi / hours)
        inside = ci[0] <= budget <= ci[1]
    else:
        rate, ci, inside = float("nan"), (float("nan"), float("nan")), False
    onsets = []
    curve_med, curve_p90, curve_missed = [], [], []
    labels = tuple(route.labels)
    for i, onset in enumerate(geo.onsets):
        d = _delays(sweep["first"][i], geo, i)  # (G, runs)
        before = sweep["before"][i]  # (G, runs)
        med_p90 = [_quantiles_fresh(d[g], before[g]) for g in range(G)]
        curve_med.append([m for m, _ in med_p90])
        curve_p90.append([p for _, p in med_p90])
        curve_missed.append([int(np.count_nonzero(~np.isfinite(d[g]) & ~before[g])) for g in range(G)])
        det = np.isfinite(d[-1]) & ~before[-1]
        lab = sweep["label"][i][-1]
        iso = {labels[j]: int(np.count_nonzero(lab[det] == j)) for j in np.unique(lab[det]).tolist()}
        true = geo.true_labels[i]
        if true is not None and true in labels:
            n_ok = int(np.count_nonzero(lab[det] == labels.index(true)))
            ci_ok = clopper_pearson(n_ok, int(det.sum()), 0.99) if det.any() else None
            iso_d = _delays(sweep["iso_first"][i][-1:], geo, i)[0]
            iso_med, iso_p90 = _quantiles(iso_d)
        else:
            n_ok, ci_ok, iso_med, iso_p90 = None, None, float("nan"), float("nan")
        onsets.append(
            OnsetFigures(
                onset_s=float(onset),
                detected=int(det.sum()),
                missed=int(np.count_nonzero(~np.isfinite(d[-1]) & ~before[-1])),
                in_alarm_at_onset=int(np.count_nonzero(before[-1])),
                delay_median_s=med_p90[-1][0],
                delay_p90_s=med_p90[-1][1],
                true_label=true,
                isolated=iso,
                correct=n_ok,
                correct_ci=ci_ok,
                isolation_median_s=iso_med,
                isolation_p90_s=iso_p90,
            )
        )
    far = (np.asarray(far_count, dtype=float) / calibration_hours).tolist() if calibration_hours > 0 else []
    return RouteBudget(
        method=route.method,
        rule=rule.to_dict(),
        budget_per_hour=float(budget),
        score=route.describe(),
        runs=runs,
        healthy_hours=hours,
        false_alarms=fa,
        rate_per_hour=rate,
        rate_ci=ci,
        budget_inside=bool(inside),
        confidence=confidence,
        calibration=dict(calibration),
        onsets=tuple(onsets),
        steps_per_second=samples / seconds if seconds > 0 else float("inf"),
        curve={
            "thresholds": [float(h) for h in thresholds],
            "far_per_hour": far,
            "far_count": [int(c) for c in far_count],
            "calibration_hours": calibration_hours,
            "delay_median_s": curve_med,
            "delay_p90_s": curve_p90,
            "missed": curve_missed,
        },
        timings=dict(timings or {}),
        route=route,
    )
