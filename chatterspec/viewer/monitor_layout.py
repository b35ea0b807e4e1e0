"""The layout of a monitor recording (:class:`MonitorLayout`): its geometry and its default blueprint.

What :class:`~chatterspec.viewer.rerun_log.RerunLogger` delegates for the look of a recording: the
spectrogram image's width (it fills its view at 1600x1000, :func:`~chatterspec.viewer.blueprint.
layout_geometry`) and the blueprint with the band, the alarm view and the units.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarms.rules import rule_spec
from ..online.monitor import ChatteringMonitor
from .blueprint import alarm_range, blueprint, layout_geometry, plot_heights, statistic_range, view_px
from .record_geometry import DB_RANGE
from .spectrogram_view import key_width

if TYPE_CHECKING:  # pragma: no cover
    from .blueprint import ExtraRow

__all__ = ["MonitorLayout"]


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
