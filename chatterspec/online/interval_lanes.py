"""The fault intervals of a recorded file: one onset/offset estimate for lanes, events, Fig 8 and JSON.

A file recording (``detect --record``, ``demo``, ``diagnose --record``) is drawn after the fact, so its
verdict lanes show the same interval estimates as ``detect --json`` and Fig 8: the window-extent
estimator of :func:`chatterspec.detection.detect.frame_intervals` applied to the per-frame flags and
statistic ``max S / threshold`` of each channel, with the healthy median
:func:`chatterspec.detection.detect.healthy_frame_level` of the frame threshold. A live viewer instead
sees each alarm when the detector knew it (the end of the deciding frame), see
:class:`~chatterspec.online.rerun_log.RerunLogger`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..detection.detect import frame_intervals, healthy_frame_level

__all__ = ["FaultInterval", "IntervalCollector", "lane_changes"]


@dataclass(frozen=True)
class FaultInterval:
    """One estimated fault interval of one channel.

    Attributes
    ----------
    channel_index : int
    onset_s, offset_s : float
        Window-extent estimates (s), as ``detect --json``'s ``intervals``.
    peak_hz : float
        Peak frequency (largest excess ``S - E`` over the threshold) of the interval's frame with the
        largest ``S / threshold`` (Hz).
    peak_db : float
        That largest ``10 log10(S / threshold)`` (dB).
    """

    channel_index: int
    onset_s: float
    offset_s: float
    peak_hz: float
    peak_db: float


@dataclass
class IntervalCollector:
    """Keeps the per-frame flags, statistic and peak frequency of a record (``9 m`` bytes per frame) and
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

    def add(self, times: np.ndarray, flags: np.ndarray, ratio: np.ndarray, peak_hz: np.ndarray) -> None:
        """Append frames: centre times (F,) s, flags (F, m), ``max S / threshold`` (F, m) and the peak
        frequency shown for them (F, m) Hz (the logger's ``peak_hz``: the largest excess ``S - E``
        among the bins over the threshold)."""
        if len(times):
            self._flags.append(np.asarray(flags, dtype=bool))
            self._ratio.append(np.asarray(ratio, dtype=np.float32))
            self._hz.append(np.asarray(peak_hz, dtype=np.float32))
            self._times.append(np.asarray(times, dtype=float))

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
        level = healthy_frame_level(mon.threshold)
        out = []
        for c in range(flags.shape[1]):
            runs = _runs(flags[:, c])
            ivs = frame_intervals(flags[:, c], times, mon.settings.stft, mon.dt, ratio[:, c], level)
            for (a, b), (on, off) in zip(runs, ivs, strict=True):
                k = a + int(np.argmax(ratio[a:b, c]))
                db = 10.0 * np.log10(max(ratio[k, c], 1e-30))
                out.append(FaultInterval(c, on, off, float(hz[k, c]), float(db)))
        return out


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` frame ranges of the runs of flagged frames (as :func:`frame_intervals` merges)."""
    padded = np.concatenate(([False], flags, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def lane_changes(
    intervals: list[FaultInterval], channel: int, start_s: float
) -> tuple[list[float], list[str]]:
    """The state changes that draw ``channel``'s intervals on its lane: ``healthy`` at ``start_s`` (the
    record's first window start) unless a fault starts there, ``fault`` at each onset and ``healthy`` at
    each offset; zero-length intervals are not drawn (two changes at one time have no order in the viewer).

    Parameters
    ----------
    intervals : list of FaultInterval
    channel : int
    start_s : float
        Start of the record's first STFT window (s).

    Returns
    -------
    (times_s, states)
    """
    times: list[float] = []
    states: list[str] = []
    mine = [iv for iv in intervals if iv.channel_index == channel and iv.offset_s > iv.onset_s]
    if not mine or mine[0].onset_s > start_s + 5e-10:
        times.append(start_s)
        states.append("healthy")
    for iv in mine:
        times += [iv.onset_s, iv.offset_s]
        states += ["fault", "healthy"]
    return times, states
