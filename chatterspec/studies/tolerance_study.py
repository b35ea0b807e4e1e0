"""Decisions on the identified parameters, measured: false alarms of plants inside their tolerances,
detection of changes beyond them, and the excitation a held actuator lacks.

Used by ``scripts/tolerance_study.py`` (the long runs, numbers in ``docs/paper-notes.md``), the
figures of :mod:`chatterspec.figures.plot_diagnosis` and the tests (short versions). The linear EHA
of the catalogue with the tolerances :data:`EHA_TOLERANCES` (bulk modulus +-15 %, friction +-30 %,
leakage +-100 %), the catalogue chirp repeated every 4 s (:class:`~chatterspec.plants.signals.Repeat`)
so that records may be long, and the monitor's decision (:func:`~chatterspec.detection.
parameter_decision.monitor_parameters`: 1 s window, 0.2 s hop, CUSUM at the budget).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, cast

import numpy as np

from ..detection.parameter_decision import (
    ParameterAlarmSettings,
    monitor_parameters,
    parameter_alarm_settings,
)
from ..plants.models import EHAFault, eha_linear
from ..plants.parameters import with_tolerances
from ..plants.scenarios import Scenario, Segment
from ..plants.signals import Chirp, Repeat
from ..plants.simulate import iter_simulations
from .intervals import clopper_pearson

__all__ = [
    "EHA_TOLERANCES",
    "chirp_scenario",
    "drift_record",
    "eha_with_tolerances",
    "excitation_cycle",
    "false_alarm_study",
    "onset_study",
    "study_settings",
]

#: The study's operating tolerances of the linear EHA's parameters.
EHA_TOLERANCES: Mapping[str, str] = {"leakage": "100%", "friction": "30%", "bulk_modulus": "15%"}
#: The catalogue chirp (10-100 Hz over 4 s, 300 rad/s), repeated.
CHIRP = Repeat(Chirp(10.0, 100.0, 4.0, 300.0), 4.0)


def eha_with_tolerances(tolerances: Mapping[str, str] = EHA_TOLERANCES) -> Any:
    """The catalogue's linear EHA (its nominal model) with ``tolerances``."""
    return with_tolerances(eha_linear(), dict(tolerances))


def chirp_scenario(
    name: str,
    duration_s: float,
    plant: Mapping[str, float] | None = None,
    fault: Mapping[str, float] | None = None,
    onset_s: float | None = None,
) -> Scenario:
    """The linear EHA under the repeated catalogue chirp: true plant ``plant`` (parameters of
    :func:`~chatterspec.plants.models.eha_linear`), changed to ``{**plant, **fault}`` from ``onset_s``.

    Parameters
    ----------
    name : str
    duration_s : float
        Record length (s).
    plant : mapping, optional
        The true plant's parameters before the onset (default the nominal model).
    fault : mapping, optional
        Parameters changed at ``onset_s`` (default none).
    onset_s : float, optional
        Onset time (s); required with ``fault``.
    """
    true = cast(EHAFault, dict(plant or {}))  # eha_linear's physical parameters
    windows: tuple[Segment, ...] = ()
    if fault:
        if onset_s is None:
            raise ValueError("a fault needs its onset_s")
        changed = cast(EHAFault, {**true, **fault})
        windows = (Segment(float(onset_s), float(duration_s), eha_linear(**changed), "fault"),)
    return Scenario(
        name=name,
        nominal=eha_linear(),
        plant=eha_linear(**true) if plant else None,
        windows=windows,
        input=CHIRP,
        duration=float(duration_s),
        description=f"linear EHA {plant or 'nominal'}, {fault or 'no fault'}; {CHIRP.describe()}",
        family="eha",
    )


def study_settings(
    model: Any, false_alarms_per_hour: float = 1.0 / 24.0, **kw: Any
) -> ParameterAlarmSettings:
    """The monitor's parameter decision for ``model``: 0.2 s hop, 1 s window, CUSUM at the budget.

    Parameters
    ----------
    model : LinearModel
        With tolerances on its parameters.
    false_alarms_per_hour : float
        The budget (default one per day).
    **kw
        Other keyword arguments of :func:`~chatterspec.detection.parameter_decision.parameter_alarm_settings`.
    """
    from ..detection.identification import identification_setup

    setup = identification_setup(model, [list(model.parameter_map.parameter_names)])
    return parameter_alarm_settings(
        setup, hop_s=0.2, window_hops=5, false_alarms_per_hour=false_alarms_per_hour, **kw
    )


