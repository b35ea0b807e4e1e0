"""Rerun recording of ``chatterspec diagnose --record FILE.rrd``: realization 0 on one
timeline -- the chattering spectrogram, frame verdicts and detection events of the online monitor
(:class:`~chatterspec.online.rerun_log.RerunLogger`, unchanged) beside the mode probabilities of the
SMM-SVSF / IMM (one scalar series per mode under ``/modes/<method>/<mode>``).

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

__all__ = ["record_diagnosis"]

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
        parts: list[Any] = []
        if views:
            parts.append(rrb.Horizontal(*views))
        if base is not None:
            parts.append(base.root_container)
        shares = [1.2, 6.0] if len(parts) == 2 else [1.0]
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
