"""The realistic bench: plants that differ from the nominal model as real ones do, monitored for a day.

Every other study of the package monitors plants that match their model exactly. Here the nominal
model is the linear EHA (``chatterspec scenarios eha-healthy --model-toml``: leakage, friction and
bulk modulus declared in its ``[parameters]``) and each :class:`BenchCase` is a plant that differs
from it:

* **parametric**: a declared parameter off by 3, 10 and 30 % (leakage and friction high, bulk
  modulus low: warm oil, entrained air), alone and all three together; the true plant's A and B come
  from the model's parameter map (:meth:`chatterspec.plants.parameters.ParameterMap.model_with`);
* **noise level**: the sensor noise ``x0.5`` and ``x2`` the model's ``R``;
* **sensor**: AR(1) coloured noise (rho 0.5, 0.9), Student-t noise (nu 4), a 12-bit ADC over
  position +-2 m, velocity +-1 m/s, pressure +-2e7 Pa (+-200 bar) and the same at 16 bits, 50 Hz
  mains hum of half the noise standard deviation per channel, a bias drift (Gauss-Markov, twice the
  noise standard deviation, correlation time 600 s), sampling jitter of 10 us (1 % of dt)
  (:mod:`chatterspec.plants.imperfections`);
* **nonlinear**: the 4-state EHA (:mod:`chatterspec.plants.eha4`), its position, velocity and
  pressure measured with the model's noise, under the SMM paper's input (94.25 sin(pi t) rad/s: the
  catalogue chirp drives its explicit Euler step beyond its stability limit, |v| < 0.056 m/s).

The linear plants run under the catalogue chirp (10-100 Hz, 300 rad/s, repeated every 4 s). The
plant is simulated without measurement noise and the case's sensor chain adds it (white ``N(0, R)``
for the parametric cases and the nonlinear plant).

Each case is monitored by every route (:class:`BenchRoute`, below, prepared from the
nominal model and the plant's own healthy data): (a) the nominal model with its simulated calibration;
(b) the model :func:`chatterspec.commission` fits to ``commission_s`` seconds of the plant's healthy
data (a refusal reported with its reason); (c) the nominal model with operating tolerances, decided on
the identified parameters (or, route ``commissioned-tolerances``, the commissioned model with them);
and the remedy for a noise the model does not describe: the nominal model with thresholds from
``recorded_hours`` of the plant's recorded healthy data.

Measured per case and route
    **False alarms**: ``hours`` (default 24; ``nonlinear_hours`` for the nonlinear plant, whose
    Python-stepped stream costs about 20 us per sample) of fresh healthy data of the plant, simulated
    in blocks of ``block_s`` seconds (the state carried from block to block, bounded memory) and pushed
    through the route's online monitor (:class:`~chatterspec.online.monitor.ChatteringMonitor`, or with
    tolerances the parameters' :class:`~chatterspec.online.identification_monitor.IdentificationMonitor`:
    one push per block); the fault starts counted, against the two-sided 99 % Poisson interval of the
    count the budget predicts (:func:`~chatterspec.detection.alarms.calibration.poisson_count_interval`),
    and the fraction of frames in alarm: the budget *holds* when the count lies inside the interval (or
    below it) and the monitor is in alarm for at most 1 % of the frames (a mismatched model often
    raises one alarm that never ends: one start, a day in alarm).
    **Detection**: the catalogue faults (leakage minor 3e-11 and major 9e-11 m^3/(s Pa), friction
    major 7000 N s/m, bulk modulus -25 % of the plant's own) switched on after ``healthy_s`` seconds
    of the healthy plant, at 8 phases of the chirp, ``runs_per_phase`` realizations each, through the
    same sensor chain; scored by the route's model with the monitor's frame engine, score and rule (or
    the parameters' decision over the whole records: the numbers of the online monitors on the same
    grid); detection rate (99 % Clopper-Pearson interval) and median delay (s, to the end of the
    frame, or identification window, that raised the first alarm after the onset). A route that alarms
    during the healthy stretch before most onsets is reported as such: its delays measure nothing.

Routes
------
A :class:`BenchRoute` prepares, per bench case, a monitoring of one of two kinds:

* :class:`SpectralMonitoring`: the chattering monitor of a model (spectral frames, their score, the
  alarm rule at the budget): the online :class:`~chatterspec.online.monitor.ChatteringMonitor` on the
  healthy stream, the same frame engine, score and rule on the onset records (the definitions of
  :func:`chatterspec.studies.alarm_budget.score_delays`, which route (a) was scored with before:
  its detections, delays and verdicts on the 23 plants of the README's run are unchanged);
* :class:`ParameterMonitoring`: the decision on the identified parameters of a model with operating
  tolerances (:mod:`chatterspec.detection.parameter_decision`; the spectral detector then reports
  mismatch only and the whole budget goes to the parameters): the online
  :class:`~chatterspec.online.identification_monitor.IdentificationMonitor` on the healthy stream,
  :func:`~chatterspec.detection.parameter_decision.monitor_parameters` on the onset records.

Both count the false alarms of a continuous healthy stream (:meth:`counter`) and score onset records
the same way (:meth:`onsets`): the delay of a record is from the onset to the end of the frame (the
identification window) of the first alarm start in a frame ending at or after the onset; alarm
starts in frames ending before it are false; a record whose alarm is active in the last frame before
the onset is *preceded* (its delay measures nothing).

The routes:

* :func:`nominal_route`, (a): the nominal model, its threshold from simulated healthy data;
* :func:`commissioned_route`, (b): the model :func:`chatterspec.commission` fits to the first
  ``commission_s`` seconds of the plant's healthy data (other seeds than the checked stream), with its
  own simulated calibration. A commissioning that refuses (a fitted noise covariance the data make
  negative, a fitted model that fails its held-out check, parameters the data cannot identify) is not
  monitored: the route reports the refusal's reason, as ``chatterspec commission`` would;
* :func:`tolerance_route`, (c): the nominal model with operating tolerances (:data:`BENCH_TOLERANCES`
  by default), decided on the identified parameters (what ``chatterspec monitor --tolerance`` does);
  the route ``commissioned-tolerances``: the same decision on the commissioned model of (b) (the
  same fit, done once per case), the tolerances around the commissioned values;
* :func:`recorded_route`: the nominal model with thresholds from ``recorded_hours`` of the plant's
  recorded healthy data (:mod:`chatterspec.online.recorded_calibration`, the recording's own
  normalization), the remedy for a noise the model does not describe.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol, cast

import numpy as np

from .._validate import positive
from ..detection.alarms.calibration import (
    MonitorSettings,
    check_budget,
    poisson_count_interval,
    poisson_interval,
)
from ..detection.alarms.rules import make_rule
from ..detection.parameter_decision import ParameterAlarmSettings
from ..errors import ChatterspecError, CommissioningError, ParameterError
from ..jsonout import finite_or_none
from ..plants.eha4 import EHA4_MODES, EHA4_PARAMETERS, eha4
from ..plants.imperfections import (
    AR1Noise,
    BiasDrift,
    MainsHum,
    Quantization,
    SampleJitter,
    SensorChain,
    StudentTNoise,
    WhiteNoise,
)
from ..plants.models import LinearModel, eha_linear
from ..plants.scenarios import Scenario, Segment, scenario
from ..plants.simulate import simulate
from ..progress import Progress
from ..studies.alarm_budget import Shifted
from ..studies.intervals import clopper_pearson
from ..studies.tolerance_study import EHA_TOLERANCES
from .simulated_stream import simulate_blocks

__all__ = [
    "BENCH_TOLERANCES",
    "CALIBRATION_SEED",
    "FAULTS",
    "ROUTES",
    "AlarmCounter",
    "BenchCase",
    "BenchConfig",
    "BenchResult",
    "BenchRoute",
    "CaseOutcome",
    "Fault",
    "FaultOutcome",
    "Monitoring",
    "OnsetScores",
    "ParameterMonitoring",
    "RouteInputs",
    "RouteOutcome",
    "SpectralMonitoring",
    "bench_cases",
    "bench_table",
    "commissioned_route",
    "healthy_blocks",
    "holds",
    "nominal_route",
    "recorded_route",
    "route_named",
    "run_bench",
    "settled",
    "tolerance_route",
]


#: The routes by name (:func:`route_named`), in the bench's order.
ROUTES = ("nominal", "commissioned", "tolerances", "commissioned-tolerances", "recorded")
#: Seed of the simulated calibrations of the routes' models.
CALIBRATION_SEED = 12345
#: BenchRoute (c)'s operating tolerances, relative to the model's values: bulk modulus +-15 % (it moves
#: with oil temperature and entrained air by about that much over a working day), viscous friction
#: +-30 % (oil viscosity over the same range of temperature), leakage +-100 % (a tight actuator's
#: leakage is poorly known, and doubling it is still far below the catalogue's minor leak, 6.25 times
#: the nominal). The tolerance study's (:data:`chatterspec.studies.tolerance_study.EHA_TOLERANCES`).
BENCH_TOLERANCES: Mapping[str, str] = EHA_TOLERANCES
#: Seed offsets (from the bench's root seed) of the healthy data a route prepares from: the fresh
#: stream the false alarms are counted on uses the root seed itself.
COMMISSION_SEED, RECORDED_SEED = 2, 3

Blocks = Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]


def stack(blocks: Blocks) -> tuple[np.ndarray, np.ndarray]:
    """``(z, u)``: the measurements and inputs of ``(t, z, u)`` blocks, concatenated."""
    parts = list(blocks)
    return np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])


# --------------------------------------------------------------------------- monitorings
class AlarmCounter(Protocol):
    """An online monitor that counts: ``push(z, u)`` one block; the counts so far."""

    starts: int  #: alarm starts (every channel together)
    frames: int  #: frames (identification windows) decided
    active: int  #: of them, frames with an alarm active on some channel
    blind: int  #: of them, frames where a declared parameter is not excited (parameter decisions only)

    def push(self, z: np.ndarray, u: np.ndarray) -> None:
        """Monitor one block ``z (K, m)``, ``u (K, p)``."""


@dataclass(frozen=True)
class OnsetScores:
    """One onset scenario's records scored by one monitoring.

    Attributes
    ----------
    delays : (runs,) array
        Seconds from the onset to the end of the frame of the first alarm start at or after it
        (``inf``: missed).
    false_starts : int
        Alarm starts in frames ending before the onset (every channel and record).
    preceded : int
        Records in alarm in the last frame before the onset.
    """

    delays: np.ndarray
    false_starts: int
    preceded: int


class Monitoring(Protocol):
    """A prepared route (module docstring)."""

    @property
    def threshold(self) -> float:
        """The alarm rule's threshold."""

    @property
    def details(self) -> Mapping[str, Any]:
        """What the preparation found (JSON-ready; e.g. the commissioned estimates)."""

    def counter(self) -> AlarmCounter:
        """A fresh online monitor for a continuous healthy stream."""

    def onsets(
        self, z: np.ndarray, u: np.ndarray, t: np.ndarray, interval: tuple[float, float]
    ) -> OnsetScores:
        """Score onset records ``z (runs, T, m)``, ``u (T, p)`` at times ``t (T,)`` (s); the fault is on
        from ``interval[0]`` to ``interval[1]`` (s)."""


