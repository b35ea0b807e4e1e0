"""Fault identification in a Rerun recording: estimates, tolerance bands, detectability and states per hop.

Entities (time on the monitor's ``time`` timeline, one row per hop, integer nanoseconds as in
:mod:`chatterspec.viewer.rerun_log`):

``/identification/<parameter>``
    five series per row: the joint estimate of the parameter (every declared parameter fitted at
    once: the plant's value), its interval's low and high end, and the tolerance band's low and
    high end (the nominal value twice without a tolerance);
``/identification/detectable/<parameter>``
    the detectable change over the last few seconds divided by the limit above which the parameter
    is not excited (:mod:`chatterspec.detection.parameter_decision`): above 1, not excited;
``/state/p<k>_<parameter>``
    the parameter's lane: healthy, fault or not excited (below the channels' verdict lanes);
``/identification/fault``
    a text log line when the fault named changes (only while an alarm is active) and when a
    parameter stops or starts being excited.

:func:`identification_views` gives the views shown below the monitor's default layout (one per
parameter, and the detectability).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.identification_results import format_with_error
from ..detection.parameter_decision import STATES
from ..palette import FAULT, HEALTHY, NOT_EXCITED, rgba32
from .arrow_columns import _TimeIndex
from .blueprint import _entity
from .record_geometry import to_ns
from .sinks import Sinks

if TYPE_CHECKING:  # pragma: no cover
    from rerun.blueprint import VisibleTimeRange
    from rerun.blueprint.archetypes import TimeAxis

__all__ = ["IDENTIFICATION", "IdentificationLog", "identification_views", "parameter_lane_entity"]

#: Root entity of the identification series.
IDENTIFICATION = "/identification"


def _path(parameter: str) -> str:
    return f"{IDENTIFICATION}/{parameter}"


def parameter_lane_entity(index: int, name: str) -> str:
    """``/state/p<index + 1>_<name>``: the lane of parameter ``index`` (sorts below the channels' lanes)."""
    return f"/state/p{index + 1}_{_entity(name)}"


def identification_views(monitor: Any) -> Any:
    """``make(time_range, axis) -> views``: one time-series view per parameter (estimate, interval,
    tolerance band), the detectability view and the log of the faults named, for
    :func:`chatterspec.viewer.blueprint.blueprint`'s ``extra_row``.

    Parameters
    ----------
    monitor : IdentificationMonitor
        Gives the parameters, their units and the intervals' level.
    """
    bands = monitor.settings.bands
    confidence = monitor.identifier.confidence
    horizon = monitor.settings.horizon_hops * monitor.settings.hop_s

    def make(time_range: VisibleTimeRange, axis: TimeAxis | None = None) -> list[Any]:
        import rerun.blueprint as rrb

        views: list[Any] = []  # rerun blueprint views
        for p, unit in zip(bands.names, bands.units, strict=True):
            views.append(
                rrb.TimeSeriesView(
                    origin=_path(p),
                    name=f"{p}" + (f" [{unit}]" if unit else "") + f", {confidence:.0%} interval, tolerance",
                    time_ranges=time_range,
                    axis_x=axis,
                    plot_legend=rrb.PlotLegend(visible=False),
                )
            )
        views.append(
            rrb.TimeSeriesView(
                origin=f"{IDENTIFICATION}/detectable",
                name=f"detectable change ({horizon:g} s) / tolerance: > 1 not excited",
                time_ranges=time_range,
                axis_x=axis,
            )
        )
        views.append(rrb.TextLogView(origin=f"{IDENTIFICATION}/fault", name="fault named, excitation"))
        return views

    return make


class IdentificationLog:
    """Sends :class:`~chatterspec.online.identification_monitor.IdentificationUpdate` results to the sinks.

    Parameters
    ----------
    sinks : Sinks
        The monitor's open sinks (file and / or live viewer).
    monitor : IdentificationMonitor
    """

    def __init__(self, sinks: Sinks, monitor: Any) -> None:
        import pyarrow as pa
        import rerun as rr

        self.rr, self.pa, self.sinks, self.monitor = rr, pa, sinks, monitor
        self.bands = monitor.settings.bands
        self.parameters = list(self.bands.names)
        self.lanes = [parameter_lane_entity(i, p) for i, p in enumerate(self.parameters)]
        self._label: str | None = None
        self._states: tuple[str, ...] | None = None
        colors = np.array([rgba32(HEALTHY), rgba32(FAULT), rgba32(NOT_EXCITED)], dtype=np.uint32)
        for s in sinks.streams:
            for p, lane in zip(self.parameters, self.lanes, strict=True):
                s.log(
                    _path(p),
                    rr.SeriesLines(
                        names=["estimate", "interval low", "interval high", "band low", "band high"],
                        colors=[
                            [255, 200, 60],
                            [150, 150, 150],
                            [150, 150, 150],
                            [80, 160, 220],
                            [80, 160, 220],
                        ],
                        widths=[2.0, 1.0, 1.0, 1.5, 1.5],
                    ),
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

    def log(self, upd: Any) -> None:
        """Log the windows of one push."""
        blk = upd.block
        W = blk.n_windows
        if W == 0 or not self.sinks.streams:
            return
        rr, pa = self.rr, self.pa
        ns = to_ns(blk.times_s)
        b = self.bands
        texts, t_text = [], []
        changes: dict[int, tuple[list[int], list[str]]] = {i: ([], []) for i in range(b.size)}
        for w in upd.windows:
            if w.label != self._label:
                texts.append(self._label_text(w, blk))
                t_text.append(ns[w.index])
            for i, st in enumerate(w.states):
                if self._states is None or st != self._states[i]:
                    changes[i][0].append(w.index)
                    changes[i][1].append(st)
                    if self._states is not None and "not-excited" in (st, self._states[i]):
                        what = "not excited" if st == "not-excited" else "excited"
                        texts.append(f"{b.names[i]} {what}")
                        t_text.append(ns[w.index])
            self._label, self._states = w.label, w.states
        ratio = blk.detectable / b.limit[None, :]
        idx = [_TimeIndex(pa, ns)]
        for i, p in enumerate(self.parameters):
            rows = np.stack(
                [
                    blk.estimate[:, i],
                    blk.ci_low[:, i],
                    blk.ci_high[:, i],
                    np.full(W, b.low[i]),
                    np.full(W, b.high[i]),
                ],
                axis=1,
            )
            r = np.where(np.isfinite(ratio[:, i]), ratio[:, i], np.nan)
            k, states = changes[i]
            for s in self.sinks.streams:
                col = rr.Scalars.columns(scalars=rows.ravel()).partition([5] * W)
                s.send_columns(_path(p), indexes=idx, columns=col)
                s.send_columns(
                    f"{IDENTIFICATION}/detectable/{p}", indexes=idx, columns=rr.Scalars.columns(scalars=r)
                )
                if k:
                    s.send_columns(
                        self.lanes[i],
                        indexes=[_TimeIndex(pa, ns[k])],
                        columns=rr.StateChange.columns(state=states),
                    )
        if texts:
            for s in self.sinks.streams:
                s.send_columns(
                    f"{IDENTIFICATION}/fault",
                    indexes=[_TimeIndex(pa, np.asarray(t_text, dtype=np.int64))],
                    columns=rr.TextLog.columns(text=texts, level=["INFO"] * len(texts)),
                )

    def _label_text(self, w: Any, blk: Any) -> str:
        if w.label is None:
            return "alarm over"
        b = self.bands
        j = w.index
        what = "; ".join(
            f"{p} = {format_with_error(blk.estimate[j, i], blk.std_error[j, i])} "
            f"[{format_with_error(blk.ci_low[j, i], blk.std_error[j, i])}, "
            f"{format_with_error(blk.ci_high[j, i], blk.std_error[j, i])}]"
            + (f" {b.units[i]}" if b.units[i] else "")
            for i, p in enumerate(b.names)
            if p in w.label.split("+")
        )
        return f"fault named: {w.label}" + (f": {what}" if what else "")
