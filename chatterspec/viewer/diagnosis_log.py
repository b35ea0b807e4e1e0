"""Rerun recording of ``chatterspec diagnose --record FILE.rrd``: realization 0 on one
timeline -- the chattering spectrogram, frame verdicts and detection events of the online monitor
(:class:`~chatterspec.viewer.rerun_log.RerunLogger`, unchanged) beside the mode probabilities of the
SMM-SVSF / IMM (one scalar series per mode under ``/modes/<method>/<mode>``) and, at a false-alarm
budget, every route's alarm statistic with its calibrated threshold (``/routes/<method>/statistic``
and ``/routes/<method>/threshold``; :func:`record_budget_diagnosis`).

Rerun is imported only when a recording is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.spectral import STFTConfig
from ..detection.thresholds import Threshold
from ..online.monitor import ChatteringMonitor, MonitorSettings
from ..palette import NEUTRAL, filter_color, mode_color, rgba32
from .blueprint import _entity, time_axis
from .drivers import scenario_truth
from .record_geometry import record_span, to_ns
from .rerun_log import RerunLogger
from .sinks import TIMELINE, open_sinks
from .truth_lane import log_truth_lane, truth_colors

if TYPE_CHECKING:  # pragma: no cover
    from types import ModuleType

    from rerun.blueprint import VisibleTimeRange
    from rerun.blueprint.archetypes import TimeAxis

    from ..plants.scenarios import Scenario
    from ..plants.simulate import Simulation
    from .sinks import Sinks

__all__ = ["MODE_HOLD_S", "held_changes", "mode_lane_entity", "record_budget_diagnosis", "record_diagnosis"]


def record_diagnosis(
    path: str | Path,
    sim: Simulation,
    threshold: Threshold | None,
    mode_outputs: dict[str, tuple[np.ndarray, np.ndarray, tuple[str, ...]]],
    *,
    config: STFTConfig | None = None,
    chunk_samples: int = 10_000,
    route_series: dict[str, tuple[np.ndarray, np.ndarray, float, str]] | None = None,
    chattering_rule: tuple[Any, float] | None = None,
) -> Path:
    """Write realization 0 of ``sim`` to a Rerun file: chattering monitor and mode probabilities.

    Parameters
    ----------
    path : str or Path
        ``.rrd`` file to write (checked by the caller with ``check_record_path``).
    sim : Simulation
        The diagnosed realizations; realization 0 is recorded.
    threshold : Threshold or None
        Per-frame threshold of the chattering route (``None``: no chattering part).
    mode_outputs : dict
        ``method -> (t (T-1,) s, mu (runs, T-1, r) or (T-1, r), modes)`` (``diagnose_modes(..., keep=...)``);
        realization 0 is recorded.
    config : STFTConfig, optional
        STFT settings of the threshold (default 1 s Hamming, 0.2 s hop).
    chunk_samples : int
        Measurements per monitor push (the output does not depend on it).
    route_series : dict, optional
        ``method -> (t (K,) s, statistic (K,), threshold, name)``: a route's alarm statistic and its
        threshold, drawn in one view per route.
    chattering_rule : (AlarmRule, float), optional
        The chattering route's calibrated alarm rule and its budget (alarm starts per hour): the channel
        lanes and events then follow the run's rule (default: the per-frame rule).

    Returns
    -------
    Path
        The file written.
    """
    import rerun as rr
    import rerun.blueprint as rrb

    sc = sim.scenario
    z0, u = np.asarray(sim.z[0]), np.asarray(sim.u)
    u0 = u[0] if u.ndim == 3 else u
    sinks = open_sinks(record=path, recording_name=f"diagnose {sc.name} (realization 0)")
    logger: RerunLogger | None = None
    try:
        if threshold is not None:
            rule = None if chattering_rule is None else chattering_rule[0]
            settings = MonitorSettings(stft=config or STFTConfig(), threshold=threshold, rule=rule)
            mon = ChatteringMonitor(sc.nominal, settings)
            span = record_span(mon, z0.shape[0], raw=True)
            truth = scenario_truth(sc)
            logger = RerunLogger(
                sinks,
                mon,
                truth=truth,
                span_s=span,
                send_blueprint=False,
                extra_lanes=len(mode_outputs),
                rows_above=1 if route_series else 0,
                peak_view=False,  # every lane visible at 1600x1000: the events and spectrogram give it
                budget_per_hour=None if chattering_rule is None else chattering_rule[1],
            )
            for lo in range(0, z0.shape[0], int(chunk_samples)):
                logger.log_update(mon.push(z0[lo : lo + chunk_samples], u0[lo : lo + chunk_samples]))
        else:
            span = (float(sim.t[0]), float(sim.t[-1]))
        time_range, axis = time_axis(span)
        truth = scenario_truth(sc)
        lane_colors = truth_colors(truth)
        for method, (t, mu, modes) in mode_outputs.items():
            mu = np.asarray(mu, dtype=float)
            _log_modes(
                sinks,
                rr,
                method,
                np.asarray(t, dtype=float),
                mu[0] if mu.ndim == 3 else mu,
                modes,
                lane_colors,
            )
        route_views = [
            _log_route(sinks, rr, rrb, method, series, time_range, axis)
            for method, series in (route_series or {}).items()
        ]
        lanes_name = (
            f"true fault (top); most probable mode per method (runs >= {MODE_HOLD_S:g} s); fault state per "
            "channel (grey = no evidence)"
        )
        if logger is not None:
            # sent again on close with the chattering views' y ranges (RerunLogger.close)
            logger.file_layout = {"has_truth": True, "above": route_views or None, "lanes_name": lanes_name}
            bp = logger.layout(span_s=span, **logger.file_layout)
        else:  # no chattering route: the route statistics above the truth and mode lanes
            log_truth_lane(sinks.streams, truth)
            lanes = rrb.StateTimelineView(
                origin="/state", name=lanes_name, time_ranges=time_range, time_view=axis
            )
            rows = ([rrb.Horizontal(*route_views)] if route_views else []) + [lanes]
            bp = rrb.Blueprint(
                rrb.Vertical(*rows, row_shares=[1.0] * (len(rows) - 1) + [0.6]),
                rrb.TimePanel(state="collapsed", timeline=TIMELINE, play_state="paused"),
                collapse_panels=True,
            )
        for s in sinks.streams:
            s.send_blueprint(bp, make_active=True, make_default=True)
    finally:
        try:
            if logger is not None:
                logger.close()
        finally:
            sinks.close()
    return Path(path)


#: Shortest run (s) of a most probable mode that its lane shows; shorter runs stay in the mode before
#: them (the lanes of a switching SMM / IMM otherwise split into slivers whose labels cannot be read).
MODE_HOLD_S = 0.2


def held_changes(best: np.ndarray, t: np.ndarray, hold_s: float) -> np.ndarray:
    """Indices where the lane of the most probable mode ``best`` (per sample at times ``t``, s) changes:
    every change of ``best`` whose new mode then holds for at least ``hold_s`` seconds (or to the end);
    the first sample always.

    Parameters
    ----------
    best : (T,) int array
    t : (T,) array
        Times (s).
    hold_s : float

    Returns
    -------
    int array
    """
    raw = np.flatnonzero(np.concatenate(([True], best[1:] != best[:-1])))
    ends = np.append(t[raw[1:]], np.inf)
    keep = [int(raw[0])]
    for k, end in zip(raw[1:].tolist(), ends[1:].tolist(), strict=True):
        if end - t[k] >= hold_s and best[k] != best[keep[-1]]:
            keep.append(k)
    return np.asarray(keep, dtype=np.intp)


def mode_lane_entity(method: str) -> str:
    """Entity of the most-probable-mode lane of ``method``: sorts right below the truth lane.

    Parameters
    ----------
    method : str

    Returns
    -------
    str
        ``/state/0m_<method>``.
    """
    return f"/state/0m_{_entity(method)}"


def _log_modes(
    sinks: Sinks,
    rr: ModuleType,
    method: str,
    t: np.ndarray,
    mu: np.ndarray,
    modes: tuple[str, ...],
    colors: dict[str, int],
) -> None:
    """Mode probabilities ``/modes/<method>/<mode>`` (series, palette colours) and the most probable mode
    as a lane (a change at each switch), coloured like the truth lane where a mode names a true segment."""
    ns = to_ns(t)
    tcol = rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))
    best = np.argmax(mu, axis=1)
    change = held_changes(best, t, MODE_HOLD_S)
    names = {"normal": "healthy"}  # the truth lane's name of the nominal mode
    lane_col = [colors.get(names.get(m, m), rgba32(mode_color(j))) for j, m in enumerate(modes)]
    for s in sinks.streams:
        for j, mode in enumerate(modes):
            ent = f"/modes/{method}/{_entity(mode)}"
            s.log(ent, rr.SeriesLines(colors=[list(mode_color(j))], names=[f"mu {mode}"]), static=True)
            s.send_columns(ent, indexes=[tcol], columns=rr.Scalars.columns(scalars=np.asarray(mu[:, j])))
        s.log(
            mode_lane_entity(method),
            rr.StateConfiguration(
                values=list(modes),
                labels=list(modes),  # the lane's path above it names the method
                colors=np.array(lane_col, dtype=np.uint32),
            ),
            static=True,
        )
        s.send_columns(
            mode_lane_entity(method),
            indexes=[rr.TimeColumn(TIMELINE, duration=ns[change].astype("timedelta64[ns]"))],
            columns=rr.StateChange.columns(state=[modes[k] for k in best[change]]),
        )


def _log_route(
    sinks: Sinks,
    rr: ModuleType,
    rrb: ModuleType,
    method: str,
    series: tuple,
    time_range: VisibleTimeRange,
    axis: TimeAxis | None = None,
) -> Any:
    """Log one route's statistic and threshold as two series; return its view (no legend over the data:
    the title names them; y range up to 1.5 h, so that the threshold shows even when a fault's statistic
    runs far above it)."""
    t, stat, h, name = series
    ns = to_ns(np.asarray(t, dtype=float)).astype("timedelta64[ns]")
    stat = np.asarray(stat, dtype=float)
    hline = np.full(stat.shape, float(h) if np.isfinite(h) else np.nan)
    for s in sinks.streams:
        for ent, vals, color, label in (
            (f"/routes/{method}/statistic", stat, list(filter_color(method)), name),
            (f"/routes/{method}/threshold", hline, list(NEUTRAL), "threshold"),
        ):
            s.log(ent, rr.SeriesLines(colors=[color], names=[label]), static=True)
            s.send_columns(
                ent, indexes=[rr.TimeColumn(TIMELINE, duration=ns)], columns=rr.Scalars.columns(scalars=vals)
            )
    top = 1.5 * float(h) if np.isfinite(h) and h > 0 else None
    return rrb.TimeSeriesView(
        origin=f"/routes/{method}",
        name=f"{method}: {name} vs h = {h:.3g}",
        time_ranges=time_range,
        axis_x=axis,
        axis_y=None if top is None else rrb.ScalarAxis(range=(0.0, top)),
        plot_legend=rrb.PlotLegend(visible=False),
    )


def record_budget_diagnosis(
    path: str | Path,
    scenario: Scenario,
    seed: int,
    routes: dict[str, Any],
    results: list[Any],
    threshold: Threshold | None,
) -> Path:
    """Write realization 0 of a diagnosis at one budget: monitor, mode probabilities, route statistics.

    Parameters
    ----------
    path : str or Path
        ``.rrd`` file to write.
    scenario : Scenario
        The diagnosed scenario.
    seed : int
        Seed of the diagnosed runs (realization 0 is simulated again, identical).
    routes : dict
        Method -> route (:mod:`chatterspec.studies.budget_diagnosis`); the results' own routes (as diagnosed,
        e.g. with a healthy NIS scale) are used where they carry one.
    results : list of RouteBudget
        Their results (the calibrated rules).
    threshold : Threshold or None
        Per-frame threshold of the chattering monitor's spectrogram view (None: no chattering part).

    Returns
    -------
    Path
    """
    from ..detection.alarms.rules import rule_from_dict, rule_spec
    from ..detection.alarms.streams import run_rule
    from ..detection.route_scores import mode_log_odds
    from ..plants.simulate import iter_simulations

    sim = next(iter_simulations(scenario, 1, seed, chunk_runs=1))
    modes: dict = {}
    series: dict = {}
    by_method = {r.method: r for r in results}
    for method, route in routes.items():
        route = by_method[method].route or route
        rule = rule_from_dict(by_method[method].rule)
        if method in ("smm", "imm"):
            x0, P0 = route._x0, route._P0
            out = route.filter.run(sim.z[:, 1:], sim.u[..., :-1, :], x0=x0, P0=P0)
            modes[method] = (sim.t[1:], out.mu, route.labels)
            score = mode_log_odds(out.mu, route.floor)[..., None]
            times = sim.t[1:]
        else:
            rs = route.scores(sim)
            score, times = rs.score, rs.times
        blk = run_rule(rule, score)
        stat = blk.statistic[0].max(axis=-1)  # the largest over the channels (the route's alarm is any)
        label = rule_spec(rule).statistic
        series[method] = (times, stat, rule.threshold, label)
    chat = by_method.get("chattering")
    chat_rule = None if chat is None else (rule_from_dict(chat.rule), chat.budget_per_hour)
    thr = threshold if "chattering" in routes else None
    return record_diagnosis(path, sim, thr, modes, route_series=series, chattering_rule=chat_rule)
