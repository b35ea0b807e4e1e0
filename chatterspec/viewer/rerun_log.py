"""Column-wise Rerun logging of monitor updates (:class:`RerunLogger`).

Times follow the one rule of :func:`~chatterspec.viewer.record_geometry.to_ns` (integer ns); the
recording's span, band and colour range are in :mod:`chatterspec.viewer.record_geometry` (and
importable from here, as before).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..detection.spectral import expected_frame_spectrum
from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorUpdate
from ..plants.nonlinear import is_linear
from .alarm_events import send_alarm_events
from .blueprint import (
    _entity,
    blueprint,
    fault_entity,
    fault_hz_entity,
    lane_entity,
    layout_geometry,
    view_px,
)
from .column_batches import ColumnBatches
from .interval_lanes import IntervalCollector, send_intervals
from .record_geometry import DB_RANGE, default_band_hz, pad_columns, record_span, to_ns
from .sinks import Sinks
from .spectrogram_images import SpectrogramImages
from .spectrogram_view import key_width
from .static_entities import log_static
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
        self.psi = monitor.settings.psi
        # a file's lanes: the record's interval estimates, drawn on close (interval_lanes)
        self._collector = IntervalCollector(monitor) if sinks.file_stream is not None else None
        self._half_win = (monitor.n_window - 1) / 2.0 * monitor.dt  # frame centre -> its last sample
        # the per-stream batches of everything time-indexed (column_batches)
        self._batches = ColumnBatches(
            rr,
            pa,
            sinks,
            monitor,
            keys=self.keys,
            lanes=self.lanes,
            fault=[fault_entity(c) for c in self.channels],
            fault_hz=[fault_hz_entity(c) for c in self.channels],
            expected=self._expected,
            images=self.images,
            collector=self._collector,
            batch_samples=self.batch_samples,
            batch_frames=self.batch_frames,
            spectrum_dtype=self.spectrum_dtype,
        )
        self._start_s: float | None = None  # start of the record's first STFT window (s)
        rule = monitor.rule
        self._cusum = rule.name == "cusum"  # the alarm view draws g; else the score itself
        self._h = float(rule.threshold) if np.isfinite(rule.threshold) else np.nan
        # the file's blueprint is sent again on close, with the record's span and amplitudes (the keyword
        # arguments of its layout; None: the caller sends the file's blueprint itself)
        self.file_layout: dict[str, Any] | None = None
        self.send_file_blueprint: Any = _send_blueprint
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

    def _log_static(self, truth: list[tuple[float, str, bool]] | None) -> None:
        """The static entities (:func:`~chatterspec.viewer.static_entities.log_static`) and the truth lane."""
        log_static(
            self.sinks.streams,
            self.monitor,
            channels=self.channels,
            keys=self.keys,
            lanes=self.lanes,
            expected=self._expected,
            band_hz=self.band_hz,
            hop_s=self.hop_s,
            width=self._width,
            key=self._key,
            cusum=self._cusum,
        )
        if truth:
            self._batches.origin_ns = int(to_ns(truth[0][0]))
            log_truth_lane(self.sinks.streams, truth)

    def log_update(self, upd: MonitorUpdate) -> None:
        """Queue one update; send it at once to a live viewer, in batches to a file.

        Parameters
        ----------
        upd : MonitorUpdate
            What one push of the monitor produced.
        """
        fr = upd.frames
        if upd.t.shape[0] or fr.n_frames:
            if self._start_s is None:  # the record starts here
                self._start_s = self._batches.start(upd)
            self._batches.queue(upd)
        if fr.n_frames and self.sinks.live_stream is not None:
            self.images.live(self.sinks.live_stream, fr)

    def flush(self) -> None:
        """Send everything buffered (bulk ``send_columns``)."""
        self._batches.flush()

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
        ranges = self._batches.extent.ranges(self.psi)
        bp = self.layout(span_s=span, chattering_range=ranges, **self.file_layout)
        self.send_file_blueprint(file, bp)

    def _send_intervals(self) -> None:
        """The file's verdict lanes and interval events: the window-extent onset/offset estimates of the
        record's flagged frames, as ``detect --json`` and Fig 8 report them."""
        file = self.sinks.file_stream
        if file is None or self._collector is None or self._start_s is None:
            return
        send_intervals(file, self._collector.intervals(), self.lanes, self.channels, self._start_s)
        self.images.mark_outside_band(file, self._collector)

    def log_event(self, ev: DetectionEvent) -> None:
        """Log one detection event at once (text log, and the lane of a live viewer) to every stream.

        Parameters
        ----------
        ev : DetectionEvent
            The event (logged at the end of its frame, converted by :func:`to_ns`).
        """
        for s in self.sinks.streams:
            send_alarm_events(s, [ev], self._half_win, self.lanes if s is self.sinks.live_stream else None)
