"""Rerun recording of an estimator comparison: truth, estimates and innovations per filter.

Entity layout (one ``time`` timeline, durations in integer nanoseconds, rounded once)::

    /states/<state>/truth                 true state x_i(k)
    /states/<state>/<filter>              estimate x_i(k|k) of each filter
    /errors/<state>/<filter>              estimation error x_i - x_i(k|k)
    /measurements/<output>                z_j(k)
    /innovations/<output>/<filter>        e_j(k|k-1) = z_j(k) - C x(k|k-1)
    /state/0_truth                        the true plant's segments (a lane: where the fault starts)
    /info                                 what the colours are, the scenario, run and filters

Everything time-indexed goes through ``RecordingStream.send_columns`` (bulk, millions of samples
per second); ``rerun`` is imported only when a recording is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ParameterError
from ..palette import TAB10, TRUTH, filter_color
from ..plants.models import state_units

if TYPE_CHECKING:  # pragma: no cover
    from ..studies.estimation import EstimateRecords

__all__ = ["estimate_blueprint", "record_estimates"]


def _ns(seconds: np.ndarray) -> np.ndarray:
    """Seconds -> integer nanoseconds (one rounding rule for every column)."""
    return np.round(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64).astype("timedelta64[ns]")


def record_estimates(records: EstimateRecords, path: str | Path, *, run: int = 0) -> Path:
    """Write one realization of :class:`~chatterspec.studies.estimation.EstimateRecords` to an ``.rrd`` file.

    Parameters
    ----------
    records : EstimateRecords
        Truth, measurements and filter outputs
        (from :func:`~chatterspec.studies.estimation.estimate_records`).
    path : str or Path
        Output file, ending in ``.rrd`` (parent folders are created).
    run : int
        Which realization of ``records`` to log (index into its run axis).

    Returns
    -------
    Path
        The file written (closed, with its footer).

    Raises
    ------
    ParameterError
        A path not ending in ``.rrd`` or a run index out of range.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ParameterError(f"recording path must end in .rrd; got {str(path)!r}")
    runs = records.x.shape[0]
    if not 0 <= run < runs:
        raise ParameterError(f"run must be in [0, {runs}); got {run}")
    import rerun as rr

    sc = records.scenario
    model = sc.nominal
    states = tuple(model.state_names)
    outputs = tuple(model.output_names)
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream("chatterspec", recording_id=f"estimate-{sc.name}-{records.first_run + run}")
    try:
        rec.save(str(path))
    except RuntimeError as exc:  # rerun reports file errors (e.g. disk full) as RuntimeError
        from .sinks import file_error

        err = file_error(exc, path)
        if err is None:
            raise ParameterError(f"cannot write the recording {str(path)!r}: {exc}") from None
        raise err from None
    try:
        rec.send_recording_name(f"estimate {sc.name} run {records.first_run + run}")
        t_all = rr.TimeColumn("time", duration=_ns(records.t))
        t_post = rr.TimeColumn("time", duration=_ns(records.t[1:]))
        names = list(records.outputs)
        rec.log("/info", rr.TextDocument(_legend(sc.name, records.first_run + run, names)), static=True)
        from .drivers import scenario_truth
        from .truth_lane import log_truth_lane

        log_truth_lane([rec], scenario_truth(sc))
        x = records.x[run]
        extents: dict[str, list[np.ndarray]] = {}  # per view, the values it draws: its y range
        _log_styles(rec, states, outputs, names)
        for i, s in enumerate(states):
            rec.send_columns(
                f"/states/{s}/truth", indexes=[t_all], columns=rr.Scalars.columns(scalars=x[:, i])
            )
            extents.setdefault(f"/states/{s}", []).append(x[:, i])
        for j, o in enumerate(outputs):
            rec.send_columns(
                f"/measurements/{o}",
                indexes=[t_all],
                columns=rr.Scalars.columns(scalars=records.z[run, :, j]),
            )
        for name in names:
            out = records.outputs[name]
            est = out.x_post[run]
            err = x[1:] - est
            for i, s in enumerate(states):
                rec.send_columns(
                    f"/states/{s}/{name}", indexes=[t_post], columns=rr.Scalars.columns(scalars=est[:, i])
                )
                rec.send_columns(
                    f"/errors/{s}/{name}", indexes=[t_post], columns=rr.Scalars.columns(scalars=err[:, i])
                )
                extents.setdefault(f"/states/{s}", []).append(est[:, i])
                extents.setdefault(f"/errors/{s}", []).append(err[:, i])
            if out.innovation is not None:
                for j, o in enumerate(outputs):
                    rec.send_columns(
                        f"/innovations/{o}/{name}",
                        indexes=[t_post],
                        columns=rr.Scalars.columns(scalars=out.innovation[run, :, j]),
                    )
                    extents.setdefault(f"/innovations/{o}", []).append(out.innovation[run, :, j])
        span = (float(records.t[0]), float(records.t[-1]))
        units = state_units(model)
        rec.send_blueprint(
            estimate_blueprint(
                states,
                outputs,
                names,
                span,
                units,
                title=f"{sc.name}, run {records.first_run + run}",
                y_ranges={k: labelled_range(np.concatenate(v)) for k, v in extents.items()},
            ),
            make_active=True,
            make_default=True,
        )
        rec.flush()
    finally:
        rec.disconnect()
    return path


