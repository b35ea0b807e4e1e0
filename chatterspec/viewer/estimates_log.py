"""Rerun recording of an estimator comparison: truth, estimates and innovations per filter.

Entity layout (one ``time`` timeline, durations in integer nanoseconds, rounded once)::

    /states/<state>/truth                 true state x_i(k)
    /states/<state>/<filter>              estimate x_i(k|k) of each filter
    /errors/<state>/<filter>              estimation error x_i - x_i(k|k)
    /measurements/<output>                z_j(k)
    /innovations/<output>/<filter>        e_j(k|k-1) = z_j(k) - C x(k|k-1)
    /info                                 a text log line naming the scenario, run and filters

Everything time-indexed goes through ``RecordingStream.send_columns`` (bulk, millions of samples
per second); ``rerun`` is imported only when a recording is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ParameterError
from ..palette import TRUTH, filter_color

if TYPE_CHECKING:  # pragma: no cover
    from ..plants.nonlinear import Model
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
        from .sinks import TIMELINE

        rec.send_recording_name(f"estimate {sc.name} run {records.first_run + run}")
        t_all = rr.TimeColumn("time", duration=_ns(records.t))
        t_post = rr.TimeColumn("time", duration=_ns(records.t[1:]))
        names = list(records.outputs)
        rec.set_time(TIMELINE, duration=np.timedelta64(int(_ns(records.t[:1])[0].astype(np.int64)), "ns"))
        rec.log(
            "/info",
            rr.TextLog(
                f"scenario {sc.name}, realization {records.first_run + run}, filters {', '.join(names)}",
                level="INFO",
            ),
        )
        x = records.x[run]
        _log_styles(rec, states, outputs, names)
        for i, s in enumerate(states):
            rec.send_columns(
                f"/states/{s}/truth", indexes=[t_all], columns=rr.Scalars.columns(scalars=x[:, i])
            )
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
            if out.innovation is not None:
                for j, o in enumerate(outputs):
                    rec.send_columns(
                        f"/innovations/{o}/{name}",
                        indexes=[t_post],
                        columns=rr.Scalars.columns(scalars=out.innovation[run, :, j]),
                    )
        span = (float(records.t[0]), float(records.t[-1]))
        units = _state_units(model, states)
        rec.send_blueprint(
            estimate_blueprint(
                states, outputs, names, span, units, title=f"{sc.name}, run {records.first_run + run}"
            ),
            make_active=True,
            make_default=True,
        )
        rec.flush()
    finally:
        rec.disconnect()
    return path


def _state_units(model: Model, states: tuple[str, ...]) -> tuple[str, ...]:
    """A state's unit where it is measured under its own name (the model lists output units only)."""
    by_output = dict(zip(model.output_names, model.output_units, strict=True))
    return tuple(by_output.get(s, "") for s in states)


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
            # drawn in name order: the first filter widest, so that a later one does not hide it
            width = 1.0 + 0.8 * (len(names) - 1 - k)
            style = rr.SeriesLines(colors=[list(filter_color(name, k))], widths=[width], names=[name])
            rec.log(f"/states/{s}/{name}", style, static=True)
            rec.log(f"/errors/{s}/{name}", style, static=True)
    for o in outputs:
        for k, name in enumerate(names):
            width = 1.0 + 0.8 * (len(names) - 1 - k)
            style = rr.SeriesLines(colors=[list(filter_color(name, k))], widths=[width], names=[name])
            rec.log(f"/innovations/{o}/{name}", style, static=True)


def estimate_blueprint(
    states: tuple[str, ...],
    outputs: tuple[str, ...],
    filters: list[str],
    span_s: tuple[float, float],
    units: tuple[str, ...],
    *,
    title: str = "",
) -> Any:
    """The layout of an estimate recording: one column per state with the truth and every filter's
    estimate on shared axes above the estimation errors; below, the innovations per output and the
    run's description. Every time view shows ``span_s`` (linked time axis); legends sit in a corner
    out of the data; playback opens paused on the whole record.

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
        return rrb.TimeSeriesView(
            origin=origin, name=name, time_ranges=time_range, axis_x=axis, plot_legend=legend
        )

    legend = rrb.PlotLegend(corner="LeftTop", visible=True)
    who = ", ".join(filters)
    columns = []
    for s, u in zip(states, units, strict=True):
        unit = f" [{u}]" if u else ""
        columns.append(
            rrb.Vertical(
                view(f"/states/{s}", f"{s}{unit}: truth (thin, light) and {who}", legend),
                view(f"/errors/{s}", f"{s} error: truth - estimate{unit}"),
                row_shares=[1.4, 1.0],
            )
        )
    bottom = [view(f"/innovations/{o}", f"{o}: innovation z - C x(k|k-1) per filter") for o in outputs]
    bottom.append(rrb.TextLogView(origin="/info", name=f"estimate {title}"))
    return rrb.Blueprint(
        rrb.Vertical(rrb.Horizontal(*columns), rrb.Horizontal(*bottom), row_shares=[4.0, 1.0]),
        time_panel(span_s),
        collapse_panels=True,
    )
