"""Diagnosis at one false-alarm budget: every route's threshold calibrated to the same alarm starts per hour.

``chatterspec diagnose NAME --false-alarms-per-hour X`` compares the routes of
:mod:`chatterspec.studies.routes` at equal false-alarm rates (the argmax rule of the mode routes and
the per-frame rule of the chattering route do not alarm equally often, so their delays cannot be
compared as they stand):

1. **Healthy streams** (:class:`HealthyScoresStudy`): ``calibration_runs`` realizations of the
   scenario's healthy version (:func:`~chatterspec.studies.chattering_diagnosis.healthy_version`),
   from ``SeedSequence([seed, BUDGET_SALT])``, disjoint from the diagnosed runs; every route scores
   the *same* healthy realizations.
2. **Calibration**: per route, the rule's threshold for ``X`` alarm starts per hour from those
   streams, by the alarm layer's calibration (:mod:`chatterspec.detection.alarms.calibration`); then
   a grid of thresholds around it, with the starts per hour of the healthy streams at each (the
   x-axis of the delay-against-false-alarms curve).
3. **Diagnosis** (:class:`BudgetStudy`): the diagnosed realizations (``SeedSequence(seed)``, the
   same as every other ``diagnose`` output); every route, every threshold of its grid and the
   calibrated one (:func:`~chatterspec.studies.route_sweep.sweep_chunk`). The realized false-alarm
   rate on their healthy time is an out-of-sample check of the calibration.

Both studies run through :func:`~chatterspec.montecarlo.run_study` (serial, worker
processes or Dask) and give the same numbers whatever the workers and the chunking: each
realization's scores depend only on that realization, and the per-run integers are folded in chunk
order.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Unpack

import numpy as np

from ..detection.alarms.rules import rule_spec
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions
from .budget_results import RouteBudget, summarize_route
from .route_sweep import DEFAULT_WARMUP_S, merge_sweeps, route_geometry, sweep_chunk

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.calibration import RuleCalibration
    from ..detection.alarms.rules import AlarmRule
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation
    from .routes import Route

__all__ = [
    "BUDGET_SALT",
    "DEFAULT_WARMUP_S",
    "BudgetSettings",
    "BudgetStudy",
    "HealthyScoresStudy",
    "diagnose_at_budget",
]

#: Second entropy word of the healthy calibration streams: ``SeedSequence([seed, BUDGET_SALT])`` is
#: independent of the diagnosed runs (``SeedSequence(seed)``) and of the chattering normalization's
#: calibration (``CALIBRATION_SALT``).
BUDGET_SALT = 0xB0D6E7
#: Thresholds of the delay-against-false-alarms curve (besides the calibrated one).
GRID_POINTS = 24
#: Healthy runs that measure the NIS scale of an innovation route whose tuning is not the noise, from
#: ``SeedSequence([seed, BUDGET_SALT, 1])`` (disjoint from the calibration streams).
PILOT_RUNS = 64


@dataclass(frozen=True)
class BudgetSettings:
    """How the routes are compared.

    Attributes
    ----------
    budget_per_hour : float
        False alarms (alarm starts) per hour of healthy time, > 0 and finite.
    rule : str
        Alarm rule of every route (``frame``, ``persistence``, ``cusum``).
    rule_parameters : dict
        Parameters common to every route (e.g. persistence ``k``, ``n``); a route's own defaults
        (its CUSUM drift) fill the rest.
    warmup_s : float
        Start-up time not fed to the rules (s, >= 0).
    calibration_runs : int
        Healthy realizations of the calibration streams (default 1000: 2.3-2.5 h of the 9 s EHA records).
    confidence : float
        Level of the realized rate's Poisson interval.
    calibration_confidence : float
        Level of the calibration's threshold and rate intervals (jackknife).
    """

    budget_per_hour: float = 1.0
    rule: str = "cusum"
    rule_parameters: tuple[tuple[str, Any], ...] = ()
    warmup_s: float = DEFAULT_WARMUP_S
    calibration_runs: int = 1000
    confidence: float = 0.99
    calibration_confidence: float = 0.95

    def __post_init__(self) -> None:
        from ..detection.alarms.calibration import check_budget

        object.__setattr__(self, "budget_per_hour", check_budget(self.budget_per_hour, "budget_per_hour"))
        if not (math.isfinite(self.warmup_s) and self.warmup_s >= 0):
            raise ParameterError(
                f"the warm-up must be a finite number of seconds >= 0; got {self.warmup_s!r}"
            )

    def make_rule(self, route: Route, threshold: float = float("inf")) -> Any:
        """The rule for ``route`` at ``threshold`` (route defaults, then the common parameters)."""
        from ..detection.alarms.rules import make_rule

        params = {**route.rule_parameters(self.rule), **dict(self.rule_parameters)}
        return make_rule(self.rule, threshold, **params)


def _scores_after_warmup(route: Route, sim: Simulation, warmup: float) -> tuple[np.ndarray, float]:
    rs = route.scores(sim)
    first = int(np.searchsorted(rs.times, warmup - 1e-9 * route.step_s, side="left"))
    return rs.score[:, first:], rs.seconds


class HealthyScoresStudy:
    """Scores of every route on healthy realizations (a :class:`~chatterspec.montecarlo.Study`).

    Parameters
    ----------
    scenario : Scenario
        A healthy scenario (the diagnosed one's healthy version).
    routes : dict
        Method -> route.
    warmup : float
        Steps known before this time (s) are dropped.
    """

    def __init__(self, scenario: Scenario, routes: dict[str, Any], warmup: float) -> None:
        self.scenario = scenario
        self.routes = routes
        self.warmup = float(warmup)

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, tuple]:
        """Per method ``(scores (runs, steps after the warm-up, C), seconds)`` of one chunk."""
        from ..plants.simulate import iter_simulations

        sim = next(iter_simulations(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run))
        return {m: _scores_after_warmup(r, sim, self.warmup) for m, r in self.routes.items()}

    def reduce(self, acc: dict | None, part: dict) -> dict:
        """Per method ``([scores of each chunk], seconds)``."""
        if acc is None:
            return {m: ([v], s) for m, (v, s) in part.items()}
        return {m: ([*acc[m][0], v], acc[m][1] + s) for m, (v, s) in part.items()}


class BudgetStudy:
    """Every route and threshold on the diagnosed realizations (a :class:`~chatterspec.montecarlo.Study`).

    Parameters
    ----------
    scenario : Scenario
    routes : dict
        Method -> route.
    rules : dict
        Method -> alarm rule (any threshold; the grid replaces it).
    grids : dict
        Method -> thresholds ``(G,)`` (the last one the calibrated threshold).
    geometries : dict
        Method -> :class:`~chatterspec.studies.route_sweep.RouteGeometry`.
    """

    def __init__(self, scenario: Scenario, routes: dict, rules: dict, grids: dict, geometries: dict) -> None:
        self.scenario = scenario
        self.routes = routes
        self.rules = rules
        self.grids = grids
        self.geometries = geometries

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, Any]:
        """The summary of realizations ``first_run .. first_run + runs - 1`` (a Monte Carlo chunk)."""
        from ..plants.simulate import iter_simulations

        sim = next(iter_simulations(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run))
        out = {}
        for m, route in self.routes.items():
            rs = route.scores(sim)
            t0 = time.perf_counter()
            part = sweep_chunk(rs, self.geometries[m], self.rules[m], self.grids[m], route.labels)
            part["seconds"] = rs.seconds
            part["rule_seconds"] = time.perf_counter() - t0
            out[m] = part
        return out

    def reduce(self, acc: dict | None, part: dict) -> dict:
        """``acc`` with one chunk's summary ``part`` folded in (``acc`` is None for the first chunk)."""
        if acc is None:
            return part
        out = {}
        for m, p in part.items():
            a = acc[m]
            merged = merge_sweeps({k: v for k, v in a.items() if k not in ("seconds", "rule_seconds")}, p)
            merged["seconds"] = a["seconds"] + p["seconds"]
            merged["rule_seconds"] = a["rule_seconds"] + p["rule_seconds"]
            out[m] = merged
        return out


def _count_starts(rule: AlarmRule, scores: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Alarm starts (all streams and channels together) of ``rule`` at each threshold on healthy scores."""
    from ..detection.alarms.calibration import starts_on_grid

    counts = starts_on_grid(rule, scores, thresholds)
    return counts.reshape(len(thresholds), -1).sum(axis=1).astype(np.int64)


def threshold_grid(
    rule: AlarmRule, scores: np.ndarray, h_star: float, points: int = GRID_POINTS
) -> np.ndarray:
    """Thresholds for the delay-against-false-alarms curve around the calibrated ``h_star``.

    A rule thresholding each step's score (``frame``, ``persistence``): upper quantiles of the healthy
    scores (from the median to the largest), so the curve spans every false-alarm rate the healthy
    streams can show. A rule on an accumulated statistic (:attr:`RuleSpec.accumulates`, ``cusum``):
    geometric from ``h_star / 50`` to ``2 h_star`` (``h_star`` not finite: from the largest healthy
    score to 100 times it).
    """
    flat = np.asarray(scores, dtype=float).ravel()
    flat = flat[np.isfinite(flat)]
    if rule_spec(rule).accumulates:
        top = h_star if math.isfinite(h_star) and h_star > 0 else max(float(flat.max(initial=1.0)), 1.0) * 50
        grid = np.geomspace(top / 50.0, 2.0 * top, points)
    else:
        q = 1.0 - np.geomspace(0.5, 1.0 / max(flat.size, 2), points - 1)
        grid = np.unique(np.append(np.quantile(flat, q), np.nextafter(flat.max(initial=0.0), np.inf)))
    return np.asarray(grid, dtype=float)


def _scaled(routes: dict[str, Any], healthy_sc: Scenario, seed: int) -> dict[str, Any]:
    """Routes whose score needs a healthy scale first (an innovation route off the chi-square law)."""
    out = dict(routes)
    for m, route in routes.items():
        if getattr(route, "matched", True) or not hasattr(route, "with_healthy_scale"):
            continue
        from ..plants.simulate import iter_simulations

        root = np.random.SeedSequence([int(seed), BUDGET_SALT, 1])
        sim = next(iter_simulations(healthy_sc, PILOT_RUNS, root, chunk_runs=PILOT_RUNS))
        out[m] = route.with_healthy_scale(sim)
    return out


def _calibrate(
    rule: AlarmRule, scores: np.ndarray, budget: float, steps_per_hour: float, confidence: float
) -> tuple[float, dict[str, Any]]:
    """The alarm layer's calibration of ``rule``'s threshold to ``budget`` starts per hour.

    Returns ``(threshold, provenance)``; a rule the healthy streams cannot calibrate (e.g. the
    frame rule on a bounded score whose healthy excursions reach its maximum more often than the
    budget allows) gets ``inf`` (it never alarms) and the layer's reason.
    """
    from ..detection.alarms.calibration import calibrate_rule

    try:
        cal = calibrate_rule(rule, scores, steps_per_hour, budget, confidence=confidence)
    except ParameterError as exc:
        return float("inf"), {"method": "failed", "reason": str(exc)}
    return float(cal.threshold), _provenance(cal)


def _provenance(cal: RuleCalibration) -> dict[str, Any]:
    """A :class:`~chatterspec.detection.alarms.calibration.RuleCalibration` as JSON (without its fit)."""
    d = cal.to_dict()
    d.pop("fit", None)
    d["describe"] = cal.describe()
    return d


def diagnose_at_budget(
    scenario: Scenario,
    routes: dict[str, Any],
    runs: int,
    seed: int,
    settings: BudgetSettings,
    **execution: Unpack[ExecutionOptions],
) -> list[RouteBudget]:
    """Calibrate every route to ``settings.budget_per_hour`` on healthy runs, then diagnose ``runs``.

    Parameters
    ----------
    scenario : Scenario
        The diagnosed scenario (faulty; its healthy version is calibrated).
    routes : dict
        Method -> route (:mod:`chatterspec.studies.routes`), in table order.
    runs : int
        Diagnosed realizations.
    seed : int
        Root seed of the diagnosed runs; the calibration streams use ``[seed, BUDGET_SALT]``.
    settings : BudgetSettings
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    list of RouteBudget
        One per route, in the order of ``routes``.
    """
    from .chattering_diagnosis import healthy_version

    ex = Execution(**execution)
    if not routes:
        raise ParameterError("no route to diagnose")
    warm = settings.warmup_s
    healthy_sc = healthy_version(scenario)
    routes = _scaled(routes, healthy_sc, seed)
    root = np.random.SeedSequence([int(seed), BUDGET_SALT])
    healthy_study = HealthyScoresStudy(healthy_sc, routes, warm)
    healthy = ex.run(healthy_study, settings.calibration_runs, root, "diagnose: healthy streams")
    rules, grids, geos, far, cal_info, cal_hours, timings = {}, {}, {}, {}, {}, {}, {}
    for m, route in routes.items():
        parts, healthy_s = healthy.pop(m)
        scores = np.concatenate(parts)
        del parts
        cal_hours[m] = scores.shape[0] * scores.shape[1] * route.step_s / 3600.0
        base = settings.make_rule(route)
        t0 = time.perf_counter()
        own = getattr(route, "own_calibration", None)
        cal = (
            None
            if own is None
            else own(base, settings.budget_per_hour, seed, settings.calibration_confidence)
        )
        if cal is not None:  # the monitor's threshold on the exact healthy law (chattering, linear model)
            h_star, info = float(cal.threshold), _provenance(cal)
        else:
            h_star, info = _calibrate(
                base, scores, settings.budget_per_hour, 3600.0 / route.step_s, settings.calibration_confidence
            )
        t1 = time.perf_counter()
        top = getattr(route, "score_max", float("inf"))
        if not rule_spec(base).accumulates and math.isfinite(h_star) and h_star > top:
            info["never_alarms"] = (
                f"the threshold {h_star:.4g} lies above the score's largest value {top:.4g}: at this budget "
                f"the {base.name} rule never alarms on this route"
            )
        grid = np.append(threshold_grid(base, scores, h_star), h_star)
        rules[m], grids[m] = base.with_threshold(h_star), grid
        far[m] = _count_starts(base, scores, grid)
        del scores
        timings[m] = {
            "healthy_scores_s": healthy_s,
            "calibrate_s": t1 - t0,
            "curve_s": time.perf_counter() - t1,
        }
        cal_info[m] = {
            **info,
            "runs": settings.calibration_runs,
            "seed": f"SeedSequence([{int(seed)}, {BUDGET_SALT:#x}])",
            "healthy_hours": cal_hours[m],
            "starts_at_threshold": int(far[m][-1]),
        }
    for m, route in routes.items():
        times = route.step_times()
        geos[m] = route_geometry(
            scenario,
            times,
            route.step_s,
            warm,
            getattr(route, "labels", None) if m in ("smm", "imm") else None,
        )
    merged = ex.run(BudgetStudy(scenario, routes, rules, grids, geos), runs, seed, "diagnose")
    samples = runs * (scenario.n_samples - 1)
    return [
        summarize_route(
            route,
            geos[m],
            merged[m],
            rule=rules[m],
            budget=settings.budget_per_hour,
            thresholds=grids[m],
            far_count=far[m],
            calibration_hours=cal_hours[m],
            calibration=cal_info[m],
            seconds=merged[m]["seconds"],
            samples=samples,
            confidence=settings.confidence,
            timings={**timings[m], "scores_s": merged[m]["seconds"], "sweep_s": merged[m]["rule_seconds"]},
        )
        for m, route in routes.items()
    ]
