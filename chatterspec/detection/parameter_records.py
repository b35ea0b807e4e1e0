"""Decisions on the identified parameters over whole records, every record at once.

:func:`monitor_parameters` is what ``chatterspec monitor`` decides per hop with tolerances
(:mod:`chatterspec.detection.parameter_decision`), on many records together (vectorized over records
and hops): for studies of false alarms and detection delays, and for benches that monitor a model
with tolerances. :func:`record_decisions` decides once per record on its whole-record identification
(``chatterspec detect``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .._validate import open_unit, positive, positive_int
from .alarms.rules import AlarmRule
from .alarms.streams import AlarmStream
from .parameter_decision import (
    ParameterAlarmSettings,
    ParameterDecisions,
    _Horizon,
    decide,
    parameter_alarm_settings,
)
from .parameter_scores import ParameterBands, band_scores, joint_estimates

__all__ = ["monitor_parameters", "record_decisions"]


def monitor_parameters(
    model: Any,
    z: np.ndarray,
    u: np.ndarray,
    settings: ParameterAlarmSettings | None = None,
    *,
    hop_s: float = 0.2,
    window_s: float = 1.0,
    rule: AlarmRule | str = "cusum",
    false_alarms_per_hour: float = 1.0 / 24.0,
    t0: float = 0.0,
    confidence: float = 0.95,
    chunk_runs: int = 64,
) -> ParameterDecisions:
    """The monitor's decisions on the identified parameters over whole records, every record at once.

    What ``chatterspec monitor`` decides per hop with tolerances (the module docstring), on many
    records together (vectorized over records and hops; each record starts from no alarm): for
    studies of the false alarms and detection delays of a model with tolerances.

    Parameters
    ----------
    model : LinearModel
        Nominal model with a parameter map (tolerances in its parameters: alarms; none: only the
        estimates, detectability and excitation).
    z : (runs, T, m) or (T, m) array
        Measurements (finite).
    u : (T, p), (runs, T, p) or (T,) array
        Inputs.
    settings : ParameterAlarmSettings, optional
        Default :func:`parameter_alarm_settings` with ``hop_s``, ``window_s``, ``rule`` and
        ``false_alarms_per_hour``.
    hop_s, window_s : float
        Hop and identification window (s), multiples of ``model.dt`` (the monitor's STFT hop and
        window; ignored with ``settings``, which fixes them).
    rule : alarm rule or str
    false_alarms_per_hour : float
    t0 : float
        Time (s) of ``z[:, 0]``.
    confidence : float
        Level of the intervals.
    chunk_runs : int
        Records per vectorized block (bounds the memory; the numbers do not depend on it).

    Returns
    -------
    ParameterDecisions
    """
    from .._validate import finite_array
    from .identification import hop_windows, identification_setup, identify_moments

    full = identification_setup(model, [list(model.parameter_map.parameter_names)])  # the joint fit only
    if settings is None:
        H = max(1, round(positive("hop_s", hop_s, unit="s") / model.dt))
        n = max(1, round(positive("window_s", window_s, unit="s") / (H * model.dt)))
        settings = parameter_alarm_settings(
            full, hop_s=H * model.dt, window_hops=n, rule=rule, false_alarms_per_hour=false_alarms_per_hour
        )
    H = max(1, round(settings.hop_s / model.dt))
    z = finite_array("z", z, ndim=(2, 3))
    z = z[None] if z.ndim == 2 else z
    u = finite_array("u", u, ndim=(1, 2, 3))
    u = u[:, None] if u.ndim == 1 else u
    confidence = open_unit("confidence", confidence)
    runs = z.shape[0]
    cal = settings.calibration
    parts: list[tuple[np.ndarray, ...]] = []
    times = np.zeros(0)
    for lo in range(0, runs, positive_int("chunk_runs", chunk_runs)):
        hi = min(runs, lo + chunk_runs)
        uc = u if u.ndim == 2 else u[lo:hi]
        _, times, mom = hop_windows(
            full, z[lo:hi], uc, hop_samples=H, window_hops=settings.window_hops, t0=t0
        )
        res = identify_moments(full, mom, confidence=confidence)
        theta, se, fits = joint_estimates(res)
        W = times.size
        theta, se, fits = theta.reshape(hi - lo, W, -1), se.reshape(hi - lo, W, -1), fits.reshape(hi - lo, W)
        stream = None if cal is None else AlarmStream(cal.rule, (hi - lo, settings.bands.size))
        parts.append(decide(theta, se, fits, settings, confidence, stream, _Horizon(settings.horizon_hops)))
    arrays = [np.concatenate([p[k] for p in parts]) for k in range(11)]
    frames = np.arange(times.size)
    return ParameterDecisions.from_block(times, frames, arrays, settings=settings)


def record_decisions(identification: Any, alpha: float) -> dict[str, np.ndarray]:
    """Whole-record decisions on the identified parameters, one per realization.

    Each parameter's joint estimate is tested against its band (the p-value of :func:`band_scores`)
    at ``alpha / P`` (Bonferroni over the ``P`` parameters: a healthy record, every parameter inside
    its band, is declared faulty with probability at most ``alpha``, the detector's per-record level).

    Parameters
    ----------
    identification : Identification
        Whole-record identification (the default setup: it tests the joint hypothesis).
    alpha : float
        Per-record level.

    Returns
    -------
    dict
        ``estimate``, ``std_error``, ``p_value`` and ``outside`` (bool), arrays ``(runs, P)`` in table
        order, and ``fits`` ``(runs,)``: False where the record is not described by constant parameters
        (a change within it: no decision, ``p_value`` NaN).
    """
    setup = identification.setup
    theta, se, fits = joint_estimates(identification)
    bands = ParameterBands.from_map(setup.parameter_map)
    ok = np.isfinite(se) & fits[:, None]
    p = np.where(ok, np.exp(-band_scores(theta, se, bands.low, bands.high)), np.nan)
    a = open_unit("alpha", alpha) / bands.size
    return {"estimate": theta, "std_error": se, "p_value": p, "outside": ok & (p <= a), "fits": fits}
