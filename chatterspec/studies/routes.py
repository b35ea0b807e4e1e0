"""The diagnosis routes as score streams: every route through one alarm layer.

A *route* turns one chunk of realizations (a :class:`~chatterspec.plants.simulate.Simulation`) into
a score stream ``(runs, steps, channels)`` for the alarm rules of
:mod:`chatterspec.detection.alarms.streams`, with the time at which each step's score is known and, per
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
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeAlias

import numpy as np

from .._validate import positive
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

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.rules import AlarmRule
    from ..detection.spectral import STFTConfig
    from ..detection.thresholds import Threshold
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation

__all__ = [
    "ALL_METHODS",
    "ChatteringRoute",
    "InnovationRoute",
    "ModeRoute",
    "ParameterRoute",
    "Route",
    "RouteScores",
    "supported_methods",
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
        from .mode_diagnosis import _filter_for

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
