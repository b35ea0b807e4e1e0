"""The online monitor's settings and outputs (frozen dataclasses), re-exported by :mod:`.monitor`.

:class:`MonitorSettings` is defined in :mod:`chatterspec.detection.alarms.calibration` (the batch alarm
studies use it too) and re-exported here.

:class:`MonitorSettings` (what the monitor tests and how it raises alarms), :class:`DetectionEvent`
(a fault start or end), :class:`FrameBlock` (the frames one push completed) and
:class:`MonitorUpdate` (everything one push produced).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from ..detection.alarms.calibration import MonitorSettings
from ..detection.alarms.rules import alarm_label
from ..jsonout import finite_or_none

__all__ = ["DetectionEvent", "EventKind", "FrameBlock", "MonitorSettings", "MonitorUpdate"]

EventKind = Literal["fault-start", "fault-end"]


@dataclass(frozen=True)
class DetectionEvent:
    """A change of a channel's verdict.

    Attributes
    ----------
    kind : {"fault-start", "fault-end"}
    channel : str
    channel_index : int
    time_s : float
        Centre time of the frame where the verdict changed (s).
    alarm_time_s : float
        When the alarm layer decided: the time of the deciding frame's last sample (s), ``time_s`` plus
        half a window (:func:`chatterspec.online.fault_state.alarm_time`). The channel's fault state
        changes here in the recording's lanes, events and live view.
    frame : int
        Global frame number.
    peak_hz : float
        ``fault-start``: frequency of the largest ``S / threshold`` in that frame;
        ``fault-end``: of the largest ratio seen during the fault.
    peak_ratio : float
        The corresponding ``S / threshold`` (> 1 means above threshold).
    estimate_s : float
        Onset / offset estimate of :func:`chatterspec.detection.verdicts.frame_intervals`:
        half a hop before ``time_s`` (the start of frame 0's window when the
        very first frame is flagged).
    rule : str
        The alarm rule that raised the event (``frame``, ``persistence``, ``cusum``).
    score : float
        The frame score ``-log p`` (nats) of the event's frame.
    statistic : float
        The rule's statistic at that frame (score, window count or CUSUM ``g``).
    threshold : float
        The rule's threshold ``h`` (same units as ``statistic``).
    false_alarms_per_hour : float or None
        The budget the threshold was set for (alarm starts per hour, all channels), None when
        the rule runs at a per-frame ``alpha``.
    """

    kind: EventKind
    channel: str
    channel_index: int
    time_s: float
    frame: int
    peak_hz: float
    peak_ratio: float
    estimate_s: float = float("nan")
    rule: str = "frame"
    score: float = float("nan")
    statistic: float = float("nan")
    threshold: float = float("nan")
    false_alarms_per_hour: float | None = None
    alarm_time_s: float = float("nan")

    def describe(self) -> str:
        """A short description for reports and recordings: the alarm time (end of the deciding frame) and
        the onset / offset estimate, each named."""
        what = "fault start" if self.kind == "fault-start" else "fault end"
        peak = "peak" if self.kind == "fault-start" else "largest peak during the fault"
        est = "onset" if self.kind == "fault-start" else "offset"
        return (
            f"{what} on {self.channel}: alarm {'raised' if self.kind == 'fault-start' else 'cleared'} at "
            f"t = {self.alarm_time_s:.2f} s (end of the deciding frame), {est} estimated "
            f"{self.estimate_s:.2f} s "
            f"({peak} {self.peak_ratio:.2f} x threshold at {self.peak_hz:.1f} Hz) "
            f"[{alarm_label(self.rule, self.false_alarms_per_hour)}]"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers become None)."""
        return {
            "kind": self.kind,
            "channel": self.channel,
            "time_s": self.time_s,
            "alarm_time_s": finite_or_none(self.alarm_time_s),
            "estimate_s": finite_or_none(self.estimate_s),
            "frame": self.frame,
            "peak_hz": self.peak_hz,
            "peak_ratio": self.peak_ratio,
            "rule": self.rule,
            "score": finite_or_none(self.score),
            "statistic": finite_or_none(self.statistic),
            "threshold": finite_or_none(self.threshold),
            "false_alarms_per_hour": self.false_alarms_per_hour,
        }


@dataclass(frozen=True, eq=False)
class FrameBlock:
    """STFT frames completed by one push.

    Attributes
    ----------
    index : (F,) int array
        Global frame numbers.
    times_s : (F,) array
        Frame-centre times (s).
    power : (F, bins, m) array
        Frame spectra (columns of :func:`chatterspec.detection.spectral.spectrogram`).
    flags : (F, m) bool array
        Per-frame, per-channel verdict (any tested bin above the threshold).
    peak_hz, peak_ratio : (F, m) arrays
        Frequency and value of the largest ``S / threshold`` over the tested bins.
    score : (F, m) array or None
        The frame score ``-log p`` (nats, :mod:`chatterspec.detection.verdicts`).
    alarm : (F, m) bool array or None
        The alarm state after each frame (the rule's decision; events are its changes).
    alarm_statistic : (F, m) array or None
        The rule's statistic after each frame (score, window count or CUSUM ``g``).
    """

    index: np.ndarray
    times_s: np.ndarray
    power: np.ndarray
    flags: np.ndarray
    peak_hz: np.ndarray
    peak_ratio: np.ndarray
    score: np.ndarray | None = None
    alarm: np.ndarray | None = None
    alarm_statistic: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return self.index.shape[0]


@dataclass(frozen=True, eq=False)
class MonitorUpdate:
    """What one :meth:`ChatteringMonitor.push` produced.

    Attributes
    ----------
    t : (K,) array
        Times of the new chattering samples (s).
    chattering : (K, m) array
        ``e(k|k-1)`` of the auxiliary filter.
    measured : (K, m) array or None
        The measurements at those times (raw pushes only).
    estimate : (K, m) array or None
        ``C x(k|k)`` of the ``sat`` SVSF (when ``psi`` is set and raw data pushed).
    frames : FrameBlock
    events : tuple of DetectionEvent
    """

    t: np.ndarray
    chattering: np.ndarray
    measured: np.ndarray | None
    estimate: np.ndarray | None
    frames: FrameBlock
    events: tuple[DetectionEvent, ...]
