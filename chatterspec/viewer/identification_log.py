"""Fault identification in a Rerun recording: estimates, nominal values, tolerance bands, detectability and
states per hop.

Entities (time on the monitor's ``time`` timeline, integer nanoseconds as in
:mod:`chatterspec.viewer.rerun_log`; one row per identification window of the
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
    channels' lanes, which show the channels' one fault state: :mod:`chatterspec.viewer.fault_lanes`);
``/events/identification``
    rows in the recording's event log: the fault named when it changes (only while a spectral alarm is
    active), a parameter that stops or starts being excited (once the detectability's horizon holds
    data), and for ``detect`` the identification of each interval of its JSON
    (:meth:`IdentificationLog.log_intervals`); with tolerances the parameters' alarms are rows of
    ``/events`` itself (:func:`~chatterspec.viewer.alarm_events.send_parameter_events`).

:meth:`IdentificationLog.views` gives the views below the monitor's default layout: one per declared
parameter (each is estimated in every window) and the detectability.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.identification import format_with_error
from ..detection.parameter_decision import STATES
from ..palette import FAULT, HEALTHY, NEUTRAL, NO_EVIDENCE, rgba32
from .alarm_events import INFO_LEVEL, log_text_rows, send_parameter_events
from .arrow_columns import _TimeIndex
from .blueprint import _entity
from .interval_events import interval_text
from .record_geometry import to_ns
from .sinks import Sinks

if TYPE_CHECKING:  # pragma: no cover
    from rerun.blueprint import VisibleTimeRange
    from rerun.blueprint.api import View
    from rerun.blueprint.archetypes import TimeAxis

    from ..online.identification_monitor import IdentificationMonitor, IdentificationUpdate
    from .blueprint import ExtraRow

__all__ = [
    "IDENTIFICATION",
    "IDENTIFICATION_EVENTS",
    "IdentificationLog",
    "display_scale",
    "identification_views",
    "parameter_lane_entity",
]

#: Root entity of the identification series.
IDENTIFICATION = "/identification"
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
    """

    def __init__(self, sinks: Sinks, monitor: IdentificationMonitor) -> None:
        import pyarrow as pa
        import rerun as rr

        self.rr, self.pa, self.sinks, self.monitor = rr, pa, sinks, monitor
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
        from .blueprint import labelled_top

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
        rr, pa = self.rr, self.pa
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
            for i, st in enumerate(w.states):
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
        idx = [_TimeIndex(pa, ns)]
        for i, p in enumerate(self.parameters):
            cols = [blk.estimate[:, i], blk.ci_low[:, i], blk.ci_high[:, i], np.full(W, b.nominal[i])]
            if self.banded[i]:
                cols += [np.full(W, b.low[i]), np.full(W, b.high[i])]
            rows = np.stack(cols, axis=1) / 10.0 ** self.scale[i]
            if np.isfinite(rows).any():
                ext = self.extent[i]
                ext[0], ext[1] = min(ext[0], float(np.nanmin(rows))), max(ext[1], float(np.nanmax(rows)))
            r = np.where(np.isfinite(ratio[:, i]), ratio[:, i], np.nan)
            k, states = changes[i]
            for s in self.sinks.streams:
                col = rr.Scalars.columns(scalars=rows.ravel()).partition([self.n_series[i]] * W)
                s.send_columns(_path(p), indexes=idx, columns=col)
                s.send_columns(
                    f"{IDENTIFICATION}/detectable/{p}", indexes=idx, columns=rr.Scalars.columns(scalars=r)
                )
                if k:
                    s.send_columns(
                        self.lanes[i],
                        indexes=[_TimeIndex(pa, to_ns(decided[k]))],
                        columns=rr.StateChange.columns(state=states),
                    )
        if texts:
            self._texts(t_text, texts)
        if upd.events:
            for s in self.sinks.streams:
                send_parameter_events(s, upd.events)

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
