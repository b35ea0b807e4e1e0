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
from .interval_lanes import IntervalCollector, send_intervals
from .monitor_layout import MonitorLayout
from .record_geometry import to_ns
from .sinks import Sinks
from .spectrogram_images import SpectrogramImages
from .static_entities import expected_spectrum, log_static
from .truth_lane import log_truth_lane

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream
    from rerun.blueprint import Blueprint

    from .blueprint import ExtraRow

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
    layout (:class:`~chatterspec.viewer.monitor_layout.MonitorLayout`). The verdict lanes start with
    ``healthy`` (or the monitor's current state) before the first frame and change exactly at the
    events. Times follow :func:`to_ns`.

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
    verdict : str
        Label of a channel lane's flagged state: ``"FAULT"``, or ``"mismatch"`` when the fault decision is
        taken on the identified parameters (tolerances; their own lanes say fault).
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
        verdict: str = "FAULT",
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
        # the layout's geometry (the spectrogram image fills its view at 1600x1000) and blueprint
        self._layout = MonitorLayout(
            monitor,
            has_truth=bool(truth),
            extra_row=extra_row,
            extra_lanes=extra_lanes,
            rows_above=rows_above,
            peak_view=peak_view,
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
        self._verdict = verdict
        # a file's lanes: the record's interval estimates, drawn on close (interval_lanes)
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
            ``above``, ``lanes_name``, ``chattering_range``), which documents them.

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
            expected=self._expected,
            band_hz=self.band_hz,
            hop_s=self.hop_s,
            width=self._layout.width,
            key=self._layout.key,
            cusum=self._layout.cusum,
            verdict=self._verdict,
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
        if file is None or self.file_layout is None:
            return
        span = self.span_s if self.span_s is not None else self.images.covered_span()
        # no frame yet (a record shorter than one window): the layout without span and ranges
        ranges = None if span is None else self._batches.extent.ranges(self.psi)
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
        self._batches.send_event(ev)