def _scores(
    starts: np.ndarray, active: np.ndarray, f_start: np.ndarray, f_end: np.ndarray, on: float, off: float
) -> OnsetScores:
    """Delays from alarm ``starts`` and ``active`` ``(runs, F, channels)`` of frames spanning
    ``[f_start, f_end]`` (s), the definitions of the module docstring."""
    valid = (f_end >= on - 1e-9) & (f_start < off)
    pre = f_end < on - 1e-9
    hit = starts.any(axis=-1) & valid
    first = np.argmax(hit, axis=1)
    d = np.where(hit.any(axis=1), f_end[first] - on, np.inf)
    before = np.flatnonzero(pre)
    preceded = int(np.count_nonzero(active[:, before[-1]].any(axis=-1))) if before.size else 0
    return OnsetScores(d, int(np.count_nonzero(starts[:, pre])), preceded)


@dataclass(frozen=True, eq=False)
class SpectralMonitoring:
    """The chattering monitor of ``model`` at ``settings`` (its alarm rule set).

    Attributes
    ----------
    model : LinearModel
    settings : MonitorSettings
        With the rule calibrated for the budget.
    details : mapping
        What the preparation found.
    """

    model: Any
    settings: MonitorSettings
    details: Mapping[str, Any] = field(default_factory=dict)

    @property
    def threshold(self) -> float:
        """The rule's threshold."""
        return float("nan") if self.settings.rule is None else float(self.settings.rule.threshold)

    def counter(self) -> AlarmCounter:
        """The online monitor (:class:`~chatterspec.online.monitor.ChatteringMonitor`), counting."""
        return _SpectralCounter(self.model, self.settings)

    def onsets(
        self, z: np.ndarray, u: np.ndarray, t: np.ndarray, interval: tuple[float, float]
    ) -> OnsetScores:
        """The monitor's frame engine, score and rule on the onset records (module docstring)."""
        from ..detection.alarms.streams import run_rule
        from ..detection.pipeline import chattering_record
        from ..detection.spectral import frame_columns
        from ..studies.alarm_budget import monitor_score

        s, dt = self.settings, self.model.dt
        assert s.rule is not None  # a prepared route carries its calibrated rule
        rec = chattering_record(self.model, z, u, gamma=s.gamma)
        _, P = frame_columns(rec.values, dt, s.stft)
        S = monitor_score(self.model, s)[0](P)
        W, H = s.stft.n_window(dt), s.stft.n_hop(dt)
        k = np.arange(S.shape[1]) * H
        run = run_rule(s.rule, S)
        return _scores(run.starts, run.active, rec.t[k], rec.t[k + W - 1], *interval)


