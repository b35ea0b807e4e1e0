"""The alarm events of a recording: one text-log line per alarm raised or cleared, at the end of its
deciding frame (when the detector knew), and in a live viewer the verdict lanes' changes there.

A file's lanes show the record's fault intervals instead (:mod:`chatterspec.viewer.interval_lanes`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..detection.bin_labels import db_over_threshold
from ..online.monitor import DetectionEvent
from .arrow_columns import _TimeIndex
from .record_geometry import to_ns

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

__all__ = ["alarm_event_text", "send_alarm_events"]


def alarm_event_text(ev: DetectionEvent, half_win_s: float) -> str:
    """Short: channel, frequency (the most significant bin) and level first (the log view cuts long
    bodies), then what happened and when.

    Parameters
    ----------
    ev : DetectionEvent
    half_win_s : float
        Half the STFT window (s): from a frame's centre to its last sample.

    Returns
    -------
    str
    """
    db = db_over_threshold(ev.peak_ratio)
    end = ev.time_s + half_win_s
    if ev.kind == "fault-start":
        return (
            f"{ev.channel} {ev.peak_hz:.1f} Hz {db:+.0f} dB: ALARM ({ev.rule}) at {end:.2f} s "
            "(end of the deciding frame: when the detector knew)"
        )
    return f"{ev.channel} {ev.peak_hz:.1f} Hz {db:+.0f} dB: alarm ({ev.rule}) cleared at {end:.2f} s"


def send_alarm_events(
    stream: RecordingStream, events: list[DetectionEvent], half_win_s: float, lanes: list[str] | None = None
) -> None:
    """Send ``events`` to ``stream`` at the end of their deciding frames; with ``lanes`` (a live viewer:
    each channel's lane entity) also the lanes' changes there.

    Parameters
    ----------
    stream : rerun.RecordingStream
    events : list of DetectionEvent
    half_win_s : float
        Half the STFT window (s).
    lanes : list of str, optional
        Lane entity per channel.
    """
    import pyarrow as pa
    import rerun as rr

    ns = to_ns([ev.time_s + half_win_s for ev in events])
    text = [alarm_event_text(ev, half_win_s) for ev in events]
    level = ["WARN" if ev.kind == "fault-start" else "INFO" for ev in events]
    stream.send_columns(
        "/events", indexes=[_TimeIndex(pa, ns)], columns=rr.TextLog.columns(text=text, level=level)
    )
    if lanes is None:
        return
    for i, lane in enumerate(lanes):
        mine = [k for k, ev in enumerate(events) if ev.channel_index == i]
        if mine:
            state = ["fault" if events[k].kind == "fault-start" else "healthy" for k in mine]
            stream.send_columns(
                lane,
                indexes=[_TimeIndex(pa, np.asarray(ns)[mine])],
                columns=rr.StateChange.columns(state=state),
            )
