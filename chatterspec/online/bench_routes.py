"""The realistic bench's routes: how a plant is monitored, prepared from the nominal model and the
plant's own healthy data (:mod:`chatterspec.online.realistic_bench`).

A :class:`BenchRoute` prepares, per bench case, a monitoring of one of two kinds:

* :class:`SpectralMonitoring`: the chattering monitor of a model (spectral frames, their score, the
  alarm rule at the budget): the online :class:`~chatterspec.online.monitor.ChatteringMonitor` on the
  healthy stream, the same frame engine, score and rule on the onset records (the definitions of
  :func:`chatterspec.studies.alarm_delays.score_delays`, which route (a) was scored with before:
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

from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from ..detection.alarms.calibration import MonitorSettings
from ..detection.parameter_decision import ParameterAlarmSettings
from ..errors import ChatterspecError, CommissioningError, ParameterError
from ..plants.models import LinearModel
from ..studies.tolerance_study import EHA_TOLERANCES

if TYPE_CHECKING:
    from .realistic_bench import BenchCase, BenchConfig

__all__ = [
    "BENCH_TOLERANCES",
    "CALIBRATION_SEED",
    "ROUTES",
    "AlarmCounter",
    "BenchRoute",
    "Monitoring",
    "OnsetScores",
    "ParameterMonitoring",
    "RouteInputs",
    "SpectralMonitoring",
    "commissioned_route",
    "nominal_route",
    "recorded_route",
    "route_named",
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
    from ..studies.recorded_calibration import HealthyRecording, array_chunks
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
