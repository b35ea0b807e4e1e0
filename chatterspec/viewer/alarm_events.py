"""The event log of a recording (``/events``): one row per alarm raised or cleared, at its alarm time (the
end of the deciding frame or window, when the detector knew: where the channel's lane changes too), each
naming that time and the onset / offset estimate. With tolerances the parameters' alarms are the faults
(:func:`parameter_event_text`) and the spectral detector's alarms are rows of *mismatch* (information,
not a fault).

Rows are logged one per call (:func:`log_text_rows`): Rerun 0.41 shows wrong levels (an ``ERROR`` row as
``WARN`` or ``INFO``) for rows sent as one multi-row chunk after earlier single rows of the same entity.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..detection.thresholds import db_over_threshold
from ..online.monitor import DetectionEvent
from .record_geometry import to_ns

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

    from ..detection.parameter_decision import ParameterEvent

__all__ = [
    "EVENTS",
    "alarm_event_text",
    "log_text_rows",
    "parameter_event_text",
    "send_alarm_events",
    "send_parameter_events",
]

#: Entity of the event log.
EVENTS = "/events"
#: Levels of the log rows: an alarm raised is a fault (red), everything else information.
ALARM_LEVEL, INFO_LEVEL = "ERROR", "INFO"


def alarm_event_text(ev: DetectionEvent, *, decides: bool = True) -> str:
    """Short, most important first (the log view cuts long bodies): when (the alarm time, end of the
    deciding frame), channel and what happened, the onset / offset estimate, then the bin and the rule.

    Parameters
    ----------
    ev : DetectionEvent
    decides : bool
        The spectral alarm is the run's fault decision; False (tolerances): a mismatch.

    Returns
    -------
    str
    """
    db = db_over_threshold(ev.peak_ratio)
    start = ev.kind == "fault-start"
    if decides:
        what = "ALARM" if start else "alarm cleared"
    else:
        what = "mismatch (tolerances decide)" if start else "mismatch over"
    est = "onset" if start else "offset"
    return (
        f"{ev.alarm_time_s:.2f} s {ev.channel} {what} ({est} est. {ev.estimate_s:.2f} s), "
        f"{ev.peak_hz:.1f} Hz {db:+.0f} dB, {ev.rule}"
    )


def parameter_event_text(ev: ParameterEvent) -> str:
    """A parameter's alarm raised or cleared (tolerances): its alarm time (the end of the deciding
    identification window), the parameter and its estimate against its band, then the rule.

    Parameters
    ----------
    ev : ParameterEvent

    Returns
    -------
    str
    """
    from ..detection.parameter_decision import band_position, status_text

    what = "ALARM" if ev.kind == "fault-start" else "alarm cleared"
    pos = band_position(ev.ci_low, ev.ci_high, *ev.band)
    st = status_text(ev.parameter, ev.estimate, ev.std_error, (ev.ci_low, ev.ci_high), ev.nominal, ev.unit,
                     ev.tolerance, pos)  # fmt: skip
    return f"{ev.alarm_time_s:.2f} s {ev.parameter} {what}: {st.removeprefix(ev.parameter + ' ')}, {ev.rule}"


def log_text_rows(
    stream: RecordingStream,
    entity: str,
    times_s: Sequence[float] | np.ndarray,
    texts: list[str],
    levels: list[str],
) -> None:
    """Log text rows one per call (see the module docstring) at ``times_s`` (:func:`to_ns`).

    Parameters
    ----------
    stream : rerun.RecordingStream
    entity : str
    times_s : sequence of float
        Row times (s).
    texts, levels : list of str
    """
    import rerun as rr

    from .sinks import TIMELINE

    for ns, text, level in zip(to_ns(np.asarray(times_s, dtype=float)).tolist(), texts, levels, strict=True):
        stream.set_time(TIMELINE, duration=np.timedelta64(int(ns), "ns"))
        stream.log(entity, rr.TextLog(text, level=level))


def send_alarm_events(stream: RecordingStream, events: list[DetectionEvent], *, decides: bool = True) -> None:
    """Log ``events`` to ``stream``'s event log at their alarm times.

    Parameters
    ----------
    stream : rerun.RecordingStream
    events : list of DetectionEvent
    decides : bool
        The spectral alarm is the run's fault decision (an alarm raised is an ``ERROR`` row); False
        (tolerances): every row is information (:func:`alarm_event_text`).
    """
    log_text_rows(
        stream,
        EVENTS,
        [ev.alarm_time_s for ev in events],
        [alarm_event_text(ev, decides=decides) for ev in events],
        [ALARM_LEVEL if decides and ev.kind == "fault-start" else INFO_LEVEL for ev in events],
    )


def send_parameter_events(stream: RecordingStream, events: Sequence[ParameterEvent]) -> None:
    """Log the parameters' alarm ``events`` (tolerances) to ``stream``'s event log at their alarm times.

    Parameters
    ----------
    stream : rerun.RecordingStream
    events : sequence of ParameterEvent
    """
    log_text_rows(
        stream,
        EVENTS,
        [ev.alarm_time_s for ev in events],
        [parameter_event_text(ev) for ev in events],
        [ALARM_LEVEL if ev.kind == "fault-start" else INFO_LEVEL for ev in events],
    )
