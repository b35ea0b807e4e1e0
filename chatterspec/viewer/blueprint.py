"""The layout of a chatterspec recording: its default Rerun blueprint, the views' ranges and the static
entities logged once per stream.

The blueprint (:func:`blueprint`, :func:`layout_geometry`, :func:`time_axis`, ...): the entity paths of
a recording, the rows of views and their heights at 1600x1000, the labelled y ranges of the statistic
and alarm views (:func:`statistic_range`, :func:`alarm_range`).

The layout of a monitor recording (:class:`MonitorLayout`): what
:class:`~chatterspec.viewer.rerun_log.RerunLogger` delegates for the look of a recording: the
spectrogram image's width (it fills its view at 1600x1000, :func:`layout_geometry`) and the blueprint
with the band, the alarm view and the units.

The y range of a recording's chattering views (:class:`ChatteringExtent`): a robust, symmetric extent
of the record's chattering. Rerun auto-ranges a time-series view from the data it shows; at 1600x1000 a
small amplitude (the chattering of a position in metres is ~1e-4) can leave a single "0" tick on the
axis, with no amplitude to read. A file's final blueprint therefore gives each chattering view a fixed
symmetric range ``[-r, r]`` with ``r`` from :class:`ChatteringExtent`.

Which ticks the viewer labels: its plots (egui_plot, Rerun 0.41) put grid lines at powers of ten only
(``10^k``, no 2 or 5 steps) and label a step only when its lines are far enough apart on screen. Seen at
1600x1000 on the ~70 px high chattering views: ``±0.005`` in ``±0.00615`` is NOT labelled (its
``0.001`` lines are ~6 px apart and ``0.01`` is out of range), nor ``±1`` in ``±2.2``; ``±0.01`` in
``±0.011`` is. So ``r`` is not the extent itself but ``1.1 p`` for the smallest power of ten ``p``
with ``1.1 p`` at or above it (:func:`labelled_half_range`): the ``±p`` lines sit at 91 % of the
half-height and are labelled; the data then fill 10 % to 100 % of the half-height.

The static entities of a monitor recording (:func:`log_static`): series styles, spectrogram axes,
threshold and expected spectra, the lanes' state configuration and the frequency note; logged once per
stream by :class:`~chatterspec.viewer.rerun_log.RerunLogger` when it opens.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np

from .. import palette
from ..detection.alarms.rules import rule_spec
from ..detection.spectral import expected_frame_spectrum
from ..online.monitor import ChatteringMonitor
from ..plants.nonlinear import is_linear
from .sinks import TIMELINE
from .spectrograms import DB_RANGE, KEY_PX, key_width, log_axes, spectrogram_view

if TYPE_CHECKING:  # pragma: no cover
    from rerun import StateConfiguration
    from rerun.blueprint import VisibleTimeRange
    from rerun.blueprint.api import View
    from rerun.blueprint.archetypes import TimeAxis

__all__ = [
    "ALARM",
    "CHATTERING",
    "MOST_SIGNIFICANT_HZ",
    "PEAK_HZ",
    "PSI",
    "QUANTILE",
    "SAMPLE_SERIES_PER_CHANNEL",
    "STATISTIC",
    "STRIDE",
    "THRESHOLD",
    "VERDICT",
    "ChatteringExtent",
    "MonitorLayout",
    "blueprint",
    "expected_spectrum",
    "fault_entity",
    "fault_hz_entity",
    "labelled_half_range",
    "lane_entity",
    "layout_geometry",
    "log_static",
    "series_styles",
    "time_axis",
    "time_panel",
    "view_px",
]


class ExtraRow(Protocol):
    """Views for a row below the lanes, given the recording's time range and axis, and whether the
    blueprint is a live viewer's (:func:`blueprint`'s ``extra_row``)."""

    def __call__(
        self, time_range: VisibleTimeRange, axis: TimeAxis | None = None, *, live: bool = False
    ) -> list[View]: ...


#: Entity of the true-fault lane: sorts before every channel lane (the viewer orders lanes by path).
TRUTH_LANE = "/state/0_truth"

# Per-sample and per-frame series: ONE entity per quantity with one scalar per channel in each row
# (series j = output channel j), so a sample costs one Rerun row (a row id and a time) for all channels;
# each channel's view shows only its own series (``visible_series`` overrides, :func:`blueprint`).
#: Everything per sample, ONE row per sample: the chattering ``e(k|k-1)`` of the auxiliary filter per
#: channel (series ``0 .. m-1``), then, for raw data, per channel the measurement [and the
#: ``sat``-SVSF estimate ``C x(k|k)``] (series ``m + c k + j``, ``k`` = 1 or 2 per channel). One entity
#: instead of two halves what the file writer encodes per sample (a row id and a time per row).
CHATTERING = "/chattering/e"
#: Most series per channel in :data:`CHATTERING` (chattering, measurement, estimate): the length of
#: the views' ``visible_series`` overrides, whatever the input mode.
SAMPLE_SERIES_PER_CHANNEL = 3
#: The boundary layer: +psi_0, -psi_0, +psi_1, ... (2 m scalars), at each batch's first and last sample.
PSI = "/chattering/psi"
#: ``10 log10(max_k S_k / threshold_k)`` (dB) per channel, one row per frame.
STATISTIC = "/detection/statistic_db"
#: The decision level, 0 dB (one series shared by every channel's view).
THRESHOLD = "/detection/threshold_db"
#: Per frame ONE row of ``3 m + 1`` series: the per-frame verdict per channel (series ``0 .. m-1``,
#: 1 = fault; not drawn), then the alarm rule's statistic per channel (``m .. 2m-1``: the frame
#: score ``-log p`` in nats for the frame and persistence rules, the CUSUM ``g``), the frame score
#: per channel (``2m .. 3m-1``; see chatterspec.detection.verdicts) and the rule's threshold ``h``
#: (``3m``). The alarm series share the verdict's rows: Rerun's cost is per row.
VERDICT = "/detection/verdict"
#: Default y range of the statistic views (dB): healthy frames sit near -3 dB, the threshold at 0 dB. The
#: viewer labels powers of ten only, and only when their grid lines are far enough apart (an auto range of
#: -5..60 dB showed the "0" tick alone at 1600x1000), so ranges are set, not automatic: a file's final
#: blueprint widens the top to hold the record's largest value (:func:`statistic_range`). The bottom is not
#: a multiple of ten, so that no tick label sits on the time axis's labels.
STATISTIC_RANGE_DB = (-15.0, 25.0)
#: Tested bin with the largest excess power ``S - E`` per channel (Hz), one row per frame.
PEAK_HZ = "/frequency/peak_hz"
#: Tested bin with the largest ``S / threshold`` per channel (Hz), one row per frame.
MOST_SIGNIFICANT_HZ = "/frequency/most_significant_hz"
#: The alarm series live in the rows of :data:`VERDICT` (series ``m .. 3m``).
ALARM = VERDICT


def labelled_top(x: float) -> float:
    """``1.1 p`` for the smallest power of ten ``p`` with ``1.1 p >= x > 0``: a range top whose ``p`` grid
    line the viewer labels (see :mod:`chatterspec.viewer.blueprint`), with room above ``x``."""
    return 1.1 * 10.0 ** math.ceil(math.log10(max(float(x), 1e-300) / 1.1) - 1e-12)


#: When the viewer labels a power-of-ten grid (Rerun 0.41 at 1600x1000, seen on its views): at most about
#: five lines of that step in the range (-15..25 dB in 10 dB steps is labelled on a 63 px plot, -54..34
#: cm/s in 10 cm/s steps is not on a 170 px one) and at least LABEL_GAP_PX apart (10 dB steps 11 px apart
#: are not labelled).
LABEL_GAP_PX = 14.0
MAX_LABELLED_LINES = 5.5


def labelled_step(lo: float, hi: float, plot_px: float) -> float | None:
    """The power-of-ten step whose ticks the viewer labels in ``[lo, hi]`` on a plot ``plot_px`` high, or
    None when no step both fits (at least two ticks in range) and has its lines far enough apart."""
    span = hi - lo
    if not span > 0:
        return None
    p = 10.0 ** math.ceil(math.log10(span / MAX_LABELLED_LINES))
    ticks = math.floor(hi / p + 1e-9) - math.ceil(lo / p - 1e-9) + 1
    return p if ticks >= 2 and plot_px * p / span >= LABEL_GAP_PX else None


def _labelled(lo: float, hi: float, plot_px: float) -> bool:
    """Whether the viewer labels a power-of-ten grid inside ``[lo, hi]`` (:func:`labelled_step`)."""
    return labelled_step(lo, hi, plot_px) is not None


def statistic_range(largest_db: float, plot_px: float = 60.0) -> tuple[float, float]:
    """The statistic view's y range (dB) for a record whose largest ``max S/threshold`` is ``largest_db``
    (-inf: unknown, a live viewer) in a plot ``plot_px`` high: :data:`STATISTIC_RANGE_DB`, or -12..12 dB
    where the plot is too low for its 10 dB ticks to be labelled; the top raised to :func:`labelled_top`
    when the record goes higher (a 62 dB fault -> up to 110 dB, ticks 0 and 100)."""
    lo, hi = STATISTIC_RANGE_DB
    if not _labelled(lo, hi, plot_px):
        lo, hi = -12.0, 12.0
    if np.isfinite(largest_db) and largest_db > 0.9 * hi:
        hi = labelled_top(1.05 * largest_db)
    if not _labelled(lo, hi, plot_px):
        hi = labelled_top(10.0 * hi)  # one decade more: its lines far enough apart
    return (lo, hi)


def alarm_range(h: float, largest: float, plot_px: float = 60.0) -> tuple[float, float] | None:
    """The alarm view's y range in a plot ``plot_px`` high: ``[0, 1.5 h]``, its top raised to
    :func:`labelled_top` when the drawn statistic goes higher (the frame score of a fault reaches hundreds
    of nats) or when no power-of-ten tick would be labelled (h = 41 on a 40 px plot: up to 110, ticks 0 and
    100); None without a finite positive ``h`` (auto range)."""
    if not (np.isfinite(h) and h > 0):
        return None
    top = 1.5 * float(h)
    if np.isfinite(largest) and largest > top / 1.05:
        top = labelled_top(1.05 * float(largest))
    p = 10.0 ** math.floor(math.log10(top))
    top = max(top, 1.1 * p)  # a power of ten just below the top: room for its label (h = 6.91: 0..11)
    if not _labelled(-0.1 * top, top, plot_px):
        top = labelled_top(1.05 * top)
    return (-0.1 * top, top)  # 0 above the bottom edge: its label clear of the time axis's


def event_log_view(name: str = "events (alarm times; estimates; identification)") -> Any:
    """The event log (``/events`` and below): level and text (each text starts with its time in s; the
    timeline and entity-path columns cut the text short at 1600x1000)."""
    import rerun.blueprint as rrb
    from rerun.blueprint.encodings import TimelineColumn

    hidden_time = [TimelineColumn(TIMELINE, visible=False)]  # an empty list means "the active timeline"
    return rrb.TextLogView(
        origin="/events",
        name=name,
        columns=rrb.TextLogColumns(timeline_columns=hidden_time, text_log_columns=["loglevel", "body"]),
    )


def title_chars(n_columns: int) -> int:
    """Characters a view title can hold, uncut, in one of ``n_columns`` columns at 1600x1000: the view's
    width less its icons (~140 px), at ~6.6 px per character (measured in Rerun 0.41: 65 characters fit
    a third of the window, 42 a quarter)."""
    return int((_WINDOW[0] / max(int(n_columns), 1) - 140.0) / 6.6)


def fit(variants: Sequence[str], chars: int) -> str:
    """The first (longest) of ``variants`` with at most ``chars`` characters, else the last: a title is
    shortened by dropping words, never cut (the viewer's cut can hide a number)."""
    return next((v for v in variants if len(v) <= chars), variants[-1])


# --------------------------------------------------------------------------- blueprint
def _entity(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def lane_entity(index: int, name: str) -> str:
    """Entity path of the verdict lane of output channel ``index`` (0-based) called ``name``.

    The viewer sorts lanes by entity path, so the path carries the 1-based channel
    number: lanes then appear in channel order below the true-fault lane.

    Parameters
    ----------
    index : int
        Channel index (0-based, model output order).
    name : str
        Channel name.

    Returns
    -------
    str
        ``/state/<index + 1>_<name>`` (name made entity-safe).
    """
    return f"/state/{index + 1}_{_entity(name)}"


def fault_hz_entity(name: str) -> str:
    """Entity path of the most significant frequency (largest ``S / threshold``, Hz: the brightest bin of
    the dB spectrogram) of channel ``name`` at its flagged frames only (red points; the peak frequencies
    of every frame are drawn dimmed).

    Parameters
    ----------
    name : str
        Channel name.

    Returns
    -------
    str
        ``/frequency/fault/<name>`` (name made entity-safe).
    """
    return f"/frequency/fault/{_entity(name)}"


def fault_entity(name: str) -> str:
    """Entity path of the flagged frames of output channel ``name``: the statistic (dB) at those frames
    only, drawn as red points (sparse, so one entity per channel).

    Parameters
    ----------
    name : str
        Channel name.

    Returns
    -------
    str
        ``/detection/fault/<name>`` (name made entity-safe).
    """
    return f"/detection/fault/{_entity(name)}"


# the shared palette (chatterspec.palette): channels without red, red only for faults
_COLORS = [list(c) for c in palette.CHANNEL_COLORS]
_GREY, _RED, _WHITE, _DIM = list(palette.NEUTRAL), list(palette.FAULT), list(palette.TRUTH), [90, 90, 90]


def series_styles(
    channels: Sequence[str],
    units: Sequence[str],
    *,
    has_estimate: bool = False,
    alarm_statistic: str = "score -log p [nats]",
) -> list[tuple[str, Any]]:
    """Static styling of the time series: one ``SeriesLines`` / ``SeriesPoints`` per entity with one
    name and colour per series (series ``j`` = channel ``j``; ``/chattering/psi`` holds 2 series per
    channel, channel-major, and :data:`CHATTERING` the raw series after the m chattering ones), logged
    once with ``static=True``.

    Parameters
    ----------
    channels : tuple of str
        Output channel names (model order).
    units : tuple of str
        Their units ("" for none), shown in the chattering series names.
    has_estimate : bool
        :data:`CHATTERING` holds the ``sat``-SVSF estimate after each measurement (``psi`` known).
        The names of the raw series are listed in either input mode; with the chattering given they
        name no series (the rows hold only the m chattering values).
    alarm_statistic : str
        Name of the rule's statistic in :data:`VERDICT` (series ``m .. 2m-1``), with its unit.

    Returns
    -------
    list of (entity path, archetype)
    """
    import rerun as rr

    m = len(channels)
    cols = [_COLORS[i % len(_COLORS)] for i in range(m)]
    named = [f"{c} [{u}]" if u else c for c, u in zip(channels, units, strict=True)]
    sig = ("measured", "SVSF estimate") if has_estimate else ("measured",)
    out = [
        (
            CHATTERING,
            rr.SeriesLines(
                colors=cols + [col if k == 0 else [0, 0, 0] for col in cols for k in range(len(sig))],
                names=named + [f"{c}: {what}" for c in named for what in sig],
            ),
        ),
        (
            PSI,
            rr.SeriesLines(
                colors=[_GREY] * (2 * m),
                widths=[1.0] * (2 * m),
                names=[f"{c}: {side}psi" for c in channels for side in "+-"],
            ),
        ),
        (
            STATISTIC,
            rr.SeriesLines(
                colors=cols, widths=[1.5] * m, names=[f"{c}: max S/threshold [dB]" for c in channels]
            ),
        ),
        (THRESHOLD, rr.SeriesLines(colors=[_GREY], widths=[1.0], names=["threshold (0 dB)"])),
        (
            PEAK_HZ,
            rr.SeriesLines(
                colors=[_DIM] * m,
                widths=[1.0] * m,
                names=[f"{c}: peak_hz, largest S-E [Hz]" for c in channels],
            ),
        ),
        (
            MOST_SIGNIFICANT_HZ,
            rr.SeriesPoints(
                colors=[_DIM] * m,
                marker_sizes=[1.0] * m,
                names=[f"{c}: most_significant_hz, largest S/thr [Hz]" for c in channels],
            ),
        ),
    ]
    out.append(
        (
            VERDICT,
            rr.SeriesLines(
                colors=[_RED] * m + cols + [_GREY] * m + [_RED],
                # the rule's statistic wider than the threshold line: a CUSUM g held at h stays visible
                widths=[1.0] * m + [2.5] * m + [1.0] * (m + 1),
                names=[f"{c}: verdict (1 = fault)" for c in channels]
                + [f"{c}: {alarm_statistic}" for c in channels]
                + [f"{c}: score -log p [nats]" for c in channels]
                + ["alarm threshold h"],
            ),
        )
    )
    for c in channels:
        style = rr.SeriesPoints(colors=[_RED], marker_sizes=[2.5], names=[f"{c}: fault (flagged frame)"])
        out.append((fault_entity(c), style))
        style = rr.SeriesPoints(
            colors=[_RED], marker_sizes=[2.5], names=[f"{c}: most_significant_hz of a flagged frame"]
        )
        out.append((fault_hz_entity(c), style))
    return out


def time_axis(
    span_s: tuple[float, float] | None, history_s: float = 10.0
) -> tuple[VisibleTimeRange, TimeAxis]:
    """The one time axis of a recording's views: the data range every time view queries and the x axis
    it shows, linked across views (zooming one zooms all).

    Parameters
    ----------
    span_s : (float, float) or None
        A file's whole record (s): every view shows exactly this span. None: a live viewer, the last
        ``history_s`` seconds before the time cursor (which follows the incoming data).
    history_s : float
        Seconds of history of a live viewer.

    Returns
    -------
    (VisibleTimeRange, TimeAxis)
        For ``time_ranges=`` and ``axis_x=`` of a ``TimeSeriesView`` (``time_view=`` of a
        ``StateTimelineView``).
    """
    import rerun.blueprint as rrb
    from rerun.blueprint.archetypes import TimeAxis
    from rerun.blueprint.components import LinkAxis
    from rerun.encodings import TimeRange

    if span_s is None:
        start = rrb.TimeRangeBoundary.cursor_relative(seconds=-history_s)
        end = rrb.TimeRangeBoundary.cursor_relative()
    else:
        start = rrb.TimeRangeBoundary.absolute(nanos=round(float(span_s[0]) * 1e9))
        end = rrb.TimeRangeBoundary.absolute(nanos=round(float(span_s[1]) * 1e9))
    return (
        rrb.VisibleTimeRange(TIMELINE, start=start, end=end),
        TimeAxis(link=LinkAxis.Independent, view_range=TimeRange(start, end)),
    )


def time_panel(span_s: tuple[float, float] | None) -> Any:
    """The time panel of a recording's blueprint (collapsed): a live viewer follows the data, a file opens
    paused with its whole record selected.

    Parameters
    ----------
    span_s : (float, float) or None
        A file's whole record (s); None: a live viewer.

    Returns
    -------
    rerun.blueprint.TimePanel
    """
    import rerun.blueprint as rrb
    from rerun.encodings import TimeInt

    if span_s is None:
        return rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="following")
    ns = [TimeInt(nanos=round(float(t) * 1e9)) for t in span_s]
    selection = rrb.components.AbsoluteTimeRange(min=ns[0], max=ns[1])
    return rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="paused", time_selection=selection)


