"""Fault identification in a Rerun recording: estimate, interval and nominal value of each parameter.

Entities (time on the monitor's ``time`` timeline, integer nanoseconds as in
:mod:`chatterspec.viewer.rerun_log`):

``/identification/<parameter>``
    four series per row: the estimate (the plant's value), the interval's low and high end and the
    nominal value, in the parameter's unit times a power of ten (:func:`display_scale`: the viewer
    writes ``0.000 000 000 03`` for a leakage in m^3/(s Pa); scaled, it reads ``3``). The estimate and
    interval are NaN (a gap) where the selected hypothesis does not hold the parameter;
``/events/identification``
    a line in the recording's event log whenever the selected hypothesis changes (with the estimate);
``/identification/summary``
    what the identification row says when no parameter was selected in the record (static).

Two sources: the per-hop identification of a monitored stream (:meth:`IdentificationLog.log`, one row per
hop) and the per-interval identification of ``detect`` (:meth:`IdentificationLog.log_intervals`: the
numbers of ``detect --json``'s ``identification_intervals``, a constant over each interval).

:meth:`IdentificationLog.views` gives the views below the monitor's default layout: one per parameter
that was identified (selected) somewhere in the record, or a sentence saying that none was; a live
viewer, which cannot know in advance, gets one per declared parameter.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..detection.identification_online import OnlineIdentification
from ..detection.identification_results import format_with_error
from ..palette import NEUTRAL
from ..plants.parameters import NO_FAULT
from .alarm_events import INFO_LEVEL, log_text_rows
from .arrow_columns import _TimeIndex
from .interval_events import interval_text
from .rerun_log import to_ns
from .sinks import Sinks

__all__ = ["IDENTIFICATION", "IdentificationLog", "display_scale", "identification_views"]

#: Root entity of the identification series.
IDENTIFICATION = "/identification"
#: Entity of the identification lines in the recording's event log.
IDENTIFICATION_EVENTS = "/events/identification"
#: Colours of the four series: estimate (amber), interval ends (grey), nominal (light, thin).
_STYLE = {
    "names": ["estimate", "interval low", "interval high", "nominal"],
    "colors": [[255, 200, 60], list(NEUTRAL), list(NEUTRAL), [220, 220, 220]],
    "widths": [2.5, 1.0, 1.0, 1.0],
}


def _path(parameter: str) -> str:
    return f"{IDENTIFICATION}/{parameter}"


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
    """Sends identification results to the sinks and gives their views.

    Parameters
    ----------
    sinks : Sinks
        The monitor's open sinks (file and / or live viewer).
    setup : IdentificationSetup
    confidence : float
        Level of the intervals (shown in the view titles).
    """

    def __init__(self, sinks: Sinks, setup: Any, confidence: float) -> None:
        import pyarrow as pa
        import rerun as rr

        self.rr, self.pa, self.sinks, self.setup = rr, pa, sinks, setup
        self.confidence = float(confidence)
        pm = setup.parameter_map
        self.parameters = [p for p in pm.parameter_names if any(p in h.parameters for h in setup.hypotheses)]
        self.nominal = {p: float(pm.parameter(p).value) for p in self.parameters}
        self.scale = {p: display_scale(self.nominal[p]) for p in self.parameters}
        self.identified: set[str] = set()  # parameters selected somewhere in the record
        # per parameter the smallest and largest value drawn (display units): the views' y ranges
        self.extent = {p: [self.nominal[p] / 10.0 ** self.scale[p]] * 2 for p in self.parameters}
        self._selected: str | None = None
        note = rr.TextDocument(
            f"Fault identification (hypotheses {', '.join(h.name for h in setup.hypotheses)}): no parameter "
            "was selected in this record (the tests kept the nominal model, or no hypothesis fits)."
        )
        for s in sinks.streams:
            for p in self.parameters:
                s.log(_path(p), rr.SeriesLines(**_STYLE), static=True)
            s.log(f"{IDENTIFICATION}/summary", note, static=True)

    def views(self, time_range: Any, axis: Any = None, *, live: bool = False) -> list[Any]:
        """One time view per identified parameter (``live``: per declared parameter); with none identified,
        the sentence that says so."""
        import rerun.blueprint as rrb

        shown = self.parameters if live else [p for p in self.parameters if p in self.identified]
        views = []
        for p in shown:
            unit = self.setup.parameter_map.parameter(p).unit
            views.append(
                rrb.TimeSeriesView(
                    origin=_path(p),
                    name=f"{p}{_unit_label(unit, self.scale[p])}: {self.confidence:.0%} interval, nominal",
                    time_ranges=time_range,
                    axis_x=axis,
                    plot_legend=rrb.PlotLegend(visible=False),
                    axis_y=None if live else rrb.ScalarAxis(range=self.y_range(p)),
                )
            )
        if not views:
            summary = f"{IDENTIFICATION}/summary"
            views.append(rrb.TextDocumentView(origin=summary, name="fault identification"))
        return views

    def y_range(self, p: str) -> tuple[float, float]:
        """The y range of parameter ``p``'s view (display units): from 0 (or the smallest value drawn, if
        negative) to a labelled top above the largest (:func:`~chatterspec.viewer.blueprint.labelled_top`),
        so that the viewer labels its ticks and the nominal line and every estimate are on the chart."""
        from .blueprint import labelled_top

        lo, hi = self.extent[p]
        top = labelled_top(1.05 * hi) if hi > 0 else 0.1 * abs(lo) or 1.0
        bottom = 0.0 if lo >= 0 else -labelled_top(1.05 * -lo)
        return (bottom - 0.05 * (top - bottom), top)

    def _send(self, p: str, ns: np.ndarray, rows: np.ndarray) -> None:
        """Rows (n, 4) of parameter ``p`` (its unit) at ``ns``, scaled for display."""
        rows = rows / 10.0 ** self.scale[p]
        if np.isfinite(rows).any():
            ext = self.extent[p]
            ext[0], ext[1] = min(ext[0], float(np.nanmin(rows))), max(ext[1], float(np.nanmax(rows)))
        col = self.rr.Scalars.columns(scalars=rows.ravel()).partition([4] * rows.shape[0])
        for s in self.sinks.streams:
            s.send_columns(_path(p), indexes=[_TimeIndex(self.pa, ns)], columns=col)

    def _texts(self, times_s: list[float], texts: list[str]) -> None:
        for s in self.sinks.streams:
            log_text_rows(s, IDENTIFICATION_EVENTS, times_s, texts, [INFO_LEVEL] * len(texts))

    def log(self, out: OnlineIdentification) -> None:
        """Log the windows of one push (per-hop identification of a monitored stream)."""
        if out.n_windows == 0 or not self.sinks.streams:
            return
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
                texts.append(f"{out.times_s[j]:.2f} s identified " + (what or name))
                t_text.append(float(out.times_s[j]))
        for p in self.parameters:
            rows = np.full((out.n_windows, 4), np.nan)
            rows[:, 3] = self.nominal[p]
            for h, hyp in enumerate(self.setup.hypotheses):
                if p in hyp.parameters:
                    mine = sel == h
                    if mine.any():
                        self.identified.add(p)
                    est, lo, hi = lo_hi[(h, p)]
                    rows[mine, :3] = np.stack([est, lo, hi], axis=1)[mine]
            self._send(p, ns, rows)
        if texts:
            self._texts(t_text, texts)

    def log_intervals(self, docs: list[dict[str, Any]], span_s: tuple[float, float]) -> None:
        """Log ``detect --json``'s ``identification_intervals``: over each interval the selected
        hypothesis's estimates and intervals (a constant from onset to offset, a gap between intervals),
        the nominal value over the whole record ``span_s``, and one log line per interval."""
        if not self.sinks.streams:
            return
        texts, t_text = [], []
        per: dict[str, list[tuple[float, list[float]]]] = {p: [] for p in self.parameters}
        for doc in docs:
            on, off = (float(x) for x in doc["interval_s"])
            sel = doc.get("selected")
            hyps = doc.get("hypotheses", [])
            picked = [h for h in hyps if h.get("hypothesis") == sel and h.get("parameter")]
            what = "; ".join(
                f"{h['parameter']} = {h['estimate']:.4g} [{h['ci_low']:.4g}, {h['ci_high']:.4g}]"
                + (f" {h['unit']}" if h.get("unit") else "")
                for h in picked
                if h.get("estimate") is not None
            )
            if sel is None:
                why = str(doc.get("reason", "no result")).split(";")[
                    0
                ]  # its first clause: the log cuts long text
                texts.append(f"{interval_text(on, off)} not identified: {why}")
            else:
                texts.append(f"{interval_text(on, off)} identified " + (what or str(sel)))
            t_text.append(on)
            for h in picked:
                p = h.get("parameter")
                if p in per and h.get("estimate") is not None:
                    self.identified.add(p)
                    row = [float(h["estimate"]), float(h["ci_low"]), float(h["ci_high"])]
                    per[p] += [(on, row), (off, row), (off + 1e-9, [np.nan] * 3)]
        for p in self.parameters:
            pts = sorted([(span_s[0], [np.nan] * 3), *per[p], (span_s[1], [np.nan] * 3)], key=lambda x: x[0])
            times = np.array([t for t, _ in pts])
            rows = np.array([[*r, self.nominal[p]] for _, r in pts])
            self._send(p, to_ns(times), rows)
        if texts:
            self._texts(t_text, texts)


def identification_views(log: IdentificationLog) -> Any:
    """``make(time_range, axis, live=False) -> views`` of ``log`` (:meth:`IdentificationLog.views`), for
    :func:`chatterspec.viewer.blueprint.blueprint`'s ``extra_row``; evaluated when a blueprint is built,
    so a file's final blueprint shows the parameters identified in its record."""

    def make(time_range: Any, axis: Any = None, live: bool = False) -> list[Any]:
        return log.views(time_range, axis, live=live)

    return make