def false_alarm_study(
    model: Any,
    plant: Mapping[str, float] | None,
    hours: float,
    *,
    record_s: float = 150.0,
    seed: int = 0,
    chunk_runs: int = 64,
    settings: ParameterAlarmSettings | None = None,
) -> dict[str, Any]:
    """Alarm starts of the parameter decision on ``hours`` of a plant that does not change.

    Parameters
    ----------
    model : LinearModel
        Nominal model with tolerances.
    plant : mapping or None
        The true plant's parameters (None: the nominal model).
    hours : float
        Data simulated, in records of ``record_s`` seconds (each from no alarm).
    record_s, seed, chunk_runs
        Record length (s), root seed, records per vectorized block (the noise is drawn 64 records at a
        time: a multiple of 64 wastes none).
    settings : ParameterAlarmSettings, optional
        Default :func:`study_settings` (one false alarm per day).

    Returns
    -------
    dict
        ``hours``, ``starts`` (per parameter), ``budget`` (alarm starts per hour), ``expected`` (at the
        budget), ``inside`` (per parameter: fraction of windows whose interval lies inside the band),
        ``median_estimate`` (per parameter).
    """
    settings = settings or study_settings(model)
    runs = max(1, round(hours * 3600.0 / record_s))
    sc = chirp_scenario("plant", record_s, plant)
    b = settings.bands
    starts = np.zeros(b.size, dtype=np.int64)
    inside = np.zeros(b.size)
    windows = 0
    est: list[np.ndarray] = []
    for sim in iter_simulations(sc, runs, seed, chunk_runs=chunk_runs):
        rec = monitor_parameters(model, sim.z, sim.u, settings)
        starts += rec.starts.sum(axis=(0, 1))
        inside += ((rec.ci_low >= b.low) & (rec.ci_high <= b.high)).sum(axis=(0, 1))
        windows += rec.estimate.shape[0] * rec.estimate.shape[1]
        est.append(np.median(rec.estimate, axis=1))
    h = runs * record_s / 3600.0
    return {
        "hours": h,
        "records": runs,
        "starts": dict(zip(b.names, starts.tolist(), strict=True)),
        "total_starts": int(starts.sum()),
        "budget": settings.false_alarms_per_hour,
        "expected": settings.false_alarms_per_hour * h,
        "inside": dict(zip(b.names, (inside / max(windows, 1)).tolist(), strict=True)),
        "median_estimate": dict(zip(b.names, np.median(np.concatenate(est), axis=0).tolist(), strict=True)),
    }


def onset_study(
    model: Any,
    fault: Mapping[str, float],
    runs: int,
    *,
    onset_s: float = 20.0,
    record_s: float = 30.0,
    plant: Mapping[str, float] | None = None,
    seed: int = 0,
    chunk_runs: int = 64,
    settings: ParameterAlarmSettings | None = None,
) -> dict[str, Any]:
    """Detection of a change ``fault`` at ``onset_s`` by the parameter decision, one onset per record.

    The delay of a record is the time from the onset to the end of the window of its first alarm start
    at or after the onset (when the monitor knew); an alarm before the onset counts as a false alarm.

    Parameters
    ----------
    model : LinearModel
        Nominal model with tolerances.
    fault : mapping
        The parameters changed at ``onset_s`` (:func:`chirp_scenario`).
    runs : int
        Records (one onset each).
    onset_s, record_s : float
        Onset and record length (s).
    plant : mapping, optional
        The true plant before the onset (default nominal).
    seed, chunk_runs
        Root seed and records per vectorized block.
    settings : ParameterAlarmSettings, optional
        Default :func:`study_settings`.

    Returns
    -------
    dict
        ``runs``, ``detected`` with its 99 % Clopper-Pearson interval, ``delay_median_s``,
        ``delay_p90_s``, ``first_parameter`` (counts of the parameter of the first alarm),
        ``alarms_before_onset``, ``named`` (per parameter: records with that parameter's alarm active in
        the last window).
    """
    settings = settings or study_settings(model)
    sc = chirp_scenario("onset", record_s, plant, fault, onset_s)
    half = 0.5 * settings.window_hops * settings.hop_s  # from a window's centre to its end
    delays, first, before = [], [], 0
    named = np.zeros(settings.bands.size, dtype=np.int64)
    for sim in iter_simulations(sc, runs, seed, chunk_runs=chunk_runs):
        rec = monitor_parameters(model, sim.z, sim.u, settings)
        known = rec.times_s + half
        starts = rec.starts
        before += int(starts[:, known <= onset_s].any(axis=(1, 2)).sum())
        after = starts & (known > onset_s)[None, :, None]
        hit = np.any(after, axis=2)
        j = np.argmax(hit, axis=1)
        ok = np.any(hit, axis=1)
        delays.extend((known[j[ok]] - onset_s).tolist())
        first.extend(np.argmax(after[np.flatnonzero(ok), j[ok]], axis=1).tolist())
        named += rec.alarm[:, -1].sum(axis=0)
    d = np.asarray(delays)
    names = settings.bands.names
    return {
        "runs": runs,
        "detected": len(d),
        "detected_ci99": list(clopper_pearson(len(d), runs)),
        "delay_median_s": float(np.median(d)) if d.size else float("nan"),
        "delay_p90_s": float(np.quantile(d, 0.9)) if d.size else float("nan"),
        "first_parameter": {n: int(np.sum(np.asarray(first) == i)) for i, n in enumerate(names)},
        "alarms_before_onset": before,
        "named": dict(zip(names, named.tolist(), strict=True)),
    }


