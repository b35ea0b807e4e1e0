"""Default Rerun blueprint of a chatterspec recording."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .viewer import TIMELINE

if TYPE_CHECKING:
    pass

__all__ = [
    "ALARM",
    "CHATTERING",
    "MOST_SIGNIFICANT_HZ",
    "PEAK_HZ",
    "PSI",
    "SAMPLE_SERIES_PER_CHANNEL",
    "STATISTIC",
    "THRESHOLD",
    "VERDICT",
    "blueprint",
    "fault_entity",
    "lane_entity",
    "series_styles",
]

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
#: per channel (``2m .. 3m-1``; see chatterspec.detection.frame_score) and the rule's threshold ``h``
#: (``3m``). The alarm series share the verdict's rows: Rerun's cost is per row.
VERDICT = "/detection/verdict"
#: Tested bin with the largest excess power ``S - E`` per channel (Hz), one row per frame.
PEAK_HZ = "/frequency/peak_hz"
#: Tested bin with the largest ``S / threshold`` per channel (Hz), one row per frame.
MOST_SIGNIFICANT_HZ = "/frequency/most_significant_hz"
#: The alarm series live in the rows of :data:`VERDICT` (series ``m .. 3m``).
ALARM = VERDICT


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


_COLORS = [[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189]]
_GREY, _RED, _WHITE = [150, 150, 150], [230, 40, 40], [235, 235, 235]


def series_styles(
    channels: tuple[str, ...],
    units: tuple[str, ...],
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
                colors=cols, widths=[1.0] * m, names=[f"{c}: peak_hz, largest S-E [Hz]" for c in channels]
            ),
        ),
        (
            MOST_SIGNIFICANT_HZ,
            rr.SeriesPoints(
                colors=[_WHITE] * m,
                marker_sizes=[1.5] * m,
                names=[f"{c}: most_significant_hz, largest S/thr [Hz]" for c in channels],
            ),
        ),
    ]
    out.append(
        (
            VERDICT,
            rr.SeriesLines(
                colors=[_RED] * m + cols + [_GREY] * m + [_RED],
                widths=[1.0] * m + [1.5] * m + [1.0] * (m + 1),
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
    return out


def blueprint(
    channels: tuple[str, ...],
    *,
    has_truth: bool = False,
    history_s: float = 10.0,
    band_hz: tuple[float, float] | None = None,
    span_s: tuple[float, float] | None = None,
    db_range: tuple[float, float] = (-5.0, 30.0),
    alarm: str | None = None,
    alarm_score: bool = False,
    alarm_range: tuple[float, float] | None = None,
    extra_row: Any = None,
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
    alarm : str, optional
        Title of the alarm view (the rule, its statistic and budget) below the detection statistic:
        channel ``i``'s rule statistic against the threshold (:data:`VERDICT`); None: no alarm view.
    alarm_score : bool
        Also draw the frame score in the alarm view (when the statistic is not the score itself).
    alarm_range : (float, float), optional
        Fixed y range of the alarm view (a fault's score, thousands of nats, would otherwise hide the
        threshold and the CUSUM ``g``, which is capped at it).
    extra_row : callable, optional
        ``extra_row(time_range)`` returns views added as a row below the lanes, with the time range
        of the other views (e.g. the identified parameters,
        :func:`chatterspec.online.identification_log.identification_views`).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun as rr
    import rerun.blueprint as rrb
    from rerun.encodings import AbsoluteTimeRange, TimeInt

    if span_s is None:
        time_range = rrb.VisibleTimeRange(
            TIMELINE,
            start=rrb.TimeRangeBoundary.cursor_relative(seconds=-history_s),
            end=rrb.TimeRangeBoundary.cursor_relative(),
        )
    else:
        time_range = rrb.VisibleTimeRange(
            TIMELINE,
            start=rrb.TimeRangeBoundary.absolute(nanos=round(float(span_s[0]) * 1e9)),
            end=rrb.TimeRangeBoundary.absolute(nanos=round(float(span_s[1]) * 1e9)),
        )
    no_legend = rrb.PlotLegend(visible=False)
    band = "" if band_hz is None else f" {band_hz[0]:g}-{band_hz[1]:g} Hz"
    m = len(channels)

    def only(i: int, k: int = 1, total: int | None = None) -> list[bool]:
        """visible_series of channel i in an entity with k series per channel (channel-major), padded
        with False up to ``total`` series."""
        return [j // k == i for j in range(k * m)] + [False] * ((total or k * m) - k * m)

    columns = []
    for i, name in enumerate(channels):
        c = _entity(name)
        columns.append(
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin="/chattering",
                    contents=[f"+ {CHATTERING}", f"+ {PSI}"],
                    name=f"{name}: chattering e(k|k-1), grey ±psi",
                    time_ranges=time_range,
                    plot_legend=no_legend,
                    # hidden series do not enter the auto-scaled y range (checked in the viewer)
                    overrides={
                        # the chattering of channel i only, not the raw series after it
                        CHATTERING: rr.SeriesLines.from_fields(
                            visible_series=only(i, total=SAMPLE_SERIES_PER_CHANNEL * m)
                        ),
                        PSI: rr.SeriesLines.from_fields(visible_series=only(i, 2)),
                    },
                ),
                rrb.TensorView(
                    origin=f"/spectrogram/{c}",
                    name=f"{name}: spectrogram{band}, dB re threshold [{db_range[0]:g}, {db_range[1]:g}]",
                    slice_selection=rrb.TensorSliceSelection(
                        width=rr.components.TensorWidthDimension(dimension=1),
                        height=rr.components.TensorHeightDimension(dimension=0, invert=True),
                    ),
                    scalar_mapping=rrb.TensorScalarMapping(colormap="magma"),
                    view_fit="Fill",
                ),
                rrb.TimeSeriesView(
                    origin="/detection",
                    contents=[f"+ {STATISTIC}", f"+ {THRESHOLD}", f"+ {fault_entity(name)}"],
                    name=f"{name}: max S/threshold [dB], 0 dB = threshold, red = fault",
                    time_ranges=time_range,
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
                            name=f"{name}: {alarm}",
                            time_ranges=time_range,
                            plot_legend=no_legend,
                            axis_y=None if alarm_range is None else rrb.ScalarAxis(range=alarm_range),
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
                rrb.TimeSeriesView(
                    origin="/frequency",
                    contents=[f"+ {PEAK_HZ}", f"+ {MOST_SIGNIFICANT_HZ}"],
                    name=f"{name}: peak frequency [Hz], dots = most significant",
                    time_ranges=time_range,
                    plot_legend=no_legend,
                    overrides={
                        PEAK_HZ: rr.SeriesLines.from_fields(visible_series=only(i)),
                        MOST_SIGNIFICANT_HZ: rr.SeriesPoints.from_fields(visible_series=only(i)),
                    },
                    axis_y=None if band_hz is None else rrb.ScalarAxis(range=(0.0, float(band_hz[1]))),
                ),
                row_shares=[1, 1.5, 1, 0.8] if alarm is None else [1, 1.5, 1, 0.9, 0.8],
            )
        )
    n_lanes = len(channels) + (1 if has_truth else 0)
    time_panel = (
        rrb.TimePanel(state="collapsed", timeline=TIMELINE)
        if span_s is None
        else rrb.TimePanel(
            state="collapsed",
            timeline=TIMELINE,
            play_state="paused",
            time_selection=AbsoluteTimeRange(
                min=TimeInt(nanos=round(float(span_s[0]) * 1e9)),
                max=TimeInt(nanos=round(float(span_s[1]) * 1e9)),
            ),
        )
    )
    extra = [] if extra_row is None else [rrb.Horizontal(*extra_row(time_range))]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*columns),
            rrb.Horizontal(
                rrb.StateTimelineView(
                    origin="/state",
                    name="true fault (top) and verdict per channel" if has_truth else "verdict per channel",
                    time_ranges=time_range,
                ),
                rrb.TextLogView(origin="/events", name="detection events"),
                column_shares=[2, 1],
            ),
            *extra,
            # about 45 px per lane at 1000 px: every lane visible at 1600x1000
            # the extra row (identified parameters) takes its height from the views above
            row_shares=[4.4 if extra else 5.2, 0.55 + 0.25 * n_lanes] + ([1.3] if extra else []),
        ),
        time_panel,
        collapse_panels=True,
    )