def _log_styles(rec: Any, states: tuple[str, ...], outputs: tuple[str, ...], names: list[str]) -> None:
    """Static colours and widths (the shared palette): the truth a thin light line over the estimates,
    each filter in its own colour in the state, error and innovation views (earlier filters wider)."""
    import rerun as rr

    for s in states:
        rec.log(
            f"/states/{s}/truth",
            rr.SeriesLines(colors=[list(TRUTH)], widths=[1.0], names=["truth"]),
            static=True,
        )
        for k, name in enumerate(names):
            style = _filter_style(rr, name, k, len(names))
            rec.log(f"/states/{s}/{name}", style, static=True)
            rec.log(f"/errors/{s}/{name}", style, static=True)
    for o in outputs:
        for k, name in enumerate(names):
            rec.log(f"/innovations/{o}/{name}", _filter_style(rr, name, k, len(names)), static=True)


def labelled_range(values: np.ndarray, plot_px: float = 140.0) -> tuple[float, float]:
    """A y range holding ``values`` whose power-of-ten ticks the viewer labels on a plot ``plot_px`` high
    (an automatic range of a velocity in cm/s labelled "0" alone): the values' own range (5 % margins)
    when it holds two such ticks far enough apart, else symmetric ``+-1.1 p`` when the values change sign
    (:func:`~chatterspec.viewer.chattering_extent.labelled_half_range`), else from 0 to a labelled top
    (:func:`~chatterspec.viewer.blueprint.labelled_top`)."""
    from .blueprint import labelled_step, labelled_top
    from .chattering_extent import labelled_half_range

    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    lo, hi = (float(v.min()), float(v.max())) if v.size else (-1.0, 1.0)
    pad = 0.05 * max(hi - lo, 1e-300)
    tight = (lo - pad, hi + pad)
    if labelled_step(*tight, plot_px) is not None:
        return tight  # the data's own range: the viewer labels its ticks
    if lo >= 0.0 and hi > 0.0:
        top = labelled_top(1.05 * hi)
        return (-0.05 * top, top)
    if hi <= 0.0 and lo < 0.0:
        bottom = labelled_top(-1.05 * lo)
        return (-bottom, 0.05 * bottom)
    r = labelled_half_range(max(abs(lo), abs(hi), 1e-300))
    return (-r, r)


