"""Column-wise Rerun logging of monitor updates (:class:`RerunLogger`).

Times follow the one rule of :func:`~chatterspec.viewer.record_geometry.to_ns` (integer ns); the
recording's span, band and colour range are in :mod:`chatterspec.viewer.record_geometry` (and
importable from here, as before).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..detection.spectral import expected_frame_spectrum
from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorUpdate
from ..palette import FAULT, HEALTHY, rgba32
from ..plants.nonlinear import is_linear
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
    _entity,
    blueprint,
    fault_entity,
    fault_hz_entity,
    lane_entity,
    layout_geometry,
    series_styles,
    view_px,
)
from .chattering_extent import ChatteringExtent
from .frame_peaks import peak_bins
from .interval_lanes import IntervalCollector, send_intervals
from .record_geometry import DB_RANGE, default_band_hz, pad_columns, record_span, to_ns
from .sinks import TIMELINE, Sinks
from .spectrogram_images import SpectrogramImages
from .spectrogram_view import key_width, log_axes
from .truth_lane import log_truth_lane

__all__ = [
    "DB_RANGE",
    "RerunLogger",
    "default_band_hz",
    "pad_columns",
    "record_span",
    "to_ns",
]


def _send_blueprint(stream: Any, bp: Any) -> None:
    """Send ``bp`` as the active and default blueprint of ``stream``."""
    stream.send_blueprint(bp, make_active=True, make_default=True)


def _joined(items: list[Any], name: str) -> np.ndarray:
    """Attribute ``name`` of every item, concatenated along axis 0 (the item's own array for one item)."""
    if len(items) == 1:
        return getattr(items[0], name)
    return np.concatenate([getattr(it, name) for it in items])


@dataclass
class _Outbox:
    """What waits to be sent to one stream: the per-sample part of the updates and, separately, their
    frames and events (each part has its own batch size, see :class:`RerunLogger`)."""

    stream: Any
    live: bool
    updates: list[MonitorUpdate] = field(default_factory=list)  # with samples
    frames: list[Any] = field(default_factory=list)  # FrameBlocks with frames
    events: list[DetectionEvent] = field(default_factory=list)
    n_samples: int = 0
    n_frames: int = 0


class RerunLogger:
    """Writes :class:`~chatterspec.online.monitor.MonitorUpdate` objects to the open sinks.

    Everything time-indexed is sent column-wise with ``send_columns`` (one call
    per entity and batch, not one ``log`` per sample or frame; one row per sample or
    frame holding every channel, since Rerun's cost is per row): to a live viewer
    at every update; to a file the per-sample series in batches of ``batch_samples``
    samples and, separately, the frames (spectra, per-frame series, events) in batches of
    ``batch_frames`` frames (and the rest on :meth:`close`). Times follow :func:`to_ns`.

    What is logged per frame (entity layout in :mod:`chatterspec.online`): the
    frame spectrum (``Tensor``, float32 by default, see ``spectrum_dtype``); the detection statistic
    ``10 log10(max_k S_k / threshold_k)`` in dB (0 dB = threshold) with the
    flagged frames as red points and the 0/1 verdict; ``peak_hz`` (largest excess
    power ``S - E``, among the bins over the threshold when there are any, else over
    the tested bins) and ``most_significant_hz`` (largest
    ``S / threshold``, the detector's peak) in Hz. The verdict lanes start with
    ``healthy`` (or the monitor's current state) before the first frame and change
    exactly at the events.

    The spectrogram shows ``10 log10(S / threshold)`` in dB over ``band_hz``,
    clipped to :data:`DB_RANGE` (float16): in a file ONE tensor per channel for the
    whole record (``freq`` x ``time``, one column per frame, no padding), logged
    on :meth:`close` at the start of the record; a live viewer gets a scrolling
    view of the last ``scroll_frames`` columns after every frame whose time
    dimension names the newest (right-most) column's time.

    Parameters
    ----------
    sinks : Sinks
    monitor : ChatteringMonitor
        Gives channels, frequencies, threshold and the boundary layer.
    scroll_frames : int
        Columns of the live scrolling spectrogram (50 = 10 s at a 0.2 s hop).
    band_hz : (float, float), optional
        Spectrogram band (Hz); default :func:`default_band_hz`.
    span_s : (float, float), optional
        Time span (s) the whole record's spectrogram will cover (first frame's
        centre minus half a hop to the last one's plus half a hop), when known in
        advance (a file): the file's blueprint then shows exactly this span in
        every time-series view and opens paused on the whole record.
    file_block_frames : int
        Most frames in one spectrogram tensor of the file (bounds memory on long
        streams: 18 000 frames = 1 h at a 0.2 s hop, ~16 MB for 3 channels x 150 bins);
        longer records get consecutive blocks that tile the record.
    batch_samples, batch_frames : int
        File batches (>= 1): the per-sample series are sent once this many samples are buffered,
        the frames once this many frames are. Defaults (measured on the 3-channel EHA monitor,
        ``benchmarks/bench_monitor.py``): 20 000 samples, so that Rerun's file writer encodes one
        batch on the second core while the monitor computes the next (one batch per minute left
        all of the encoding to the end: 1860x against 2630x real time, best of 60), and 300 frames
        (one minute at a 0.2 s hop: every ``send_columns`` call is a chunk with its own schema,
        ~0.15 ms of CPU for a small one, and the per-frame series are small). At most ~2 MB of
        samples and ~2 MB of spectra are buffered for 3 channels.
    truth : list of (start_s, label, is_fault), optional
        True fault timeline, drawn as the top lane.
    send_blueprint : bool
        Send the default :func:`~chatterspec.viewer.blueprint.blueprint` to the sinks (default True).
    spectrum_dtype : {"float32", "float64"}
        Precision of the logged frame spectra ``/spectrum/<c>``. float32 (default) keeps 7
        significant digits (relative rounding <= 6e-8, far below the chi-squared scatter of a
        frame's bins and below any display resolution) and halves the largest payload of the file
        (~3.6 -> 1.8 MB per minute for 3 channels x 501 bins); the monitor's verdicts are computed
        in float64 before logging either way. "float64" logs the monitor's values bit-exactly.
    extra_row : callable, optional
        Views below the default layout (see :func:`~chatterspec.viewer.blueprint.blueprint`).
    extra_lanes, rows_above : int
        Lanes under ``/state`` and rows above the columns that the caller's layout adds (its
        :meth:`layout` ``above=``): they set the spectrogram image's aspect ratio.
    peak_view : bool
        The layout shows the peak-frequency views (see :func:`~chatterspec.viewer.blueprint.blueprint`).
    """

    def __init__(
        self,
        sinks: Sinks,
        monitor: ChatteringMonitor,
        *,
        scroll_frames: int = 50,
        band_hz: tuple[float, float] | None = None,
        span_s: tuple[float, float] | None = None,
        file_block_frames: int = 18_000,
        batch_samples: int = 20_000,
        batch_frames: int = 300,
        truth: list[tuple[float, str, bool]] | None = None,
        send_blueprint: bool = True,
        spectrum_dtype: str = "float32",
        extra_row: Any = None,
        extra_lanes: int = 0,
        rows_above: int = 0,
        peak_view: bool = True,
    ) -> None:
        import pyarrow as pa
        import rerun as rr

        self.rr, self.pa = rr, pa
        if spectrum_dtype not in ("float32", "float64"):
            raise ParameterError(f"spectrum_dtype must be 'float32' or 'float64'; got {spectrum_dtype!r}")
        self.spectrum_dtype = np.dtype(spectrum_dtype)
        self.sinks = sinks
        self.monitor = monitor
        self.channels = monitor.channels
        self.keys = [_entity(c) for c in self.channels]
        self.lanes = [lane_entity(i, c) for i, c in enumerate(self.channels)]
        m = len(self.channels)
        freqs = monitor.freqs_hz
        thr = monitor.threshold
        if not is_linear(monitor.model):  # nonlinear: the calibrated threshold's empirical normalization
            self._expected = np.asarray(thr.expected)
        else:
            self._expected = expected_frame_spectrum(monitor.model, freqs, monitor.settings.stft, monitor.dt)
        # the bins tested by the detector
        tested = np.flatnonzero(thr.tested)
        self._tested_idx = tested.astype(np.int64)
        self._tested_hz = freqs[tested]
        self._tested_expected = np.ascontiguousarray(self._expected[tested])  # (k, m)
        self._tested_thr = np.ascontiguousarray(thr.values[tested])  # (k, m)
        self.span_s = span_s
        # the layout's geometry: the spectrogram image fills its view at 1600x1000 (blueprint.layout_geometry)
        self._has_truth, self._extra_lanes, self._rows_above = bool(truth), int(extra_lanes), int(rows_above)
        self._extra_row, self._peak_view = extra_row, bool(peak_view)
        n_lanes = m + self._has_truth + self._extra_lanes
        self._width = layout_geometry(
            m,
            n_lanes,
            alarm=True,
            rows_above=self._rows_above,
            rows_below=1 if extra_row else 0,
            peak=self._peak_view,
        )[1]
        self._key = key_width(self._width, view_px(m))  # the colour key: as wide as a time view's labels
        self.images = SpectrogramImages(
            monitor,
            self.keys,
            self._width,
            band_hz=band_hz,
            scroll_frames=scroll_frames,
            file_block_frames=file_block_frames,
        )
        self.band_hz, self.hop_s = self.images.band_hz, self.images.hop_s
        self.batch_samples = int(batch_samples)
        self.batch_frames = int(batch_frames)
        if self.batch_samples < 1 or self.batch_frames < 1:
            raise ParameterError(
                f"batch_samples and batch_frames must be >= 1; got {batch_samples!r}, {batch_frames!r}"
            )
        self._cols = _Columns(rr, DB_RANGE)
        self._boxes = [_Outbox(s, live=s is sinks.live_stream) for s in sinks.streams]
        self.psi = monitor.settings.psi
        # two-row columns reused by every batch: the ±psi lines (+psi_0, -psi_0, +psi_1, ...) and 0 dB
        self._psi_rows = None
        if self.psi is not None:
            pm = np.repeat(np.asarray(self.psi, dtype=float), 2) * np.tile([1.0, -1.0], m)
            self._psi_rows = self._cols.scalars_column(np.tile(pm, (2, 1)), own=True)
        self._zero_rows = self._cols.scalars_column(np.zeros(2), own=True)
        self._fault = [fault_entity(c) for c in self.channels]
        self._fault_hz = [fault_hz_entity(c) for c in self.channels]
        # a file's lanes: the record's interval estimates, drawn on close (interval_lanes)
        self._collector = IntervalCollector(monitor) if sinks.file_stream is not None else None
        self._half_win = (monitor.n_window - 1) / 2.0 * monitor.dt  # frame centre -> its last sample
        self._origin_ns: int | None = None  # earliest time logged (truth start / record start)
        self._start_s: float | None = None  # start of the record's first STFT window (s)
        self._started = False
        rule = monitor.rule
        self._cusum = rule.name == "cusum"  # the alarm view draws g; else the score itself
        self._h = float(rule.threshold) if np.isfinite(rule.threshold) else np.nan
        # the file's blueprint is sent again on close, with the record's span and amplitudes (the keyword
        # arguments of its layout; None: the caller sends the file's blueprint itself)
        self.file_layout: dict[str, Any] | None = None
        self.send_file_blueprint: Any = _send_blueprint
        self._extent = ChatteringExtent(m)
        if send_blueprint:
            self.file_layout = {"has_truth": bool(truth), "extra_row": extra_row}
            for s in sinks.streams:
                bp = self.layout(
                    span_s=None if s is sinks.live_stream else span_s,
                    has_truth=bool(truth),
                    extra_row=extra_row,
                )
                s.send_blueprint(bp, make_active=True, make_default=True)
        self._log_static(truth)

    def layout(
        self,
        *,
        span_s: tuple[float, float] | None,
        has_truth: bool | None = None,
        extra_row: Any = None,
        above: list[Any] | None = None,
        lanes_name: str | None = None,
        chattering_range: Any = None,
    ) -> Any:
        """This logger's default :func:`~chatterspec.viewer.blueprint.blueprint` (band, alarm view, units,
        and the geometry given to the constructor).

        Parameters
        ----------
        span_s : (float, float) or None
            A file's whole record (s); None for a live viewer (follows the data).
        has_truth : bool, optional
            Draw the true fault lane (default: a truth was given).
        extra_row : callable, optional
            See :func:`~chatterspec.viewer.blueprint.blueprint` (default: the constructor's).
        above : list of views, optional
            A row above the channel columns (the constructor's ``rows_above`` must be 1).
        lanes_name : str, optional
            Title of the lanes view.
        chattering_range : sequence of float, optional
            Per channel the half-height of the chattering view's symmetric y range (output units).
        """
        return blueprint(
            self.channels,
            has_truth=self._has_truth if has_truth is None else has_truth,
            band_hz=self.band_hz,
            span_s=span_s,
            db_range=DB_RANGE,
            alarm=self._alarm_title(),
            alarm_score=self._cusum,
            alarm_range=(0.0, 1.5 * self._h) if self._h > 0 else None,
            extra_row=extra_row if extra_row is not None else self._extra_row,
            units=tuple(self.monitor.model.output_units),
            above=above,
            extra_lanes=self._extra_lanes,
            lanes_name=lanes_name,
            peak_view=self._peak_view,
            chattering_range=chattering_range,
        )

    def _alarm_title(self) -> str:
        """The alarm view's title: the rule's statistic against its threshold, and the budget."""
        from ..online.monitor_types import alarm_label

        rule, budget = self.monitor.rule, self.monitor.settings.false_alarms_per_hour
        what = {"cusum": "CUSUM g", "persistence": f"score ({rule.name} {getattr(rule, 'k', '')} of "
                f"{getattr(rule, 'n', '')})"}.get(rule.name, "score")  # fmt: skip
        label = alarm_label(rule.name, budget).split(", ", 1)[1]
        grey = ", grey = score" if self._cusum else ""
        return f"{what} vs h = {rule.threshold:.3g} [nats] ({label}){grey}"

    def _each(self, fn: Any) -> None:
        for s in self.sinks.streams:
            fn(s)

    def _set_time(self, s: Any, ns: int) -> None:
        s.set_time(TIMELINE, duration=np.timedelta64(int(ns), "ns"))

    def _log_static(self, truth: list[tuple[float, str, bool]] | None) -> None:
        rr = self.rr
        thr = self.monitor.threshold
        units = self.monitor.model.output_units
        lo, hi = self.band_hz

        styles = series_styles(
            self.channels,
            units,
            has_estimate=self.monitor.settings.psi is not None,
            alarm_statistic="CUSUM g [nats]" if self._cusum else "score -log p [nats]",
        )

        def static(s: Any) -> None:
            for path, style in styles:
                s.log(path, style, static=True)
            df = float(self.monitor.freqs_hz[1] - self.monitor.freqs_hz[0])
            for i, (name, c) in enumerate(zip(self.channels, self.keys, strict=True)):
                log_axes(s, f"/spectrogram/{c}", self.band_hz, df, DB_RANGE, self._width, self._key)
                s.log(f"/threshold/{c}", rr.Tensor(thr.values[:, i], dim_names=["freq"]), static=True)
                s.log(f"/expected/{c}", rr.Tensor(self._expected[:, i], dim_names=["freq"]), static=True)
                s.log(
                    self.lanes[i],
                    rr.StateConfiguration(
                        values=["healthy", "fault"],
                        labels=[f"{name}: healthy", f"{name}: FAULT"],
                        colors=np.array([rgba32(HEALTHY), rgba32(FAULT)], dtype=np.uint32),
                    ),
                    static=True,
                )
            s.log(
                "/frequencies",
                rr.TextDocument(
                    f"Spectra: {len(self.monitor.freqs_hz)} bins, 0 .. {self.monitor.freqs_hz[-1]:g} Hz "
                    f"(step {self.monitor.freqs_hz[1]:g} Hz); spectrogram {lo:g}-{hi:g} Hz, hop "
                    f"{self.hop_s:g} s, dB re threshold in [{DB_RANGE[0]:g}, {DB_RANGE[1]:g}]. "
                    f"{thr.describe()}"
                ),
                static=True,
            )

        self._each(static)
        if truth:
            t_first = truth[0][0]
            self._origin_ns = int(to_ns(t_first))

            log_truth_lane(self.sinks.streams, truth)

    def _initial_state(self, upd: MonitorUpdate) -> None:
        """The live lanes' state before ``upd``, logged 1 ns before the end of its first frame (when the
        detector first knows anything; nothing is painted before). A file's lanes are drawn on
        :meth:`close` from the record's interval estimates."""
        live = self.sinks.live_stream
        mon, fr = self.monitor, upd.frames
        m = len(self.channels)
        state = mon.active  # after upd: undo its first event per channel
        seen = np.zeros(m, dtype=bool)
        for ev in upd.events:
            if not seen[ev.channel_index]:
                seen[ev.channel_index] = True
                state[ev.channel_index] = ev.kind == "fault-end"
        n_before = mon.n_frames - fr.n_frames
        t_first = mon.frame_time(0) if n_before == 0 else (fr.times_s[0] if fr.n_frames else upd.t[0])
        # the start of this record's first STFT window (the first chattering sample of a fresh monitor)
        self._start_s = float(t_first - self._half_win) if n_before == 0 or fr.n_frames else float(upd.t[0])
        ns0 = int(to_ns(self._start_s))
        self._origin_ns = ns0 if self._origin_ns is None else min(ns0, self._origin_ns)
        if live is None:
            return
        ns = int(to_ns(t_first + self._half_win)) - 1
        t = _TimeIndex(self.pa, np.array([ns], dtype=np.int64))
        for i in range(m):
            state_col = self.rr.StateChange.columns(state=["fault" if state[i] else "healthy"])
            live.send_columns(self.lanes[i], indexes=[t], columns=state_col)

    def log_update(self, upd: MonitorUpdate) -> None:
        """Queue one update; send it at once to a live viewer, in batches to a file.

        Parameters
        ----------
        upd : MonitorUpdate
            What one push of the monitor produced.
        """
        fr = upd.frames
        if upd.t.shape[0] or fr.n_frames:
            if not self._started:
                self._started = True
                self._initial_state(upd)
            for box in self._boxes:
                if upd.t.shape[0]:
                    box.updates.append(upd)
                    box.n_samples += upd.t.shape[0]
                    if box.live or box.n_samples >= self.batch_samples:
                        self._send_samples(box)
                if fr.n_frames:
                    box.frames.append(fr)
                    box.events.extend(upd.events)
                    box.n_frames += fr.n_frames
                    if box.live or box.n_frames >= self.batch_frames:
                        self._send_frames(box)
        if fr.n_frames and self.sinks.live_stream is not None:
            self.images.live(self.sinks.live_stream, fr)

    def flush(self) -> None:
        """Send everything buffered (bulk ``send_columns``)."""
        for box in self._boxes:
            self._send_samples(box)
            self._send_frames(box)

    def close(self) -> None:
        """Send what is buffered, the file's spectrogram (the whole record, or its last block) and the
        file's lanes: the record's fault intervals (:mod:`chatterspec.viewer.interval_lanes`)."""
        self.flush()
        if self.sinks.file_stream is not None:  # its last block, padded: the record's span
            self.images.close_file(self.sinks.file_stream)
        self._send_intervals()
        self._send_final_blueprint()

    def _send_final_blueprint(self) -> None:
        """A file's final blueprint: paused on the whole record (the span given in advance, else the
        span its spectrogram covers: a streamed or rotated file), with each chattering view's y range
        from the record's amplitudes. The viewer opens a file on the last blueprint it holds."""
        file = self.sinks.file_stream
        span = self.span_s if self.span_s is not None else self.images.covered_span()
        if file is None or self.file_layout is None or span is None:
            return
        bp = self.layout(span_s=span, chattering_range=self._extent.ranges(self.psi), **self.file_layout)
        self.send_file_blueprint(file, bp)

    def _send_intervals(self) -> None:
        """The file's verdict lanes and interval events: the window-extent onset/offset estimates of the
        record's flagged frames, as ``detect --json`` and Fig 8 report them."""
        file = self.sinks.file_stream
        if file is None or self._collector is None or self._start_s is None:
            return
        send_intervals(file, self._collector.intervals(), self.lanes, self.channels, self._start_s)
        self.images.mark_outside_band(file, self._collector)

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
            self._extent.add(row[:, :m])
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
        peak_hz, peak_ratio = self._peak_hz(frames)
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
            self.images.add_file(self.sinks.file_stream, times, spectra, self._origin_ns)
            if self._collector is not None:  # the file's intervals, drawn on close
                self._collector.add(times, flags, ratio, sig_hz, peak_hz, peak_ratio)
        if events:
            send_alarm_events(s, events, self._half_win, self.lanes if box.live else None)

    def _peak_hz(self, frames: list[Any]) -> tuple[np.ndarray, np.ndarray]:
        """(F, m) tested bin (Hz) with the largest excess power ``S - E`` among the bins over the threshold
        when a frame has any (as the batch report's ``peak_hz``: a frame's overall largest excess sits on
        noise once a fault fades), else among all tested bins (:func:`peak_bins`); and (F, m) its
        ``S / threshold``."""
        m = len(self.channels)
        F = sum(f.n_frames for f in frames)
        k = np.empty((F, m), dtype=np.int64)
        ratio = np.empty((F, m))
        cols = np.arange(m)
        a = 0
        for f in frames:
            b = a + f.n_frames
            peak_bins(f.power, self._tested_idx, self._tested_expected, self._tested_thr, out=k[a:b])
            kb = k[a:b]
            ratio[a:b] = (
                f.power[np.arange(b - a)[:, None], self._tested_idx[kb], cols] / self._tested_thr[kb, cols]
            )
            a = b
        return self._tested_hz[k], ratio

    def _send_spectra(self, s: Any, path: str, tcol: _TimeIndex, ns: np.ndarray, power: np.ndarray) -> None:
        """One ``Tensor`` row per frame: ``power`` is (frames, bins) in ``spectrum_dtype``."""
        if not self._cols.tensors_ok:
            for f in range(power.shape[0]):
                self._set_time(s, ns[f])
                s.log(path, self.rr.Tensor(power[f], dim_names=["freq"]))
            return
        for lo in range(0, power.shape[0], _MAX_TENSOR_ROWS):
            hi = lo + _MAX_TENSOR_ROWS
            cols = self._cols.tensor_columns(power[lo:hi], ("freq",))
            s.send_columns(path, indexes=[tcol[lo:hi]], columns=cols)

    def log_event(self, ev: DetectionEvent) -> None:
        """Log one detection event at once (text log, and the lane of a live viewer) to every stream.

        Parameters
        ----------
        ev : DetectionEvent
            The event (logged at the end of its frame, converted by :func:`to_ns`).
        """
        for s in self.sinks.streams:
            send_alarm_events(s, [ev], self._half_win, self.lanes if s is self.sinks.live_stream else None)
