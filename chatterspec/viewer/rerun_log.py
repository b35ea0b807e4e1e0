"""Column-wise Rerun logging of monitor updates (:class:`RerunLogger`).

Times follow the one rule of :func:`~chatterspec.viewer.record_geometry.to_ns` (integer ns); the
recording's span, band and colour range are in :mod:`chatterspec.viewer.record_geometry`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorUpdate
from .blueprint import (
    _entity,
    lane_entity,
)
from .column_batches import ColumnBatches
from .interval_events import IntervalCollector, send_interval_events
from .monitor_layout import MonitorLayout
from .record_geometry import to_ns
from .sinks import Sinks
from .spectrogram_images import SpectrogramImages
from .static_entities import expected_spectrum, log_static
from .truth_lane import log_truth_lane

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream
    from rerun.blueprint import Blueprint

    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from .blueprint import ExtraRow
    from .identification_log import IdentificationLog

__all__ = ["RerunLogger"]


def _send_blueprint(stream: RecordingStream, bp: Blueprint) -> None:
    """Send ``bp`` as the active and default blueprint of ``stream``."""
    stream.send_blueprint(bp, make_active=True, make_default=True)


class RerunLogger:
    """Writes :class:`~chatterspec.online.monitor.MonitorUpdate` objects to the open sinks.

    Everything time-indexed is sent column-wise, to a live viewer at every update and to a file in
    batches (:class:`~chatterspec.viewer.column_batches.ColumnBatches`, which lists what is logged per
    sample and per frame); the static entities on opening (:mod:`~chatterspec.viewer.static_entities`);
    the spectrogram images (:class:`~chatterspec.viewer.spectrogram_images.SpectrogramImages`: one
    tensor per channel for a file's whole record, logged on :meth:`close`, a scrolling view live); the
    layout (:class:`~chatterspec.viewer.monitor_layout.MonitorLayout`). The channels' lanes show one
    fault state each (:mod:`~chatterspec.viewer.fault_lanes`): ``no evidence`` until the first window is
    decided, then the run's decision, changing at the alarm times of the events. With an identification
    monitor the lanes follow its windows (fault, healthy, not excited), and its estimates, parameter
    lanes and events are drawn below (:mod:`~chatterspec.viewer.identification_log`;
    :meth:`log_identification`). Times follow :func:`to_ns`.

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
        the frames once this many frames are (defaults measured: see
        :class:`~chatterspec.viewer.column_batches.ColumnBatches`).
    truth : list of (start_s, label, is_fault), optional
        True fault timeline, drawn as the top lane.
    send_blueprint : bool
        Send the default :func:`~chatterspec.viewer.blueprint.blueprint` to the sinks (default True).
    spectrum_dtype : {"float32", "float64"}
        Precision of the logged frame spectra ``/spectrum/<c>``: float32 (default) keeps 7 significant
        digits and halves the file's largest payload (see
        :class:`~chatterspec.viewer.column_batches.ColumnBatches`); "float64" logs them bit-exactly.
    extra_row : callable, optional
        Views below the default layout (see :func:`~chatterspec.viewer.blueprint.blueprint`).
    extra_lanes, rows_above : int
        Lanes under ``/state`` and rows above the columns that the caller's layout adds (its
        :meth:`layout` ``above=``): they set the spectrogram image's aspect ratio.
    peak_view : bool
        The layout shows the peak-frequency views (see :func:`~chatterspec.viewer.blueprint.blueprint`).
    budget_per_hour : float, optional
        The false-alarm budget of the monitor's rule when its settings do not carry it (alarm starts per
        hour; shown in the titles).
    identification : IdentificationMonitor, optional
        The run's identification beside the monitor: its views form the row below the lanes (unless
        ``extra_row`` is given), its parameters' lanes are added, and the channels' lanes follow its
        windows' channel states (give each push's update to :meth:`log_identification`). With
        tolerances the spectral alarms are logged as mismatch, the parameters' alarms as the faults.
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
        extra_row: ExtraRow | None = None,
        extra_lanes: int = 0,
        rows_above: int = 0,
        peak_view: bool = True,
        budget_per_hour: float | None = None,
        identification: IdentificationMonitor | None = None,
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
        self._expected = expected_spectrum(monitor)
        self.span_s = span_s
        self.identification = identification
        self._ident_log: IdentificationLog | None = None
        if identification is not None and sinks.streams:
            from .identification_log import IdentificationLog, identification_views

            self._ident_log = IdentificationLog(sinks, identification)
            extra_row = extra_row if extra_row is not None else identification_views(self._ident_log)
            extra_lanes += len(self._ident_log.parameters)
        # the layout's geometry (the spectrogram image fills its view at 1600x1000) and blueprint
        self._layout = MonitorLayout(
            monitor,
            has_truth=bool(truth),
            extra_row=extra_row,
            extra_lanes=extra_lanes,
            rows_above=rows_above,
            peak_view=peak_view,
            budget_per_hour=budget_per_hour,
        )
        self.images = SpectrogramImages(
            monitor,
            self.keys,
            self._layout.width,
            band_hz=band_hz,
            scroll_frames=scroll_frames,
            file_block_frames=file_block_frames,
        )
        self.band_hz, self.hop_s = self.images.band_hz, self.images.hop_s
        self.psi = monitor.settings.psi
        # a file's interval events: the record's window-extent estimates, sent on close (interval_events)
        self._collector = IntervalCollector(monitor) if sinks.file_stream is not None else None
        # the per-stream batches of everything time-indexed (column_batches)
        self._batches = ColumnBatches(
            rr,
            pa,
            sinks,
            monitor,
            keys=self.keys,
            lanes=self.lanes,
            expected=self._expected,
            images=self.images,
            collector=self._collector,
            batch_samples=batch_samples,
            batch_frames=batch_frames,
            spectrum_dtype=self.spectrum_dtype,
        )
        self.batch_samples, self.batch_frames = self._batches.batch_samples, self._batches.batch_frames
        if identification is not None:  # the lanes follow the identification windows too (fault_lanes)
            self._batches.fault_lanes.follow_identification(
                tolerances=identification.tolerances,
                parameters=tuple(identification.parameters),
                carried=identification.carried,
            )
            self._batches.spectral_decides = not identification.tolerances
        self._start_s: float | None = None  # start of the record's first STFT window (s)
        # the file's blueprint is sent again on close, with the record's span and amplitudes (the keyword
        # arguments of its layout; None: the caller sends the file's blueprint itself)
        self.file_layout: dict[str, Any] | None = None
        self.send_file_blueprint: Any = _send_blueprint
        if send_blueprint:
            self.file_layout = {"has_truth": bool(truth), "extra_row": extra_row}
            # a file whose span is known in advance gets its one blueprint on close (with the chattering
            # ranges: building and sending one costs ~15 ms of CPU, so not twice per file); a streamed file
            # gets a following one now as well (kept if the process dies before close), a live viewer too
            for s in sinks.streams:
                if s is sinks.file_stream and span_s is not None:
                    continue
                bp = self.layout(
                    span_s=None if s is sinks.live_stream else span_s,
                    has_truth=bool(truth),
                    extra_row=extra_row,
                )
                s.send_blueprint(bp, make_active=True, make_default=True)
        self._log_static(truth)

    def layout(self, *, span_s: tuple[float, float] | None, **options: Any) -> Any:
        """This logger's default :func:`~chatterspec.viewer.blueprint.blueprint` (band, alarm view, units,
        and the geometry given to the constructor): :meth:`MonitorLayout.blueprint
        <chatterspec.viewer.monitor_layout.MonitorLayout.blueprint>` over this logger's band.

        Parameters
        ----------
        span_s : (float, float) or None
            A file's whole record (s); None for a live viewer (follows the data).
        **options
            The other keyword arguments of :meth:`MonitorLayout.blueprint
            <chatterspec.viewer.monitor_layout.MonitorLayout.blueprint>` (``has_truth``, ``extra_row``,
            ``above``, ``lanes_name``, ``chattering_range``, ``largest``), which documents them.

        Returns
        -------
        rerun.blueprint.Blueprint
        """
        return self._layout.blueprint(band_hz=self.band_hz, span_s=span_s, **options)

    def _log_static(self, truth: list[tuple[float, str, bool]] | None) -> None:
        """The static entities (:func:`~chatterspec.viewer.static_entities.log_static`) and the truth lane."""
        log_static(
            self.sinks.streams,
            self.monitor,
            channels=self.channels,
            keys=self.keys,
            lanes=self.lanes,
            lane_configs=[self._batches.fault_lanes.configuration(i) for i in range(len(self.lanes))],
            expected=self._expected,
            band_hz=self.band_hz,
            hop_s=self.hop_s,
            width=self._layout.width,
            key=self._layout.key,
            cusum=self._layout.cusum,
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

    def log_identification(self, upd: IdentificationUpdate) -> None:
        """Log one push's identification (its estimates, parameter lanes and events) and move the channels'
        lanes to its windows' states (a live viewer at once, a file with its next batch).

        Parameters
        ----------
        upd : IdentificationUpdate
            What the ``identification`` monitor given to the constructor made of the same push.
        """
        if self.identification is None:
            raise ParameterError("log_identification needs the logger's identification monitor")
        if self._ident_log is not None:
            self._ident_log.log(upd)
        self._batches.follow_identification(upd)

    def log_identification_intervals(self, docs: list[dict[str, Any]]) -> None:
        """Rows of the event log for ``detect --json``'s ``identification_intervals`` (the record's
        identification per fault interval; :meth:`~chatterspec.viewer.identification_log.IdentificationLog.
        log_intervals`); nothing without an identification monitor."""
        if self._ident_log is not None:
            self._ident_log.log_intervals(docs)

    def flush(self) -> None:
        """Send everything buffered (bulk ``send_columns``)."""
        self._batches.flush()

    def close(self) -> None:
        """Send what is buffered, the file's spectrogram (the whole record, or its last block) and the
        file's interval events: the record's fault interval estimates
        (:mod:`chatterspec.viewer.interval_events`)."""
        self._batches.finish()
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
        if file is None or self.file_layout is None:
            return
        span = self.span_s if self.span_s is not None else self.images.covered_span()
        # no frame yet (a record shorter than one window): the layout without span and ranges
        ranges = None if span is None else self._batches.extent.ranges(self.psi)
        largest = None if span is None else (self._batches.largest_db, self._batches.largest_alarm)
        bp = self.layout(span_s=span, chattering_range=ranges, largest=largest, **self.file_layout)
        self.send_file_blueprint(file, bp)

    def _send_intervals(self) -> None:
        """The file's interval events: the window-extent onset/offset estimates of the record's flagged
        frames, as ``detect --json`` and Fig 8 report them, and the spectrogram's annotations
        (:meth:`~chatterspec.viewer.spectrogram_images.SpectrogramImages.annotate_file`)."""
        file = self.sinks.file_stream
        if file is None or self._collector is None or self._start_s is None:
            return
        send_interval_events(file, self._collector.intervals(), self.channels)
        self.images.annotate_file(file, self._collector)

    def log_event(self, ev: DetectionEvent) -> None:
        """Log one detection event at once (the event log) to every stream.

        Parameters
        ----------
        ev : DetectionEvent
            The event (logged at its alarm time, converted by :func:`to_ns`).
        """
        self._batches.send_event(ev)
