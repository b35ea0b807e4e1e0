"""The fault intervals of a recorded file: the window-extent onset/offset estimates of its flagged frames,
the numbers of ``detect --json``'s ``intervals`` and Fig 8, logged as events at their onsets.

The estimator is :func:`chatterspec.detection.verdicts.frame_intervals` applied to the per-frame flags and
statistic ``max S / threshold`` of each channel, with the healthy median
:func:`chatterspec.detection.verdicts.healthy_frame_level` of the frame threshold. They annotate the
channel's fault state; the state itself (the lanes) is the alarm layer's
(:mod:`chatterspec.viewer.fault_lanes`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.thresholds import db_over_threshold, two_bins_text
from ..detection.verdicts import frame_intervals, healthy_frame_level

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

__all__ = ["FaultInterval", "IntervalCollector", "interval_text", "send_interval_events"]


def interval_text(onset_s: float, offset_s: float) -> str:
    """``"0.00-2.00 s"``, or ``"2.60 s"`` for an interval of zero length at two decimals.

    Parameters
    ----------
    onset_s, offset_s : float
        The interval (s).
    """
    on, off = f"{onset_s:.2f}", f"{offset_s:.2f}"
    return f"{on} s" if on == off else f"{on}-{off} s"


@dataclass(frozen=True)
class FaultInterval:
    """One estimated fault interval of one channel.

    Attributes
    ----------
    channel_index : int
    onset_s, offset_s : float
        Window-extent estimates (s), as ``detect --json``'s ``intervals``.
    peak_hz : float
        The most significant bin (largest ``S / threshold``, the detector's peak) of the interval's frame
        with the largest ``S / threshold`` (Hz).
    peak_db : float
        That largest ``10 log10(S / threshold)`` (dB).
    excess_hz : float
        In that frame, the bin of largest excess power ``S - E`` among the bins over the threshold (Hz;
        :mod:`chatterspec.detection.thresholds`).
    excess_db : float
        Its ``10 log10(S / threshold)`` (dB).
    """

    channel_index: int
    onset_s: float
    offset_s: float
    peak_hz: float
    peak_db: float
    excess_hz: float = float("nan")
    excess_db: float = float("nan")

    def describe(self, channel: str) -> str:
        """``"<onset>-<offset> s <channel> flagged frames (estimate), <two bins>"`` (``<onset> s`` for an
        estimate of zero length): times and channel first
        (the viewer's log view cuts long lines), both bins labelled (:func:`~chatterspec.detection.
        thresholds.two_bins_text`)."""
        bins = two_bins_text(self.peak_hz, self.peak_db, self.excess_hz, self.excess_db)
        return f"{interval_text(self.onset_s, self.offset_s)} {channel} flagged frames (estimate), {bins}"


@dataclass
class IntervalCollector:
    """Keeps the per-frame flags, statistic and the two peak bins of a record (``17 m`` bytes per frame) and
    estimates its fault intervals at the end.

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the STFT settings, the sampling time and the frame threshold.
    """

    monitor: Any
    _flags: list[np.ndarray] = field(default_factory=list)
    _ratio: list[np.ndarray] = field(default_factory=list)
    _hz: list[np.ndarray] = field(default_factory=list)
    _times: list[np.ndarray] = field(default_factory=list)
    _excess: list[np.ndarray] = field(default_factory=list)

    def add(
        self,
        times: np.ndarray,
        flags: np.ndarray,
        ratio: np.ndarray,
        peak_hz: np.ndarray,
        excess_hz: np.ndarray | None = None,
        excess_ratio: np.ndarray | None = None,
    ) -> None:
        """Append frames: centre times (F,) s, flags (F, m), ``max S / threshold`` (F, m), the most
        significant bin (F, m) Hz (largest ``S / threshold``) and, optionally, the bin of largest excess
        ``S - E`` among the bins over the threshold (F, m) Hz with its ``S / threshold`` (F, m) (the
        logger's ``peak_hz``; NaN when not given)."""
        if len(times):
            self._flags.append(np.asarray(flags, dtype=bool))
            self._ratio.append(np.asarray(ratio, dtype=np.float32))
            self._hz.append(np.asarray(peak_hz, dtype=np.float32))
            self._times.append(np.asarray(times, dtype=float))
            nan = np.full(np.shape(flags), np.nan, dtype=np.float32)
            ex_hz = nan if excess_hz is None else np.asarray(excess_hz, dtype=np.float32)
            ex_r = nan if excess_ratio is None else np.asarray(excess_ratio, dtype=np.float32)
            self._excess.append(np.stack([ex_hz, ex_r], axis=-1))  # (F, m, 2)

    def frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All frames so far: (times (F,) s, flags (F, m), peak_hz (F, m) Hz)."""
        if not self._flags:
            return np.zeros(0), np.zeros((0, 0), dtype=bool), np.zeros((0, 0))
        return np.concatenate(self._times), np.concatenate(self._flags), np.concatenate(self._hz)

    def intervals(self) -> list[FaultInterval]:
        """The record's fault intervals, channel by channel in time order (zero-length ones included).

        Returns
        -------
        list of FaultInterval
        """
        if not self._flags:
            return []
        mon = self.monitor
        flags, ratio = np.concatenate(self._flags), np.concatenate(self._ratio).astype(float)
        hz, times = np.concatenate(self._hz), np.concatenate(self._times)
        excess = np.concatenate(self._excess).astype(float)  # (F, m, 2): Hz, S / threshold
        level = healthy_frame_level(mon.threshold)
        out = []
        for c in range(flags.shape[1]):
            runs = _runs(flags[:, c])
            ivs = frame_intervals(flags[:, c], times, mon.settings.stft, mon.dt, ratio[:, c], level)
            for (a, b), (on, off) in zip(runs, ivs, strict=True):
                k = a + int(np.argmax(ratio[a:b, c]))
                db = db_over_threshold(ratio[k, c])
                ex_hz, ex_r = excess[k, c]
                ex_db = db_over_threshold(ex_r) if np.isfinite(ex_r) else float("nan")
                out.append(FaultInterval(c, on, off, float(hz[k, c]), float(db), float(ex_hz), ex_db))
        return out


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` frame ranges of the runs of flagged frames (as :func:`frame_intervals` merges)."""
    padded = np.concatenate(([False], flags, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def send_interval_events(
    file: RecordingStream, intervals: list[FaultInterval], channels: tuple[str, ...]
) -> None:
    """Log one event per fault interval of a file at its onset estimate (:meth:`FaultInterval.describe`:
    both bins named), in time order: the window-extent estimates of ``detect --json``'s ``intervals``,
    which annotate the lanes' alarm episodes (the lanes show the alarm state,
    :mod:`~chatterspec.viewer.fault_lanes`).

    Parameters
    ----------
    file : rerun.RecordingStream
    intervals : list of FaultInterval
        :meth:`IntervalCollector.intervals`.
    channels : tuple of str
    """
    from .alarm_events import EVENTS, INFO_LEVEL, log_text_rows

    order = sorted(intervals, key=lambda iv: iv.onset_s)
    text = [iv.describe(channels[iv.channel_index]) for iv in order]
    log_text_rows(file, EVENTS, [iv.onset_s for iv in order], text, [INFO_LEVEL] * len(text))
