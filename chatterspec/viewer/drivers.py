"""Drivers: run the online monitor over a record into Rerun sinks; record a batch detection."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorSettings
from .record_geometry import record_span
from .rerun_log import RerunLogger
from .sinks import Sinks, default_recording_path, file_error, open_sinks

if TYPE_CHECKING:
    from collections.abc import Callable

    from ..detection.identification import IdentificationSetup
    from ..detection.parameter_decision import ParameterEvent
    from ..detection.pipeline import ChatteringRecord
    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation

__all__ = [
    "RecordingSummary",
    "record_detection",
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
        Spectrogram band (Hz); default :func:`~chatterspec.viewer.record_geometry.default_band_hz`.
    identifier : IdentificationMonitor, optional
        Fault identification and the decisions on the identified parameters per hop on the same raw
        pushes (:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`), logged to
        the sinks (:mod:`chatterspec.viewer.identification_log`); raw data only. The channels' lanes then
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
        mon = ChatteringMonitor(model, settings, t0=float(source.t[0]))
        kw: dict[str, Any] = {"z": source.z[run], "u": source.input_of(run)}
        if identification is not None:
            ident = _identification_beside(identification, mon, confidence)
        if ident is not None:
            on_event = _noting(ident, on_event)
    elif isinstance(source, ChatteringRecord):
        mon = ChatteringMonitor(source.model, settings, t0=float(source.t[0]))
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
