"""The fault intervals of a recorded file: one onset/offset estimate for lanes, events, Fig 8 and JSON.

A file recording (``detect --record``, ``demo``, ``diagnose --record``) is drawn after the fact, so its
verdict lanes show the same interval estimates as ``detect --json`` and Fig 8: the window-extent
estimator of :func:`chatterspec.detection.frames.frame_intervals` applied to the per-frame flags and
statistic ``max S / threshold`` of each channel, with the healthy median
:func:`chatterspec.detection.frames.healthy_frame_level` of the frame threshold. A live viewer instead
sees each alarm when the detector knew it (the end of the deciding frame), see
:class:`~chatterspec.viewer.rerun_log.RerunLogger`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.bin_labels import db_over_threshold, two_bins_text
from ..detection.frames import frame_intervals, healthy_frame_level

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

__all__ = ["FaultInterval", "IntervalCollector", "lane_changes", "send_intervals"]


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
        :mod:`chatterspec.detection.bin_labels`).
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
        """``"<channel> <two bins>: fault <onset>-<offset> s (estimate)"``: channel and bins first (the
        viewer's log view cuts long lines), both bins labelled (:func:`~chatterspec.detection.bin_labels.
        two_bins_text`)."""
        bins = two_bins_text(self.peak_hz, self.peak_db, self.excess_hz, self.excess_db)
        return f"{channel} {bins}: fault {self.onset_s:.2f}-{self.offset_s:.2f} s (estimate)"


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


def send_intervals(
    file: RecordingStream,
    intervals: list[FaultInterval],
    lanes: list[str],
    channels: tuple[str, ...],
    start_s: float,
) -> None:
    """Send a file's verdict lanes (:func:`lane_changes`) and one interval event per interval at its
    onset (:meth:`FaultInterval.describe`: both bins named), in time order.

    Parameters
    ----------
    file : rerun.RecordingStream
    intervals : list of FaultInterval
        :meth:`IntervalCollector.intervals`.
    lanes : list of str
        The channels' lane entities (:func:`~chatterspec.viewer.blueprint.lane_entity`).
    channels : tuple of str
    start_s : float
        Start of the record's first STFT window (s).
    """
    import pyarrow as pa
    import rerun as rr

    from .arrow_columns import _TimeIndex
    from .record_geometry import to_ns

    for i, lane in enumerate(lanes):
        times, states = lane_changes(intervals, i, start_s)
        file.send_columns(
            lane, indexes=[_TimeIndex(pa, to_ns(times))], columns=rr.StateChange.columns(state=states)
        )
    if intervals:
        order = sorted(intervals, key=lambda iv: iv.onset_s)
        text = [iv.describe(channels[iv.channel_index]) for iv in order]
        file.send_columns(
            "/events",
            indexes=[_TimeIndex(pa, to_ns([iv.onset_s for iv in order]))],
            columns=rr.TextLog.columns(text=text, level=["ERROR"] * len(text)),
        )