def _width(k: int, n: int) -> float:
    """Line width of filter ``k`` of ``n``: the first widest (3.5 px down to 1 px), so that a later one
    drawn over it (the estimates nearly coincide) leaves its edges visible."""
    return 1.0 + 2.5 * (n - 1 - k) / max(n - 1, 1)


def _filter_style(rr: Any, name: str, k: int, n: int) -> Any:
    """Filter ``k`` of ``n``: its palette colour and :func:`_width`."""
    return rr.SeriesLines(colors=[list(filter_color(name, k))], widths=[_width(k, n)], names=[name])


def _legend(scenario: str, run: int, names: list[str]) -> str:
    """The recording's legend (a text beside the views, not over the data): the colour of every filter."""
    by_rgb = {rgb: word for word, rgb in TAB10.items()}
    n = len(names)
    parts = [
        f"{name} {by_rgb.get(filter_color(name, k), f'colour {k}')} ({_width(k, n):.1f} px)"
        for k, name in enumerate(names)
    ]
    return f"Scenario {scenario}, realization {run}. Truth: light grey, thin. Estimates: {', '.join(parts)}."


def estimate_blueprint(
    states: tuple[str, ...],
    outputs: tuple[str, ...],
    filters: list[str],
    span_s: tuple[float, float],
    units: tuple[str, ...],
    *,
    title: str = "",
    y_ranges: dict[str, tuple[float, float]] | None = None,
) -> Any:
    """The layout of an estimate recording: one row per state with the truth and every filter's
    estimate on shared axes beside the estimation errors; below, the innovations per output and the
    run's description with the colours (no legend over the data); at the bottom the true plant's lane,
    which marks where the fault starts. Every time view shows ``span_s`` (linked time axis); playback
    opens paused on the whole record.

    Parameters
    ----------
    states, outputs : tuple of str
        State and output names.
    filters : list of str
        Filter names (their colours come from :data:`chatterspec.palette.FILTER_COLORS`).
    span_s : (float, float)
        The record's time span (s).
    units : tuple of str
        Unit per state ("" where unknown).
    title : str
        Scenario and run, shown in the view titles.
    y_ranges : dict, optional
        Per view origin (``/states/<s>``, ``/errors/<s>``, ``/innovations/<o>``) its y range
        (:func:`labelled_range`: the viewer then labels its ticks); default auto range.

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun.blueprint as rrb

    from .blueprint import time_axis, time_panel

    time_range, axis = time_axis(span_s)
    hidden = rrb.PlotLegend(visible=False)

    def view(origin: str, name: str, legend: Any = hidden) -> Any:
        """A time view of the whole record, on the linked time axis."""
        rng = (y_ranges or {}).get(origin)
        return rrb.TimeSeriesView(
            origin=origin,
            name=name,
            time_ranges=time_range,
            axis_x=axis,
            plot_legend=legend,
            axis_y=None if rng is None else rrb.ScalarAxis(range=rng),
        )

    rows = []  # one row per state, each view half the window wide: the time axis labels its ms ticks
    for s, u in zip(states, units, strict=True):
        unit = f" [{u}]" if u else ""
        rows.append(
            rrb.Horizontal(
                view(f"/states/{s}", f"{s}{unit}: truth and estimates"),
                view(f"/errors/{s}", f"{s} error: truth - estimate{unit}"),
            )
        )
    bottom = [view(f"/innovations/{o}", f"{o}: innovation z - C x(k|k-1)") for o in outputs]
    bottom.append(rrb.TextDocumentView(origin="/info", name=f"estimate {title}: colours"))
    lane = rrb.StateTimelineView(
        origin="/state", name="true plant (the fault's start)", time_ranges=time_range, time_view=axis
    )
    return rrb.Blueprint(
        rrb.Vertical(*rows, rrb.Horizontal(*bottom), lane, row_shares=[1.0] * len(rows) + [0.9, 0.5]),
        time_panel(span_s),
        collapse_panels=True,
    )