class _Counter:
    """An :class:`AlarmCounter` over an online monitor whose ``push`` returns an update with ``events``:
    counts the fault starts; :meth:`_tally` counts the update's frames."""

    def __init__(self, monitor: Any) -> None:
        self.monitor = monitor
        self.starts = self.frames = self.active = self.blind = 0

    def push(self, z: np.ndarray, u: np.ndarray) -> None:
        upd = self.monitor.push(z, u)
        self.starts += sum(e.kind == "fault-start" for e in upd.events)
        self._tally(upd)

    def _tally(self, upd: Any) -> None:
        raise NotImplementedError


class _SpectralCounter(_Counter):
    def __init__(self, model: Any, settings: MonitorSettings) -> None:
        from .monitor import ChatteringMonitor

        super().__init__(ChatteringMonitor(model, settings))

    def _tally(self, upd: Any) -> None:
        fr = upd.frames
        self.frames += fr.n_frames
        if fr.alarm is not None and fr.n_frames:
            self.active += int(np.count_nonzero(fr.alarm.any(axis=1)))


@dataclass(frozen=True, eq=False)
class ParameterMonitoring:
    """The decision on the identified parameters of ``model`` (tolerances declared).

    Attributes
    ----------
    model : LinearModel
        With tolerances in its parameter map.
    setup : IdentificationSetup
        The joint fit of every declared parameter (all the decision uses).
    settings : ParameterAlarmSettings
        Hop, window, rule at the budget.
    details : mapping
        What the preparation found.
    """

    model: Any
    setup: Any
    settings: ParameterAlarmSettings
    details: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def of(
        cls, model: Any, stft: Any, rule: str, budget: float, details: Mapping[str, Any]
    ) -> ParameterMonitoring:
        """The monitor's decision for ``model``: one window per STFT hop over the STFT window, ``rule`` at
        ``budget`` false alarms per hour (what ``chatterspec monitor`` decides with tolerances)."""
        from ..detection.alarms.rules import make_rule
        from ..detection.identification import identification_setup
        from ..detection.parameter_decision import parameter_alarm_settings

        setup = identification_setup(model, [list(model.parameter_map.parameter_names)])
        H = stft.n_hop(model.dt)
        settings = parameter_alarm_settings(
            setup,
            hop_s=H * model.dt,
            window_hops=max(1, round(stft.n_window(model.dt) / H)),
            rule=make_rule(rule),
            false_alarms_per_hour=budget,
        )
        return cls(model, setup, settings, details)

    @property
    def threshold(self) -> float:
        """The rule's threshold on the parameters' scores."""
        cal = self.settings.calibration
        return float("nan") if cal is None else float(cal.threshold)

    def counter(self) -> AlarmCounter:
        """The online decision (:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`),
        counting the parameters' alarms."""
        return _ParameterCounter(self.setup, self.settings)

    def onsets(
        self, z: np.ndarray, u: np.ndarray, t: np.ndarray, interval: tuple[float, float]
    ) -> OnsetScores:
        """The decisions over the whole records (:func:`~chatterspec.detection.parameter_decision.
        monitor_parameters`); the frames are the identification windows."""
        from ..detection.parameter_decision import monitor_parameters

        rec = monitor_parameters(self.model, z, u, self.settings, t0=float(t[0]))
        # from a window's centre to its first and last chattering sample
        half = 0.5 * (self.settings.window_hops * self.settings.hop_s - self.model.dt)
        return _scores(rec.starts, rec.alarm, rec.times_s - half, rec.times_s + half, *interval)


class _ParameterCounter(_Counter):
    def __init__(self, setup: Any, settings: ParameterAlarmSettings) -> None:
        from .identification_monitor import IdentificationMonitor

        super().__init__(IdentificationMonitor(setup, settings))

    def _tally(self, upd: Any) -> None:
        self.frames += upd.block.n_windows
        self.active += int(np.count_nonzero(upd.block.alarm.any(axis=-1)))
        # a window in which some channel's carried parameter is not excited: the decision is blind there
        self.blind += int(np.count_nonzero(np.asarray(upd.not_excited).any(axis=-1)))


# --------------------------------------------------------------------------- routes
@dataclass(frozen=True, eq=False)
class RouteInputs:
    """What a route may use to prepare its monitoring.

    Attributes
    ----------
    nominal : LinearModel
        The nominal model (of the model file).
    case : BenchCase
    config : BenchConfig
    healthy : callable
        ``(duration_s, seed) -> iterator of (t, z, u) blocks`` of the case's healthy plant and sensors
        (other data than the bench's fresh stream: seeds differ).
    """

    nominal: LinearModel
    case: BenchCase
    config: BenchConfig
    healthy: Callable[[float, int], Blocks]
    _commissioned: dict[Any, Any] = field(default_factory=dict, repr=False)

    def commissioned(self, fit: Callable[[LinearModel, np.ndarray, np.ndarray], Any]) -> Any:
        """``fit(nominal, z, u)`` on the first ``commission_s`` of the plant's healthy data, once per case
        and ``fit`` (the routes that use the same ``fit`` share it).

        Raises
        ------
        CommissioningError
            The commissioning refused (its reason), or its fitted model failed the held-out check.
        """
        if fit not in self._commissioned:
            try:
                z, u = stack(self.healthy(self.config.commission_s, COMMISSION_SEED))
                res = fit(self.nominal, z, u)
                if res.adequate is False:
                    raise CommissioningError(
                        "not adequate on the held-out data: " + "; ".join(res.check.failures())
                    )
                self._commissioned[fit] = res
            except ChatterspecError as exc:
                self._commissioned[fit] = f"commissioning refused: {exc}"
        got = self._commissioned[fit]
        if isinstance(got, str):
            raise CommissioningError(got)
        return got


@dataclass(frozen=True)
class BenchRoute:
    """How a case is monitored: ``prepare(inputs) -> Monitoring``.

    Attributes
    ----------
    name : str
        Short identifier (:data:`ROUTES`).
    label : str
        Column heading.
    prepare : callable
        ``RouteInputs -> Monitoring``; may raise a :class:`~chatterspec.errors.ChatterspecError`
        (reported as the route's note, the route skipped for that case).
    """

    name: str
    label: str
    prepare: Callable[[RouteInputs], Monitoring]


def _simulated(model: Any, settings: MonitorSettings, cfg: BenchConfig) -> MonitorSettings:
    from ..studies.alarm_budget import alarm_settings

    return alarm_settings(
        model, settings, cfg.rule, cfg.budget, hours=cfg.calibration_hours, seed=CALIBRATION_SEED
    )


def nominal_route() -> BenchRoute:
    """(a) the nominal model, its alarm threshold from ``calibration_hours`` of simulated healthy data."""

    def prepare(r: RouteInputs) -> Monitoring:
        return SpectralMonitoring(r.nominal, _simulated(r.nominal, MonitorSettings(), r.config))

    return BenchRoute("nominal", "(a) nominal model", prepare)


