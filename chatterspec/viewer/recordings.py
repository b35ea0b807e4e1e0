"""The recordings the commands write: the online monitor run over a record into Rerun sinks
(:func:`run_monitor`, ``monitor``), a batch detection (:func:`record_detection`, ``detect`` and
``demo --record``), an estimator comparison (:func:`record_estimates`, ``estimate --record``) and a
diagnosis (:func:`record_diagnosis`, :func:`record_budget_diagnosis`, ``diagnose --record``).

Rerun is imported only when a recording is written.

An estimator comparison (:func:`record_estimates`): truth, estimates and innovations per filter.
Entity layout (one ``time`` timeline, durations in integer nanoseconds, rounded once)::

    /states/<state>/truth                 true state x_i(k)
    /states/<state>/<filter>              estimate x_i(k|k) of each filter
    /errors/<state>/<filter>              estimation error x_i - x_i(k|k)
    /measurements/<output>                z_j(k)
    /innovations/<output>/<filter>        e_j(k|k-1) = z_j(k) - C x(k|k-1)
    /state/0_truth                        the true plant's segments (a lane: where the fault starts)
    /info                                 what the colours are, the scenario, run and filters

Everything time-indexed goes through ``RecordingStream.send_columns`` (bulk, millions of samples
per second).

A diagnosis (:func:`record_diagnosis`): realization 0 on one timeline -- the chattering spectrogram,
frame verdicts and detection events of the online monitor
(:class:`~chatterspec.viewer.rerun_log.RerunLogger`, unchanged) beside the mode probabilities of the
SMM-SVSF / IMM (one scalar series per mode under ``/modes/<method>/<mode>``) and, at a false-alarm
budget, every route's alarm statistic with its calibrated threshold (``/routes/<method>/statistic``
and ``/routes/<method>/threshold``; :func:`record_budget_diagnosis`).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.spectral import STFTConfig
from ..detection.thresholds import Threshold
from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorSettings
from ..palette import NEUTRAL, TAB10, TRUTH, filter_color, mode_color, rgba32
from ..plants.models import state_units
from .blueprint import _entity, labelled_half_range, labelled_step, labelled_top, time_axis, time_panel
from .events import log_truth_lane, truth_colors
from .rerun_log import RerunLogger
from .sinks import TIMELINE, Sinks, default_recording_path, file_error, open_sinks
from .spectrograms import record_span, to_ns

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Callable
    from types import ModuleType

    from rerun.blueprint import VisibleTimeRange
    from rerun.blueprint.archetypes import TimeAxis

    from ..detection.identification import IdentificationSetup, OnlineIdentification, OnlineIdentifier
    from ..detection.parameter_decision import ParameterEvent
    from ..detection.pipeline import ChatteringRecord
    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation
    from ..studies.estimation import EstimateRecords

__all__ = [
    "MODE_HOLD_S",
    "RecordingSummary",
    "estimate_blueprint",
    "held_changes",
    "mode_lane_entity",
    "record_budget_diagnosis",
    "record_detection",
    "record_diagnosis",
    "record_estimates",
    "run_monitor",
    "scenario_truth",
]


#: Hops per push of an unpaced replay (:func:`run_monitor` without ``rate``): 250 hops (50 s at the
#: default 0.2 s hop, a few MB of spectra per push). Every push costs a fixed overhead (compiled
#: calls, logging, and the Gauss-Newton fits of the identification, which iterate as long as the
#: slowest window of the push), so fewer, larger pushes are faster; the output is the same.
UNPACED_HOPS = 250


# --------------------------------------------------------------------------- drivers
@dataclass(frozen=True)
class RecordingSummary:
    """Outcome of :func:`record_detection` / :func:`run_monitor`.

    Attributes
    ----------
    path : Path or None
        The ``.rrd`` written (None if no file sink).
    live_url : str or None
        The viewer streamed to (None if none or unreachable).
    events : tuple of DetectionEvent
    n_samples, n_frames : int
        Chattering samples and STFT frames processed.
    duration_s : float
        Data time covered (s).
    wall_s : float
        Wall-clock time of the run (s).
    notes : tuple of str
        Messages for the user (no display, unreachable viewer, ...).
    write_error : str or None
        Why the recording could not be completed (e.g. the disk filled during the run); the run
        itself finished and its events are here.
    parameter_events : tuple of ParameterEvent
        With tolerances, the identified parameters' alarms: the run's fault events (``events`` are then
        the spectral detector's mismatches). Not in :meth:`to_dict`: ``monitor --json`` puts them into
        its summary itself (``MonitorIdentification.into_summary``).
    """

    path: Path | None
    live_url: str | None
    events: tuple[DetectionEvent, ...]
    n_samples: int
    n_frames: int
    duration_s: float
    wall_s: float
    notes: tuple[str, ...] = ()
    write_error: str | None = None
    parameter_events: tuple[ParameterEvent, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print): ``events`` are the spectral
        detector's events, each with its ``alarm_time_s`` (where the lanes change without tolerances)."""
        return {
            "recording": None if self.path is None else str(self.path),
            "live_url": self.live_url,
            "n_samples": self.n_samples,
            "n_frames": self.n_frames,
            "duration_s": self.duration_s,
            "wall_s": self.wall_s,
            "events": [e.to_dict() for e in self.events],
            "notes": list(self.notes),
        }


def _pace(start_wall: float, data_elapsed: float, rate: float | None) -> None:
    if rate is None:
        return
    delay = start_wall + data_elapsed / rate - time.perf_counter()
    if delay > 0:
        time.sleep(delay)


def _chunks(total: int, size: int) -> Iterator[tuple[int, int]]:
    for lo in range(0, total, size):
        yield lo, min(lo + size, total)


#: An unpaced replay identifies the windows of at least this many hops (whole pushes) at once.
IDENTIFY_AHEAD_HOPS = 2500


class _IdentifyAhead:
    """The identification windows of an unpaced file replay, identified several pushes ahead at once
    and handed to each push as it comes: the same windows and numbers as identifying push by push
    (:meth:`~chatterspec.detection.identification.OnlineIdentifier.share`), with the per-push cost (and
    the Gauss-Newton iterations of a batch's slowest window) paid once per batch. ``batch`` (samples)
    is a whole number of pushes: a push's windows lie in one batch."""

    def __init__(self, identifier: OnlineIdentifier, z: np.ndarray, u: np.ndarray, batch: int) -> None:
        self.identifier, self.z, self.u, self.batch = identifier, z, u, batch
        self.fed = 0  # raw samples pushed into the identifier
        self.pending: OnlineIdentification | None = None

    def upto(self, hi: int) -> OnlineIdentification:
        """The windows complete once the first ``hi`` samples are in (``hi``: the end of a push)."""
        if hi > self.fed:
            assert self.pending is None or self.pending.n_windows == 0  # (handed out up to the last push)
            stop = min(self.z.shape[0], self.fed + self.batch)
            self.pending = self.identifier.push(self.z[self.fed : stop], self.u[self.fed : stop])
            self.fed = stop
        assert self.pending is not None  # (the first call pushed)
        mine, self.pending = self.identifier.share(self.pending, hi)
        return mine


def run_monitor(
    monitor: ChatteringMonitor,
    sinks: Sinks,
    *,
    z: np.ndarray | None = None,
    u: np.ndarray | None = None,
    chattering: np.ndarray | None = None,
    chunk_samples: int | None = None,
    rate: float | None = None,
    truth: list[tuple[float, str, bool]] | None = None,
    scroll_frames: int = 50,
    on_event: Callable[[DetectionEvent], None] | None = None,
    band_hz: tuple[float, float] | None = None,
    identifier: IdentificationMonitor | None = None,
    on_identification: Callable[[IdentificationUpdate], None] | None = None,
    identification_intervals: list[dict[str, Any]] | None = None,
) -> RecordingSummary:
    """Drive ``monitor`` over raw data (``z`` (T, m), ``u`` (T, p)) or precomputed ``chattering`` (N, m)
    and log everything to ``sinks``; closes the sinks at the end (also on Ctrl-C).

    Parameters
    ----------
    monitor : ChatteringMonitor
        The online monitor to drive.
    sinks : Sinks
        Where to log (see :func:`open_sinks`); closed at the end.
    z, u : arrays, optional
        Raw measurements (T, m) and inputs (T, p): both SVSFs run online.
    chattering : array, optional
        Precomputed chattering (N, m) instead of ``z``/``u``.
    chunk_samples : int, optional
        Samples per push; default one hop when paced and :data:`UNPACED_HOPS` hops otherwise
        (the output does not depend on it).
    rate : float, optional
        Replay speed (1.0 = real time); ``None`` runs as fast as possible.
    truth : list of (start_s, label, is_fault), optional
        True fault timeline for the viewer.
    scroll_frames : int
        Columns of the scrolling spectrogram.
    on_event : callable, optional
        Called with each :class:`~chatterspec.online.monitor.DetectionEvent` (e.g. to print it).
    band_hz : (float, float), optional
        Spectrogram band (Hz); default :func:`~chatterspec.viewer.spectrograms.default_band_hz`.
    identifier : IdentificationMonitor, optional
        Fault identification and the decisions on the identified parameters per hop on the same raw
        pushes (:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`), logged to
        the sinks (:mod:`chatterspec.viewer.rerun_log`); raw data only. The channels' lanes then
        follow its windows' states (fault, healthy, not excited); without tolerances it must hear of the
        monitor's alarms (``note_alarm``, e.g. from ``on_event``: :func:`record_detection` does).
    on_identification : callable, optional
        Called with each push's :class:`~chatterspec.online.identification_monitor.IdentificationUpdate`.
    identification_intervals : list of dict, optional
        ``detect --json``'s ``identification_intervals``: rows of the event log (with ``identifier``).

    Returns
    -------
    RecordingSummary
    """
    t_start = time.perf_counter()
    events: list[DetectionEvent] = []
    parameter_events: list[ParameterEvent] = []
    # paced replays push one hop at a time (smooth live view); unpaced runs push UNPACED_HOPS hops at
    # once. The output does not depend on the chunking, only the per-call overhead does.
    size = chunk_samples or (monitor.n_hop if rate is not None else UNPACED_HOPS * monitor.n_hop)
    logger = None  # a RerunLogger that fails to build must not hide its error behind this name
    done = False
    try:
        if chattering is not None:
            total = chattering.shape[0]
        elif z is not None and u is not None:
            total = z.shape[0]
        else:
            raise ValueError("give z and u, or chattering")
        if chattering is not None:
            identifier = None  # identification regresses on the raw measurements
        logger = (
            RerunLogger(
                sinks,
                monitor,
                scroll_frames=scroll_frames,
                truth=truth,
                band_hz=band_hz,
                span_s=record_span(monitor, total, raw=chattering is None),
                identification=identifier,
            )
            if sinks.streams
            else None
        )
        ahead = None  # an unpaced replay of raw data identifies ahead
        if identifier is not None and chattering is None and z is not None and u is not None:
            if rate is None:
                batch = size * max(1, -(-IDENTIFY_AHEAD_HOPS * monitor.n_hop // size))  # whole pushes
                ahead = _IdentifyAhead(identifier.identifier, z, u, batch)
        for lo, hi in _chunks(total, size):
            if chattering is not None:
                upd = monitor.push_chattering(chattering[lo:hi])
            else:
                assert z is not None and u is not None  # (checked above)
                upd = monitor.push(z[lo:hi], u[lo:hi])
            if logger is not None:
                logger.log_update(upd)
            for ev in upd.events:
                events.append(ev)
                if on_event is not None:
                    on_event(ev)
            if identifier is not None:
                assert z is not None and u is not None  # (no identifier on precomputed chattering)
                if ahead is not None:
                    found = identifier.handle(ahead.upto(hi))
                else:
                    found = identifier.push(z[lo:hi], u[lo:hi])
                parameter_events.extend(found.events)
                if logger is not None:
                    logger.log_identification(found)
                if on_identification is not None:
                    on_identification(found)
            _pace(t_start, hi * monitor.dt, rate)
        if logger is not None and identification_intervals:
            logger.log_identification_intervals(identification_intervals)
        done = True
    finally:
        write_error = _close(logger, sinks, keep_going=done)
    return RecordingSummary(
        path=sinks.path,
        live_url=sinks.live_url,
        events=tuple(events),
        n_samples=monitor.n_samples,
        n_frames=monitor.n_frames,
        duration_s=monitor.n_samples * monitor.dt,
        wall_s=time.perf_counter() - t_start,
        notes=tuple(sinks.notes),
        write_error=write_error,
        parameter_events=tuple(parameter_events),
    )


def _close(logger: RerunLogger | None, sinks: Sinks, *, keep_going: bool) -> str | None:
    """Close the logger and the sinks; after a finished run, a write failure is returned, not raised."""
    try:
        try:
            if logger is not None:
                logger.close()
        finally:
            sinks.close()
    except (OSError, RuntimeError) as exc:
        err = file_error(exc, sinks.path or "recording")
        if not keep_going or err is None:
            raise
        return err.strerror or str(err)
    return None


def scenario_truth(scenario: Scenario) -> list[tuple[float, str, bool]]:
    """The true fault timeline of a scenario, as the viewer's truth lane takes it.

    Parameters
    ----------
    scenario : Scenario
        A simulated scenario (its segments of true plant).

    Returns
    -------
    list of (start_s, label, is_fault)
        One entry per segment: start time (s), label, and whether the true plant
        differs from the nominal model there.
    """
    out = []
    for seg in scenario.segments:
        fault = scenario.deviates(seg)
        out.append(
            (seg.start, seg.label if fault and seg.label else ("fault" if fault else "healthy"), fault)
        )
    return out


def record_detection(
    source: Simulation | ChatteringRecord,
    settings: MonitorSettings | None = None,
    *,
    path: str | Path | None = None,
    live: str | None = None,
    run: int = 0,
    chunk_samples: int | None = None,
    rate: float | None = None,
    recording_name: str | None = None,
    application_id: str = "chatterspec",
    on_event: Callable[[DetectionEvent], None] | None = None,
    band_hz: tuple[float, float] | None = None,
    identification: IdentificationSetup | None = None,
    confidence: float = 0.95,
    identification_intervals: list[dict[str, Any]] | None = None,
    threshold: Threshold | None = None,
) -> RecordingSummary:
    """Run the online monitor over one realization of a simulation or chattering record and record it.

    Parameters
    ----------
    source : Simulation or ChatteringRecord
        A :class:`~chatterspec.plants.simulate.Simulation` is filtered online from its
        raw measurements (both SVSFs, the same kernel as the batch path); a
        :class:`~chatterspec.detection.pipeline.ChatteringRecord` is analysed from its
        chattering. The scenario's true fault timeline is logged when known.
    settings : MonitorSettings, optional
        Detector settings; ``psi`` defaults to the scenario's ``psi`` if it has one.
    path : path, optional
        ``.rrd`` file to write. With neither ``path`` nor ``live`` it defaults
        to :func:`default_recording_path` under ``recordings/``.
    live : str, optional
        ``"spawn"`` or a viewer URL (see :func:`open_sinks`).
    run : int
        Which realization (index into the leading axis).
    chunk_samples, rate : see :func:`run_monitor`.
    recording_name : str, optional
        Name shown in the viewer (default: the scenario name).
    application_id : str
        Rerun application id.
    on_event : callable, optional
        Called with each detection event.
    band_hz : (float, float), optional
        Spectrogram band (Hz); see :func:`run_monitor`.
    identification : IdentificationSetup, optional
        Identify the parameters of a simulation's nominal model per hop beside the monitor
        (:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`, at the monitor's
        alpha, rule and budget; one false alarm per day without a budget): its estimates are drawn below
        the lanes and the channels' lanes read "not excited" where the data cannot see a change of the
        parameters' tolerance (without one, their nominal value). None: the spectral alarm alone.
    confidence : float
        Level of the identification's intervals.
    identification_intervals : list of dict, optional
        The record's identification per fault interval (``detect --json``'s
        ``identification_intervals``), rows of the event log.
    threshold : Threshold, optional
        The monitor's per-frame threshold for ``settings``
        (:func:`~chatterspec.detection.thresholds.monitor_threshold`), when the caller has it already.

    Returns
    -------
    RecordingSummary
    """
    from ..detection.pipeline import ChatteringRecord
    from ..plants.simulate import Simulation

    scenario = getattr(source, "scenario", None)
    name = recording_name or (scenario.name if scenario is not None else "chattering")
    settings = settings or MonitorSettings()
    if settings.psi is None and scenario is not None and scenario.psi is not None:
        settings = dataclasses.replace(settings, psi=tuple(scenario.psi))
    if path is None and live is None:
        path = default_recording_path(name)
    truth = scenario_truth(scenario) if scenario is not None else None
    ident = None
    if isinstance(source, Simulation):
        model = source.scenario.nominal
        mon = ChatteringMonitor(model, settings, t0=float(source.t[0]), threshold=threshold)
        kw: dict[str, Any] = {"z": source.z[run], "u": source.input_of(run)}
        if identification is not None:
            ident = _identification_beside(identification, mon, confidence)
        if ident is not None:
            on_event = _noting(ident, on_event)
    elif isinstance(source, ChatteringRecord):
        mon = ChatteringMonitor(source.model, settings, t0=float(source.t[0]), threshold=threshold)
        kw = {"chattering": source.values[run]}
    else:
        raise TypeError(f"source must be a Simulation or a ChatteringRecord; got {type(source).__name__}")
    sinks = open_sinks(
        record=path,
        live=live,
        application_id=application_id,
        recording_name=name,
        default_record=default_recording_path(name),
    )
    return run_monitor(
        mon,
        sinks,
        chunk_samples=chunk_samples,
        rate=rate,
        truth=truth,
        on_event=on_event,
        band_hz=band_hz,
        identifier=ident,
        identification_intervals=identification_intervals,
        **kw,
    )


def _identification_beside(
    setup: IdentificationSetup, monitor: ChatteringMonitor, confidence: float
) -> IdentificationMonitor | None:
    """An identification monitor beside ``monitor``: its hop and window, its alpha, rule and budget (one
    false alarm per day without a budget: the level of the detectable change); None when the model's
    parameters cannot all be fitted at once and it declares no tolerance (as ``monitor`` does)."""
    from ..detection.parameter_decision import parameter_alarm_settings
    from ..errors import IdentifiabilityError
    from ..online.identification_monitor import IdentificationMonitor

    st = monitor.settings
    try:
        decision = parameter_alarm_settings(
            setup,
            hop_s=monitor.n_hop * monitor.dt,
            window_hops=max(1, round(monitor.n_window / monitor.n_hop)),
            rule=st.rule if st.rule is not None else "cusum",
            false_alarms_per_hour=st.false_alarms_per_hour or 1.0 / 24.0,
        )
    except IdentifiabilityError:
        if setup.parameter_map.has_tolerances:
            raise
        return None
    return IdentificationMonitor(
        setup,
        decision,
        t0=monitor.t0,
        alpha=st.alpha,
        confidence=confidence,
        frame_samples=monitor.n_window,
    )


def _noting(
    ident: IdentificationMonitor, on_event: Callable[[DetectionEvent], None] | None
) -> Callable[[DetectionEvent], None]:
    """``on_event`` that first tells ``ident`` of the monitor's alarm (the fault named under it, the
    channels' fault state without tolerances)."""

    def noted(ev: DetectionEvent) -> None:
        ident.note_alarm(ev.kind, ev.channel, ev.alarm_time_s)
        if on_event is not None:
            on_event(ev)

    return noted


# -------------------------------------------------------------------------- an estimator comparison


def _ns(seconds: np.ndarray) -> np.ndarray:
    """Seconds -> integer nanoseconds as durations (:func:`~chatterspec.viewer.spectrograms.to_ns`)."""
    return to_ns(seconds).astype("timedelta64[ns]")


def record_estimates(records: EstimateRecords, path: str | Path, *, run: int = 0) -> Path:
    """Write one realization of :class:`~chatterspec.studies.estimation.EstimateRecords` to an ``.rrd`` file.

    Parameters
    ----------
    records : EstimateRecords
        Truth, measurements and filter outputs
        (from :func:`~chatterspec.studies.estimation.estimate_records`).
    path : str or Path
        Output file, ending in ``.rrd`` (parent folders are created).
    run : int
        Which realization of ``records`` to log (index into its run axis).

    Returns
    -------
    Path
        The file written (closed, with its footer).

    Raises
    ------
    ParameterError
        A path not ending in ``.rrd`` or a run index out of range.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ParameterError(f"recording path must end in .rrd; got {str(path)!r}")
    runs = records.x.shape[0]
    if not 0 <= run < runs:
        raise ParameterError(f"run must be in [0, {runs}); got {run}")
    import rerun as rr

    sc = records.scenario
    model = sc.nominal
    states = tuple(model.state_names)
    outputs = tuple(model.output_names)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("chatterspec", recording_id=f"estimate-{sc.name}-{records.first_run + run}")
    try:
        rec.save(str(path))
    except RuntimeError as exc:  # rerun reports file errors (e.g. disk full) as RuntimeError
        err = file_error(exc, path)
        if err is None:
            raise ParameterError(f"cannot write the recording {str(path)!r}: {exc}") from None
        raise err from None
    try:
        rec.send_recording_name(f"estimate {sc.name} run {records.first_run + run}")
        t_all = rr.TimeColumn("time", duration=_ns(records.t))
        t_post = rr.TimeColumn("time", duration=_ns(records.t[1:]))
        names = list(records.outputs)
        rec.log("/info", rr.TextDocument(_legend(sc.name, records.first_run + run, names)), static=True)
        log_truth_lane([rec], scenario_truth(sc))
        x = records.x[run]
        extents: dict[str, list[np.ndarray]] = {}  # per view, the values it draws: its y range
        _log_styles(rec, states, outputs, names)
        for i, s in enumerate(states):
            rec.send_columns(
                f"/states/{s}/truth", indexes=[t_all], columns=rr.Scalars.columns(scalars=x[:, i])
            )
            extents.setdefault(f"/states/{s}", []).append(x[:, i])
        for j, o in enumerate(outputs):
            rec.send_columns(
                f"/measurements/{o}",
                indexes=[t_all],
                columns=rr.Scalars.columns(scalars=records.z[run, :, j]),
            )
        for name in names:
            out = records.outputs[name]
            est = out.x_post[run]
            err = x[1:] - est
            for i, s in enumerate(states):
                rec.send_columns(
                    f"/states/{s}/{name}", indexes=[t_post], columns=rr.Scalars.columns(scalars=est[:, i])
                )
                rec.send_columns(
                    f"/errors/{s}/{name}", indexes=[t_post], columns=rr.Scalars.columns(scalars=err[:, i])
                )
                extents.setdefault(f"/states/{s}", []).append(est[:, i])
                extents.setdefault(f"/errors/{s}", []).append(err[:, i])
            if out.innovation is not None:
                for j, o in enumerate(outputs):
                    rec.send_columns(
                        f"/innovations/{o}/{name}",
                        indexes=[t_post],
                        columns=rr.Scalars.columns(scalars=out.innovation[run, :, j]),
                    )
                    extents.setdefault(f"/innovations/{o}", []).append(out.innovation[run, :, j])
        span = (float(records.t[0]), float(records.t[-1]))
        units = state_units(model)
        rec.send_blueprint(
            estimate_blueprint(
                states,
                outputs,
                names,
                span,
                units,
                title=f"{sc.name}, run {records.first_run + run}",
                y_ranges={k: labelled_range(np.concatenate(v)) for k, v in extents.items()},
            ),
            make_active=True,
            make_default=True,
        )
        rec.flush()
    finally:
        rec.disconnect()
    return path


def _log_styles(rec: Any, states: tuple[str, ...], outputs: tuple[str, ...], names: list[str]) -> None:
    """Static colours and widths (the shared palette): the truth a thin light line over the estimates,
    each filter in its own colour in the state, error and innovation views (earlier filters wider)."""
    import rerun as rr

    for s in states:
        rec.log(
            f"/states/{s}/truth",
            rr.SeriesLines(colors=[list(TRUTH)], widths=[1.0], names=["truth"]),
            static=True,
        )
        for k, name in enumerate(names):
            style = _filter_style(rr, name, k, len(names))
            rec.log(f"/states/{s}/{name}", style, static=True)
            rec.log(f"/errors/{s}/{name}", style, static=True)
    for o in outputs:
        for k, name in enumerate(names):
            rec.log(f"/innovations/{o}/{name}", _filter_style(rr, name, k, len(names)), static=True)


def labelled_range(values: np.ndarray, plot_px: float = 140.0) -> tuple[float, float]:
    """A y range holding ``values`` whose power-of-ten ticks the viewer labels on a plot ``plot_px`` high
    (an automatic range of a velocity in cm/s labelled "0" alone): the values' own range (5 % margins)
    when it holds two such ticks far enough apart, else symmetric ``+-1.1 p`` when the values change sign
    (:func:`~chatterspec.viewer.blueprint.labelled_half_range`), else from 0 to a labelled top
    (:func:`~chatterspec.viewer.blueprint.labelled_top`)."""
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    lo, hi = (float(v.min()), float(v.max())) if v.size else (-1.0, 1.0)
    pad = 0.05 * max(hi - lo, 1e-300)
    tight = (lo - pad, hi + pad)
    if labelled_step(*tight, plot_px) is not None:
        return tight  # the data's own range: the viewer labels its ticks
    if lo >= 0.0 and hi > 0.0:
        top = labelled_top(1.05 * hi)
        return (-0.05 * top, top)
    if hi <= 0.0 and lo < 0.0:
        bottom = labelled_top(-1.05 * lo)
        return (-bottom, 0.05 * bottom)
    r = labelled_half_range(max(abs(lo), abs(hi), 1e-300))
    return (-r, r)


def _width(k: int, n: int) -> float:
    """Line width of filter ``k`` of ``n``: the first widest (3.5 px down to 1 px), so that a later one
    drawn over it (the estimates nearly coincide) leaves its edges visible."""
    return 1.0 + 2.5 * (n - 1 - k) / max(n - 1, 1)


def _filter_style(rr: Any, name: str, k: int, n: int) -> Any:
    """Filter ``k`` of ``n``: its palette colour and :func:`_width`."""
    return rr.SeriesLines(colors=[list(filter_color(name, k))], widths=[_width(k, n)], names=[name])


def _legend(scenario: str, run: int, names: list[str]) -> str:
    """The recording's legend (a text beside the views, not over the data): the colour of every filter."""
    by_rgb = {rgb: word for word, rgb in TAB10.items()}
    n = len(names)
    parts = [
        f"{name} {by_rgb.get(filter_color(name, k), f'colour {k}')} ({_width(k, n):.1f} px)"
        for k, name in enumerate(names)
    ]
    return f"Scenario {scenario}, realization {run}. Truth: light grey, thin. Estimates: {', '.join(parts)}."


def estimate_blueprint(
    states: tuple[str, ...],
    outputs: tuple[str, ...],
    filters: list[str],
    span_s: tuple[float, float],
    units: tuple[str, ...],
    *,
    title: str = "",
    y_ranges: dict[str, tuple[float, float]] | None = None,
) -> Any:
    """The layout of an estimate recording: one row per state with the truth and every filter's
    estimate on shared axes beside the estimation errors; below, the innovations per output and the
    run's description with the colours (no legend over the data); at the bottom the true plant's lane,
    which marks where the fault starts. Every time view shows ``span_s`` (linked time axis); playback
    opens paused on the whole record.

    Parameters
    ----------
    states, outputs : tuple of str
        State and output names.
    filters : list of str
        Filter names (their colours come from :data:`chatterspec.palette.FILTER_COLORS`).
    span_s : (float, float)
        The record's time span (s).
    units : tuple of str
        Unit per state ("" where unknown).
    title : str
        Scenario and run, shown in the view titles.
    y_ranges : dict, optional
        Per view origin (``/states/<s>``, ``/errors/<s>``, ``/innovations/<o>``) its y range
        (:func:`labelled_range`: the viewer then labels its ticks); default auto range.

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun.blueprint as rrb

    time_range, axis = time_axis(span_s)
    hidden = rrb.PlotLegend(visible=False)

    def view(origin: str, name: str, legend: Any = hidden) -> Any:
        """A time view of the whole record, on the linked time axis."""
        rng = (y_ranges or {}).get(origin)
        return rrb.TimeSeriesView(
            origin=origin,
            name=name,
            time_ranges=time_range,
            axis_x=axis,
            plot_legend=legend,
            axis_y=None if rng is None else rrb.ScalarAxis(range=rng),
        )

    rows = []  # one row per state, each view half the window wide: the time axis labels its ms ticks
    for s, u in zip(states, units, strict=True):
        unit = f" [{u}]" if u else ""
        rows.append(
            rrb.Horizontal(
                view(f"/states/{s}", f"{s}{unit}: truth and estimates"),
                view(f"/errors/{s}", f"{s} error: truth - estimate{unit}"),
            )
        )
    bottom = [view(f"/innovations/{o}", f"{o}: innovation z - C x(k|k-1)") for o in outputs]
    bottom.append(rrb.TextDocumentView(origin="/info", name=f"estimate {title}: colours"))
    lane = rrb.StateTimelineView(
        origin="/state", name="true plant (the fault's start)", time_ranges=time_range, time_view=axis
    )
    return rrb.Blueprint(
        rrb.Vertical(*rows, rrb.Horizontal(*bottom), lane, row_shares=[1.0] * len(rows) + [0.9, 0.5]),
        time_panel(span_s),
        collapse_panels=True,
    )


# -------------------------------------------------------------------------------------- a diagnosis


def record_diagnosis(
    path: str | Path,
    sim: Simulation,
    threshold: Threshold | None,
    mode_outputs: dict[str, tuple[np.ndarray, np.ndarray, tuple[str, ...]]],
    *,
    config: STFTConfig | None = None,
    chunk_samples: int = 10_000,
    route_series: dict[str, tuple[np.ndarray, np.ndarray, float, str]] | None = None,
    chattering_rule: tuple[Any, float] | None = None,
) -> Path:
    """Write realization 0 of ``sim`` to a Rerun file: chattering monitor and mode probabilities.

    Parameters
    ----------
    path : str or Path
        ``.rrd`` file to write (checked by the caller with ``check_record_path``).
    sim : Simulation
        The diagnosed realizations; realization 0 is recorded.
    threshold : Threshold or None
        Per-frame threshold of the chattering route (``None``: no chattering part).
    mode_outputs : dict
        ``method -> (t (T-1,) s, mu (runs, T-1, r) or (T-1, r), modes)`` (``diagnose_modes(..., keep=...)``);
        realization 0 is recorded.
    config : STFTConfig, optional
        STFT settings of the threshold (default 1 s Hamming, 0.2 s hop).
    chunk_samples : int
        Measurements per monitor push (the output does not depend on it).
    route_series : dict, optional
        ``method -> (t (K,) s, statistic (K,), threshold, name)``: a route's alarm statistic and its
        threshold, drawn in one view per route.
    chattering_rule : (AlarmRule, float), optional
        The chattering route's calibrated alarm rule and its budget (alarm starts per hour): the channel
        lanes and events then follow the run's rule (default: the per-frame rule).

    Returns
    -------
    Path
        The file written.
    """
    import rerun as rr
    import rerun.blueprint as rrb

    sc = sim.scenario
    z0, u = np.asarray(sim.z[0]), np.asarray(sim.u)
    u0 = u[0] if u.ndim == 3 else u
    sinks = open_sinks(record=path, recording_name=f"diagnose {sc.name} (realization 0)")
    logger: RerunLogger | None = None
    try:
        if threshold is not None:
            rule = None if chattering_rule is None else chattering_rule[0]
            settings = MonitorSettings(stft=config or STFTConfig(), threshold=threshold, rule=rule)
            mon = ChatteringMonitor(sc.nominal, settings)
            span = record_span(mon, z0.shape[0], raw=True)
            truth = scenario_truth(sc)
            logger = RerunLogger(
                sinks,
                mon,
                truth=truth,
                span_s=span,
                send_blueprint=False,
                extra_lanes=len(mode_outputs),
                rows_above=1 if route_series else 0,
                peak_view=False,  # every lane visible at 1600x1000: the events and spectrogram give it
                budget_per_hour=None if chattering_rule is None else chattering_rule[1],
            )
            for lo in range(0, z0.shape[0], int(chunk_samples)):
                logger.log_update(mon.push(z0[lo : lo + chunk_samples], u0[lo : lo + chunk_samples]))
        else:
            span = (float(sim.t[0]), float(sim.t[-1]))
        time_range, axis = time_axis(span)
        truth = scenario_truth(sc)
        lane_colors = truth_colors(truth)
        for method, (t, mu, modes) in mode_outputs.items():
            mu = np.asarray(mu, dtype=float)
            _log_modes(
                sinks,
                rr,
                method,
                np.asarray(t, dtype=float),
                mu[0] if mu.ndim == 3 else mu,
                modes,
                lane_colors,
            )
        route_views = [
            _log_route(sinks, rr, rrb, method, series, time_range, axis)
            for method, series in (route_series or {}).items()
        ]
        lanes_name = (
            f"true fault (top); most probable mode per method (runs >= {MODE_HOLD_S:g} s); fault state per "
            "channel (grey = no evidence)"
        )
        if logger is not None:
            # sent again on close with the chattering views' y ranges (RerunLogger.close)
            logger.file_layout = {"has_truth": True, "above": route_views or None, "lanes_name": lanes_name}
            bp = logger.layout(span_s=span, **logger.file_layout)
        else:  # no chattering route: the route statistics above the truth and mode lanes
            log_truth_lane(sinks.streams, truth)
            lanes = rrb.StateTimelineView(
                origin="/state", name=lanes_name, time_ranges=time_range, time_view=axis
            )
            rows = ([rrb.Horizontal(*route_views)] if route_views else []) + [lanes]
            bp = rrb.Blueprint(
                rrb.Vertical(*rows, row_shares=[1.0] * (len(rows) - 1) + [0.6]),
                rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="paused"),
                collapse_panels=True,
            )
        for s in sinks.streams:
            s.send_blueprint(bp, make_active=True, make_default=True)
    finally:
        try:
            if logger is not None:
                logger.close()
        finally:
            sinks.close()
    return Path(path)


#: Shortest run (s) of a most probable mode that its lane shows; shorter runs stay in the mode before
#: them (the lanes of a switching SMM / IMM otherwise split into slivers whose labels cannot be read).
MODE_HOLD_S = 0.2


def held_changes(best: np.ndarray, t: np.ndarray, hold_s: float) -> np.ndarray:
    """Indices where the lane of the most probable mode ``best`` (per sample at times ``t``, s) changes:
    every change of ``best`` whose new mode then holds for at least ``hold_s`` seconds (or to the end);
    the first sample always.

    Parameters
    ----------
    best : (T,) int array
    t : (T,) array
        Times (s).
    hold_s : float

    Returns
    -------
    int array
    """
    raw = np.flatnonzero(np.concatenate(([True], best[1:] != best[:-1])))
    ends = np.append(t[raw[1:]], np.inf)
    keep = [int(raw[0])]
    for k, end in zip(raw[1:].tolist(), ends[1:].tolist(), strict=True):
        if end - t[k] >= hold_s and best[k] != best[keep[-1]]:
            keep.append(k)
    return np.asarray(keep, dtype=np.intp)


def mode_lane_entity(method: str) -> str:
    """Entity of the most-probable-mode lane of ``method``: sorts right below the truth lane.

    Parameters
    ----------
    method : str

    Returns
    -------
    str
        ``/state/0m_<method>``.
    """
    return f"/state/0m_{_entity(method)}"


def _log_modes(
    sinks: Sinks,
    rr: ModuleType,
    method: str,
    t: np.ndarray,
    mu: np.ndarray,
    modes: tuple[str, ...],
    colors: dict[str, int],
) -> None:
    """Mode probabilities ``/modes/<method>/<mode>`` (series, palette colours) and the most probable mode
    as a lane (a change at each switch), coloured like the truth lane where a mode names a true segment."""
    ns = to_ns(t)
    tcol = rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))
    best = np.argmax(mu, axis=1)
    change = held_changes(best, t, MODE_HOLD_S)
    names = {"normal": "healthy"}  # the truth lane's name of the nominal mode
    lane_col = [colors.get(names.get(m, m), rgba32(mode_color(j))) for j, m in enumerate(modes)]
    for s in sinks.streams:
        for j, mode in enumerate(modes):
            ent = f"/modes/{method}/{_entity(mode)}"
            s.log(ent, rr.SeriesLines(colors=[list(mode_color(j))], names=[f"mu {mode}"]), static=True)
            s.send_columns(ent, indexes=[tcol], columns=rr.Scalars.columns(scalars=np.asarray(mu[:, j])))
        s.log(
            mode_lane_entity(method),
            rr.StateConfiguration(
                values=list(modes),
                labels=list(modes),  # the lane's path above it names the method
                colors=np.array(lane_col, dtype=np.uint32),
            ),
            static=True,
        )
        s.send_columns(
            mode_lane_entity(method),
            indexes=[rr.TimeColumn(TIMELINE, duration=ns[change].astype("timedelta64[ns]"))],
            columns=rr.StateChange.columns(state=[modes[k] for k in best[change]]),
        )


def _log_route(
    sinks: Sinks,
    rr: ModuleType,
    rrb: ModuleType,
    method: str,
    series: tuple,
    time_range: VisibleTimeRange,
    axis: TimeAxis | None = None,
) -> Any:
    """Log one route's statistic and threshold as two series; return its view (no legend over the data:
    the title names them; y range up to 1.5 h, so that the threshold shows even when a fault's statistic
    runs far above it)."""
    t, stat, h, name = series
    ns = _ns(np.asarray(t, dtype=float))
    stat = np.asarray(stat, dtype=float)
    hline = np.full(stat.shape, float(h) if np.isfinite(h) else np.nan)
    for s in sinks.streams:
        for ent, vals, color, label in (
            (f"/routes/{method}/statistic", stat, list(filter_color(method)), name),
            (f"/routes/{method}/threshold", hline, list(NEUTRAL), "threshold"),
        ):
            s.log(ent, rr.SeriesLines(colors=[color], names=[label]), static=True)
            s.send_columns(
                ent, indexes=[rr.TimeColumn(TIMELINE, duration=ns)], columns=rr.Scalars.columns(scalars=vals)
            )
    top = 1.5 * float(h) if np.isfinite(h) and h > 0 else None
    return rrb.TimeSeriesView(
        origin=f"/routes/{method}",
        name=f"{method}: {name} vs h = {h:.3g}",
        time_ranges=time_range,
        axis_x=axis,
        axis_y=None if top is None else rrb.ScalarAxis(range=(0.0, top)),
        plot_legend=rrb.PlotLegend(visible=False),
    )


def record_budget_diagnosis(
    path: str | Path,
    scenario: Scenario,
    seed: int,
    routes: dict[str, Any],
    results: list[Any],
    threshold: Threshold | None,
) -> Path:
    """Write realization 0 of a diagnosis at one budget: monitor, mode probabilities, route statistics.

    Parameters
    ----------
    path : str or Path
        ``.rrd`` file to write.
    scenario : Scenario
        The diagnosed scenario.
    seed : int
        Seed of the diagnosed runs (realization 0 is simulated again, identical).
    routes : dict
        Method -> route (:mod:`chatterspec.studies.budget_diagnosis`); the results' own routes (as diagnosed,
        e.g. with a healthy NIS scale) are used where they carry one.
    results : list of RouteBudget
        Their results (the calibrated rules).
    threshold : Threshold or None
        Per-frame threshold of the chattering monitor's spectrogram view (None: no chattering part).

    Returns
    -------
    Path
    """
    from ..detection.alarms.rules import rule_from_dict, rule_spec
    from ..detection.alarms.streams import run_rule
    from ..detection.route_scores import mode_log_odds
    from ..plants.simulate import iter_simulations

    sim = next(iter_simulations(scenario, 1, seed, chunk_runs=1))
    modes: dict = {}
    series: dict = {}
    by_method = {r.method: r for r in results}
    for method, route in routes.items():
        route = by_method[method].route or route
        rule = rule_from_dict(by_method[method].rule)
        if method in ("smm", "imm"):
            x0, P0 = route._x0, route._P0
            out = route.filter.run(sim.z[:, 1:], sim.u[..., :-1, :], x0=x0, P0=P0)
            modes[method] = (sim.t[1:], out.mu, route.labels)
            score = mode_log_odds(out.mu, route.floor)[..., None]
            times = sim.t[1:]
        else:
            rs = route.scores(sim)
            score, times = rs.score, rs.times
        blk = run_rule(rule, score)
        stat = blk.statistic[0].max(axis=-1)  # the largest over the channels (the route's alarm is any)
        label = rule_spec(rule).statistic
        series[method] = (times, stat, rule.threshold, label)
    chat = by_method.get("chattering")
    chat_rule = None if chat is None else (rule_from_dict(chat.rule), chat.budget_per_hour)
    thr = threshold if "chattering" in routes else None
    return record_diagnosis(path, sim, thr, modes, route_series=series, chattering_rule=chat_rule)
