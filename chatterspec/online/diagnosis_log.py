"""Rerun recording of ``chatterspec diagnose --record FILE.rrd``: realization 0 on one
timeline -- the chattering spectrogram, frame verdicts and detection events of the online monitor
(:class:`~chatterspec.online.rerun_log.RerunLogger`, unchanged) beside the mode probabilities of the
SMM-SVSF / IMM (one scalar series per mode under ``/modes/<method>/<mode>``) and, at a false-alarm
budget, every route's alarm statistic with its calibrated threshold (``/routes/<method>/statistic``
and ``/routes/<method>/threshold``; :func:`record_budget_diagnosis`).

Rerun is imported only when a recording is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..detection.spectral import STFTConfig
from ..detection.thresholds import Threshold
from .blueprint import _entity, blueprint
from .drivers import scenario_truth
from .monitor import ChatteringMonitor, MonitorSettings
from .rerun_log import DB_RANGE, RerunLogger, to_ns
from .viewer import TIMELINE, open_sinks

__all__ = ["record_budget_diagnosis", "record_diagnosis"]

_MODE_COLORS = ([31, 119, 180], [255, 127, 14], [214, 39, 40], [44, 160, 44], [148, 103, 189])


def _span(mon: ChatteringMonitor, n_meas: int) -> tuple[float, float] | None:
    """Time span (s) of the frames of ``n_meas`` raw measurements (first centre - hop/2, last + hop/2)."""
    n_chat = n_meas - 1
    if n_chat < mon.n_window:
        return None
    last = (n_chat - mon.n_window) // mon.n_hop
    half, centre = mon.n_hop * mon.dt / 2.0, (mon.n_window - 1) / 2.0
    t0 = mon.t0 + mon.dt
    return (t0 + centre * mon.dt - half, t0 + (last * mon.n_hop + centre) * mon.dt + half)


def record_diagnosis(
    path: str | Path,
    sim: Any,
    threshold: Threshold | None,
    mode_outputs: dict[str, tuple[np.ndarray, np.ndarray, tuple[str, ...]]],
    *,
    config: STFTConfig | None = None,
    chunk_samples: int = 10_000,
    route_series: dict[str, tuple[np.ndarray, np.ndarray, float, str]] | None = None,
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
        base = None
        if threshold is not None:
            settings = MonitorSettings(stft=config or STFTConfig(), threshold=threshold)
            mon = ChatteringMonitor(sc.nominal, settings)
            span = _span(mon, z0.shape[0])
            truth = scenario_truth(sc)
            logger = RerunLogger(sinks, mon, truth=truth, span_s=span, send_blueprint=False)
            for lo in range(0, z0.shape[0], int(chunk_samples)):
                logger.log_update(mon.push(z0[lo : lo + chunk_samples], u0[lo : lo + chunk_samples]))
            base = blueprint(
                mon.channels, has_truth=True, band_hz=logger.band_hz, span_s=span, db_range=DB_RANGE
            )
        else:
            span = (float(sim.t[0]), float(sim.t[-1]))
        time_range = rrb.VisibleTimeRange(
            TIMELINE,
            start=rrb.TimeRangeBoundary.absolute(nanos=int(to_ns(span[0]))),
            end=rrb.TimeRangeBoundary.absolute(nanos=int(to_ns(span[1]))),
        )
        views = []
        for method, (t, mu, modes) in mode_outputs.items():
            ns = to_ns(np.asarray(t, dtype=float))
            mu = np.asarray(mu, dtype=float)
            mu = mu[0] if mu.ndim == 3 else mu
            for s in sinks.streams:
                for j, mode in enumerate(modes):
                    ent = f"/modes/{method}/{_entity(mode)}"
                    color = _MODE_COLORS[j % len(_MODE_COLORS)]
                    s.log(ent, rr.SeriesLines(colors=[color], names=[f"mu {mode}"]), static=True)
                    s.send_columns(
                        ent,
                        indexes=[rr.TimeColumn(TIMELINE, duration=ns.astype("timedelta64[ns]"))],
                        columns=rr.Scalars.columns(scalars=np.asarray(mu[:, j], dtype=float)),
                    )
            views.append(
                rrb.TimeSeriesView(
                    origin=f"/modes/{method}",
                    name=f"{method}: mode probabilities ({', '.join(modes)})",
                    time_ranges=time_range,
                    axis_y=rrb.ScalarAxis(range=(0.0, 1.0)),
                )
            )
        route_views = [
            _log_route(sinks, rr, rrb, method, series, time_range)
            for method, series in (route_series or {}).items()
        ]
        parts: list[Any] = []
        if route_views:
            parts.append(rrb.Horizontal(*route_views))
        if views:
            parts.append(rrb.Horizontal(*views))
        if base is not None:
            parts.append(base.root_container)
        shares = [1.2] * (len(parts) - (base is not None)) + ([6.0] if base is not None else [])
        root = rrb.Vertical(*parts, row_shares=shares)
        extra = [base.time_panel] if base is not None else []
        bp = rrb.Blueprint(root, *extra, collapse_panels=True)
        for s in sinks.streams:
            s.send_blueprint(bp, make_active=True, make_default=True)
    finally:
        try:
            if logger is not None:
                logger.close()
        finally:
            sinks.close()
    return Path(path)


def _log_route(sinks: Any, rr: Any, rrb: Any, method: str, series: tuple, time_range: Any) -> Any:
    """Log one route's statistic and threshold as two series; return its view."""
    t, stat, h, name = series
    ns = to_ns(np.asarray(t, dtype=float)).astype("timedelta64[ns]")
    stat = np.asarray(stat, dtype=float)
    hline = np.full(stat.shape, float(h) if np.isfinite(h) else np.nan)
    for s in sinks.streams:
        for ent, vals, color, label in (
            (f"/routes/{method}/statistic", stat, [31, 119, 180], name),
            (f"/routes/{method}/threshold", hline, [214, 39, 40], "threshold"),
        ):
            s.log(ent, rr.SeriesLines(colors=[color], names=[label]), static=True)
            s.send_columns(
                ent, indexes=[rr.TimeColumn(TIMELINE, duration=ns)], columns=rr.Scalars.columns(scalars=vals)
            )
    return rrb.TimeSeriesView(
        origin=f"/routes/{method}", name=f"{method}: {name} and threshold", time_ranges=time_range
    )


def record_budget_diagnosis(
    path: str | Path,
    scenario: Any,
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
        Method -> route (:mod:`chatterspec.studies.routes`); the results' own routes (as diagnosed,
        e.g. with a healthy NIS scale) are used where they carry one.
    results : list of RouteBudget
        Their results (the calibrated rules).
    threshold : Threshold or None
        Per-frame threshold of the chattering monitor's spectrogram view (None: no chattering part).

    Returns
    -------
    Path
    """
    from ..detection.alarms import rule_from_dict, run_rule
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
        label = {"frame": "score", "persistence": "exceedances in window", "cusum": "CUSUM g"}[rule.name]
        series[method] = (times, stat, rule.threshold, label)
    return record_diagnosis(
        path, sim, threshold if "chattering" in routes else None, modes, route_series=series
    )