def _commission(nominal: LinearModel, z: np.ndarray, u: np.ndarray) -> Any:
    from ..studies.commissioning import commission

    return commission(nominal, z, u)


def commissioned_details(res: Any) -> dict[str, Any]:
    """The commissioned estimates and noise of a :class:`~chatterspec.studies.commissioning.Commissioning`
    (JSON-ready)."""
    params = {} if res.parameters is None else {p.name: p.estimate for p in res.parameters.parameters}
    m = res.model
    return {
        "commissioned": params,
        "R": [float(x) for x in np.diag(m.R)],
        "Q": [float(x) for x in np.diag(m.Q)],
        "adequate": res.adequate,
    }


def commissioned_route(fit: Callable[[LinearModel, np.ndarray, np.ndarray], Any] | None = None) -> BenchRoute:
    """(b) the model commissioned from ``commission_s`` of the plant's healthy data, with its own
    simulated alarm calibration; a refusal is the route's note.

    Parameters
    ----------
    fit : callable, optional
        ``(nominal, z (K, m), u (K, p)) -> Commissioning`` (anything with ``.model``, ``.adequate``,
        ``.check``, ``.parameters``, ``.detector`` and ``.gamma``); default :func:`chatterspec.commission`
        with its defaults (what ``chatterspec commission`` does).
    """
    fit = fit or _commission

    def prepare(r: RouteInputs) -> Monitoring:
        res = r.commissioned(fit)
        settings = MonitorSettings.from_detector(res.detector, gamma=res.gamma)
        settings = _simulated(res.model, settings, r.config)
        return SpectralMonitoring(res.model, settings, commissioned_details(res))

    return BenchRoute("commissioned", "(b) commissioned", prepare)


def tolerance_route(
    tolerances: Mapping[str, str] = BENCH_TOLERANCES,
    fit: Callable[[LinearModel, np.ndarray, np.ndarray], Any] | None = None,
) -> BenchRoute:
    """(c) the nominal model with operating ``tolerances``, decided on the identified parameters at the
    budget (what ``chatterspec monitor --tolerance`` decides); with ``fit``, the model commissioned by it
    (:func:`commissioned_route`'s, the same fit) with the tolerances around the commissioned values.

    Parameters
    ----------
    tolerances : mapping
        Parameter name -> tolerance text (``"15%"``: :func:`chatterspec.with_tolerances`).
    fit : callable, optional
        As :func:`commissioned_route`'s; None: no commissioning, the nominal model's values are the
        bands' centres and its R and Q the scores' law.
    """
    from ..plants.parameters import with_tolerances

    def prepare(r: RouteInputs) -> Monitoring:
        details: dict[str, Any] = {"tolerances": dict(tolerances)}
        if fit is None:
            model, stft = r.nominal, MonitorSettings().stft
        else:
            res = r.commissioned(fit)
            model, stft = res.model, MonitorSettings.from_detector(res.detector, gamma=res.gamma).stft
            details |= commissioned_details(res)
        banded = with_tolerances(model, dict(tolerances))
        return ParameterMonitoring.of(banded, stft, r.config.rule, r.config.budget, details)

    if fit is None:
        return BenchRoute("tolerances", "(c) nominal + tolerances", prepare)
    return BenchRoute("commissioned-tolerances", "commissioned + tolerances", prepare)


def recorded_route() -> BenchRoute:
    """The nominal model with thresholds from ``recorded_hours`` of the plant's recorded healthy data
    (the recording's own normalization, :mod:`chatterspec.online.recorded_calibration`)."""
    from ..studies.calibration.recorded import HealthyRecording, array_chunks
    from .recorded_calibration import calibrate_recorded

    def prepare(r: RouteInputs) -> Monitoring:
        cfg = r.config
        # held once (the "data" normalization reads it twice): hours x 1 kHz x 4 columns of float64
        z, u = stack(r.healthy(cfg.recorded_hours * 3600.0, RECORDED_SEED))
        n = z.shape[0]
        chunks = array_chunks(z, u, max(1, round(60.0 / r.nominal.dt)))
        cal = calibrate_recorded(
            r.nominal,
            chunks,
            n,
            normalization="data",
            rule=cfg.rule,
            false_alarms_per_hour=cfg.budget,
            recording=HealthyRecording(f"{r.case.name} healthy {cfg.recorded_hours:g} h", ""),
        )
        assert cal.alarm is not None
        settings = MonitorSettings(
            threshold=cal.threshold("frame-family-wise"), rule=cal.alarm.rule, budget=cal.alarm
        )
        return SpectralMonitoring(r.nominal, settings)

    return BenchRoute("recorded", "nominal + thresholds from recorded data", prepare)


def route_named(name: str) -> BenchRoute:
    """The route ``name`` (:data:`ROUTES`), its defaults."""
    makers: dict[str, Callable[[], BenchRoute]] = {
        "nominal": nominal_route,
        "commissioned": commissioned_route,
        "tolerances": tolerance_route,
        "commissioned-tolerances": lambda: tolerance_route(fit=_commission),
        "recorded": recorded_route,
    }
    if name not in makers:
        raise ParameterError(f"unknown route {name!r}; known: {', '.join(makers)}")
    return makers[name]()


#: The nonlinear plant's measured states (position, velocity, pressure), as the linear model's outputs.
EHA4_CHANNELS = (0, 1, 3)
#: The ADC cases' sensor ranges ``(low, high)`` per channel: +-2 m, +-1 m/s, +-2e7 Pa (+-200 bar). The
#: position range covers the open-loop stream's drift under the repeated chirp (about 5 cm per hour, 1.2 m
#: in 24 h): a range the position leaves saturates the sensor, a different imperfection (at +-0.1 m it did
#: after 1.9 h, and the monitor rightly alarmed on the stuck position).
ADC_RANGE = (np.array([-2.0, -1.0, -2e7]), np.array([2.0, 1.0, 2e7]))

#: Largest fraction of healthy frames in alarm for a budget to hold (1/day of a few frames each is ~1e-5).
STANDING_ALARM = 0.01


