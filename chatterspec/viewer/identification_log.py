"""Fault identification in a Rerun recording: estimate and interval per hop, selected hypothesis.

Entities (time on the monitor's ``time`` timeline, one row per hop, integer nanoseconds as in
:mod:`chatterspec.viewer.rerun_log`):

``/identification/<parameter>``
    three series per row: the estimate (the plant's value) and the interval's low and high end,
    of the hypothesis selected in that window when it contains the parameter (NaN otherwise, a
    gap in the plot);
``/identification/selected``
    a text log line whenever the selected hypothesis changes (with the estimate).

:func:`identification_views` gives the views shown below the monitor's default layout (one per
parameter).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..detection.identification_online import OnlineIdentification
from ..detection.identification_results import format_with_error
from ..plants.parameters import NO_FAULT
from .arrow_columns import _TimeIndex
from .record_geometry import to_ns
from .sinks import Sinks

__all__ = ["IDENTIFICATION", "IdentificationLog", "identification_views"]

#: Root entity of the identification series.
IDENTIFICATION = "/identification"


def _path(parameter: str) -> str:
    return f"{IDENTIFICATION}/{parameter}"


def identification_views(setup: Any, confidence: float) -> Any:
    """``make(time_range, axis) -> views``: one time-series view per identified parameter (estimate and
    interval of the selected hypothesis) and the log of the selected hypothesis, for
    :func:`chatterspec.viewer.blueprint.blueprint`'s ``extra_row``.

    Parameters
    ----------
    setup : IdentificationSetup
        Gives the parameters (and their units) of the hypotheses tested.
    confidence : float
        Level of the logged intervals (shown in the view titles).
    """
    pm = setup.parameter_map
    used = [p for p in pm.parameter_names if any(p in h.parameters for h in setup.hypotheses)]

    def make(time_range: Any, axis: Any = None) -> list[Any]:
        import rerun.blueprint as rrb

        views = []
        for p in used:
            unit = pm.parameter(p).unit
            views.append(
                rrb.TimeSeriesView(
                    origin=_path(p),
                    name=f"identified {p}" + (f" [{unit}]" if unit else "") + f", {confidence:.0%} interval",
                    time_ranges=time_range,
                    axis_x=axis,
                    plot_legend=rrb.PlotLegend(visible=False),
                )
            )
        views.append(rrb.TextLogView(origin=f"{IDENTIFICATION}/selected", name="identified fault (changes)"))
        return views

    return make


class IdentificationLog:
    """Sends :class:`~chatterspec.detection.identification_online.OnlineIdentification` results to the sinks.

    Parameters
    ----------
    sinks : Sinks
        The monitor's open sinks (file and / or live viewer).
    setup : IdentificationSetup
    """

    def __init__(self, sinks: Sinks, setup: Any) -> None:
        import pyarrow as pa
        import rerun as rr

        self.rr, self.pa, self.sinks, self.setup = rr, pa, sinks, setup
        pm = setup.parameter_map
        self.parameters = [p for p in pm.parameter_names if any(p in h.parameters for h in setup.hypotheses)]
        self._selected: str | None = None
        for s in sinks.streams:
            for p in self.parameters:
                s.log(
                    _path(p),
                    rr.SeriesLines(
                        names=["estimate", "interval low", "interval high"],
                        colors=[[255, 200, 60], [150, 150, 150], [150, 150, 150]],
                        widths=[2.0, 1.0, 1.0],
                    ),
                    static=True,
                )

    def log(self, out: OnlineIdentification) -> None:
        """Log the windows of one push."""
        if out.n_windows == 0 or not self.sinks.streams:
            return
        rr, pa = self.rr, self.pa
        ns = to_ns(out.times_s)
        res = out.result
        sel = res.fit["selected"]
        names = [h.name for h in self.setup.hypotheses]
        theta, lo_hi = res.fit["theta"], {}
        for h, hyp in enumerate(self.setup.hypotheses):
            for i, p in enumerate(hyp.parameters):
                lo_hi[(h, p)] = (theta[:, h, i], *res.interval(hyp.name, p))
        texts, t_text = [], []
        for j in range(out.n_windows):
            name = NO_FAULT if sel[j] == -1 else "unexplained" if sel[j] == -2 else names[sel[j]]
            if name != self._selected:
                self._selected = name
                rep = out.report(j)
                fmt = format_with_error
                what = "; ".join(
                    f"{e.parameter} = {fmt(e.estimate, e.std_error)} [{fmt(e.ci_low, e.std_error)}, "
                    f"{fmt(e.ci_high, e.std_error)}]" + (f" {e.unit}" if e.unit else "")
                    for e in rep.estimate()
                )
                texts.append(f"identified: {name}" + (f": {what}" if what else ""))
                t_text.append(ns[j])
        for p in self.parameters:
            rows = np.full((out.n_windows, 3), np.nan)
            for h, hyp in enumerate(self.setup.hypotheses):
                if p in hyp.parameters:
                    mine = sel == h
                    est, lo, hi = lo_hi[(h, p)]
                    rows[mine] = np.stack([est, lo, hi], axis=1)[mine]
            for s in self.sinks.streams:
                col = rr.Scalars.columns(scalars=rows.ravel()).partition([3] * out.n_windows)
                s.send_columns(_path(p), indexes=[_TimeIndex(pa, ns)], columns=col)
        if texts:
            for s in self.sinks.streams:
                s.send_columns(
                    f"{IDENTIFICATION}/selected",
                    indexes=[_TimeIndex(pa, np.asarray(t_text, dtype=np.int64))],
                    columns=rr.TextLog.columns(text=texts, level=["INFO"] * len(texts)),
                )
