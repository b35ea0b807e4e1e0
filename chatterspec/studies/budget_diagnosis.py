"""Diagnosis at one false-alarm budget (``chatterspec diagnose``): the routes, their sweep and their results.

In the order a budget diagnosis uses them: the routes as score streams (:class:`Route` and its
kinds), the alarm rules swept over thresholds on a chunk of route scores (:func:`sweep_chunk`), the
per-route results (:class:`RouteBudget`) and the study that calibrates every route's threshold to
the same alarm starts per hour (:func:`diagnose_at_budget`).

The diagnosis routes as score streams: every route through one alarm layer.

A *route* turns one chunk of realizations (a :class:`~chatterspec.plants.simulate.Simulation`) into
a score stream ``(runs, steps, channels)`` for the alarm rules of
:mod:`chatterspec.detection.alarms`, with the time at which each step's score is known and, per
step, the label a route would isolate if it were in alarm then:

========== ============================================ ========================= ================
method     score (per step)                             step                      isolation label
========== ============================================ ========================= ================
chattering ``-log p`` of the STFT frame of the auxiliary  one frame (hop, 0.2 s),   the channel
           sgn-SVSF's chattering, per measured channel  known at the frame's end  in alarm
           (:mod:`chatterspec.detection.verdicts`)
parameters ``-log p`` of "inside its tolerance" of each     one identification        the parameter
           declared parameter's joint estimate          window (hop), known at    in alarm
           (:mod:`chatterspec.detection.                its last sample
           parameter_decision`; tolerances declared)
smm, imm   log posterior odds of the fault modes         one sample                most probable
           (:func:`~chatterspec.detection.route_scores.  (``dt``)                  fault mode
           mode_log_odds`)
innovation covariance-inflation log-likelihood ratio of   one sample (``dt``)       channel of the
           the Kalman filter's (EKF's) NIS (Mehra and                                largest
           Peschon 1971; :mod:`~chatterspec.detection.                               ``e_i^2/S_ii``
           route_scores`)
========== ============================================ ========================= ================

Each route also names the rule parameters its score needs (:meth:`rule_parameters`): the CUSUM drift
is the score's healthy offset (chattering: the layer's default for ``-log p``; innovation: the
``(m/2) log L`` of the likelihood ratio; modes: 0, the log odds being negative when healthy).

Routes are picklable (worker processes run them on their own chunks) and pure: a realization's scores
depend only on that realization, whatever the chunking.

Alarm rules swept over thresholds on one chunk of route scores: false alarms and delays per threshold.

The comparison of the diagnosis routes (``chatterspec diagnose``) needs, for every route and every
threshold ``h`` of a grid, on the *same* realizations:

* the alarm **starts** on healthy time (the false alarms; their rate per hour is what a budget sets);
* per fault onset and run, the first step at or after the onset where the route is in alarm (the
  detection; the delay is that step's time minus the onset), whether the run was already in alarm
  on the last step before the onset, and the label the route isolates at the detection.

:func:`route_geometry` places the onsets and the healthy steps on a route's step times, and
:func:`sweep_chunk` runs the rule (:func:`chatterspec.detection.alarms.run_rule`) for each threshold
and keeps only per-run integers, so that the chunks of a study fold into the same numbers whatever
the chunking (:func:`merge_sweeps`).

Conventions
    * The detector starts at the warm-up time: steps known before it are not fed to the rule (the
      start-up transient of a filter started from ``x0 = 0``, uniform mode probabilities, is not a
      false alarm a person monitoring for hours would see).
    * Healthy time is the time before the first fault onset (after the warm-up); a step is healthy
      when its score is known by the onset (a frame whose last sample is at or before it: the data
      of time ``t`` come from the plant active before ``t``).
    * Onset ``a`` (next change ``b``) is detected at the first step in alarm known in ``(a, b]``.
    * A route is in alarm when any of its score channels is; its alarm starts are counted per
      channel (all channels together, as the monitor's budget counts them).
    * An onset's detection window ends at the next change of the true plant (or the record's end).
    * A run already in alarm on the last step before an onset (a false alarm still active, or an
      earlier fault's alarm) has no new detection there: its delay is not defined (the conditional
      delay of sequential detection, given no alarm at the change) and it is counted apart.

Results of the diagnosis at one false-alarm budget (``chatterspec diagnose``): one record per route.

:class:`RouteBudget` holds, for one route under one rule whose threshold was calibrated on healthy
runs to the budget: the false alarms realized on the diagnosed runs' healthy time with their
two-sided Poisson interval, the detection delay per onset (median, 90th percentile), missed onsets,
isolation, cost, and the delay-against-false-alarms curve (thresholds swept on the same
realizations). :func:`summarize_route` builds it from the merged sweep of
:mod:`chatterspec.studies.budget_diagnosis`.

Diagnosis at one false-alarm budget: every route's threshold calibrated to the same alarm starts per hour.

``chatterspec diagnose NAME --false-alarms-per-hour X`` compares the routes of
:mod:`chatterspec.studies.budget_diagnosis` at equal false-alarm rates (the argmax rule of the mode routes and
the per-frame rule of the chattering route do not alarm equally often, so their delays cannot be
compared as they stand):

1. **Healthy streams** (:class:`HealthyScoresStudy`): ``calibration_runs`` realizations of the
   scenario's healthy version (:func:`~chatterspec.studies.diagnosis.healthy_version`),
   from ``SeedSequence([seed, BUDGET_SALT])``, disjoint from the diagnosed runs; every route scores
   the *same* healthy realizations.
2. **Calibration**: per route, the rule's threshold for ``X`` alarm starts per hour from those
   streams, by the alarm layer's calibration (:mod:`chatterspec.detection.alarms.calibration`); then
   a grid of thresholds around it, with the starts per hour of the healthy streams at each (the
   x-axis of the delay-against-false-alarms curve).
3. **Diagnosis** (:class:`BudgetStudy`): the diagnosed realizations (``SeedSequence(seed)``, the
   same as every other ``diagnose`` output); every route, every threshold of its grid and the
   calibrated one (:func:`~chatterspec.studies.budget_diagnosis.sweep_chunk`). The realized false-alarm
   rate on their healthy time is an out-of-sample check of the calibration.

Both studies run through :func:`~chatterspec.montecarlo.run_study` (serial, worker
processes or Dask) and give the same numbers whatever the workers and the chunking: each
realization's scores depend only on that realization, and the per-run integers are folded in chunk
order.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeAlias, Unpack, cast

import numpy as np

from .._validate import positive
from ..detection.alarms.calibration import poisson_interval
from ..detection.alarms.rules import rule_spec
from ..detection.route_scores import (
    DEFAULT_INFLATION,
    DEFAULT_MODE_FLOOR,
    NIS_CAP_TAIL,
    inflation_drift,
    inflation_score,
    innovation_channel,
    isolated_fault_mode,
    mode_log_odds,
    nis_cap,
    normalized_innovation_squared,
)
from ..errors import ParameterError
from ..jsonout import finite_or_none
from ..montecarlo import Execution, ExecutionOptions
from .intervals import clopper_pearson

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.calibration import RuleCalibration
    from ..detection.alarms.rules import AlarmRule
    from ..detection.spectral import STFTConfig
    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation

__all__ = [
    "ALL_METHODS",
    "BUDGET_SALT",
    "DEFAULT_WARMUP_S",
    "BudgetSettings",
    "BudgetStudy",
    "ChatteringRoute",
    "HealthyScoresStudy",
    "InnovationRoute",
    "ModeRoute",
    "OnsetFigures",
    "ParameterRoute",
    "Route",
    "RouteBudget",
    "RouteGeometry",
    "RouteScores",
    "diagnose_at_budget",
    "merge_sweeps",
    "onsets_of",
    "route_geometry",
    "summarize_route",
    "supported_methods",
    "sweep_chunk",
    "unsupported_reason",
]


#: Every diagnosis method, in table order.
ALL_METHODS = ("chattering", "smm", "imm", "innovation", "parameters")

#: Rule parameters a route may set itself (its score's healthy offset); a rule takes those it has.
ROUTE_RULE_PARAMETERS = ("drift",)


def _taken(rule: str, **offered: float) -> dict[str, float]:
    """The ``offered`` parameters (of :data:`ROUTE_RULE_PARAMETERS`) that ``rule`` has."""
    from ..detection.alarms.rules import rule_spec

    have = rule_spec(rule).parameters
    return {k: v for k, v in offered.items() if k in have}


#: Samples per filter call of the innovation route (bounds the memory of the EKF's per-run S).
INNOVATION_BLOCK = 2048


@dataclass(frozen=True, eq=False)
class RouteScores:
    """One chunk's score stream of a route.

    Attributes
    ----------
    method : str
    times : (steps,) array
        Time (s) at which each step's score is known: the sample time, or a frame's last sample.
    score : (runs, steps, channels) array
        Larger = less healthy.
    label : (runs, steps) int array or None
        Per step, the label the route isolates (an index into the route's ``labels``); ``None``:
        the isolated label is the score channel in alarm.
    seconds : float
        Wall time spent computing the scores.
    """

    method: str
    times: np.ndarray
    score: np.ndarray
    label: np.ndarray | None
    seconds: float


def unsupported_reason(sc: Scenario, method: str) -> str | None:
    """Why ``method`` cannot run on scenario ``sc`` (None when it can)."""
    fs = sc.filter_settings
    if method == "chattering":
        if not getattr(sc.nominal, "full_measurement", False):
            return "a nominal model that measures every state"
        return None
    if method == "innovation":
        return None
    if method == "parameters":
        pm = getattr(sc.nominal, "parameter_map", None)
        if not getattr(sc.nominal, "full_measurement", False) or pm is None or not sc.is_linear:
            return "a linear nominal model that measures every state and declares its parameters"
        if not pm.has_tolerances:
            return "operating tolerances on its declared parameters (--tolerance NAME=SPEC)"
        return None
    if method in ("smm", "imm"):
        if fs is None or not fs.modes:
            return "filter_settings with modes"
        if method == "smm" and fs.psi is None:
            return "filter_settings with modes and psi"
        if method == "imm" and fs.transition_matrix is None:
            return "filter_settings with modes and a transition matrix"
        return None
    raise ParameterError(f"method must be one of {', '.join(ALL_METHODS)}; got {method!r}")


def supported_methods(sc: Scenario) -> tuple[str, ...]:
    """The methods scenario ``sc`` supports, in :data:`ALL_METHODS` order."""
    return tuple(m for m in ALL_METHODS if unsupported_reason(sc, m) is None)


def _initial(sc: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """``x(0|0)`` and ``P(0|0)`` of the scenario's filters (settings, else zeros and 10 Q)."""
    fs = sc.filter_settings
    x0 = np.zeros(sc.nominal.n_states) if fs is None or fs.x0 is None else np.asarray(fs.x0, dtype=float)
    P0 = np.asarray(fs.P0 if fs is not None and fs.P0 is not None else np.asarray(sc.nominal.Q) * 10.0)
    return x0, np.asarray(P0, dtype=float)


class ModeRoute:
    """SMM-SVSF or IMM: log posterior odds of the fault modes against the normal mode.

    Parameters
    ----------
    scenario : Scenario
        ``filter_settings`` with modes (mode 0 normal), ``psi`` (smm) or a transition matrix (imm).
    method : {"smm", "imm"}
    floor : float, optional
        Probability floor of the score (default: the scenario's SMM weight floor, else
        :data:`~chatterspec.detection.route_scores.DEFAULT_MODE_FLOOR`).
    """

    def __init__(self, scenario: Scenario, method: str, floor: float | None = None) -> None:
        from .diagnosis import _filter_for

        why = unsupported_reason(scenario, method) if method in ("smm", "imm") else "smm or imm"
        if why is not None:
            raise ParameterError(f"scenario {scenario.name!r} does not support {method!r} (it needs {why})")
        fs = scenario.filter_settings
        assert fs is not None  # (unsupported_reason: a mode route needs the settings)
        self.scenario = scenario
        self.method = method
        self.filter = _filter_for(method, fs)
        if floor is None:
            floor = fs.weight_floor if fs.weight_floor else DEFAULT_MODE_FLOOR
        self.floor = float(floor)
        #: The score's largest value, ``-log floor``: a frame or persistence threshold above it never alarms.
        self.score_max = -float(np.log(self.floor))
        self.labels = tuple(fs.modes)
        self.channels = ("log odds",)
        self.step_s = float(scenario.dt)
        self._x0, self._P0 = _initial(scenario)

    def step_times(self) -> np.ndarray:
        """When each step's score is known (s): the sample times ``t[1:]``."""
        return self.scenario.time[1:]

    def rule_parameters(self, rule: str) -> dict[str, float]:
        """CUSUM drift 0: the log odds sit near ``log floor`` when healthy."""
        return _taken(rule, drift=0.0)

    def describe(self) -> dict[str, Any]:
        """A short description for reports and recordings."""
        return {"score": "log posterior odds of the fault modes against normal", "floor": self.floor}

    def scores(self, sim: Simulation) -> RouteScores:
        """Score stream of one chunk: times ``t[1:]``, score ``(runs, T - 1, 1)``, label = fault mode."""
        z, u = sim.z[:, 1:], sim.u[..., :-1, :]  # u per run in closed loop
        t0 = time.perf_counter()
        out = self.filter.run(z, u, x0=self._x0, P0=self._P0)
        score = mode_log_odds(out.mu, self.floor)[..., None]
        label = isolated_fault_mode(out.mu).astype(np.int8)
        return RouteScores(self.method, sim.t[1:], score, label, time.perf_counter() - t0)


class InnovationRoute:
    """Kalman filter (EKF on a nonlinear plant) innovations: NIS and its CUSUM likelihood ratio.

    Parameters
    ----------
    scenario : Scenario
        Any scenario; the filter runs on its nominal model (whose ``Q`` and ``R`` are the scenario's
        filter tuning) from the filter settings' ``x0``, ``P0`` (default zeros and ``10 Q``).
    inflation : float
        ``L > 1`` of the covariance-inflation likelihood ratio (default
        :data:`~chatterspec.detection.route_scores.DEFAULT_INFLATION`).
    cap : bool
        Cap NIS at the chi-square quantile of tail :data:`~chatterspec.detection.route_scores.NIS_CAP_TAIL`
        (the CUSUM's robust form; irrelevant to the frame and persistence rules, whose thresholds
        can lie above any cap, so they get the uncapped score).
    scale : float
        NIS is divided by it first (default 1). Where the filter's tuning is not the plant's noise
        (:attr:`matched` false), the healthy NIS is not chi-square and :meth:`with_healthy_scale` sets
        it from healthy runs, so that the likelihood ratio is taken against the innovation covariance the
        healthy data show.

    Attributes
    ----------
    matched : bool
        True when NIS is exactly chi-square on healthy data: a linear nominal model whose ``Q`` and
        ``R`` are those of the scenario's healthy plant (e.g. the linear EHA); false for the EKF on a
        nonlinear plant and for a tuning that differs from the noise (DETC2015).
    """

    method = "innovation"

    def __init__(
        self, scenario: Scenario, inflation: float = DEFAULT_INFLATION, cap: bool = True, scale: float = 1.0
    ) -> None:
        from ..filters import ExtendedKalmanFilter, KalmanFilter
        from ..plants.models import LinearModel

        self.scenario = scenario
        model = scenario.nominal
        self.filter = KalmanFilter(model) if isinstance(model, LinearModel) else ExtendedKalmanFilter(model)
        self.kind = "KF" if isinstance(model, LinearModel) else "EKF"
        m = int(model.n_outputs)
        self.m = m
        self.inflation = float(inflation)
        self.drift = inflation_drift(m, self.inflation)
        self.cap = nis_cap(m, NIS_CAP_TAIL) if cap else None
        self.labels = tuple(model.output_names)
        self.channels = ("NIS LLR",)
        self.step_s = float(scenario.dt)
        self.scale = positive("scale", scale)
        self._x0, self._P0 = _initial(scenario)
        plant = scenario.plant
        self.matched = bool(
            isinstance(model, LinearModel)
            and isinstance(plant, LinearModel)
            and np.allclose(plant.Q, model.Q, rtol=1e-9, atol=0.0)
            and np.allclose(plant.R, model.R, rtol=1e-9, atol=0.0)
            and np.allclose(plant.A, model.A, rtol=1e-12, atol=0.0)
        )

    def with_healthy_scale(self, sim: Simulation) -> InnovationRoute:
        """This route with NIS divided by its healthy scale, measured on the healthy runs ``sim``.

        The scale is ``median(NIS) / median(chi2_m)`` over the samples after the first 10 % of the
        record (a median: the nonlinear EHA's healthy NIS is heavy-tailed at the piston's reversals,
        which a mean would follow); 1 on a matched filter, about 0.01 for the DETC2015 tuning.
        """
        from scipy.stats import chi2

        nis, _ = self.nis(sim)
        k0 = nis.shape[1] // 10
        c = float(np.median(nis[:, k0:]) / chi2.median(self.m))
        return InnovationRoute(self.scenario, self.inflation, cap=self.cap is not None, scale=c)

    def step_times(self) -> np.ndarray:
        """When each step's score is known (s): the sample times ``t[1:]``."""
        return self.scenario.time[1:]

    def rule_parameters(self, rule: str) -> dict[str, float]:
        """CUSUM drift ``(m/2) log L``: the constant term of the likelihood ratio."""
        return _taken(rule, drift=self.drift)

    def describe(self) -> dict[str, Any]:
        """A short description for reports and recordings."""
        return {
            "score": f"(1 - 1/L) min(NIS / scale, cap) / 2 of the {self.kind}",
            "inflation_L": self.inflation,
            "cusum_drift": self.drift,
            "nis_cap": self.cap,
            "nis_scale": self.scale,
            "chi_square_law": self.matched,
            "degrees_of_freedom": self.m,
        }

    def nis(self, sim: Simulation) -> tuple[np.ndarray, np.ndarray]:
        """NIS ``(runs, T - 1)`` and the channel of the largest ``e_i^2 / S_ii`` (runs, T - 1)."""
        z, u = sim.z[:, 1:], sim.u[..., :-1, :]  # u per run in closed loop
        runs, K = z.shape[:2]
        state = self.filter.initialize(self._x0, self._P0, runs=runs)
        nis = np.empty((runs, K))
        chan = np.empty((runs, K), dtype=np.int8)
        for lo in range(0, K, INNOVATION_BLOCK):
            hi = min(lo + INNOVATION_BLOCK, K)
            state, out = self.filter.update(state, z[:, lo:hi], u[..., lo:hi, :], store=("innovation", "S"))
            e, S = out.innovation, out.S
            assert e is not None and S is not None  # (stored)
            nis[:, lo:hi] = normalized_innovation_squared(e, S)
            chan[:, lo:hi] = innovation_channel(e, S)
        return nis, chan

    def scores(self, sim: Simulation) -> RouteScores:
        """Score stream of one chunk: times ``t[1:]``, ``(1 - 1/L) min(NIS, cap) / 2`` (runs, T - 1, 1)."""
        t0 = time.perf_counter()
        nis, chan = self.nis(sim)
        if self.scale != 1.0:
            nis /= self.scale
        score = inflation_score(nis, self.inflation, self.cap)[..., None]
        return RouteScores(self.method, sim.t[1:], score, chan, time.perf_counter() - t0)


class ChatteringRoute:
    """STFT of the auxiliary sgn-SVSF's chattering: per frame and channel ``-log p``.

    Parameters
    ----------
    scenario : Scenario
        A scenario whose nominal model measures every state.
    law : Threshold
        The healthy law of the frame bins (:class:`~chatterspec.detection.verdicts.FrameScore`):
        the exact law of a linear model (:func:`~chatterspec.detection.thresholds.frame_threshold`) or a
        calibration's per-frame threshold (its expected spectrum) for a nonlinear one.
    config : STFTConfig, optional
        STFT settings (default 1 s Hamming window, 0.2 s hop).
    gamma : float
        Convergence rate of the auxiliary SVSF in (0, 1) (eq 8-10).
    """

    method = "chattering"

    def __init__(
        self, scenario: Scenario, law: Threshold, config: STFTConfig | None = None, gamma: float = 0.1
    ) -> None:
        from ..detection.spectral import STFTConfig
        from ..detection.verdicts import FrameScore

        why = unsupported_reason(scenario, "chattering")
        if why is not None:
            raise ParameterError(f"scenario {scenario.name!r} does not support 'chattering' (it needs {why})")
        self.scenario = scenario
        self.config = STFTConfig() if config is None else config
        self.gamma = float(gamma)
        self.law = law
        self._score: FrameScore | None = FrameScore(law)
        model = scenario.nominal
        self.labels = tuple(model.output_names)
        self.channels = tuple(model.output_names)
        self.step_s = float(self.config.n_hop(model.dt) * model.dt)
        self._W = self.config.n_window(model.dt)

    def step_times(self) -> np.ndarray:
        """When each frame's score is known (s): the time of its last sample."""
        t = self.scenario.time
        n = t.size - 1  # chattering samples 1 .. T-1
        H = self.config.n_hop(self.scenario.dt)
        starts = np.arange((n - self._W) // H + 1) * H if n >= self._W else np.zeros(0, dtype=int)
        return t[starts + self._W]

    @property
    def frame_score(self) -> Any:
        """The :class:`~chatterspec.detection.verdicts.FrameScore` of the law (rebuilt after pickling)."""
        if self._score is None:
            from ..detection.verdicts import FrameScore

            self._score = FrameScore(self.law)
        return self._score

    def __getstate__(self) -> dict[str, Any]:
        # a FrameScore holds the Python function behind a compiled kernel, which pickle cannot send to a
        # worker process; the law it is built from can
        return {**self.__dict__, "_score": None}

    def own_calibration(self, rule: AlarmRule, budget: float, seed: int, confidence: float) -> Any:
        """On a linear model, the monitor's threshold for ``rule`` at ``budget`` (else None).

        The healthy chattering of a linear model is an exact MA(1) process, so the alarm layer's monitor
        calibration (:func:`~chatterspec.studies.alarm_budget.calibrate_alarm`: its in-call hours of
        continuous healthy frames, seeds ``[seed, ALARM_SALT, block]``) applies as it stands, and gives
        the threshold ``chatterspec monitor`` would use at this budget; the 4 s records of the linear
        catalogue hold too few frames per run (16) for the diagnosis's own healthy runs to reach one
        false alarm per hour.
        """
        from ..plants.models import LinearModel

        model = self.scenario.nominal
        if not isinstance(model, LinearModel) or self.frame_score.law != "exact":
            return None
        from ..detection.alarms.calibration import MonitorSettings
        from .alarm_budget import calibrate_alarm

        settings = MonitorSettings(stft=self.config, threshold=self.law)
        return calibrate_alarm(model, settings, rule, budget, seed=int(seed), confidence=confidence)

    def rule_parameters(self, rule: str) -> dict[str, float]:
        """The layer's defaults (its CUSUM drift is set for ``-log p``)."""
        return {}

    def describe(self) -> dict[str, Any]:
        """A short description for reports and recordings."""
        return {"score": "-log p of the STFT frame (Bonferroni over bins)", "law": self.frame_score.law}

    def scores(self, sim: Simulation) -> RouteScores:
        """Score stream of one chunk: frame end times, ``-log p`` ``(runs, frames, m)``, label None."""
        from ..detection.pipeline import chattering_record
        from ..detection.spectral import spectrogram

        model = self.scenario.nominal
        t0 = time.perf_counter()
        rec = chattering_record(model, sim.z, sim.u, gamma=self.gamma)
        spec = spectrogram(rec.values, model.dt, self.config)
        score = self.frame_score(spec.power)
        # frame j covers chattering samples [jH, jH + W) = simulation samples [jH + 1, jH + W]
        times = sim.t[np.asarray(spec.frame_starts) + self._W]
        return RouteScores(self.method, times, score, None, time.perf_counter() - t0)


class ParameterRoute:
    """The identified parameters against their tolerances: per hop and parameter ``-log p`` of "the
    parameter lies inside its band" (:mod:`chatterspec.detection.parameter_decision`).

    Parameters
    ----------
    scenario : Scenario
        Its nominal model declares tolerances on its parameters (and measures every state).
    config : STFTConfig, optional
        Hop and window of the identification (default 1 s window, 0.2 s hop: the monitor's).
    """

    method = "parameters"

    def __init__(self, scenario: Any, config: Any = None) -> None:
        from ..detection.identification import identification_setup
        from ..detection.parameter_decision import ParameterBands
        from ..detection.spectral import STFTConfig

        why = unsupported_reason(scenario, "parameters")
        if why is not None:
            raise ParameterError(f"scenario {scenario.name!r} does not support 'parameters' (it needs {why})")
        self.scenario = scenario
        self.config = STFTConfig() if config is None else config
        model = scenario.nominal
        self.setup = identification_setup(model, [list(model.parameter_map.parameter_names)])
        self.bands = ParameterBands.from_map(model.parameter_map)
        self.labels = self.channels = self.bands.names
        self.H = self.config.n_hop(model.dt)
        self.n = max(1, round(self.config.n_window(model.dt) / self.H))
        self.step_s = float(self.H * model.dt)

    def _known(self, t: np.ndarray) -> np.ndarray:
        """When each window's score is known (s): its last chattering sample ``e(k+1)``, ``k = j H + n H``."""
        W = (t.size - 2) // self.H - self.n + 1
        return t[np.arange(max(W, 0)) * self.H + self.n * self.H + 1]

    def step_times(self) -> np.ndarray:
        """When each window's score is known (s)."""
        return self._known(self.scenario.time)

    def own_calibration(self, rule: Any, budget: float, seed: int, confidence: float) -> Any:
        """The monitor's threshold: the rule on worst-case streams (parameters on their band edges), not
        on healthy runs, whose parameters sit at the nominal values inside the bands (a threshold set on
        them would alarm on a plant that moved within its tolerance)."""
        from ..detection.parameter_decision import calibrate_parameter_rule

        per_hour = 3600.0 / self.step_s
        return calibrate_parameter_rule(rule, self.bands, self.n, per_hour, budget, seed=int(seed))

    def rule_parameters(self, rule: str) -> dict[str, float]:
        """The layer's defaults (its CUSUM drift is set for ``-log p``)."""
        return {}

    def describe(self) -> dict[str, Any]:
        """A short description for reports and recordings."""
        b = self.bands
        return {
            "score": "-log p of each parameter's joint estimate inside its tolerance band",
            "tolerances": {p: (t or None) for p, t in zip(b.names, b.tolerances, strict=True)},
            "window_s": self.n * self.step_s,
        }

    def scores(self, sim: Any) -> RouteScores:
        """Score stream of one chunk: window end times, ``(runs, windows, P)``, label None (the parameter)."""
        from ..detection.identification import hop_windows, identify_moments
        from ..detection.parameter_decision import band_scores, joint_estimates

        t0 = time.perf_counter()
        runs = sim.z.shape[0]
        _, _, mom = hop_windows(self.setup, sim.z, sim.u, hop_samples=self.H, window_hops=self.n, t0=sim.t[0])
        theta, se, fits = joint_estimates(identify_moments(self.setup, mom))
        se = np.where(fits[:, None], se, np.nan)  # a window the parameters do not describe: no evidence
        score = band_scores(theta, se, self.bands.low, self.bands.high).reshape(runs, -1, self.bands.size)
        return RouteScores(self.method, self._known(sim.t), score, None, time.perf_counter() - t0)


#: A diagnosis route: the per-frame score of one method.
Route: TypeAlias = ModeRoute | InnovationRoute | ChatteringRoute | ParameterRoute


#: Seconds of start-up not fed to the rules (the filters start from ``x0 = 0`` and uniform modes).
DEFAULT_WARMUP_S = 0.1


def onsets_of(sc: Scenario) -> tuple[tuple[float, float, int], ...]:
    """Fault onsets of scenario ``sc``: ``(onset_s, end_s, segment)`` per change into a faulty segment.

    ``end_s`` is the next change of the true plant (or the record's end); a scenario faulty from
    ``t = 0`` has an onset at 0.
    """
    segs = sc.segments
    out = []
    for i, s in enumerate(segs):
        if not sc.deviates(s):
            continue
        if i > 0 and segs[i - 1].model is s.model:
            continue
        out.append((float(s.start), float(s.stop), i))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class RouteGeometry:
    """Where the healthy steps and the onsets fall on a route's step times.

    Attributes
    ----------
    first : int
        First step fed to the rule (the first whose time is >= the warm-up).
    times : (steps,) array
        Step times (s) from ``first`` on.
    healthy : (steps,) bool array
        Steps known by the first onset.
    onsets : tuple of float
        Onset times (s).
    lo, hi : tuple of int
        Per onset, the detection window: steps ``lo .. hi - 1`` (from ``first``), known in ``(a, b]``.
    true_labels : tuple of str or None
        Per onset, the label a correct isolation names (the new mode), when the route isolates modes.
    step_s : float
        Seconds of data per step (``dt`` or the STFT hop).
    """

    first: int
    times: np.ndarray
    healthy: np.ndarray
    onsets: tuple[float, ...]
    lo: tuple[int, ...]
    hi: tuple[int, ...]
    true_labels: tuple[str | None, ...]
    step_s: float

    @property
    def healthy_steps(self) -> int:
        """Number of healthy steps."""
        return int(np.count_nonzero(self.healthy))


def route_geometry(
    sc: Scenario, times: np.ndarray, step_s: float, warmup: float, modes: tuple[str, ...] | None = None
) -> RouteGeometry:
    """Healthy steps and onset windows of a route whose step ``j`` is known at ``times[j]`` (s).

    Parameters
    ----------
    sc : Scenario
        The diagnosed scenario.
    times : (steps,) array
        When each step's score is known (s).
    step_s : float
        Seconds of data per step.
    warmup : float
        Steps known before this time (s) are not fed to the rule.
    modes : tuple of str, optional
        The route's mode names (mode routes): the onsets' true new modes are looked up among them.

    Returns
    -------
    RouteGeometry
    """
    times = np.asarray(times, dtype=float)
    first = int(np.searchsorted(times, warmup - 1e-9 * step_s, side="left"))
    t = times[first:]
    if not t.size:
        raise ParameterError(f"the warm-up ({warmup:g} s) leaves no step of the record to diagnose")
    ons = onsets_of(sc)
    t_first = ons[0][0] if ons else float("inf")
    # the score known at t depends on the data up to t, which the plant active before t produced:
    # a step is healthy when t <= the first onset, and onset a's window (next change b) is (a, b]
    eps = 1e-9 * step_s
    healthy = t <= t_first + eps
    lo = tuple(int(np.searchsorted(t, a + eps, side="right")) for a, _, _ in ons)
    hi = tuple(int(np.searchsorted(t, b + eps, side="right")) for _, b, _ in ons)
    labels: list[str | None] = []
    for _, _, i in ons:
        name = None
        if modes is not None and sc.filter_settings is not None:
            from ..plants.nonlinear import same_dynamics

            seg = sc.segments[i]
            hit = [j for j, m in enumerate(sc.filter_settings.mode_models) if same_dynamics(m, seg.model)]
            name = modes[hit[0]] if hit else None
        labels.append(name)
    return RouteGeometry(first, t, healthy, tuple(a for a, _, _ in ons), lo, hi, tuple(labels), float(step_s))


def sweep_chunk(
    route_scores: RouteScores,
    geometry: RouteGeometry,
    rule: AlarmRule,
    thresholds: np.ndarray,
    labels: tuple[str, ...],
) -> dict[str, Any]:
    """Run ``rule`` at every threshold on one chunk's scores; keep per-run integers.

    Parameters
    ----------
    route_scores : RouteScores
        The chunk's scores ``(runs, steps, C)`` (all steps; :attr:`RouteGeometry.first` on are fed).
    geometry : RouteGeometry
    rule : alarm rule
        Its threshold is replaced by each entry of ``thresholds``.
    thresholds : (G,) array
    labels : tuple of str
        The route's labels (``route_scores.label`` indexes them; with no label array, the score
        channel in alarm is the label).

    Returns
    -------
    dict
        ``healthy_starts`` (G,) int; per onset ``first`` (G, runs) int step in the window (-1: none),
        ``label`` (G, runs) int label at detection (-1), ``iso_first`` (G, runs) first step in alarm
        with the correct label (-1; mode routes), ``before`` (G, runs) bool: in alarm on the last step
        before the onset.
    """
    from ..detection.alarms.streams import run_rule

    g0 = geometry
    s = np.ascontiguousarray(route_scores.score[:, g0.first :])
    lab = None if route_scores.label is None else route_scores.label[:, g0.first :]
    runs = s.shape[0]
    if s.shape[1] != g0.times.size:
        raise ParameterError(
            f"every chunk must have the scenario's record length: {s.shape[1]} steps, not {g0.times.size}"
        )
    G = len(thresholds)
    n_on = len(g0.onsets)
    out: dict[str, Any] = {
        "runs": runs,
        "healthy_starts": np.zeros(G, dtype=np.int64),
        "first": [np.full((G, runs), -1, dtype=np.int32) for _ in range(n_on)],
        "label": [np.full((G, runs), -1, dtype=np.int16) for _ in range(n_on)],
        "iso_first": [np.full((G, runs), -1, dtype=np.int32) for _ in range(n_on)],
        "before": [np.zeros((G, runs), dtype=bool) for _ in range(n_on)],
    }
    true_idx = [labels.index(x) if x is not None and x in labels else -1 for x in g0.true_labels]
    rows = np.arange(runs)
    for g, h in enumerate(thresholds):
        blk = run_rule(rule.with_threshold(float(h)), s)
        act_c = blk.active  # (runs, steps, C)
        active = cast(np.ndarray, act_c.any(axis=-1))  # (runs, steps)
        if g0.healthy.any():
            out["healthy_starts"][g] = int(np.count_nonzero(blk.starts[:, g0.healthy]))
        for i in range(n_on):
            lo, hi = g0.lo[i], g0.hi[i]
            win = active[:, lo:hi]
            hit = win.any(axis=1)
            first = np.where(hit, np.argmax(win, axis=1), -1)
            out["first"][i][g] = first
            if lo > 0:
                out["before"][i][g] = active[:, lo - 1]
            k = lo + np.maximum(first, 0)
            if lab is not None:
                at = lab[rows, k]
            else:
                at = np.argmax(act_c[rows, k], axis=-1)
            out["label"][i][g] = np.where(hit, at, -1)
            if lab is not None and true_idx[i] >= 0:
                ok = win & (lab[:, lo:hi] == true_idx[i])
                out["iso_first"][i][g] = np.where(ok.any(axis=1), np.argmax(ok, axis=1), -1)
    return out


def merge_sweeps(acc: dict[str, Any] | None, part: dict[str, Any]) -> dict[str, Any]:
    """Fold ``part``, one chunk's :func:`sweep_chunk`, into ``acc`` (None at first; runs in chunk order)."""
    if acc is None:
        return part
    out = {
        "runs": acc["runs"] + part["runs"],
        "healthy_starts": acc["healthy_starts"] + part["healthy_starts"],
    }
    for key in ("first", "label", "iso_first", "before"):
        out[key] = [np.concatenate([a, b], axis=1) for a, b in zip(acc[key], part[key], strict=True)]
    return out


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
        :func:`~chatterspec.studies.budget_diagnosis.merge_sweeps` over the diagnosed runs, thresholds
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
        Method -> :class:`~chatterspec.studies.budget_diagnosis.RouteGeometry`.
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
        Method -> route (:mod:`chatterspec.studies.budget_diagnosis`), in table order.
    runs : int
        Diagnosed realizations.
    seed : int
        Root seed of the diagnosed runs; the calibration streams use ``[seed, BUDGET_SALT]``.
    settings : BudgetSettings
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    list of RouteBudget
        One per route, in the order of ``routes``.
    """
    from .diagnosis import healthy_version

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