# --------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class BenchConfig:
    """How much of everything (defaults: the published bench).

    Attributes
    ----------
    hours : float
        Fresh healthy data per case (h), streamed through every route's monitor.
    nonlinear_hours : float
        The same for the nonlinear plant (its stream steps ``f`` in Python).
    block_s : float
        Seconds per simulated block and per monitor push.
    commission_s : float
        Healthy data (s) given to a commissioning route.
    recorded_hours : float
        Healthy data (h) from which :func:`recorded_route` reads its thresholds (0: no such route).
    calibration_hours : float
        Simulated healthy hours of the routes' alarm calibrations.
    runs_per_phase : int
        Onset realizations per chirp phase and fault.
    phases : tuple of float
        Times into the input (s) at which the onsets fall.
    healthy_s, fault_s : float
        Healthy stretch before an onset, and the fault's duration (s).
    budget : float
        False alarms per hour (all channels together).
    rule : str
        Alarm rule.
    seed : int
        Root seed.
    """

    hours: float = 24.0
    nonlinear_hours: float = 4.0
    block_s: float = 60.0
    commission_s: float = 600.0
    recorded_hours: float = 4.0
    calibration_hours: float = 48.0
    runs_per_phase: int = 25
    phases: tuple[float, ...] = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5)
    healthy_s: float = 6.0
    fault_s: float = 8.0
    budget: float = 1.0 / 24.0
    rule: str = "cusum"
    seed: int = 0

    def __post_init__(self) -> None:
        names = (
            "hours",
            "nonlinear_hours",
            "block_s",
            "commission_s",
            "calibration_hours",
            "healthy_s",
            "fault_s",
        )
        for name in names:
            object.__setattr__(self, name, positive(name, getattr(self, name)))
        if not (math.isfinite(self.recorded_hours) and self.recorded_hours >= 0):
            raise ParameterError(f"recorded_hours must be >= 0 h; got {self.recorded_hours!r}")
        if int(self.runs_per_phase) < 1 or not self.phases:
            raise ParameterError("runs_per_phase must be >= 1 and phases non-empty")
        object.__setattr__(self, "budget", check_budget(self.budget, "budget"))
        object.__setattr__(self, "phases", tuple(float(p) for p in self.phases))
        make_rule(self.rule)


# --------------------------------------------------------------------------- cases and faults
@dataclass(frozen=True)
class Fault:
    """A catalogue fault as parameter changes of the plant.

    Attributes
    ----------
    name, label : str
    channel : str
        The output the fault shows on.
    set_to : mapping
        Linear plant: parameters set to these values (the catalogue's absolute levels).
    scale : mapping
        Linear plant: parameters multiplied by these factors (relative to the plant's own).
    eha4 : mapping
        The nonlinear plant's parameters (set; ``bulk_modulus`` scaled by the same factor).
    """

    name: str
    label: str
    channel: str
    set_to: Mapping[str, float] = field(default_factory=dict)
    scale: Mapping[str, float] = field(default_factory=dict)
    eha4: Mapping[str, float] = field(default_factory=dict)


FAULTS: tuple[Fault, ...] = (
    Fault("leak-minor", "leak minor", "pressure", {"leakage": 3e-11}, eha4=EHA4_MODES["leak-minor"]),
    Fault("leak-major", "leak major", "pressure", {"leakage": 9e-11}, eha4=EHA4_MODES["leak-major"]),
    Fault("friction-major", "friction major", "velocity", {"friction": 7000.0}, eha4={"a2": 7000.0}),
    Fault(
        "bulk-25down",
        "bulk -25 %",
        "pressure",
        scale={"bulk_modulus": 0.75},
        eha4={"bulk_modulus": 0.75 * EHA4_PARAMETERS["bulk_modulus"]},
    ),
)


@dataclass(frozen=True, eq=False)
class BenchCase:
    """A plant and its sensors.

    Attributes
    ----------
    name : str
        Short identifier.
    group : {"exact", "parametric", "noise", "sensor", "nonlinear"}
    description : str
        What differs from the nominal model, with values and units.
    scale : mapping
        Parameter factors of the true plant against the nominal (e.g. ``{"bulk_modulus": 0.9}``).
    sensor : callable
        ``nominal -> SensorChain``: the measurement of the plant's noise-free output.
    nonlinear : bool
        The plant is the 4-state nonlinear EHA.
    """

    name: str
    group: str
    description: str
    sensor: Callable[[LinearModel], SensorChain]
    scale: Mapping[str, float] = field(default_factory=dict)
    nonlinear: bool = False

    def plant(self, nominal: LinearModel) -> Any:
        """The true plant without measurement noise (the sensor chain adds it)."""
        if self.nonlinear:
            return eha4(Q=1e-9 * np.eye(4), R=np.zeros((4, 4)))
        pm = nominal.parameter_map
        if pm is None:
            raise ParameterError(
                "the nominal model declares no parameters: the bench needs its parameter map"
            )
        values = {k: pm.parameter(k).value * f for k, f in self.scale.items()}
        return dataclasses.replace(pm.model_with(nominal, values), R=np.zeros_like(nominal.R))

    def faulty(self, nominal: LinearModel, fault: Fault) -> Any:
        """The true plant with ``fault`` (no measurement noise)."""
        if self.nonlinear:
            overrides = cast("dict[str, Any]", fault.eha4)  # physical parameters: keys of EHA4_PARAMETERS
            return eha4(Q=1e-9 * np.eye(4), R=np.zeros((4, 4)), **overrides)
        healthy = self.plant(nominal)
        pm = healthy.parameter_map
        values = {k: pm.parameter(k).value * f for k, f in fault.scale.items()} | dict(fault.set_to)
        return pm.model_with(healthy, values)

    def input(self) -> Any:
        """The input signal: the catalogue chirp (linear plants) or the SMM paper's sine (nonlinear)."""
        return scenario("eha4-healthy" if self.nonlinear else "eha-healthy").input


def _white(s: float = 1.0) -> Callable[[LinearModel], SensorChain]:
    return lambda m: SensorChain((WhiteNoise(s * m.R),))


def bench_cases() -> tuple[BenchCase, ...]:
    """The cases of the bench (module docstring), in table order."""
    cases = [BenchCase("exact", "exact", "the nominal model itself", _white())]
    signs = {"leakage": 1.0, "friction": 1.0, "bulk_modulus": -1.0}
    short = {"leakage": "leakage", "friction": "friction", "bulk_modulus": "bulk modulus"}
    for pct in (3, 10, 30):
        for p, sgn in signs.items():
            f = 1.0 + sgn * pct / 100.0
            cases.append(
                BenchCase(
                    f"{p}{'+' if sgn > 0 else '-'}{pct}",
                    "parametric",
                    f"{short[p]} {sgn * pct:+g} %",
                    _white(),
                    {p: f},
                )
            )
        cases.append(
            BenchCase(
                f"all{pct}",
                "parametric",
                f"all three off by {pct} %",
                _white(),
                {p: 1.0 + s * pct / 100.0 for p, s in signs.items()},
            )
        )
    cases += [
        BenchCase("R-x0.5", "noise", "sensor noise 0.5 R", _white(0.5)),
        BenchCase("R-x2", "noise", "sensor noise 2 R", _white(2.0)),
        BenchCase("ar1-0.5", "sensor", "AR(1) noise, rho 0.5", lambda m: SensorChain((AR1Noise(m.R, 0.5),))),
        BenchCase("ar1-0.9", "sensor", "AR(1) noise, rho 0.9", lambda m: SensorChain((AR1Noise(m.R, 0.9),))),
        BenchCase(
            "adc12",
            "sensor",
            "12-bit ADC (+-2 m, +-1 m/s, +-2e7 Pa)",
            lambda m: SensorChain((WhiteNoise(m.R), Quantization(12, *ADC_RANGE))),
        ),
        # the same ranges at 16 bits: the pressure step (610 Pa) below the noise's standard deviation
        # (1 kPa), which then dithers it (at 12 bits the 9.8 kPa step is almost 10 of them)
        BenchCase(
            "adc16",
            "sensor",
            "16-bit ADC (same ranges)",
            lambda m: SensorChain((WhiteNoise(m.R), Quantization(16, *ADC_RANGE))),
        ),
        BenchCase(
            "hum50",
            "sensor",
            "50 Hz hum, 0.5 noise std",
            lambda m: SensorChain((WhiteNoise(m.R), MainsHum(0.5 * np.sqrt(np.diag(m.R)), 50.0))),
        ),
        BenchCase(
            "drift",
            "sensor",
            "bias drift, 2 noise std, 600 s",
            lambda m: SensorChain((WhiteNoise(m.R), BiasDrift(2.0 * np.sqrt(np.diag(m.R)), 600.0, m.dt))),
        ),
        BenchCase(
            "student-t", "sensor", "Student-t noise, nu 4", lambda m: SensorChain((StudentTNoise(m.R, 4.0),))
        ),
        BenchCase(
            "jitter",
            "sensor",
            "sampling jitter 10 us",
            lambda m: SensorChain((SampleJitter(1e-5, m.dt), WhiteNoise(m.R))),
        ),
        BenchCase("eha4", "nonlinear", "nonlinear 4-state EHA", _white(), nonlinear=True),
    ]
    return tuple(cases)