#: The hold-move-hold cycle of :func:`excitation_cycle`: held at 0 mm, four 10 mm minimum-jerk moves of
#: 0.5 s from 15 s on (the catalogue's moves), held again to 35 s.
CYCLE_MOVES = (15.0, 16.0, 17.0, 18.0)
CYCLE_DURATION_S = 35.0


def excitation_cycle(
    dither_amplitude: float | None,
    runs: int = 16,
    *,
    seed: int = 0,
    leakage: float | None = None,
    horizon_s: float | None = None,
    tolerances: Mapping[str, str] = EHA_TOLERANCES,
) -> Any:
    """The parameter decision over a hold-move-hold cycle of the closed-loop EHA (``eha-cl-*`` loop and
    sensor), without or with the closed-loop study's multisine dither on the pump command.

    Parameters
    ----------
    dither_amplitude : float or None
        Amplitude of each tone of the 20/30/40 Hz multisine (rad/s); None: no dither.
    runs, seed
        Realizations and root seed.
    leakage : float, optional
        The true plant's leakage (default the nominal).
    horizon_s : float, optional
        Detectability horizon (default the decision's).
    tolerances : mapping
        The tolerances of the decision.

    Returns
    -------
    ParameterDecisions
        Of the ``runs`` records (35 s each).
    """
    from ..plants.closed_loop import ClosedLoop, Multisine, SCurve
    from ..plants.scenarios import EHA_CL_CONTROLLER, eha_closed_loop_scenario

    ref = SCurve(CYCLE_MOVES, (0.01, -0.01, 0.01, 0.0), 0.5)
    dither = None if dither_amplitude is None else Multisine(float(dither_amplitude))
    kw: EHAFault = {} if leakage is None else {"leakage": float(leakage)}
    sc = eha_closed_loop_scenario(
        "hold-move-hold", ClosedLoop(EHA_CL_CONTROLLER, ref, dither=dither), duration_s=CYCLE_DURATION_S, **kw
    )
    from ..plants.simulate import simulate

    model = with_tolerances(sc.nominal, dict(tolerances))
    extra = {} if horizon_s is None else {"horizon_s": horizon_s}
    settings = study_settings(model, **extra)
    sim = simulate(sc, runs, seed)
    return monitor_parameters(model, sim.z, sim.u, settings)


def drift_record(seed: int = 0, duration_s: float = 60.0, step_s: float = 2.0) -> tuple[Any, Any]:
    """A plant drifting in steps: the bulk modulus from nominal to 25 % below it (its +-15 % band is left
    at about 60 % of the way) and the friction from nominal to 20 % above it (inside its +-30 %), under
    the repeated chirp; one record through the parameter decision.

    Parameters
    ----------
    seed : int
        Seed of the record.
    duration_s, step_s : float
        Record length and the length of each step of the drift (s).

    Returns
    -------
    (ParameterDecisions, dict)
        The decisions and the true values ``{"times_s", "bulk_modulus", "friction"}`` per step.
    """
    from ..plants.simulate import simulate

    starts = np.arange(0.0, duration_s, step_s)
    frac = starts / duration_s
    be, a = 2.07e8 * (1.0 - 0.25 * frac), 2144.0 * (1.0 + 0.2 * frac)
    windows = tuple(
        Segment(float(t0), float(min(t0 + step_s, duration_s)), eha_linear(bulk_modulus=b, friction=f), "")
        for t0, b, f in zip(starts[1:], be[1:], a[1:], strict=True)
    )
    sc = Scenario(
        name="drift",
        nominal=eha_linear(),
        windows=windows,
        input=CHIRP,
        duration=float(duration_s),
        description="bulk modulus drifting to -25 %, friction to +20 %",
        family="eha",
    )
    model = eha_with_tolerances()
    sim = simulate(sc, 1, seed)
    rec = monitor_parameters(model, sim.z, sim.u, study_settings(model))
    return rec, {"times_s": starts, "bulk_modulus": be, "friction": a}
