"""Fault diagnosis by mode probabilities (SMM-SVSF, IMM) on the same realizations: the mode-based half of
issue 9 item 6 (``chatterspec diagnose``); the chattering route (item 5) plugs in beside it.

Per method, on one :class:`~chatterspec.plants.simulate.Simulation`:

* **alarm**: at sample k the method declares a fault when its most probable mode is not the first
  (healthy) mode of ``filter_settings.modes``;
* **false alarms**: on the healthy samples (true mode 0), per run: does the run raise any alarm there
  (family-wise, with a Clopper-Pearson interval over runs), and the fraction of healthy samples in alarm;
* **detection delay** per fault onset: first sample at or after the onset whose argmax is a fault mode,
  minus the onset (s); **isolation delay**: first sample whose argmax is the *true* new mode; median and
  90th percentile over runs (NaN-aware: runs that never detect are counted separately);
* **isolation**: the confusion matrix (:func:`~chatterspec.studies.modes.confusion_matrix`);
* **cost**: realization-steps per second of the filter alone.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError
from ..filters import ExtendedKalmanFilter
from ..filters.multiple_model import IMM, SMMSVSF
from .intervals import clopper_pearson
from .modes import confusion_matrix

__all__ = ["METHODS", "ModeDiagnosis", "diagnose_modes"]

#: Mode-based methods offered here.
METHODS = ("smm", "imm")


@dataclass(frozen=True, eq=False)
class ModeDiagnosis:
    """Diagnosis figures of one mode-based method.

    Attributes
    ----------
    method : str
        ``"smm"`` or ``"imm"``.
    modes : tuple of str
        Mode names (index 0 = healthy).
    runs : int
        Realizations.
    false_alarm_runs : int
        Runs with at least one alarm on a healthy sample.
    false_alarm_rate : float
        ``false_alarm_runs / runs`` (family-wise per run).
    false_alarm_ci : tuple of float
        99 % Clopper-Pearson interval of that rate.
    healthy_alarm_fraction : float
        Fraction of the healthy samples (all runs) in alarm.
    onsets : tuple of float
        Fault onset times in seconds.
    detection_median, detection_p90 : tuple of float
        Median / 90th percentile over the detecting runs of the detection delay per onset (s).
    isolation_median, isolation_p90 : tuple of float
        Same for the isolation delay (argmax = true new mode).
    missed : tuple of int
        Runs that never isolate the new mode before the next switch, per onset.
    confusion : (r, r) array
        Mean mode probability per actual mode (percent; columns sum to 100).
    steps_per_second : float
        Realization-steps per second of the filter.
    new_modes : tuple of int
        Index of the mode switched to at each onset.
    """

    method: str
    modes: tuple[str, ...]
    runs: int
    false_alarm_runs: int
    false_alarm_rate: float
    false_alarm_ci: tuple[float, float]
    healthy_alarm_fraction: float
    onsets: tuple[float, ...]
    detection_median: tuple[float, ...]
    detection_p90: tuple[float, ...]
    isolation_median: tuple[float, ...]
    isolation_p90: tuple[float, ...]
    missed: tuple[int, ...]
    confusion: np.ndarray
    steps_per_second: float
    new_modes: tuple[int, ...] = ()

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""

        def f(v: float) -> float | None:
            return None if not np.isfinite(v) else float(v)

        return {
            "method": self.method,
            "modes": list(self.modes),
            "runs": self.runs,
            "false_alarm_runs": self.false_alarm_runs,
            "false_alarm_rate": self.false_alarm_rate,
            "false_alarm_ci99": list(self.false_alarm_ci),
            "healthy_alarm_fraction": self.healthy_alarm_fraction,
            "onsets_s": list(self.onsets),
            "detection_delay_median_s": [f(v) for v in self.detection_median],
            "detection_delay_p90_s": [f(v) for v in self.detection_p90],
            "isolation_delay_median_s": [f(v) for v in self.isolation_median],
            "isolation_delay_p90_s": [f(v) for v in self.isolation_p90],
            "missed": list(self.missed),
            "confusion_percent": [[f(v) for v in row] for row in self.confusion],
            "steps_per_second": self.steps_per_second,
            "new_modes": [self.modes[i] for i in self.new_modes],
        }


def _filter_for(method: str, settings: object) -> SMMSVSF | IMM:
    fs = settings
    if not fs.modes:  # type: ignore[attr-defined]
        raise ParameterError("the scenario's filter_settings name no modes: mode-based diagnosis needs them")
    models = fs.mode_models  # type: ignore[attr-defined]
    if method == "smm":
        if fs.psi is None:  # type: ignore[attr-defined]
            raise ParameterError("SMM-SVSF needs filter_settings.psi (the boundary layer)")
        return SMMSVSF(
            models,
            psi=np.array(fs.psi),  # type: ignore[attr-defined]
            gamma=0.1 if fs.gamma is None else fs.gamma,  # type: ignore[attr-defined]
            mapping=fs.mapping if fs.mapping in ("full", "pinv", "cov") else None,  # type: ignore[attr-defined]
            weight_floor=1e-3 if fs.weight_floor is None else fs.weight_floor,  # type: ignore[attr-defined]
            mu0=None if fs.mu0 is None else np.array(fs.mu0),  # type: ignore[attr-defined]
            modes=fs.modes,  # type: ignore[attr-defined]
        )
    if method == "imm":
        if fs.transition_matrix is None:  # type: ignore[attr-defined]
            raise ParameterError("IMM needs filter_settings.transition_matrix (the scenario prints none)")
        return IMM(
            [ExtendedKalmanFilter(mdl) for mdl in models],
            fs.transition_matrix,  # type: ignore[attr-defined]
            mu0=None if fs.mu0 is None else np.array(fs.mu0),  # type: ignore[attr-defined]
            modes=fs.modes,  # type: ignore[attr-defined]
        )
    raise ParameterError(f"method must be one of {', '.join(METHODS)}; got {method!r}")


def _delays(first: np.ndarray, t: np.ndarray, k0: int) -> np.ndarray:
    return np.where(first >= 0, t[k0 + np.maximum(first, 0)] - t[k0], np.nan)


def diagnose_modes(
    sim: object, methods: Sequence[str] = METHODS, *, keep: dict | None = None
) -> list[ModeDiagnosis]:
    """Run each mode-based method on the same realizations and measure its diagnosis figures.

    Parameters
    ----------
    sim : Simulation
        Realizations of a scenario whose ``filter_settings`` name the modes (mode 0 = healthy), e.g.
        ``simulate(scenario("eha4-leak-timeline"), runs, seed)``.
    methods : sequence of str
        Any of :data:`METHODS`. IMM uses a bank of EKFs and the scenario's transition matrix.
    keep : dict, optional
        When given, ``keep[method]`` receives ``(t, mu, modes)``: the times ``sim.t[1:]`` (s), the mode
        probabilities ``(runs, T - 1, r)`` and the mode names (for ``diagnose --record`` and figures).

    Returns
    -------
    list of ModeDiagnosis
        One per method, in the given order.
    """
    sc = sim.scenario  # type: ignore[attr-defined]
    fs = sc.filter_settings
    if fs is None:
        raise ParameterError(f"scenario {sc.name!r} has no filter_settings (no modes to diagnose)")
    z, u = sim.z[:, 1:], sim.u[:-1]  # type: ignore[attr-defined]
    t = sim.t[1:]  # type: ignore[attr-defined]
    runs, T = z.shape[:2]
    true = fs.mode_index(sc)[1:]
    x0 = np.zeros(sc.nominal.n_states) if fs.x0 is None else fs.x0
    P0 = fs.P0 if fs.P0 is not None else np.asarray(sc.nominal.Q) * 10.0
    change = np.flatnonzero((true[1:] != true[:-1]) & (true[1:] > 0)) + 1
    ends = np.append(change[1:], T)
    results = []
    for method in methods:
        filt = _filter_for(method, fs)
        t0 = time.perf_counter()
        out = filt.run(z, u, x0=x0, P0=P0)
        wall = time.perf_counter() - t0
        if keep is not None:
            keep[method] = (t, np.asarray(out.mu), tuple(fs.modes))
        am = out.argmax_mode
        alarm = am != 0
        healthy = true == 0
        fa_runs = int(np.count_nonzero(alarm[:, healthy].any(axis=1))) if healthy.any() else 0
        det_med, det_p90, iso_med, iso_p90, missed = [], [], [], [], []
        for k0, k1 in zip(change, ends, strict=True):
            seg = slice(k0, k1)
            hit_d = alarm[:, seg]
            hit_i = am[:, seg] == true[k0]
            dd = _delays(np.where(hit_d.any(axis=1), np.argmax(hit_d, axis=1), -1), t, k0)
            di = _delays(np.where(hit_i.any(axis=1), np.argmax(hit_i, axis=1), -1), t, k0)
            for arr, med, p90 in ((dd, det_med, det_p90), (di, iso_med, iso_p90)):
                ok = arr[np.isfinite(arr)]
                med.append(float(np.median(ok)) if ok.size else float("nan"))
                p90.append(float(np.quantile(ok, 0.9)) if ok.size else float("nan"))
            missed.append(int(np.count_nonzero(~np.isfinite(di))))
        results.append(
            ModeDiagnosis(
                method=method,
                modes=tuple(fs.modes),
                runs=runs,
                false_alarm_runs=fa_runs,
                false_alarm_rate=fa_runs / runs,
                false_alarm_ci=clopper_pearson(fa_runs, runs, 0.99),
                healthy_alarm_fraction=float(alarm[:, healthy].mean()) if healthy.any() else float("nan"),
                onsets=tuple(float(v) for v in t[change]),
                detection_median=tuple(det_med),
                detection_p90=tuple(det_p90),
                isolation_median=tuple(iso_med),
                isolation_p90=tuple(iso_p90),
                missed=tuple(missed),
                confusion=confusion_matrix(out.mu, true),
                steps_per_second=runs * T / wall if wall > 0 else float("inf"),
                new_modes=tuple(int(true[k]) for k in change),
            )
        )
    return results