# --------------------------------------------------------------------------- data
def _outputs(case: BenchCase, y: np.ndarray) -> np.ndarray:
    return y[..., list(EHA4_CHANNELS)] if case.nonlinear else y


def healthy_blocks(
    case: BenchCase, nominal: LinearModel, duration_s: float, block_s: float, seed: int
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One continuous healthy stream of the case's plant through its sensors, block by block.

    The plant is :func:`chatterspec.online.simulated_stream.simulate_blocks` (the state carried from
    block to block, the input repeating with its 4 s period, bounded memory for any duration); the
    sensor chain's state is carried too.

    Parameters
    ----------
    case : BenchCase
    nominal : LinearModel
        The nominal model (the plant and the sensors are the case's departures from it).
    duration_s : float
        Length of the stream (s).
    block_s : float
        Length of a block (s; the stream does not depend on it).
    seed : int
        The stream's seed (plant and sensors).

    Yields
    ------
    (t, z, u)
        Times (K,) s, measurements (K, m) in the nominal model's output order, inputs (K, p).
    """
    plant = case.plant(nominal)
    sc = Scenario(name=f"{case.name} healthy", nominal=plant, input=case.input(), duration=4.0)
    chain = case.sensor(nominal)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 1]))
    state = chain.init(1, rng)
    for t, y, u in simulate_blocks(sc, int(seed), duration_s, block_s=block_s):
        z, state = chain.apply(_outputs(case, y[None]), t, rng, state)
        yield t, z[0], u


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class FaultOutcome:
    """Detection of one fault by one route.

    Attributes
    ----------
    fault : str
    runs, detected : int
        Onsets and onsets detected.
    detected_interval : (float, float)
        99 % Clopper-Pearson interval of the detection rate.
    median_s, p90_s : float
        Delay quantiles (s; ``inf`` when more than half / a tenth missed).
    false_starts : int
        Alarm starts in the healthy stretches before the onsets.
    onsets_preceded : int
        Onsets before which the route had already raised an alarm (its delay measures nothing).
    """

    fault: str
    runs: int
    detected: int
    detected_interval: tuple[float, float]
    median_s: float
    p90_s: float
    false_starts: int
    onsets_preceded: int

    @property
    def rate(self) -> float:
        """Fraction detected."""
        return self.detected / self.runs

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        d = dataclasses.asdict(self)
        d["median_s"], d["p90_s"] = finite_or_none(self.median_s), finite_or_none(self.p90_s)
        d["detected_interval"] = list(self.detected_interval)
        return d


def holds(note: str, starts: int, most: int, alarm_fraction: float) -> bool:
    """Whether a route that ran held the budget.

    Parameters
    ----------
    note : str
        Why the route did not run (empty when it ran: a route that did not run holds nothing).
    starts : int
        Alarm starts counted on the healthy hours.
    most : int
        The upper end of the budget's 99 % Poisson count interval.
    alarm_fraction : float
        Fraction of the healthy frames in alarm; above :data:`STANDING_ALARM` an alarm stands.
    """
    return not note and starts <= most and alarm_fraction <= STANDING_ALARM


@dataclass(frozen=True)
class RouteOutcome:
    """One route on one case.

    Attributes
    ----------
    route : str
    hours : float
        Healthy hours streamed (fewer than planned when the verdict was settled before the end:
        :func:`settled`).
    starts : int
        Fault starts on them (false alarms).
    count_interval : (int, int)
        Two-sided 99 % Poisson interval of the count the budget predicts.
    rate_interval : (float, float)
        99 % Garwood interval of the realized rate (per hour).
    faults : tuple of FaultOutcome
    threshold : float
        The rule's threshold.
    note : str
        Why the route did not run, if it did not.
    cpu_s : float
        CPU time of the route on the case (preparation, monitor, onsets).
    alarm_fraction : float
        Fraction of the healthy frames with an alarm active on some channel.
    details : mapping
        What the route's preparation found (e.g. the commissioned estimates).
    planned_hours : float
        Healthy hours the case's stream holds.
    blind_fraction : float
        Fraction of the healthy frames in which a declared parameter is not excited (a parameter
        decision is blind there: no false alarm, and no detection either); 0 for the spectrum.
    """

    route: str
    hours: float
    starts: int
    count_interval: tuple[int, int]
    rate_interval: tuple[float, float]
    faults: tuple[FaultOutcome, ...]
    threshold: float
    note: str = ""
    cpu_s: float = 0.0
    alarm_fraction: float = 0.0
    details: Mapping[str, Any] = field(default_factory=dict)
    planned_hours: float = 0.0
    blind_fraction: float = 0.0

    @property
    def holds(self) -> bool:
        """The false-alarm count lies in the budget's 99 % Poisson interval (or below it) and no alarm
        stands: the monitor is in alarm for at most :data:`STANDING_ALARM` of the healthy frames (a
        start that never ends counts once, yet the monitor says "fault" all day)."""
        return holds(self.note, self.starts, self.count_interval[1], self.alarm_fraction)

    @property
    def rate(self) -> float:
        """False alarms per hour."""
        return self.starts / self.hours if self.hours else float("nan")

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "route": self.route,
            "hours": self.hours,
            "planned_hours": self.planned_hours,
            "starts": self.starts,
            "rate_per_hour": finite_or_none(self.rate),
            "count_interval_99": list(self.count_interval),
            "rate_interval_99": list(self.rate_interval),
            "holds": self.holds,
            "alarm_fraction": self.alarm_fraction,
            "not_excited_fraction": self.blind_fraction,
            "threshold": finite_or_none(self.threshold),
            "faults": [f.to_dict() for f in self.faults],
            "note": self.note,
            "cpu_s": self.cpu_s,
            "details": dict(self.details),
        }


@dataclass(frozen=True)
class CaseOutcome:
    """Every route on one case.

    Attributes
    ----------
    case : str
        The case's name.
    group : str
        Its group (exact, parametric, noise, sensor, nonlinear).
    description : str
        What differs from the nominal model.
    routes : tuple of RouteOutcome
        One per route, in the routes' order.
    """

    case: str
    group: str
    description: str
    routes: tuple[RouteOutcome, ...]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "case": self.case,
            "group": self.group,
            "description": self.description,
            "routes": [r.to_dict() for r in self.routes],
        }


@dataclass(frozen=True)
class BenchResult:
    """The whole bench.

    Attributes
    ----------
    config : BenchConfig
    cases : tuple of CaseOutcome
    cpu_s : float
        CPU time of the whole bench (s; the worker processes' included).
    """

    config: BenchConfig
    cases: tuple[CaseOutcome, ...]
    cpu_s: float

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {
            "config": dataclasses.asdict(self.config),
            "cases": [c.to_dict() for c in self.cases],
            "cpu_s": self.cpu_s,
        }

    def table(self) -> str:
        """A Markdown table: per case and route, false alarms and detection (:func:`bench_table`)."""
        return bench_table(self.to_dict())


def bench_table(doc: Mapping[str, Any]) -> str:
    """The Markdown table of a bench document (``BenchResult.to_dict()``, or its JSON read back).

    Parameters
    ----------
    doc : mapping
        The bench document.
    """
    cases = doc["cases"]
    faults = [f.label for f in FAULTS]
    head = "| plant | monitor | false alarms per hour, 99 % Poisson interval (count in the hours streamed) | "
    head += " | ".join(f"{f}: detected, 99 % Clopper-Pearson, median delay s" for f in faults) + " |"
    lines = [head, "|---|---|---:|" + "---:|" * len(faults)]
    for c in cases:
        for i, r in enumerate(c["routes"]):
            name = c["description"] if i == 0 else ""
            if r["note"]:  # its first clause (the whole text is in the JSON)
                lines.append(f"| {name} | {r['route']} | {r['note'].split(' (')[0]} |" + " |" * len(faults))
                continue
            planned = r.get("planned_hours") or r["hours"]
            span = f"{r['hours']:.3g} h"
            if r["hours"] < planned * (1 - 1e-9):  # stopped once settled
                span = f"the first {r['hours']:.3g} of {planned:.3g} h"
            lo, hi = r["rate_interval_99"]
            fa = f"{r['rate_per_hour']:.3g} [{lo:.2g}, {hi:.3g}] ({r['starts']} in {span})"
            frac = r.get("alarm_fraction", 0.0)
            fa += f", in alarm {100 * frac:.3g} % of the time" if frac > 1e-3 else ""
            blind = r.get("not_excited_fraction", 0.0)
            fa += f", not excited {100 * blind:.3g} % of the time" if blind >= 0.01 else ""
            fa += "" if r["holds"] else " **not held**"
            cells = []
            for f in r["faults"]:
                med = "-" if f["median_s"] is None else f"{f['median_s']:.2f}"
                dlo, dhi = f["detected_interval"]
                pre = f", {f['onsets_preceded']} pre-alarmed" if f["onsets_preceded"] else ""
                cells.append(f"{f['detected']}/{f['runs']} [{dlo:.2f}, {dhi:.2f}], {med}{pre}")
            lines.append(f"| {name} | {r['route']} | {fa} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


# --------------------------------------------------------------------------- running
class _Clock:
    """CPU seconds spent per route, and in the work the routes share (simulation, sensors)."""

    def __init__(self, n: int) -> None:
        self.own = [0.0] * n
        self.shared = 0.0
        self._t = time.process_time()

    def lap(self, route: int | None = None) -> None:
        """Charge the time since the last lap to ``route`` (None: shared)."""
        t = time.process_time()
        if route is None:
            self.shared += t - self._t
        else:
            self.own[route] += t - self._t
        self._t = t


def settled(starts: int, active: int, frames: int, fraction_seen: float, most: int) -> bool:
    """Whether a stream's verdict is "not held" whatever its rest holds: more alarm starts than the
    budget's interval allows (``most``), or more frames in alarm than :data:`STANDING_ALARM` of the
    whole stream's (``frames`` seen in the first ``fraction_seen`` of it).

    Parameters
    ----------
    starts, active, frames : int
        Alarm starts, frames in alarm and frames so far.
    fraction_seen : float
        Fraction of the stream seen (0 < f <= 1).
    most : int
        Upper end of the budget's 99 % Poisson count interval.
    """
    return starts > most or active > STANDING_ALARM * frames / fraction_seen


def _false_alarms(
    case: BenchCase, nominal: LinearModel, counters: Sequence[AlarmCounter], cfg: BenchConfig, clock: _Clock
) -> list[float]:
    """Push the case's fresh healthy stream through every counter; the hours each one saw (a counter
    whose verdict is :func:`settled` stops there)."""
    hours = cfg.nonlinear_hours if case.nonlinear else cfg.hours
    most = poisson_count_interval(cfg.budget * hours, 0.99)[1]
    seen = [0.0] * len(counters)
    live = list(range(len(counters)))
    clock.lap()
    for _, z, u in healthy_blocks(case, nominal, hours * 3600.0, cfg.block_s, cfg.seed):
        clock.lap()
        for i in live:
            counters[i].push(z, u)
            seen[i] += z.shape[0] * nominal.dt / 3600.0
            clock.lap(i)
        live = [
            i
            for i in live
            if not settled(counters[i].starts, counters[i].active, counters[i].frames, seen[i] / hours, most)
        ]
        if not live:
            break
    return seen


def _onsets(case: BenchCase, nominal: LinearModel, fault: Fault, cfg: BenchConfig) -> list[Scenario]:
    healthy, faulty = case.plant(nominal), case.faulty(nominal, fault)
    signal, period = case.input(), 4.0
    return [
        Scenario(
            name=f"{case.name} {fault.name} @ phase {ph:g} s",
            nominal=healthy,
            input=Shifted(signal, cfg.healthy_s - ph, period),
            duration=cfg.healthy_s + cfg.fault_s,
            windows=(Segment(cfg.healthy_s, cfg.healthy_s + cfg.fault_s, faulty, fault.label),),
            fault=fault.name,
            fault_channel=fault.channel,
        )
        for ph in cfg.phases
    ]


def _detection(
    case: BenchCase, nominal: LinearModel, prepared: Sequence[Monitoring], cfg: BenchConfig, clock: _Clock
) -> list[list[FaultOutcome]]:
    """Per prepared route, per fault: detection over the onsets (one simulation shared by the routes)."""
    chain = case.sensor(nominal)
    out: list[list[FaultOutcome]] = [[] for _ in prepared]
    for j, fault in enumerate(FAULTS):
        scored: list[list[OnsetScores]] = [[] for _ in prepared]
        for i, sc in enumerate(_onsets(case, nominal, fault, cfg)):
            clock.lap()
            seed = np.random.SeedSequence([cfg.seed, 7, j, i])
            sim = simulate(sc, cfg.runs_per_phase, seed)
            rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 8, j, i]))
            y = _outputs(case, sim.z)
            z, _ = chain.apply(y, sim.t, rng, chain.init(y.shape[0], rng))
            ((on, off),) = sc.fault_intervals
            clock.lap()
            for r, mon in enumerate(prepared):
                scored[r].append(mon.onsets(z, sim.u, sim.t, (on, off)))
                clock.lap(r)
        for r in range(len(prepared)):
            d = np.concatenate([s.delays for s in scored[r]])
            n, k = d.size, int(np.count_nonzero(np.isfinite(d)))
            ds = np.sort(d)
            med = float(ds[max(0, math.ceil(0.5 * n) - 1)])
            p90 = float(ds[max(0, math.ceil(0.9 * n) - 1)])
            out[r].append(
                FaultOutcome(
                    fault.name,
                    n,
                    k,
                    clopper_pearson(k, n, 0.99),
                    med,
                    p90,
                    sum(s.false_starts for s in scored[r]),
                    sum(s.preceded for s in scored[r]),
                )
            )
    return out


def _run_case(
    case: BenchCase, routes: Sequence[BenchRoute], cfg: BenchConfig, nominal: LinearModel
) -> tuple[CaseOutcome, float]:
    """Every route on one case; its outcome and CPU time (s)."""
    t_case = time.process_time()

    def healthy(duration_s: float, seed: int) -> Iterator[Any]:
        return healthy_blocks(case, nominal, duration_s, cfg.block_s, 1000 * cfg.seed + seed)

    inputs = RouteInputs(nominal, case, cfg, healthy)
    prepared: list[Monitoring | None] = []
    notes, cpu = [], []
    for route in routes:
        t0 = time.process_time()
        try:
            prepared.append(route.prepare(inputs))
            notes.append("")
        except ChatterspecError as exc:  # the package's own refusal, with its reason
            prepared.append(None)
            notes.append(f"not run: {exc}")
        cpu.append(time.process_time() - t0)
    ready = [i for i, p in enumerate(prepared) if p is not None]
    runs = [p for p in prepared if p is not None]
    clock = _Clock(len(runs))
    counters = [mon.counter() for mon in runs]
    seen = _false_alarms(case, nominal, counters, cfg, clock)
    detection = _detection(case, nominal, runs, cfg, clock)
    hours = cfg.nonlinear_hours if case.nonlinear else cfg.hours
    ci = poisson_count_interval(cfg.budget * hours, 0.99)
    rows = []
    for i, route in enumerate(routes):
        if i not in ready:
            row = RouteOutcome(route.label, 0.0, 0, ci, (0.0, 0.0), (), float("nan"), notes[i], cpu[i])
            rows.append(dataclasses.replace(row, planned_hours=hours))
            continue
        j = ready.index(i)
        c = counters[j]
        lo, hi = poisson_interval(c.starts, 0.99)
        rows.append(
            RouteOutcome(
                route.label,
                seen[j],
                c.starts,
                ci,
                (lo / seen[j], hi / seen[j]),
                tuple(detection[j]),
                runs[j].threshold,
                "",
                cpu[i] + clock.own[j] + clock.shared / len(runs),
                c.active / max(1, c.frames),
                dict(runs[j].details),
                hours,
                c.blind / max(1, c.frames),
            )
        )
    return CaseOutcome(case.name, case.group, case.description, tuple(rows)), time.process_time() - t_case


#: The job of the worker processes (set before they fork; only case indices travel to them).
_JOB: tuple[Sequence[BenchCase], Sequence[BenchRoute], BenchConfig, LinearModel] | None = None


def _worker(i: int) -> tuple[CaseOutcome, float]:
    assert _JOB is not None
    cases, routes, cfg, nominal = _JOB
    return _run_case(cases[i], routes, cfg, nominal)


def run_bench(
    routes: Sequence[BenchRoute] | None = None,
    cases: Sequence[BenchCase] | None = None,
    config: BenchConfig | None = None,
    *,
    nominal: LinearModel | None = None,
    progress: bool | None = None,
    workers: int = 1,
    on_case: Callable[[CaseOutcome], None] | None = None,
) -> BenchResult:
    """Run the bench (module docstring).

    Parameters
    ----------
    routes : sequence of BenchRoute, optional
        Default: (a) :func:`~chatterspec.online.realistic_bench.nominal_route`, (b)
        :func:`~chatterspec.online.realistic_bench.commissioned_route`, (c)
        :func:`~chatterspec.online.realistic_bench.tolerance_route` and, with ``recorded_hours > 0``,
        :func:`~chatterspec.online.realistic_bench.recorded_route`.
    cases : sequence of BenchCase, optional
        Default :func:`bench_cases`.
    config : BenchConfig, optional
    nominal : LinearModel, optional
        The nominal model (default the linear EHA of the catalogue, the model file's).
    progress : bool, optional
        Progress bar on stderr (default: when it is a terminal).
    workers : int
        Cases run in this many forked processes (the numbers do not depend on it: every case's
        seeds are its own). ``BenchResult.cpu_s`` adds the workers' CPU time.
    on_case : callable, optional
        Called with each case's outcome as it finishes (e.g. to save partial results).
    """
    global _JOB
    cfg = config or BenchConfig()
    nominal = nominal or eha_linear()
    if routes is None:
        routes = [nominal_route(), commissioned_route(), tolerance_route()]
        routes += [recorded_route()] if cfg.recorded_hours > 0 else []
    cases = tuple(bench_cases() if cases is None else cases)
    cpu = time.process_time()
    results: list[tuple[CaseOutcome, float] | None] = [None] * len(cases)
    with Progress(len(cases), "realistic bench", enabled=progress) as bar:
        if int(workers) <= 1:
            for i, case in enumerate(cases):
                outcome = results[i] = _run_case(case, routes, cfg, nominal)
                if on_case is not None:
                    on_case(outcome[0])
                bar.update(1, case.name)
            worker_cpu = 0.0
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor, as_completed

            _JOB = (cases, routes, cfg, nominal)
            try:
                ctx = multiprocessing.get_context("fork")
                with ProcessPoolExecutor(int(workers), mp_context=ctx) as pool:
                    futures = {pool.submit(_worker, i): i for i in range(len(cases))}
                    for fut in as_completed(futures):
                        res = results[futures[fut]] = fut.result()
                        if on_case is not None:
                            on_case(res[0])
                        bar.update(1, cases[futures[fut]].name)
            finally:
                _JOB = None
            worker_cpu = sum(r[1] for r in results if r is not None)
    done = [r for r in results if r is not None]
    return BenchResult(cfg, tuple(r[0] for r in done), time.process_time() - cpu + worker_cpu)
