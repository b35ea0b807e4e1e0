"""Per-stream batching and column-wise sending of monitor updates (:class:`ColumnBatches`).

The job :class:`~chatterspec.viewer.rerun_log.RerunLogger` delegates for everything time-indexed:
each stream has an :class:`_Outbox` holding the per-sample part of the queued updates and, separately,
their frames and events; a live viewer's outbox is sent at every update, a file's once a batch is full
(``batch_samples`` samples, ``batch_frames`` frames) and the rest on :meth:`ColumnBatches.flush`. Each
batch goes out with ``send_columns``: one call per entity and batch, one row per sample or frame holding
every channel (Rerun's cost is per row). Times follow :func:`~chatterspec.viewer.record_geometry.to_ns`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarms.rules import rule_spec
from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorUpdate
from .alarm_events import send_alarm_events
from .arrow_columns import _MAX_TENSOR_ROWS, _Columns, _TimeIndex
from .blueprint import (
    CHATTERING,
    MOST_SIGNIFICANT_HZ,
    PEAK_HZ,
    PSI,
    STATISTIC,
    THRESHOLD,
    VERDICT,
    fault_entity,
    fault_hz_entity,
)
from .chattering_extent import ChatteringExtent
from .fault_lanes import Changes, FaultLanes
from .frame_peaks import FramePeaks
from .interval_events import IntervalCollector
from .record_geometry import DB_RANGE, to_ns
from .sinks import TIMELINE, Sinks
from .spectrogram_images import SpectrogramImages

if TYPE_CHECKING:  # pragma: no cover
    from types import ModuleType

    from ..online.identification_monitor import IdentificationUpdate


__all__ = ["ColumnBatches"]


def _joined(items: list[Any], name: str) -> np.ndarray:
    """Attribute ``name`` of every item, concatenated along axis 0 (the item's own array for one item)."""
    if len(items) == 1:
        return getattr(items[0], name)
    return np.concatenate([getattr(it, name) for it in items])


@dataclass
class _Outbox:
    """What waits to be sent to one stream: the per-sample part of the updates and, separately, their
    frames and events (each part has its own batch size)."""

    stream: Any
    live: bool
    updates: list[MonitorUpdate] = field(default_factory=list)  # with samples
    frames: list[Any] = field(default_factory=list)  # FrameBlocks with frames
    events: list[DetectionEvent] = field(default_factory=list)
    lane_changes: list[tuple[np.ndarray, np.ndarray, list[str]]] = field(default_factory=list)
    lane_versions: list[int] = field(default_factory=list)  # per channel: the labels last sent
    n_samples: int = 0
    n_frames: int = 0


class ColumnBatches:
    """Queues monitor updates per stream and sends them column-wise in batches.

    Per sample (``/chattering/e``, ONE row per sample for all channels): the chattering ``e(k|k-1)`` of
    each channel, then for raw data per channel the measurement [and the sat-SVSF estimate]; the ±psi
    lines at the batch's first and last sample. Per frame: the frame spectrum (``Tensor`` in
    ``spectrum_dtype``); the detection statistic ``10 log10(max_k S_k / threshold_k)`` in dB (0 dB =
    threshold) with the flagged frames as red points and the 0/1 verdict, the rule's statistic, score
    and threshold (:data:`~chatterspec.viewer.blueprint.VERDICT`); ``peak_hz`` (largest excess power
    ``S - E``, among the bins over the threshold when there are any, else over the tested bins) and
    ``most_significant_hz`` (largest ``S / threshold``, the detector's peak) in Hz; the events. A file's
    batches also feed its spectrogram (``images``), its interval estimates (``collector``) and the
    chattering amplitudes of its final blueprint (``extent``).

    Parameters
    ----------
    rr, pa : module
        ``rerun`` and ``pyarrow``.
    sinks : Sinks
        The streams (one outbox each) and which is live / the file.
    monitor : ChatteringMonitor
        Gives channels, frequencies, threshold, rule and the boundary layer.
    keys, lanes : list of str
        Per channel: entity key and verdict lane.
    expected : ndarray, shape (bins, m)
        Expected frame spectrum (the ``peak_hz`` excess is over it).
    images : SpectrogramImages
        The file's spectrogram blocks.
    collector : IntervalCollector or None
        The file's interval estimates (None without a file).
    batch_samples, batch_frames : int
        A file's batches (>= 1): the per-sample series are sent once this many samples are buffered,
        the frames once this many frames are. The logger's defaults (measured on the 3-channel EHA
        monitor, ``benchmarks/bench_monitor.py``): 20 000 samples, so that Rerun's file writer encodes
        one batch on the second core while the monitor computes the next (one batch per minute left all
        of the encoding to the end: 1860x against 2630x real time, best of 60), and 300 frames (one
        minute at a 0.2 s hop: every ``send_columns`` call is a chunk with its own schema, ~0.15 ms of
        CPU for a small one, and the per-frame series are small). At most ~2 MB of samples and ~2 MB of
        spectra are buffered for 3 channels.
    spectrum_dtype : numpy.dtype
        Precision of the logged frame spectra. float32 (the logger's default) keeps 7 significant
        digits (relative rounding <= 6e-8, far below the chi-squared scatter of a frame's bins and below
        any display resolution) and halves the largest payload of the file (~3.6 -> 1.8 MB per minute
        for 3 channels x 501 bins); the monitor's verdicts are computed in float64 before logging either
        way. float64 logs the monitor's values bit-exactly.
    """

    def __init__(
        self,
        rr: ModuleType,
        pa: Any,
        sinks: Sinks,
        monitor: ChatteringMonitor,
        *,
        keys: list[str],
        lanes: list[str],
        expected: np.ndarray,
        images: SpectrogramImages,
        collector: IntervalCollector | None,
        batch_samples: int,
        batch_frames: int,
        spectrum_dtype: np.dtype,
    ) -> None:
        self.rr, self.pa = rr, pa
        self.sinks, self.images, self._collector = sinks, images, collector
        self.keys, self.lanes = keys, lanes
        self._fault = [fault_entity(c) for c in monitor.channels]
        self._fault_hz = [fault_hz_entity(c) for c in monitor.channels]
        self.batch_samples, self.batch_frames = int(batch_samples), int(batch_frames)
        if self.batch_samples < 1 or self.batch_frames < 1:
            raise ParameterError(
                f"batch_samples and batch_frames must be >= 1; got {batch_samples!r}, {batch_frames!r}"
            )
        self.spectrum_dtype = spectrum_dtype
        m = len(keys)
        self._peaks = FramePeaks(monitor, expected)
        self._cols = _Columns(rr, DB_RANGE)
        self._boxes = [_Outbox(s, live=s is sinks.live_stream, lane_versions=[0] * m) for s in sinks.streams]
        # the channels' fault states (chatterspec.online.fault_state), the same in a file and live: the
        # spectral alarm's frame by frame, with identification its windows' too (fault_lanes)
        self.fault_lanes = FaultLanes(tuple(monitor.channels), monitor.n_window, monitor.n_hop, monitor.dt)
        #: The spectral alarm is the run's fault decision (else, with tolerances, a mismatch: its events
        #: are logged as such).
        self.spectral_decides = True
        psi = monitor.settings.psi
        # two-row columns reused by every batch: the ±psi lines (+psi_0, -psi_0, +psi_1, ...) and 0 dB
        self._psi_rows = None
        if psi is not None:
            pm = np.repeat(np.asarray(psi, dtype=float), 2) * np.tile([1.0, -1.0], m)
            self._psi_rows = self._cols.scalars_column(np.tile(pm, (2, 1)), own=True)
        self._zero_rows = self._cols.scalars_column(np.zeros(2), own=True)
        self._half_win = (monitor.n_window - 1) / 2.0 * monitor.dt  # frame centre -> its last sample
        rule = monitor.rule
        self._cusum = rule_spec(rule).accumulates  # the alarm view draws g; else the score itself
        self._h = float(rule.threshold) if np.isfinite(rule.threshold) else np.nan
        self.extent = ChatteringExtent(m)  # the file's chattering amplitudes
        # the file's largest statistic (dB) and alarm-view value per channel: its views' y ranges
        self.largest_db = np.full(m, -np.inf)
        self.largest_alarm = np.full(m, -np.inf)
        self.monitor = monitor
        self.origin_ns: int | None = None  # earliest time logged: the file's spectrogram starts there

    def start(self, upd: MonitorUpdate) -> float:
        """Start the record at ``upd`` (the first update with samples or frames) and return the start (s)
        of its first STFT window; it also moves :attr:`origin_ns` back to it. Every lane starts there with
        ``no-evidence`` (:mod:`chatterspec.online.fault_state`) until its first frame is decided (a rotated
        file too: it holds no verdict of its own before that frame)."""
        mon, fr = self.monitor, upd.frames
        n_before = mon.n_frames - fr.n_frames
        t_first = mon.frame_time(0) if n_before == 0 else (fr.times_s[0] if fr.n_frames else upd.t[0])
        # the start of this record's first STFT window (the first chattering sample of a fresh monitor)
        start_s = float(t_first - self._half_win) if n_before == 0 or fr.n_frames else float(upd.t[0])
        ns0 = int(to_ns(start_s))
        self.origin_ns = ns0 if self.origin_ns is None else min(ns0, self.origin_ns)
        first = self.fault_lanes.start(start_s)
        for box in self._boxes:
            box.lane_changes.append(first)
        return start_s

    def queue(self, upd: MonitorUpdate) -> None:
        """Queue ``upd`` in every outbox; send a live viewer's at once, a file's once a batch is full."""
        fr = upd.frames
        changes: Changes | None = None
        if fr.n_frames:  # the lanes: the alarm layer's state (flags without an alarm rule)
            alarm = fr.alarm if fr.alarm is not None else fr.flags
            changes = self.fault_lanes.update(fr.times_s, alarm, list(upd.events))
        for box in self._boxes:
            if upd.t.shape[0]:
                box.updates.append(upd)
                box.n_samples += upd.t.shape[0]
                if box.live or box.n_samples >= self.batch_samples:
                    self._send_samples(box)
            if fr.n_frames:
                if changes is not None and changes[2]:
                    box.lane_changes.append(changes)
                box.frames.append(fr)
                box.events.extend(upd.events)
                box.n_frames += fr.n_frames
                if box.live or box.n_frames >= self.batch_frames:
                    self._send_frames(box)

    def follow_identification(self, upd: IdentificationUpdate) -> None:
        """Queue the lane changes of one push's identification windows
        (:meth:`~chatterspec.viewer.fault_lanes.FaultLanes.follow`); a live viewer's are sent at once, a
        file's with its next frames."""
        self._queue_lanes(self.fault_lanes.follow(upd))

    def finish(self) -> None:
        """The record ends: queue the lane changes still waiting for an identification window."""
        self._queue_lanes(self.fault_lanes.finish())

    def _queue_lanes(self, changes: Changes) -> None:
        if not changes[2]:
            return
        for box in self._boxes:
            box.lane_changes.append(changes)
            if box.live:
                self._send_lanes(box)

    def flush(self) -> None:
        """Send everything buffered (bulk ``send_columns``)."""
        for box in self._boxes:
            self._send_samples(box)
            self._send_frames(box)
            self._send_lanes(box)

    def send_event(self, ev: DetectionEvent) -> None:
        """Send one detection event at once (the event log) to every stream."""
        for s in self.sinks.streams:
            send_alarm_events(s, [ev], decides=self.spectral_decides)

    def _send_samples(self, box: _Outbox) -> None:
        """Send the per-sample part of the updates in ``box`` (one ``send_columns`` per entity)."""
        if not box.updates:
            return
        ups, box.updates, box.n_samples = box.updates, [], 0
        s, cols, pa = box.stream, self._cols, self.pa
        m = len(self.keys)
        one = len(ups) == 1
        t = _joined(ups, "t")
        ns = to_ns(t)
        tcol = _TimeIndex(pa, ns)
        # ONE row per sample for all channels and quantities (Rerun's cost is per row: a row id and
        # a time each, encoded again by the file writer): /chattering/e holds e(k|k-1) of each channel,
        # then for raw data per channel the measurement [and the sat-SVSF estimate]
        keys = [k for k in ("measured", "estimate") if all(getattr(u, k) is not None for u in ups)]
        if keys or not one:
            row = np.empty((t.size, m * (1 + len(keys))))
            sig = row[:, m:].reshape(t.size, m, len(keys))  # view: channel-major (measured, estimate)
            a = 0
            for u in ups:
                b = a + u.t.shape[0]
                row[a:b, :m] = u.chattering
                for j, k in enumerate(keys):
                    sig[a:b, :, j] = getattr(u, k)
                a = b
        else:
            row = ups[0].chattering
        own = row is not ups[0].chattering  # a fresh array here; else the update's own (copied)
        if not box.live:
            self.extent.add(row[:, :m])
        s.send_columns(CHATTERING, indexes=[tcol], columns=[cols.scalars_column(row, own=own)])
        if self._psi_rows is not None:  # the batch's first and last sample: +psi_0, -psi_0, +psi_1, ...
            s.send_columns(PSI, indexes=[_TimeIndex(pa, ns[[0, -1]])], columns=[self._psi_rows])

    def _send_frames(self, box: _Outbox) -> None:
        """Send the frames and events in ``box``: spectra, per-frame series, fault points, events and
        lanes, and (file) append the frames to the file's spectrogram block."""
        if not box.frames:
            return
        frames, events, box.frames, box.events, box.n_frames = box.frames, box.events, [], [], 0
        s, cols, pa = box.stream, self._cols, self.pa
        m = len(self.keys)
        times, ratio = _joined(frames, "times_s"), _joined(frames, "peak_ratio")
        flags, sig_hz = _joined(frames, "flags"), _joined(frames, "peak_hz")
        fns = to_ns(times)
        fcol = _TimeIndex(pa, fns)
        stat_db = 10.0 * np.log10(np.maximum(ratio, 1e-30))
        # channel-major spectra (m, F, bins) in spectrum_dtype, converted while transposing (one pass)
        F = times.shape[0]
        spectra = np.empty((m, F, frames[0].power.shape[1]), dtype=self.spectrum_dtype)
        a = 0
        for f in frames:
            b = a + f.n_frames
            spectra[:, a:b] = f.power.transpose(2, 0, 1)  # (m, n, bins), cast on the fly
            a = b
        peak_hz, peak_ratio = self._peaks(frames)
        s.send_columns(STATISTIC, indexes=[fcol], columns=[cols.scalars_column(stat_db, own=True)])
        s.send_columns(THRESHOLD, indexes=[_TimeIndex(pa, fns[[0, -1]])], columns=[self._zero_rows])

        s.send_columns(PEAK_HZ, indexes=[fcol], columns=[cols.scalars_column(peak_hz, own=True)])
        s.send_columns(MOST_SIGNIFICANT_HZ, indexes=[fcol], columns=[cols.scalars_column(sig_hz)])
        # one row per frame: verdict flags, rule statistic, score, threshold (blueprint.VERDICT)
        rows = np.empty((F, 3 * m + 1))
        rows[:, :m] = flags
        a = 0
        for f in frames:
            b = a + f.n_frames
            rows[a:b, m : 2 * m] = f.alarm_statistic if self._cusum else f.score
            rows[a:b, 2 * m : 3 * m] = f.score
            a = b
        rows[:, 3 * m] = self._h
        if not box.live:
            np.maximum(self.largest_db, stat_db.max(axis=0), out=self.largest_db)
            np.maximum(self.largest_alarm, rows[:, m : 2 * m].max(axis=0), out=self.largest_alarm)
        s.send_columns(VERDICT, indexes=[fcol], columns=[cols.scalars_column(rows, own=True)])
        for i, c in enumerate(self.keys):
            self._send_spectra(s, f"/spectrum/{c}", fcol, fns, spectra[i])
            hit = np.flatnonzero(flags[:, i])
            if hit.size:  # sparse: one entity per channel, rows at its flagged frames only
                hit_t = _TimeIndex(pa, fns[hit])
                s.send_columns(
                    self._fault[i], indexes=[hit_t], columns=[cols.scalars_column(stat_db[hit, i])]
                )
                s.send_columns(
                    self._fault_hz[i], indexes=[hit_t], columns=[cols.scalars_column(sig_hz[hit, i])]
                )
        if not box.live:  # the file's spectrogram: dB columns of the whole batch at once
            self.images.add_file(self.sinks.file_stream, times, spectra, self.origin_ns)
            if self._collector is not None:  # the file's intervals, drawn on close
                self._collector.add(times, flags, ratio, sig_hz, peak_hz, peak_ratio)
        self._send_lanes(box)
        if events:
            send_alarm_events(s, events, decides=self.spectral_decides)

    def _send_lanes(self, box: _Outbox) -> None:
        """Send the queued lane changes of ``box`` (one ``send_columns`` per channel that changed) and the
        lanes' labels where a new alarm episode was labelled (:mod:`~chatterspec.viewer.fault_lanes`)."""
        if not box.lane_changes:
            return
        parts, box.lane_changes = box.lane_changes, []
        s, lanes = box.stream, self.fault_lanes
        for c, v in enumerate(lanes.version):
            if v != box.lane_versions[c]:
                s.log(self.lanes[c], lanes.configuration(c), static=True)
                box.lane_versions[c] = v
        times = np.concatenate([p[0] for p in parts])
        chan = np.concatenate([p[1] for p in parts])
        values = [v for p in parts for v in p[2]]
        ns = to_ns(times)
        for c in np.unique(chan).tolist():
            mine = np.flatnonzero(chan == c)
            s.send_columns(
                self.lanes[c],
                indexes=[_TimeIndex(self.pa, ns[mine])],
                columns=self.rr.StateChange.columns(state=[values[k] for k in mine.tolist()]),
            )

    def _send_spectra(self, s: Any, path: str, tcol: _TimeIndex, ns: np.ndarray, power: np.ndarray) -> None:
        """One ``Tensor`` row per frame: ``power`` is (frames, bins) in ``spectrum_dtype``."""
        if not self._cols.tensors_ok:
            for f in range(power.shape[0]):
                s.set_time(TIMELINE, duration=np.timedelta64(int(ns[f]), "ns"))
                s.log(path, self.rr.Tensor(power[f], dim_names=["freq"]))
            return
        for lo in range(0, power.shape[0], _MAX_TENSOR_ROWS):
            hi = lo + _MAX_TENSOR_ROWS
            cols = self._cols.tensor_columns(power[lo:hi], ("freq",))
            s.send_columns(path, indexes=[tcol[lo:hi]], columns=cols)
