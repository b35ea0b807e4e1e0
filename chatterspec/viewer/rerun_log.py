"""Column-wise Rerun logging of monitor updates (:class:`RerunLogger`, :class:`ColumnBatches`) and of its
fault identification (:class:`IdentificationLog`).

Times follow the one rule of :func:`~chatterspec.viewer.spectrograms.to_ns` (integer ns); the
recording's span, band and colour range are in :mod:`chatterspec.viewer.spectrograms`.

Per-stream batching and column-wise sending (:class:`ColumnBatches`): the job :class:`RerunLogger`
delegates for everything time-indexed. Each stream has an :class:`_Outbox` holding the per-sample part of
the queued updates and, separately, their frames and events; a live viewer's outbox is sent at every
update, a file's once a batch is full (``batch_samples`` samples, ``batch_frames`` frames) and the rest
on :meth:`ColumnBatches.flush`. Each batch goes out with ``send_columns``: one call per entity and batch,
one row per sample or frame holding every channel (Rerun's cost is per row).

The columns are built straight from numpy arrays (zero-copy arrow views, :class:`_Columns`,
:class:`_TimeIndex`): time indexes in integer nanoseconds, float64 scalar columns and batches of
``Tensor`` rows (which ``rr.Tensor`` cannot build itself).

Fault identification (:class:`IdentificationLog`): estimates, nominal values, tolerance bands,
detectability and states per hop. Entities (time on the monitor's ``time`` timeline, integer
nanoseconds; one row per identification window of the
:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`):

``/identification/<parameter>``
    per row, at the window's centre: the joint estimate of the parameter (every declared parameter
    fitted at once: the plant's value), its interval's low and high end, the nominal value and, for a
    parameter with a tolerance, the band's low and high end; in the parameter's unit times a power of
    ten (:func:`display_scale`: the viewer writes ``0.000 000 000 03`` for a leakage in m^3/(s Pa);
    scaled, it reads ``3``);
``/identification/detectable/<parameter>``
    the detectable change over the last few seconds divided by the limit above which the parameter
    is not excited (:mod:`chatterspec.detection.parameter_decision`): above 1, not excited;
``/state/p<k>_<parameter>``
    the parameter's lane at the windows' alarm times: healthy, fault or not excited (below the
    channels' lanes, which show the channels' one fault state: :mod:`chatterspec.viewer.events`);
``/events/identification``
    rows in the recording's event log: the fault named when it changes (only while a spectral alarm is
    active), a parameter that stops or starts being excited (once the detectability's horizon holds
    data), and for ``detect`` the identification of each interval of its JSON
    (:meth:`IdentificationLog.log_intervals`); with tolerances the parameters' alarms are rows of
    ``/events`` itself (:func:`~chatterspec.viewer.events.send_parameter_events`).

:meth:`IdentificationLog.views` gives the views below the monitor's default layout: one per declared
parameter (each is estimated in every window) and the detectability.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarms.rules import rule_spec
from ..detection.identification import format_with_error
from ..detection.parameter_decision import STATES
from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor, DetectionEvent, MonitorUpdate
from ..palette import FAULT, HEALTHY, NEUTRAL, NO_EVIDENCE, rgba32
from .blueprint import (
    CHATTERING,
    MOST_SIGNIFICANT_HZ,
    PEAK_HZ,
    PSI,
    STATISTIC,
    THRESHOLD,
    VERDICT,
    ChatteringExtent,
    MonitorLayout,
    _entity,
    expected_spectrum,
    fault_entity,
    fault_hz_entity,
    labelled_top,
    lane_entity,
    log_static,
)
from .events import (
    INFO_LEVEL,
    Changes,
    FaultLanes,
    IntervalCollector,
    interval_text,
    log_text_rows,
    log_truth_lane,
    send_alarm_events,
    send_interval_events,
    send_parameter_events,
)
from .sinks import TIMELINE, Sinks
from .spectrograms import DB_RANGE, FramePeaks, SpectrogramImages, to_ns

if TYPE_CHECKING:  # pragma: no cover
    from types import ModuleType

    from rerun import RecordingStream
    from rerun.blueprint import Blueprint, VisibleTimeRange
    from rerun.blueprint.api import View
    from rerun.blueprint.archetypes import TimeAxis

    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from .blueprint import ExtraRow

__all__ = [
    "IDENTIFICATION",
    "IDENTIFICATION_EVENTS",
    "ColumnBatches",
    "IdentificationLog",
    "RerunLogger",
    "display_scale",
    "identification_views",
    "parameter_lane_entity",
]


def _send_blueprint(stream: RecordingStream, bp: Blueprint) -> None:
    """Send ``bp`` as the active and default blueprint of ``stream``."""
    stream.send_blueprint(bp, make_active=True, make_default=True)


class RerunLogger:
    """Writes :class:`~chatterspec.online.monitor.MonitorUpdate` objects to the open sinks.

    Everything time-indexed is sent column-wise, to a live viewer at every update and to a file in
    batches (:class:`ColumnBatches`, which lists what is logged per
    sample and per frame); the static entities on opening (:mod:`~chatterspec.viewer.blueprint`);
    the spectrogram images (:class:`~chatterspec.viewer.spectrograms.SpectrogramImages`: one
    tensor per channel for a file's whole record, logged on :meth:`close`, a scrolling view live); the
    layout (:class:`~chatterspec.viewer.blueprint.MonitorLayout`). The channels' lanes show one
    fault state each (:mod:`~chatterspec.viewer.events`): ``no evidence`` until the first window is
    decided, then the run's decision, changing at the alarm times of the events. With an identification
    monitor the lanes follow its windows (fault, healthy, not excited), and its estimates, parameter
    lanes and events are drawn below (:mod:`~chatterspec.viewer.rerun_log`;
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
        the frames (and the identification's windows) once this many frames are (defaults measured: see
        :class:`ColumnBatches`).
    truth : list of (start_s, label, is_fault), optional
        True fault timeline, drawn as the top lane.
    send_blueprint : bool
        Send the default :func:`~chatterspec.viewer.blueprint.blueprint` to the sinks (default True).
    spectrum_dtype : {"float32", "float64"}
        Precision of the logged frame spectra ``/spectrum/<c>``: float32 (default) keeps 7 significant
        digits and halves the file's largest payload (see
        :class:`ColumnBatches`); "float64" logs them bit-exactly.
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
        # the arrow columns built straight from numpy (one builder, validated once, for every batch)
        self._columns = _Columns(rr, DB_RANGE)
        self._ident_log: IdentificationLog | None = None
        if identification is not None and sinks.streams:
            self._ident_log = IdentificationLog(sinks, identification, self._columns, batch_frames)
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
            columns=self._columns,
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
        <chatterspec.viewer.blueprint.MonitorLayout.blueprint>` over this logger's band.

        Parameters
        ----------
        span_s : (float, float) or None
            A file's whole record (s); None for a live viewer (follows the data).
        **options
            The other keyword arguments of :meth:`MonitorLayout.blueprint
            <chatterspec.viewer.blueprint.MonitorLayout.blueprint>` (``has_truth``, ``extra_row``,
            ``above``, ``lanes_name``, ``chattering_range``, ``largest``), which documents them.

        Returns
        -------
        rerun.blueprint.Blueprint
        """
        return self._layout.blueprint(band_hz=self.band_hz, span_s=span_s, **options)

    def _log_static(self, truth: list[tuple[float, str, bool]] | None) -> None:
        """The static entities (:func:`~chatterspec.viewer.blueprint.log_static`) and the truth lane."""
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
            spectrum=lambda values: self._columns.static_tensor(values, ("freq",)),
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
        identification per fault interval; :meth:`~chatterspec.viewer.rerun_log.IdentificationLog.
        log_intervals`); nothing without an identification monitor."""
        if self._ident_log is not None:
            self._ident_log.log_intervals(docs)

    def flush(self) -> None:
        """Send everything buffered (bulk ``send_columns``)."""
        self._batches.flush()
        if self._ident_log is not None:
            self._ident_log.flush()

    def close(self) -> None:
        """Send what is buffered, the file's spectrogram (the whole record, or its last block) and the
        file's interval events: the record's fault interval estimates
        (:mod:`chatterspec.viewer.events`)."""
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
        (:meth:`~chatterspec.viewer.spectrograms.SpectrogramImages.annotate_file`)."""
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


# ------------------------------------------------------ per-stream batching and column-wise sending


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
    columns : _Columns
        The logger's arrow column builder (shared with its identification log).
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
        columns: _Columns,
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
        self._cols = columns
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
        (:meth:`~chatterspec.viewer.events.FaultLanes.follow`); a live viewer's are sent at once, a
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
        lanes' labels where a new alarm episode was labelled (:mod:`~chatterspec.viewer.events`)."""
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


# --------------------------------------------------------- columns built straight from numpy arrays

#: numpy dtype -> variant of Rerun's ``TensorBuffer`` union
_TENSOR_DTYPES = {
    np.dtype(np.float64): "F64",
    np.dtype(np.float32): "F32",
    np.dtype(np.float16): "F16",
}
#: Most tensors per ``send_columns`` call (keeps chunks and int32 arrow offsets small).
_MAX_TENSOR_ROWS = 256
#: Everything of a tensor batch but its values, per (rows, shape, dim names, dtype): the same for every
#: batch of one layout, so built once per process (~0.15 ms each) and shared by all loggers.
_PARTS: dict[tuple, tuple] = {}


class _ArrowBatch:
    """A ready pyarrow array as a Rerun component batch (the ``ComponentBatchLike`` protocol)."""

    __slots__ = ("array",)

    def __init__(self, array: Any) -> None:
        self.array = array

    def as_arrow_array(self) -> Any:
        return self.array


def _arrow(pa: Any, x: np.ndarray, type_: Any) -> Any:
    """Zero-copy arrow view of a 1-D numpy array (``pa.array`` copies and scans: ~25 ns per value)."""
    x = np.ascontiguousarray(x)
    buf = pa.py_buffer(x)  # keeps x alive as long as the arrow array
    return pa.Array.from_buffers(type_, x.shape[0], [None, buf])


#: numpy dtype -> arrow type of the zero-copy views
_ARROW_TYPES = {
    np.dtype(np.float64): "float64",
    np.dtype(np.float32): "float32",
    np.dtype(np.float16): "float16",
}


class _TimeIndex:
    """A ``time`` column converted to arrow once and shared by several ``send_columns`` calls."""

    __slots__ = ("array",)

    def __init__(self, pa: Any, ns: np.ndarray) -> None:
        self.array = _arrow(pa, np.asarray(ns, dtype=np.int64), pa.duration("ns"))

    def timeline_name(self) -> str:
        return TIMELINE

    def as_arrow_array(self) -> Any:
        return self.array

    def __getitem__(self, sl: slice) -> _TimeIndex:
        out = _TimeIndex.__new__(_TimeIndex)
        out.array = self.array[sl]
        return out


class _Columns:
    """``send_columns`` component columns built straight from numpy arrays.

    ``rr.Tensor`` has no ``columns()`` batch constructor ("Tensors do not support
    batches"), so a batch of tensors is assembled here as the arrow array Rerun
    itself produces for one ``rr.log(path, rr.Tensor(...))`` per row (same
    component descriptor, same arrow type): a reader sees one ``Tensor:data`` row
    per frame either way. The arrays are built with the arrow type Rerun declares
    for the component and validated once on two probes; on any mismatch (a future
    Rerun) ``tensors_ok`` is False and the caller falls back to one ``rr.log`` per
    tensor (the tests compare the arrays with ``rr.Tensor``'s, value for value).
    """

    def __init__(self, rr: ModuleType, value_range: tuple[float, float]) -> None:
        import pyarrow as pa  # a dependency of rerun-sdk

        self.rr, self.pa = rr, pa
        self.scalars = rr.Scalars.descriptor_scalars()
        self.tensor = rr.Tensor.descriptor_data()
        self.value_range = rr.Tensor.descriptor_value_range()
        self._parts = _PARTS  # shared by every logger of the process (immutable arrow arrays)
        # built from Rerun's declared arrow types, not by encoding a probe with rr.Tensor: its one-tensor
        # encoder casts int64 list offsets with pyarrow.compute, whose import costs ~0.06 s of CPU
        # (tests compare these arrays with rr.Tensor's value for value)
        self.value_range_row = rr.components.ValueRangeBatch(list(value_range)).as_arrow_array()
        self.tensor_type = rr.components.TensorDataBatch._ARROW_DATATYPE
        self.tensors_ok = False
        try:
            for probe in (np.array([[1.0, 2.0, 3.0]]), np.arange(6, dtype=np.float16).reshape(1, 3, 2)):
                names = ("freq",) if probe.ndim == 2 else ("freq", "time")
                self._tensor_array(probe, names, cache=False).validate(full=True)
            self.tensors_ok = True
        except Exception:  # any layout change of a future Rerun: fall back to rr.log per tensor
            self.tensors_ok = False

    def scalars_column(self, values: np.ndarray, own: bool = False) -> Any:
        """One scalar per row from a 1-D ``values``; ``k`` scalars per row (one line per column in
        Rerun's plot, e.g. one per channel) from a 2-D ``(rows, k)`` one. Rerun's cost is per row (a
        16-byte row id and an 8-byte time besides the values): 60 000 samples of 3 channels as one
        entity of 3 scalars per row plus one of 6 (measured and estimate) cost 11.4 ms CPU and 6.0 MB,
        as 3 + 3 per-channel entities 24.6 ms and 9.4 MB (send + flush + close, best of 15).

        ``own``: the caller hands ``values`` over (a fresh array it will not modify): no copy when it
        is already C-contiguous float64."""
        # otherwise a private copy (~20 us per 60k values): Rerun encodes later, the caller may reuse
        # its array
        values = np.array(values, dtype=np.float64, order="C", copy=None if own else True)
        arr = _arrow(self.pa, values.reshape(-1), self.pa.float64())
        if values.ndim == 1:
            return self.rr.ComponentColumn(self.scalars, _ArrowBatch(arr))
        k = values.shape[1]
        offsets = np.arange(0, values.size + 1, k, dtype=np.int32)
        return self.rr.ComponentColumn(self.scalars, _ArrowBatch(arr), offsets=offsets)

    def tensor_columns(
        self, data: np.ndarray, names: tuple[str, ...], *, value_range: bool = False, cache: bool = True
    ) -> list:
        """One ``Tensor`` row per ``data[k]`` (and the dB ``value_range`` on each row if asked); ``cache``
        False builds everything afresh and keeps nothing: for a layout that will not come back (the live
        spectrogram names its newest time) and for the layout probe."""
        cols = [self.rr.ComponentColumn(self.tensor, _ArrowBatch(self._tensor_array(data, names, cache)))]
        if value_range:
            vr = self.pa.concat_arrays([self.value_range_row] * data.shape[0])
            cols.append(self.rr.ComponentColumn(self.value_range, _ArrowBatch(vr)))
        return cols

    def static_tensor(self, values: np.ndarray, names: tuple[str, ...]) -> Any:
        """What ``rr.log(path, rr.Tensor(values, dim_names=names), static=True)`` logs: the one
        ``Tensor:data`` component of ``values`` (``rr.Tensor`` itself on the fallback)."""
        if not self.tensors_ok:
            return self.rr.Tensor(values, dim_names=list(names))
        arr = self._tensor_array(np.asarray(values)[None], names, cache=False)
        return [self.rr.DescribedComponentBatch(_ArrowBatch(arr), self.tensor)]

    def _tensor_array(self, data: np.ndarray, names: tuple[str, ...], cache: bool = True) -> Any:
        pa, t = self.pa, self.tensor_type
        data = np.ascontiguousarray(data)
        n, shape = data.shape[0], data.shape[1:]
        key = (n, shape, names, data.dtype, t)
        parts = self._parts.get(key) if cache else None
        if parts is None:  # everything but the values: the same for every batch of this layout
            size, nd = int(np.prod(shape)), len(shape)
            dim_offsets = pa.array(np.arange(0, n * nd + 1, nd, dtype=np.int32))
            shape_arr = pa.ListArray.from_arrays(
                dim_offsets,
                pa.array(np.tile(np.asarray(shape, dtype=np.uint64), n)),
                type=t.field("shape").type,
            )
            names_arr = pa.ListArray.from_arrays(
                dim_offsets, pa.array(list(names) * n, type=pa.string()), type=t.field("names").type
            )
            union = t.field("buffer").type
            k = [f.name for f in union].index(_TENSOR_DTYPES[data.dtype])
            children = [pa.nulls(0, type=f.type) for f in union]
            offsets = pa.array(np.arange(0, n * size + 1, size, dtype=np.int32))
            union_buffers = [
                None,
                pa.py_buffer(np.full(n, k, np.int8)),
                pa.py_buffer(np.arange(n, dtype=np.int32)),
            ]
            parts = (shape_arr, names_arr, union, k, children, offsets, union_buffers)
            if cache:
                if len(self._parts) > 64:
                    self._parts.clear()
                self._parts[key] = parts
        shape_arr, names_arr, union, k, children, offsets, union_buffers = parts
        children = list(children)
        flat = _arrow(pa, data.reshape(-1), getattr(pa, _ARROW_TYPES[data.dtype])())
        children[k] = pa.ListArray.from_arrays(offsets, flat, type=union[k].type)
        buffer = pa.Array.from_buffers(type=union, length=n, buffers=union_buffers, children=children)
        return pa.Array.from_buffers(
            type=t, length=n, buffers=[None], children=[shape_arr, names_arr, buffer]
        )


# ----------------------------------------------------------------------------- fault identification

#: Root entity of the identification series.
IDENTIFICATION = "/identification"
#: A parameter's rows of one push: series ``(W, 4 or 6)`` and detectability ``(W,)`` (display units), the
#: times (ns) of its lane's changes and their states.
_ParameterRows = tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]
#: Entity of the identification rows in the recording's event log.
IDENTIFICATION_EVENTS = "/events/identification"
#: The series of a parameter: estimate (amber), interval ends (grey), nominal (light, thin), and with a
#: tolerance the band's ends (blue).
_NAMES = ["estimate", "interval low", "interval high", "nominal", "band low", "band high"]
_COLORS = [[255, 200, 60], list(NEUTRAL), list(NEUTRAL), [220, 220, 220], [80, 160, 220], [80, 160, 220]]
_WIDTHS = [2.5, 1.0, 1.0, 1.0, 1.5, 1.5]


def _path(parameter: str) -> str:
    return f"{IDENTIFICATION}/{parameter}"


def parameter_lane_entity(index: int, name: str) -> str:
    """``/state/p<index + 1>_<name>``: the lane of parameter ``index`` (sorts below the channels' lanes)."""
    return f"/state/p{index + 1}_{_entity(name)}"


def display_scale(nominal: float) -> int:
    """The power of ten ``k`` a parameter is drawn in (values divided by ``10**k``): the nominal value's
    engineering exponent (a multiple of 3), 0 for a zero nominal or one between 0.01 and 1000.

    Parameters
    ----------
    nominal : float
        Nominal value (in the parameter's unit).

    Returns
    -------
    int
    """
    a = abs(float(nominal))
    if a == 0.0 or not math.isfinite(a) or 1e-2 <= a < 1e3:
        return 0
    return 3 * math.floor(math.log10(a) / 3)


def _unit_label(unit: str, k: int) -> str:
    """``"[1e-12 m^3/(s Pa)]"``, ``"[Hz]"``, ``""``."""
    scale = f"1e{k} " if k else ""
    text = f"{scale}{unit}".strip()
    return f" [{text}]" if text else ""


class IdentificationLog:
    """Sends an identification monitor's results to the sinks and gives their views.

    Parameters
    ----------
    sinks : Sinks
        The monitor's open sinks (file and / or live viewer).
    monitor : IdentificationMonitor
        Gives the parameters, their units, nominal values and bands, and the intervals' level.
    columns : _Columns
        The logger's arrow column builder (its series are built straight from numpy).
    batch_windows : int
        A file's series and parameter lanes are sent once this many windows are queued (one
        ``send_columns`` per entity and batch; the rest on :meth:`flush`), a live viewer's at every push.
    """

    def __init__(
        self, sinks: Sinks, monitor: IdentificationMonitor, columns: _Columns, batch_windows: int = 300
    ) -> None:
        import pyarrow as pa
        import rerun as rr

        self.rr, self.pa, self.sinks, self.monitor = rr, pa, sinks, monitor
        self._cols = columns  # the series' columns straight from numpy
        self.bands = b = monitor.settings.bands
        self.confidence = float(monitor.identifier.confidence)
        self.parameters = list(b.names)
        self.lanes = [parameter_lane_entity(i, p) for i, p in enumerate(self.parameters)]
        self.scale = [display_scale(float(v)) for v in b.nominal]
        self.banded = [bool(t) for t in b.tolerances]  # a band is drawn (a tolerance declared)
        self.n_series = [6 if t else 4 for t in self.banded]
        # per parameter the smallest and largest value drawn (display units): the views' y ranges
        self.extent = [
            [
                min(float(b.low[i]), float(b.nominal[i])) / 10.0**k,
                max(float(b.high[i]), float(b.nominal[i])) / 10.0**k,
            ]
            for i, k in enumerate(self.scale)
        ]
        self._label: str | None = None
        self._states: tuple[str, ...] | None = None
        self._windows = 0  # since the start or a reset: the detectability's horizon fills
        # a file's queued pushes: (times ns, per parameter (series rows, detectability, lane changes' times
        # ns, their states)), sent once batch_windows windows wait
        self._batch = max(1, int(batch_windows))
        self._queued: list[tuple[np.ndarray, list[_ParameterRows]]] = []
        self._n_queued = 0
        colors = np.array([rgba32(HEALTHY), rgba32(FAULT), rgba32(NO_EVIDENCE)], dtype=np.uint32)
        for s in sinks.streams:
            for i, (p, lane) in enumerate(zip(self.parameters, self.lanes, strict=True)):
                n = self.n_series[i]
                s.log(
                    _path(p),
                    rr.SeriesLines(names=_NAMES[:n], colors=_COLORS[:n], widths=_WIDTHS[:n]),
                    static=True,
                )
                s.log(f"{IDENTIFICATION}/detectable/{p}", rr.SeriesLines(names=[p]), static=True)
                s.log(
                    lane,
                    rr.StateConfiguration(
                        values=list(STATES),
                        labels=[f"{p}: healthy", f"{p}: FAULT", f"{p}: not excited"],
                        colors=colors,
                    ),
                    static=True,
                )

    # ------------------------------------------------------------------ views
    def views(
        self, time_range: VisibleTimeRange, axis: TimeAxis | None = None, *, live: bool = False
    ) -> list[View]:
        """One time view per declared parameter (estimate, interval, nominal, band) and the detectability
        view; a file's views get y ranges from the values drawn (:meth:`y_range`), a live viewer's follow
        the data."""
        import rerun.blueprint as rrb

        b = self.bands
        views: list[View] = []
        for i, p in enumerate(self.parameters):
            what = f"{self.confidence:.0%} interval, nominal" + (", tolerance" if self.banded[i] else "")
            views.append(
                rrb.TimeSeriesView(
                    origin=_path(p),
                    name=f"{p}{_unit_label(b.units[i], self.scale[i])}: {what}",
                    time_ranges=time_range,
                    axis_x=axis,
                    plot_legend=rrb.PlotLegend(visible=False),
                    axis_y=None if live else rrb.ScalarAxis(range=self.y_range(i)),
                )
            )
        horizon = self.monitor.settings.horizon_hops * self.monitor.settings.hop_s
        limit = "tolerance" if any(self.banded) else "nominal"
        views.append(
            rrb.TimeSeriesView(
                origin=f"{IDENTIFICATION}/detectable",
                name=f"detectable change ({horizon:g} s) / {limit}: > 1 not excited",
                time_ranges=time_range,
                axis_x=axis,
            )
        )
        return views

    def y_range(self, i: int) -> tuple[float, float]:
        """The y range of parameter ``i``'s view (display units): from 0 (or the smallest value drawn, if
        negative) to a labelled top above the largest (:func:`~chatterspec.viewer.blueprint.labelled_top`),
        so that the viewer labels its ticks and the nominal line, the band and every estimate are on the
        chart."""
        lo, hi = self.extent[i]
        top = labelled_top(1.05 * hi) if hi > 0 else 0.1 * abs(lo) or 1.0
        bottom = 0.0 if lo >= 0 else -labelled_top(1.05 * -lo)
        return (bottom - 0.05 * (top - bottom), top)

    # ------------------------------------------------------------------ rows
    def _texts(self, times_s: list[float], texts: list[str]) -> None:
        for s in self.sinks.streams:
            log_text_rows(s, IDENTIFICATION_EVENTS, times_s, texts, [INFO_LEVEL] * len(texts))

    def log(self, upd: IdentificationUpdate) -> None:
        """Log the windows of one push: the series, the parameter lanes, the rows of the event log."""
        blk = upd.block
        W = blk.n_windows
        if W == 0 or not self.sinks.streams:
            return
        if int(blk.frames[0]) == 0:  # a fresh identifier (the start, or a reset after a gap)
            self._windows, self._label, self._states = 0, None, None
        ns = to_ns(blk.times_s)
        decided = np.array([w.alarm_time_s for w in upd.windows])
        b = self.bands
        warm = self.monitor.settings.horizon_hops  # windows before the detectability means anything
        texts: list[str] = []
        t_text: list[float] = []
        changes: dict[int, tuple[list[int], list[str]]] = {i: ([], []) for i in range(b.size)}
        for w in upd.windows:
            self._windows += 1
            t = w.alarm_time_s
            if w.label != self._label and not self.monitor.tolerances:  # with tolerances: their events
                if w.label is not None or self._label is not None:
                    texts.append(self._label_text(w, upd))
                    t_text.append(t)
            for i, st in enumerate(w.states if w.states != self._states else ()):  # (most windows: none)
                if self._states is None or st != self._states[i]:
                    changes[i][0].append(w.index)
                    changes[i][1].append(st)
                    blind = "not-excited"
                    if self._states is not None and blind in (st, self._states[i]) and self._windows > warm:
                        det = blk.detectable[w.index, i]
                        unit = f" {b.units[i]}" if b.units[i] else ""
                        what = "not excited" if st == blind else "excited"
                        texts.append(f"{t:.2f} s {b.names[i]} {what}: changes >= {det:.2g}{unit} detectable")
                        t_text.append(t)
            self._label, self._states = w.label, w.states
        ratio = blk.detectable / b.limit[None, :]
        per: list[_ParameterRows] = []
        for i in range(b.size):
            cols = [blk.estimate[:, i], blk.ci_low[:, i], blk.ci_high[:, i], np.full(W, b.nominal[i])]
            if self.banded[i]:
                cols += [np.full(W, b.low[i]), np.full(W, b.high[i])]
            rows = np.stack(cols, axis=1) / 10.0 ** self.scale[i]
            if np.isfinite(rows).any():
                ext = self.extent[i]
                ext[0], ext[1] = min(ext[0], float(np.nanmin(rows))), max(ext[1], float(np.nanmax(rows)))
            r = np.where(np.isfinite(ratio[:, i]), ratio[:, i], np.nan)
            k, states = changes[i]
            per.append((rows, r, to_ns(decided[k]), states))
        for s in self.sinks.streams:
            if s is not self.sinks.file_stream:  # a live viewer: at once
                self._send(s, ns, per)
        if self.sinks.file_stream is not None:
            self._queued.append((ns, per))
            self._n_queued += W
            if self._n_queued >= self._batch:
                self.flush()
        if texts:
            self._texts(t_text, texts)
        if upd.events:
            for s in self.sinks.streams:
                send_parameter_events(s, upd.events)

    def flush(self) -> None:
        """Send the file's queued series and parameter lanes (one ``send_columns`` per entity)."""
        file = self.sinks.file_stream
        if not self._queued or file is None:
            return
        queued, self._queued, self._n_queued = self._queued, [], 0
        if len(queued) == 1:
            self._send(file, *queued[0])
            return
        per: list[_ParameterRows] = []
        for i in range(len(self.parameters)):
            parts = [q[1][i] for q in queued]
            per.append(
                (
                    np.concatenate([p[0] for p in parts]),
                    np.concatenate([p[1] for p in parts]),
                    np.concatenate([p[2] for p in parts]),
                    [st for p in parts for st in p[3]],
                )
            )
        self._send(file, np.concatenate([q[0] for q in queued]), per)

    def _send(self, s: Any, ns: np.ndarray, per: list[_ParameterRows]) -> None:
        """Send windows at ``ns`` to ``s``: per parameter its series, detectability and lane changes."""
        idx, cols = [_TimeIndex(self.pa, ns)], self._cols
        for i, p in enumerate(self.parameters):
            rows, r, lane_ns, states = per[i]
            s.send_columns(_path(p), indexes=idx, columns=[cols.scalars_column(rows, own=True)])
            detectable = cols.scalars_column(r, own=True)
            s.send_columns(f"{IDENTIFICATION}/detectable/{p}", indexes=idx, columns=[detectable])
            if states:
                s.send_columns(
                    self.lanes[i],
                    indexes=[_TimeIndex(self.pa, lane_ns)],
                    columns=self.rr.StateChange.columns(state=states),
                )

    def _label_text(self, w: Any, upd: IdentificationUpdate) -> str:
        """``"2.60 s fault named: leakage = 3.1(2)e-11 [..] m^3/(s Pa)"``, or the alarm over."""
        if w.label is None:
            return f"{w.alarm_time_s:.2f} s alarm over: no fault named"
        blk, b, j = upd.block, self.bands, w.index
        what = "; ".join(
            f"{p} = {format_with_error(blk.estimate[j, i], blk.std_error[j, i])} "
            f"[{format_with_error(blk.ci_low[j, i], blk.std_error[j, i])}, "
            f"{format_with_error(blk.ci_high[j, i], blk.std_error[j, i])}]"
            + (f" {b.units[i]}" if b.units[i] else "")
            for i, p in enumerate(b.names)
            if p in w.label.split("+")
        )
        return f"{w.alarm_time_s:.2f} s fault named: {w.label}" + (f": {what}" if what else "")

    def log_intervals(self, docs: list[dict[str, Any]]) -> None:
        """Rows of the event log for ``detect --json``'s ``identification_intervals``: per interval, at its
        onset, the selected hypothesis with its estimates and intervals (the numbers of the JSON), or why
        it was not identified."""
        if not self.sinks.streams or not docs:
            return
        texts, t_text = [], []
        for doc in docs:
            on, off = (float(x) for x in doc["interval_s"])
            sel = doc.get("selected")
            picked = [
                h for h in doc.get("hypotheses", []) if h.get("hypothesis") == sel and h.get("parameter")
            ]
            what = "; ".join(
                f"{h['parameter']} = {h['estimate']:.4g} [{h['ci_low']:.4g}, {h['ci_high']:.4g}]"
                + (f" {h['unit']}" if h.get("unit") else "")
                for h in picked
                if h.get("estimate") is not None
            )
            if sel is None:
                why = str(doc.get("reason", "no result")).split(";")[0]  # its first clause: the log cuts text
                texts.append(f"{interval_text(on, off)} not identified: {why}")
            else:
                texts.append(f"{interval_text(on, off)} identified " + (what or str(sel)))
            t_text.append(on)
        self._texts(t_text, texts)


def identification_views(log: IdentificationLog) -> ExtraRow:
    """``make(time_range, axis, live=False) -> views`` of ``log`` (:meth:`IdentificationLog.views`), for
    :func:`chatterspec.viewer.blueprint.blueprint`'s ``extra_row``; evaluated when a blueprint is built,
    so a file's final blueprint gets the y ranges of its record."""

    def make(time_range: VisibleTimeRange, axis: TimeAxis | None = None, *, live: bool = False) -> list[View]:
        return log.views(time_range, axis, live=live)

    return make