#: Logical pixels of the window the layouts are designed for (1600x1000, menu and time panel excluded).
_WINDOW = (1600.0, 840.0)
#: Pixels of one state lane, of a view's title bar, of an extra row above or below the columns.
_LANE_PX, _TITLE_PX, _ROW_PX = 42.0, 26.0, 100.0
#: The event log's table in Rerun 0.41 at 1600x1000 (logical px, measured on screenshots): from the view's
#: top to its first row (title bar, header), one row, and from the end of the table's visible area to the
#: next view's top (its scroll area's margin and the separator).
_LOG_TOP_PX, _LOG_ROW_PX, _LOG_BOTTOM_PX = 70.0, 20.0, 14.0
#: The height the viewer spreads the row shares over (the shares of _WINDOW[1] come out 11 % taller;
#: measured from view top to view top, the same for the layout's last row down to the time panel).
_REAL_PX = 935.0
#: What the event log's visible area may hold beyond its whole rows: less than the ~6 px from a row's top
#: to its text, so no row shows half of its text (an empty sliver at most).
_LOG_SLACK_PX = 3.0


def _column_shares(alarm: bool, peak: bool = True) -> list[float]:
    shares = [1, 1.5, 1] + ([0.9] if alarm else []) + ([0.8] if peak else [])
    return [float(x) for x in shares]


