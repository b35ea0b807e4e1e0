"""The event log of a recording (``/events``): one row per alarm raised or cleared, at its alarm time (the
end of the deciding frame, when the detector knew: where the channel's lane changes too), each naming
that time and the onset / offset estimate.

Rows are logged one per call (:func:`log_text_rows`): Rerun 0.41 shows wrong levels (an ``ERROR`` row as
``WARN`` or ``INFO``) for rows sent as one multi-row chunk after earlier single rows of the same entity.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ..detection.bin_labels import db_over_threshold
from ..online.monitor import DetectionEvent
from .record_geometry import to_ns

__all__ = ["EVENTS", "alarm_event_text", "log_text_rows", "send_alarm_events"]

#: Entity of the event log.
EVENTS = "/events"
#: Levels of the log rows: an alarm raised is a fault (red), everything else information.
ALARM_LEVEL, INFO_LEVEL = "ERROR", "INFO"


def alarm_event_text(ev: DetectionEvent) -> str:
    """Short, most important first (the log view cuts long bodies): when (the alarm time, end of the
    deciding frame), channel and what happened, the onset / offset estimate, then the bin and the rule.

    Parameters
    ----------
    ev : DetectionEvent

    Returns
    -------
    str
    """
    db = db_over_threshold(ev.peak_ratio)
    if ev.kind == "fault-start":
        what, est = "ALARM", "onset"
    else:
        what, est = "alarm cleared", "offset"
    return (
        f"{ev.alarm_time_s:.2f} s {ev.channel} {what} ({est} est. {ev.estimate_s:.2f} s), "
        f"{ev.peak_hz:.1f} Hz {db:+.0f} dB, {ev.rule}"
    )


def log_text_rows(
    stream: Any, entity: str, times_s: Sequence[float] | np.ndarray, texts: list[str], levels: list[str]
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


def send_alarm_events(stream: Any, events: list[DetectionEvent]) -> None:
    """Log ``events`` to ``stream``'s event log at their alarm times.

    Parameters
    ----------
    stream : rerun.RecordingStream
    events : list of DetectionEvent
    """
    log_text_rows(
        stream,
        EVENTS,
        [ev.alarm_time_s for ev in events],
        [alarm_event_text(ev) for ev in events],
        [ALARM_LEVEL if ev.kind == "fault-start" else INFO_LEVEL for ev in events],
    )
