"""The layout of a monitor recording (:class:`MonitorLayout`): its geometry and its default blueprint.

What :class:`~chatterspec.viewer.rerun_log.RerunLogger` delegates for the look of a recording: the
spectrogram image's width (it fills its view at 1600x1000, :func:`~chatterspec.viewer.blueprint.
layout_geometry`) and the blueprint with the band, the alarm view and the units.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.alarm_rules import rule_spec
from ..online.monitor import ChatteringMonitor
from .blueprint import blueprint, layout_geometry, view_px
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
        The layout shows the peak-frequency views.

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
    ) -> None:
        self.monitor = monitor
        self.has_truth, self.extra_lanes, self.rows_above = bool(has_truth), int(extra_lanes), int(rows_above)
        self.extra_row, self.peak_view = extra_row, bool(peak_view)
        m = len(monitor.channels)
        n_lanes = m + self.has_truth + self.extra_lanes
        self.width = layout_geometry(
            m,
            n_lanes,
            alarm=True,
            rows_above=self.rows_above,
            rows_below=1 if extra_row else 0,
            peak=self.peak_view,
        )[1]
        self.key = key_width(self.width, view_px(m))  # the colour key: as wide as a time view's labels
        rule = monitor.rule
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
        """
        return blueprint(
            self.monitor.channels,
            has_truth=self.has_truth if has_truth is None else has_truth,
            band_hz=band_hz,
            span_s=span_s,
            db_range=DB_RANGE,
            alarm=self.alarm_title(),
            alarm_score=self.cusum,
            alarm_range=(0.0, 1.5 * self.h) if self.h > 0 else None,
            extra_row=extra_row if extra_row is not None else self.extra_row,
            units=tuple(self.monitor.model.output_units),
            above=above,
            extra_lanes=self.extra_lanes,
            lanes_name=lanes_name,
            peak_view=self.peak_view,
            chattering_range=chattering_range,
        )

    def alarm_title(self) -> str:
        """The alarm view's title: the rule's statistic against its threshold, and the budget."""
        from ..detection.alarm_rules import alarm_label

        rule, budget = self.monitor.rule, self.monitor.settings.false_alarms_per_hour
        what = rule.view_label()
        label = alarm_label(rule.name, budget).split(", ", 1)[1]
        grey = ", grey = score" if self.cusum else ""
        return f"{what} vs h = {rule.threshold:.3g} [nats] ({label}){grey}"