def plot_heights(columns_px: float, peak: bool) -> tuple[float, float]:
    """Plot heights (logical px at 1600x1000) of the statistic and alarm views in a columns row
    ``columns_px`` high: the view's share less its title bar and the time axis's labels (~16 px)."""
    shares = _column_shares(True, peak)
    each = [columns_px * s / sum(shares) - _TITLE_PX - 16.0 for s in shares]
    return each[2], each[3]


def view_px(n_channels: int) -> float:
    """Width (logical px at 1600x1000) of one channel column's views in the default layout.

    Parameters
    ----------
    n_channels : int
        Channel columns.

    Returns
    -------
    float
    """
    return _WINDOW[0] / max(int(n_channels), 1) - 8.0


def layout_geometry(
    n_channels: int,
    n_lanes: int,
    *,
    alarm: bool = True,
    rows_above: int = 0,
    rows_below: int = 0,
    peak: bool = True,
) -> tuple[list[float], float]:
    """Row heights of the default layout at 1600x1000 and the spectrogram image's world width.

    The lanes row gets ``45 + 42`` px per lane (a lane and its name; every lane visible), each extra
    row 100 px, the channel
    columns the rest; the spectrogram image's width (:func:`~chatterspec.viewer.spectrograms`) is
    its view's aspect ratio there, so that it fills the view.

    Parameters
    ----------
    n_channels : int
        Channel columns.
    n_lanes : int
        State lanes (truth, mode lanes, one per channel).
    alarm : bool
        The columns hold the alarm view.
    rows_above, rows_below : int
        Extra rows above the columns and below the lanes.
    peak : bool
        The columns hold the peak-frequency view.

    Returns
    -------
    (row_shares, image_width)
        Shares (px) of: the rows above, the columns, the lanes, the rows below; the image width
        (its height is 1): the view's width less the colour key (:data:`~chatterspec.online.
        spectrogram_view.KEY_PX`), over the view's height.
    """
    lanes = 45.0 + _LANE_PX * n_lanes
    # the event log beside the lanes: its title, header and whole rows (no half-hidden last row), in the
    # viewer's pixels (the shares are spread over _REAL_PX) and back
    fixed = _LOG_TOP_PX + _LOG_BOTTOM_PX + _LOG_SLACK_PX
    rows = max(math.ceil((lanes * _REAL_PX / _WINDOW[1] - fixed) / _LOG_ROW_PX), 1)
    lanes = (fixed + rows * _LOG_ROW_PX) * _WINDOW[1] / _REAL_PX
    cols = max(_WINDOW[1] - lanes - _ROW_PX * (rows_above + rows_below), 200.0)
    shares = _column_shares(alarm, peak)
    spec_h = max(cols * shares[1] / sum(shares) - _TITLE_PX, 20.0)
    width = (view_px(n_channels) - KEY_PX) / spec_h
    return [_ROW_PX] * rows_above + [cols, lanes] + [_ROW_PX] * rows_below, float(width)


def _symmetric_axis(ranges: list[float | None] | None, i: int) -> Any:
    """``ScalarAxis`` ``[-r, r]`` for channel ``i`` of ``ranges`` (None: auto range)."""
    import rerun.blueprint as rrb

    r = None if ranges is None else ranges[i]
    return None if r is None else rrb.ScalarAxis(range=(-float(r), float(r)))


def blueprint(
    channels: tuple[str, ...],
    *,
    has_truth: bool = False,
    history_s: float = 10.0,
    band_hz: tuple[float, float] | None = None,
    span_s: tuple[float, float] | None = None,
    db_range: tuple[float, float] = (-5.0, 30.0),
    alarm: str | Sequence[str] | None = None,
    alarm_score: bool = False,
    alarm_range: tuple[float, float] | Sequence[tuple[float, float] | None] | None = None,
    statistic_ranges: Sequence[tuple[float, float]] | None = None,
    extra_row: ExtraRow | None = None,
    units: tuple[str, ...] | None = None,
    above: list[Any] | None = None,
    extra_lanes: int = 0,
    lanes_name: str | None = None,
    peak_view: bool = True,
    chattering_range: list[float | None] | None = None,
    psi: bool = True,
    alarm_rule: str | None = None,
) -> Any:
    """The default layout: per channel (columns) chattering, spectrogram, detection statistic and peak
    frequency; below, the state lanes (true fault first, then one verdict lane per channel in channel
    order) and the event log. The time panel is collapsed and legends are hidden (view titles say what
    each colour is), so no plot area is covered.

    Parameters
    ----------
    channels : tuple of str
        Measured channel names, one column of views each.
    has_truth : bool
        Add the true fault timeline lane (simulated data).
    history_s : float
        Live mode (``span_s`` None): seconds of history shown by the time-series views, relative to
        the time cursor (which follows the incoming data).
    band_hz : (float, float), optional
        Frequency band of the spectrogram (Hz), shown in its title.
    span_s : (float, float), optional
        File mode: the time span (s) of the whole record's spectrogram. Every time-series view then
        shows exactly this span (so the spectrogram columns line up with the time axes) and playback
        opens paused on the whole record.
    db_range : (float, float)
        Colour range of the spectrogram (dB re the frame threshold), shown in its title.
    alarm : str or sequence of str, optional
        Title of the alarm view (the rule, its statistic and budget) below the detection statistic:
        channel ``i``'s rule statistic against the threshold (:data:`VERDICT`); several: from the longest
        to the shortest, the longest that fits is used (:func:`fit`); None: no alarm view.
    alarm_score : bool
        Also draw the frame score in the alarm view (when the statistic is not the score itself).
    alarm_range : (float, float) or sequence of them (one per channel), optional
        Fixed y range of the alarm view (:func:`alarm_range`: from ``h`` and, in a file's final blueprint,
        the record's largest value, so that neither the threshold nor the statistic leaves the chart).
    statistic_ranges : sequence of (float, float), optional
        Per channel the statistic view's y range (:func:`statistic_range`); default
        :data:`STATISTIC_RANGE_DB`.
    extra_row : callable, optional
        ``extra_row(time_range, axis, live=...)`` returns views added as a row below the lanes, with the
        time range and the (linked) time axis of the other views (:func:`time_axis`) and whether the
        blueprint is a live viewer's (e.g. the identified parameters,
        :func:`chatterspec.viewer.rerun_log.identification_views`).

    units : tuple of str, optional
        The channels' units, shown in the chattering views' titles.
    above : list of views, optional
        A row of views above the channel columns (e.g. a diagnosis's route statistics).
    extra_lanes : int
        Lanes logged under ``/state`` besides the truth and the channels (e.g. most probable modes):
        the lanes row grows so that every lane stays visible.
    lanes_name : str, optional
        Title of the lanes view.
    peak_view : bool
        Show the peak-frequency view in each column (the viewer keeps a minimum height per view: a
        layout with many lanes leaves it out so that every lane stays visible).
    chattering_range : sequence of (float or None), optional
        Per channel ``r``: the chattering view shows ``[-r, r]`` (output units), so that the viewer
        labels its ticks (auto-ranged, a small amplitude can leave a single "0" tick); None (or a None
        entry): auto range. A file's final blueprint gives it
        (:class:`~chatterspec.viewer.blueprint.ChatteringExtent`).
    psi : bool
        The boundary layer ±psi is drawn (known): the chattering views' titles name it.
    alarm_rule : str, optional
        The alarm rule and budget in a few words (``"cusum, 1 false alarm/24 h"``), for the lanes' title.

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun as rr
    import rerun.blueprint as rrb

    time_range, axis = time_axis(span_s, history_s)
    no_legend = rrb.PlotLegend(visible=False)
    band = "" if band_hz is None else f" {band_hz[0]:g}-{band_hz[1]:g} Hz"
    m = len(channels)

    def only(i: int, k: int = 1, total: int | None = None) -> list[bool]:
        """visible_series of channel i in an entity with k series per channel (channel-major), padded
        with False up to ``total`` series."""
        return [j // k == i for j in range(k * m)] + [False] * ((total or k * m) - k * m)

    n_lanes = len(channels) + (1 if has_truth else 0) + int(extra_lanes)
    row_px, width = layout_geometry(
        m,
        n_lanes,
        alarm=alarm is not None,
        rows_above=1 if above else 0,
        rows_below=1 if extra_row else 0,
        peak=peak_view,
    )

    def unit(i: int) -> str:
        return f" [{units[i]}]" if units and units[i] else ""

    budget = title_chars(m)
    grey = ", grey ±psi" if psi else ""
    alarms = [alarm] if isinstance(alarm, str) else list(alarm or [])
    alarm_axes: list[tuple[float, float] | None]
    if alarm_range is None or isinstance(alarm_range[0], (int, float)):  # one range for every channel
        alarm_axes = [cast("tuple[float, float] | None", alarm_range)] * m
    else:
        alarm_axes = list(cast("Sequence[tuple[float, float] | None]", alarm_range))
    columns = []
    for i, name in enumerate(channels):
        c = _entity(name)
        u = unit(i)
        variants = {  # longest first: fit() keeps the longest that the column's width holds
            "chattering": [f"chattering e(k|k-1){u}{grey}", f"chattering{u}{grey}", f"chattering{u}"],
            "spectrogram": [f"spectrogram{band}, dB re threshold", f"spectrogram{band}, dB", "spectrogram"],
            "statistic": [
                "max S/threshold [dB], red = flagged",
                "max S/thr [dB], red = flagged",
                "max S/thr [dB]",
            ],
            "alarm": alarms or ["alarm"],
            "frequency": [
                "frequency of max S/thr [Hz], red = flagged",
                "peak frequency [Hz], red = flagged",
                "peak frequency [Hz]",
            ],
        }
        title = {k: fit([f"{name}: {v}" for v in vs], budget) for k, vs in variants.items()}
        columns.append(
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin="/chattering",
                    contents=[f"+ {CHATTERING}", f"+ {PSI}"],
                    name=title["chattering"],
                    time_ranges=time_range,
                    axis_x=axis,
                    plot_legend=no_legend,
                    axis_y=_symmetric_axis(chattering_range, i),
                    # hidden series do not enter the auto-scaled y range (checked in the viewer)
                    overrides={
                        # the chattering of channel i only, not the raw series after it
                        CHATTERING: rr.SeriesLines.from_fields(
                            visible_series=only(i, total=SAMPLE_SERIES_PER_CHANNEL * m)
                        ),
                        PSI: rr.SeriesLines.from_fields(visible_series=only(i, 2)),
                    },
                ),
                spectrogram_view(
                    f"/spectrogram/{c}",
                    title["spectrogram"],
                    width,
                    key_width(width, view_px(m)),
                ),
                rrb.TimeSeriesView(
                    origin="/detection",
                    contents=[f"+ {STATISTIC}", f"+ {THRESHOLD}", f"+ {fault_entity(name)}"],
                    name=title["statistic"],
                    time_ranges=time_range,
                    axis_x=axis,
                    axis_y=rrb.ScalarAxis(
                        range=STATISTIC_RANGE_DB if statistic_ranges is None else statistic_ranges[i]
                    ),
                    plot_legend=no_legend,
                    overrides={STATISTIC: rr.SeriesLines.from_fields(visible_series=only(i))},
                ),
                *(
                    []
                    if alarm is None
                    else [
                        rrb.TimeSeriesView(
                            origin="/alarm",
                            contents=[f"+ {VERDICT}"],
                            name=title["alarm"],
                            time_ranges=time_range,
                            axis_x=axis,
                            plot_legend=no_legend,
                            axis_y=None if alarm_axes[i] is None else rrb.ScalarAxis(range=alarm_axes[i]),
                            overrides={
                                VERDICT: rr.SeriesLines.from_fields(
                                    visible_series=[
                                        j == m + i or (alarm_score and j == 2 * m + i) or j == 3 * m
                                        for j in range(3 * m + 1)
                                    ]
                                )
                            },
                        )
                    ]
                ),
                *(
                    []
                    if not peak_view
                    else [
                        rrb.TimeSeriesView(
                            origin="/frequency",
                            contents=[
                                f"+ {PEAK_HZ}",
                                f"+ {MOST_SIGNIFICANT_HZ}",
                                f"+ {fault_hz_entity(name)}",
                            ],
                            name=title["frequency"],
                            time_ranges=time_range,
                            axis_x=axis,
                            plot_legend=no_legend,
                            overrides={
                                PEAK_HZ: rr.SeriesLines.from_fields(visible_series=only(i)),
                                MOST_SIGNIFICANT_HZ: rr.SeriesPoints.from_fields(visible_series=only(i)),
                            },
                            axis_y=None
                            if band_hz is None
                            else rrb.ScalarAxis(range=(-0.1 * float(band_hz[1]), 1.05 * float(band_hz[1]))),
                        ),
                    ]
                ),
                row_shares=_column_shares(alarm is not None, peak_view),
            )
        )
    extra = [] if extra_row is None else [rrb.Horizontal(*extra_row(time_range, axis, live=span_s is None))]
    top = [rrb.Horizontal(*above)] if above else []
    what = f"fault state per channel ({alarm_rule or 'alarm rule'}; grey = no evidence)"
    default_name = f"true fault (top); {what}" if has_truth else what
    return rrb.Blueprint(
        rrb.Vertical(
            *top,
            rrb.Horizontal(*columns),
            rrb.Horizontal(
                rrb.StateTimelineView(
                    origin="/state",
                    name=lanes_name or default_name,
                    time_ranges=time_range,
                    time_view=axis,
                ),
                event_log_view(),
                column_shares=[1.4, 1],
            ),
            *extra,
            # pixels at 1600x1000 (layout_geometry): every lane visible
            row_shares=row_px,
        ),
        time_panel(span_s),
        collapse_panels=True,
    )


# -------------------------------------------------------------------- the chattering views' y range

#: Quantile of ``|e(k|k-1)|`` taken per batch: a handful of samples (the filters' start, a glitch)
#: cannot set the range, a fault that lasts a fraction of a batch (20 s of 1 kHz data) still does.
QUANTILE = 0.999
#: Every STRIDE-th sample of a batch enters its quantile (5 000 of a 20 000-sample file batch): the
#: quantile of a 60 000-value batch cost ~0.6 ms, 13 % of a file's logging time
#: (``benchmarks/bench_monitor.py --cases d``); a quarter of it stays robust (the 5 largest of 5 000 are
#: ignored) and a fault lasting a second still holds ~250 of them.
STRIDE = 4
#: Headroom above the extent, so that the largest values and the ±psi lines are not drawn on the frame.
MARGIN = 1.15


def labelled_half_range(a: float) -> float:
    """``1.1 p`` for the smallest power of ten ``p`` with ``1.1 p >= a > 0``: a symmetric range whose
    ``±p`` grid lines the viewer labels (see the module docstring).

    Parameters
    ----------
    a : float
        Half-height the range must hold (> 0, output units).

    Returns
    -------
    float
    """
    p = 10.0 ** math.ceil(math.log10(a / 1.1) - 1e-12)
    return 1.1 * p


class ChatteringExtent:
    """Running robust extent of the chattering per channel, in bounded memory.

    Each batch of samples contributes its :data:`QUANTILE` of ``|e|`` per channel (over every
    :data:`STRIDE`-th sample of a batch of at least ``100 STRIDE`` samples); the extent is the largest
    of these over the record (so a fault late in a long record widens it).

    Parameters
    ----------
    n_channels : int
    """

    def __init__(self, n_channels: int) -> None:
        self._max = np.zeros(int(n_channels))
        self.n_samples = 0

    def add(self, chattering: np.ndarray) -> None:
        """Take one batch ``(samples, channels)`` of chattering ``e(k|k-1)`` (output units)."""
        e = np.asarray(chattering, dtype=float)
        n = e.shape[0]
        if n == 0:
            return
        a = np.abs(e[:: STRIDE if n >= 100 * STRIDE else 1])
        # np.quantile (one partition of every column) gives nanquantile's numbers where a column has no
        # NaN, in a third of its time (nanquantile goes column by column); a NaN makes its column's
        # quantile NaN, and only such batches take nanquantile
        q = np.quantile(a, QUANTILE, axis=0) if a.shape[0] > 1 else a[0]
        if np.isnan(q).any():
            with np.errstate(invalid="ignore"):
                q = np.nanquantile(a, QUANTILE, axis=0)
        np.fmax(self._max, q, out=self._max)
        self.n_samples += e.shape[0]

    def ranges(self, psi: Sequence[float] | None = None) -> list[float | None] | None:
        """Per channel the half-height ``r`` of the symmetric range ``[-r, r]``: :func:`labelled_half_range`
        of :data:`MARGIN` times the larger of the extent and the boundary layer ``psi`` (so that the ±psi
        lines are in view); a channel without any finite non-zero value gets None (auto range). None before
        any sample.

        Parameters
        ----------
        psi : sequence of float, optional
            The SVSF boundary layer per channel (output units).

        Returns
        -------
        list of (float or None), or None
        """
        if self.n_samples == 0:
            return None
        r = self._max.copy()
        if psi is not None:
            r = np.fmax(r, np.abs(np.asarray(psi, dtype=float)))
        return [labelled_half_range(MARGIN * float(x)) if np.isfinite(x) and x > 0 else None for x in r]


# ---------------------------------------------------------------- the layout of a monitor recording


class MonitorLayout:
    """Geometry and default blueprint of one monitor's recording.

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives channels, units and the alarm rule.
    has_truth : bool
        The recording has a true fault lane.
    extra_row : callable or None
        Views below the default layout.
    extra_lanes, rows_above : int
        Lanes under ``/state`` and rows above the columns that the caller's layout adds.
    peak_view : bool
        The layout shows the peak-frequency views (unless there is an extra row).
    budget_per_hour : float, optional
        The budget the rule's threshold was set for when the settings do not carry it (a diagnosis
        calibrates its routes itself), alarm starts per hour; None: the settings'.

    Attributes
    ----------
    width, key : int
        The spectrogram image's width and its colour key's width (pixels).
    cusum : bool
        The alarm rule is CUSUM (its view draws g; else the score itself).
    """

    def __init__(
        self,
        monitor: ChatteringMonitor,
        *,
        has_truth: bool,
        extra_row: ExtraRow | None,
        extra_lanes: int,
        rows_above: int,
        peak_view: bool,
        budget_per_hour: float | None = None,
    ) -> None:
        self.monitor = monitor
        self.has_truth, self.extra_lanes, self.rows_above = bool(has_truth), int(extra_lanes), int(rows_above)
        # the peak-frequency views give way to an extra row (the viewer keeps a minimum height per view)
        self.extra_row, self.peak_view = extra_row, bool(peak_view) and extra_row is None
        m = len(monitor.channels)
        n_lanes = m + self.has_truth + self.extra_lanes
        rows, self.width = layout_geometry(
            m,
            n_lanes,
            alarm=True,
            rows_above=self.rows_above,
            rows_below=1 if extra_row else 0,
            peak=self.peak_view,
        )
        # the plot heights (logical px) of the statistic and alarm views: their ranges keep labelled ticks
        self.statistic_px, self.alarm_px = plot_heights(rows[self.rows_above], self.peak_view)
        self.key = key_width(self.width, view_px(m))  # the colour key: as wide as a time view's labels
        rule = monitor.rule
        self.budget_per_hour = budget_per_hour
        self.cusum = rule_spec(rule).accumulates  # the alarm view draws the rule's statistic
        self.h = float(rule.threshold) if np.isfinite(rule.threshold) else np.nan

    def blueprint(
        self,
        *,
        band_hz: tuple[float, float],
        span_s: tuple[float, float] | None,
        has_truth: bool | None = None,
        extra_row: ExtraRow | None = None,
        above: list[Any] | None = None,
        lanes_name: str | None = None,
        chattering_range: list[float | None] | None = None,
        largest: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> Any:
        """The default :func:`~chatterspec.viewer.blueprint.blueprint` of the recording (band, alarm view,
        units, and the geometry given to the constructor).

        Parameters
        ----------
        band_hz : (float, float)
            The spectrogram's band (Hz).
        span_s : (float, float) or None
            A file's whole record (s); None for a live viewer (follows the data).
        has_truth : bool, optional
            Draw the true fault lane (default: the constructor's ``has_truth``).
        extra_row : callable, optional
            See :func:`~chatterspec.viewer.blueprint.blueprint` (default: the constructor's).
        above : list of views, optional
            A row above the channel columns (the constructor's ``rows_above`` must be 1).
        lanes_name : str, optional
            Title of the lanes view.
        chattering_range : sequence of float, optional
            Per channel the half-height of the chattering view's symmetric y range (output units).
        largest : (ndarray, ndarray), optional
            Per channel the record's largest statistic (dB) and alarm-view value: the statistic and alarm
            views' y ranges hold them (:func:`~chatterspec.viewer.blueprint.statistic_range`,
            :func:`~chatterspec.viewer.blueprint.alarm_range`); None: the default ranges (a live viewer).
        """
        m = len(self.monitor.channels)
        if largest is None:
            largest = (np.full(m, -np.inf), np.full(m, -np.inf))
        stat_ranges = [statistic_range(float(x), self.statistic_px) for x in largest[0]]
        alarm_ranges = [alarm_range(self.h, float(x), self.alarm_px) for x in largest[1]]
        assert stat_ranges is None or len(stat_ranges) == m
        return blueprint(
            self.monitor.channels,
            has_truth=self.has_truth if has_truth is None else has_truth,
            band_hz=band_hz,
            span_s=span_s,
            db_range=DB_RANGE,
            alarm=self.alarm_title(),
            alarm_score=False,  # CUSUM: g and h only (the frame score, up to thousands of nats, hid them)
            alarm_range=alarm_ranges,
            statistic_ranges=stat_ranges,
            extra_row=extra_row if extra_row is not None else self.extra_row,
            units=tuple(self.monitor.model.output_units),
            above=above,
            extra_lanes=self.extra_lanes,
            lanes_name=lanes_name,
            peak_view=self.peak_view,
            chattering_range=chattering_range,
            psi=self.monitor.settings.psi is not None,
            alarm_rule=self.budget_words(),
        )

    def alarm_title(self) -> list[str]:
        """The alarm view's title, longest first (:func:`~chatterspec.viewer.blueprint.fit` picks the one
        that fits): the rule's statistic against its threshold (nats) and the budget."""
        rule = self.monitor.rule
        what = rule.view_label()
        h = f"{rule.threshold:.3g}"
        return [
            f"{what} vs h = {h} nats, {self.budget_words(rule=False)}",
            f"{what} vs h = {h} nats",
            f"{what}, h = {h}",
        ]

    def budget_words(self, *, rule: bool = True) -> str:
        """``"cusum, 1 false alarm/24 h"`` (``rule`` False: the budget only; ``per-frame alpha`` without
        one)."""
        budget = self.monitor.settings.false_alarms_per_hour
        if budget is None:
            budget = self.budget_per_hour
        if budget is None:
            per = "per-frame alpha"
        else:
            x = float(budget)
            per = f"1 false alarm/{1 / x:.3g} h" if x < 1 else f"{x:.3g} false alarms/h"
        return f"{self.monitor.rule.name}, {per}" if rule else per


# ------------------------------------------------------- the static entities of a monitor recording


def expected_spectrum(monitor: ChatteringMonitor) -> np.ndarray:
    """(bins, m) expected frame spectrum of ``monitor``'s healthy chattering: the model's
    (:func:`~chatterspec.detection.spectral.expected_frame_spectrum`), or for a nonlinear model the
    calibrated threshold's empirical normalization."""
    thr = monitor.threshold
    if not is_linear(monitor.model):
        return np.asarray(thr.expected)
    return expected_frame_spectrum(monitor.model, monitor.freqs_hz, monitor.settings.stft, monitor.dt)


def log_static(
    streams: list[Any],
    monitor: ChatteringMonitor,
    *,
    channels: Sequence[str],
    keys: Sequence[str],
    lanes: list[str],
    lane_configs: list[StateConfiguration],
    expected: np.ndarray,
    band_hz: tuple[float, float],
    hop_s: float,
    width: float,
    key: float,
    cusum: bool,
    spectrum: Callable[[np.ndarray], Any],
) -> None:
    """Log the static entities of a monitor recording to every stream of ``streams``.

    Parameters
    ----------
    streams : list of RecordingStream
    monitor : ChatteringMonitor
        Gives frequencies (Hz), threshold, units and the boundary layer.
    channels, keys, lanes : list of str
        Per channel: name, entity key and fault-state lane entity.
    lane_configs : list of rerun.StateConfiguration
        Per channel: the lane's states and labels (:meth:`~chatterspec.viewer.events.FaultLanes.
        configuration`).
    expected : ndarray, shape (bins, m)
        Expected frame spectrum, logged as ``/expected/<c>``.
    band_hz : (float, float)
        The spectrogram's band (Hz).
    hop_s : float
        Hop between frames (s).
    width, key : int
        The spectrogram image's width and its colour key's width (pixels,
        :func:`~chatterspec.viewer.spectrograms.log_axes`).
    cusum : bool
        The alarm rule is CUSUM (its view draws g; else the score).
    spectrum : callable
        The static components of one spectrum, shape (bins,): a ``Tensor`` with dim ``freq`` (the
        logger's column builder, :class:`~chatterspec.viewer.rerun_log.RerunLogger`).
    """
    import rerun as rr

    thr = monitor.threshold
    freqs = monitor.freqs_hz
    lo, hi = band_hz
    styles = series_styles(
        channels,
        monitor.model.output_units,
        has_estimate=monitor.settings.psi is not None,
        alarm_statistic="CUSUM g [nats]" if cusum else "score -log p [nats]",
    )
    df = float(freqs[1] - freqs[0])
    note = rr.TextDocument(
        f"Spectra: {len(freqs)} bins, 0 .. {freqs[-1]:g} Hz "
        f"(step {freqs[1]:g} Hz); spectrogram {lo:g}-{hi:g} Hz, hop "
        f"{hop_s:g} s, dB re threshold in [{DB_RANGE[0]:g}, {DB_RANGE[1]:g}]. "
        f"{thr.describe()}"
    )
    for s in streams:
        for path, style in styles:
            s.log(path, style, static=True)
        for i, c in enumerate(keys):
            log_axes(s, f"/spectrogram/{c}", band_hz, df, DB_RANGE, width, key)
            s.log(f"/threshold/{c}", spectrum(thr.values[:, i]), static=True)
            s.log(f"/expected/{c}", spectrum(expected[:, i]), static=True)
            s.log(lanes[i], lane_configs[i], static=True)
        s.log("/frequencies", note, static=True)
