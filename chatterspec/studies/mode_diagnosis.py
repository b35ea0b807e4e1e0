"""Fault diagnosis by mode probabilities (SMM-SVSF, IMM) on the same realizations: the mode-based routes of
``chatterspec diagnose`` (``docs/design.md`` §2); the chattering route
(:mod:`chatterspec.studies.chattering_diagnosis`) plugs in beside it.

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
from typing import TYPE_CHECKING

import numpy as np

from .._repr import short_repr
from .._validate import finite_array
from ..errors import ParameterError
from ..filters import ExtendedKalmanFilter
from ..filters.imm import IMM
from ..filters.smm_svsf import SMMSVSF
from ..jsonout import finite_or_none
from .diagnosis_figures import DiagnosisFigures
from .intervals import clopper_pearson

if TYPE_CHECKING:  # pragma: no cover
    from ..plants.scenarios import FilterSettings, Scenario
    from ..plants.simulate import Simulation

__all__ = ["METHODS", "ModeDiagnosis", "ModeTally", "diagnose_modes"]

#: Mode-based methods offered here.
METHODS = ("smm", "imm")


@dataclass(frozen=True, eq=False)
class ModeDiagnosis(DiagnosisFigures):
    """Diagnosis figures of one mode-based method.

    The false-alarm and detection-delay figures (and ``method``, ``runs``, ``steps_per_second``) are
    those every route reports (:class:`~chatterspec.studies.diagnosis_figures.DiagnosisFigures`); here
    a verdict is one sample's most probable mode.

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

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    # method, runs, the false-alarm and detection-delay figures, steps_per_second: DiagnosisFigures
    modes: tuple[str, ...]
    isolation_median: tuple[float, ...]
    isolation_p90: tuple[float, ...]
    missed: tuple[int, ...]
    confusion: np.ndarray
    new_modes: tuple[int, ...] = ()

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""
        return {
            "method": self.method,
            "modes": list(self.modes),
            "runs": self.runs,
            **self.alarm_figures(),
            "isolation_delay_median_s": [finite_or_none(v) for v in self.isolation_median],
            "isolation_delay_p90_s": [finite_or_none(v) for v in self.isolation_p90],
            "missed": list(self.missed),
            "confusion_percent": [[finite_or_none(v) for v in row] for row in self.confusion],
            "steps_per_second": self.steps_per_second,
            "new_modes": [self.modes[i] for i in self.new_modes],
        }


def _filter_for(method: str, settings: FilterSettings) -> SMMSVSF | IMM:
    fs = settings
    if not fs.modes:
        raise ParameterError("the scenario's filter_settings name no modes: mode-based diagnosis needs them")
    models = fs.mode_models
    if method == "smm":
        if fs.psi is None:
            raise ParameterError("SMM-SVSF needs filter_settings.psi (the boundary layer)")
        return SMMSVSF(
            models,
            psi=np.array(fs.psi),
            gamma=0.1 if fs.gamma is None else fs.gamma,
            mapping=fs.mapping if fs.mapping in ("full", "pinv", "cov") else None,
            weight_floor=1e-3 if fs.weight_floor is None else fs.weight_floor,
            mu0=None if fs.mu0 is None else np.array(fs.mu0),
            modes=fs.modes,
        )
    if method == "imm":
        if fs.transition_matrix is None:
            raise ParameterError("IMM needs filter_settings.transition_matrix (the scenario prints none)")
        return IMM(
            [ExtendedKalmanFilter(mdl) for mdl in models],
            fs.transition_matrix,
            mu0=None if fs.mu0 is None else np.array(fs.mu0),
            modes=fs.modes,
        )
    raise ParameterError(f"method must be one of {', '.join(METHODS)}; got {method!r}")


def _delays(first: np.ndarray, t: np.ndarray, k0: int) -> np.ndarray:
    return np.where(first >= 0, t[k0 + np.maximum(first, 0)] - t[k0], np.nan)


def diagnose_modes(
    sim: Simulation, methods: Sequence[str] = METHODS, *, keep: dict | None = None
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

    Notes
    -----
    Same as one :meth:`ModeTally.add` of ``sim`` per method (use the tallies to feed runs in chunks).
    """
    sc = sim.scenario
    results = []
    for method in methods:
        tally = ModeTally(sc, method)
        tally.add(sim, keep=keep, keep_runs=None)
        results.append(tally.result())
    return results


class ModeTally:
    """One method of :func:`diagnose_modes` fed chunk by chunk: memory bounded independently of the runs.

    Each :meth:`add` runs the filter on one chunk of realizations and keeps only per-run scalars (the
    detection and isolation delays per onset) and running totals (false-alarm runs, healthy samples in
    alarm, the confusion sums); :meth:`result` gives the same :class:`ModeDiagnosis` (bit for bit,
    ``steps_per_second`` aside) as :func:`diagnose_modes` on the concatenated runs whatever the
    chunking: each realization's filter output depends only on that realization, the counts are
    integers, the medians come from the same multisets of delays, and the confusion sums continue
    numpy's sequential sum over (run, sample) rows from one chunk to the next.

    Parameters
    ----------
    scenario : Scenario
        The diagnosed scenario (``filter_settings`` with modes; mode 0 = healthy).
    method : str
        One of :data:`METHODS`.
    """

    def __init__(self, scenario: Scenario, method: str) -> None:
        sc = scenario
        fs = sc.filter_settings
        if fs is None:
            raise ParameterError(f"scenario {sc.name!r} has no filter_settings (no modes to diagnose)")
        self.scenario = sc
        self.method = method
        self._filter = _filter_for(method, fs)
        self._fs = fs
        t = sc.time[1:]
        T = t.size
        true = np.asarray(fs.mode_index(sc))[1:]
        self._t, self._true = t, true
        self._x0 = np.zeros(sc.nominal.n_states) if fs.x0 is None else fs.x0
        self._P0 = fs.P0 if fs.P0 is not None else np.asarray(sc.nominal.Q) * 10.0
        change = np.flatnonzero((true[1:] != true[:-1]) & (true[1:] > 0)) + 1
        if true[0] > 0:  # faulty from the start: an onset at the first sample
            change = np.insert(change, 0, 0)
        self._change = change
        self._ends = np.append(change[1:], T)[: change.size]
        self._healthy = true == 0
        r = len(fs.modes)
        self._sums = [np.zeros(r) for _ in range(r)]
        self.runs = 0
        self._wall = 0.0
        self._fa_runs = 0
        self._healthy_alarms = 0
        self._dd: list[list[np.ndarray]] = [[] for _ in self._change]
        self._di: list[list[np.ndarray]] = [[] for _ in self._change]

    def add(self, sim: Simulation, *, keep: dict | None = None, keep_runs: int | None = 1) -> None:
        """Run the filter on one chunk of realizations and keep its per-run figures.

        Parameters
        ----------
        sim : Simulation
            Realizations (k, T, m) of the tally's scenario (e.g. one chunk of
            :func:`~chatterspec.plants.simulate.iter_simulations`).
        keep : dict, optional
            When given and nothing is kept yet, ``keep[method]`` receives ``(t, mu, modes)`` as in
            :func:`diagnose_modes`, with the first ``keep_runs`` realizations of this chunk.
        keep_runs : int or None
            Realizations kept in ``keep`` (None: all of this chunk).
        """
        self.absorb(self.compute(sim), keep=keep, keep_runs=keep_runs)

    def compute(self, sim: Simulation) -> tuple[np.ndarray, np.ndarray, float]:
        """The heavy part of :meth:`add` (the mode filter), without changing the tally.

        Returns ``(mu (k, T, r), argmax mode (k, T), seconds)`` for :meth:`absorb`: worker processes
        compute, the tally absorbs in chunk order (the same figures, bit for bit, as :meth:`add`).
        """
        z, u = sim.z[:, 1:], sim.u[..., :-1, :]  # u per run in closed loop
        if z.shape[1] != self._t.size:
            raise ParameterError(
                f"every chunk must have the scenario's {self._t.size + 1} samples; got {z.shape[1] + 1}"
            )
        t0 = time.perf_counter()
        out = self._filter.run(z, u, x0=self._x0, P0=self._P0)
        return out.mu, out.argmax_mode, time.perf_counter() - t0

    def absorb(
        self,
        computed: tuple[np.ndarray, np.ndarray, float],
        *,
        keep: dict | None = None,
        keep_runs: int | None = 1,
    ) -> None:
        """Count one chunk's :meth:`compute` output (``keep``, ``keep_runs`` as in :meth:`add`)."""
        fs = self._fs
        mu_raw, am, seconds = computed
        self._wall += seconds
        k = mu_raw.shape[0]
        mu = finite_array("mu", mu_raw, ndim=3)  # as confusion_matrix checks it
        if keep is not None and self.method not in keep:
            kept = mu if keep_runs is None else mu[:keep_runs].copy()
            keep[self.method] = (self._t, kept, tuple(fs.modes))
        self.runs += k
        true, healthy = self._true, self._healthy
        alarm = am != 0
        if healthy.any():
            self._fa_runs += int(np.count_nonzero(alarm[:, healthy].any(axis=1)))
            self._healthy_alarms += int(np.count_nonzero(alarm[:, healthy]))
        for i, (k0, k1) in enumerate(zip(self._change, self._ends, strict=True)):
            seg = slice(k0, k1)
            hit_d = alarm[:, seg]
            hit_i = am[:, seg] == true[k0]
            first_d = np.where(hit_d.any(axis=1), np.argmax(hit_d, axis=1), -1)
            first_i = np.where(hit_i.any(axis=1), np.argmax(hit_i, axis=1), -1)
            self._dd[i].append(_delays(first_d, self._t, int(k0)))
            self._di[i].append(_delays(first_i, self._t, int(k0)))
        # confusion sums per actual mode a: numpy sums the (run, sample) rows of mu[true == a] one after
        # the other (axis-0 reduction); prepending the running sum continues that same sequence, so the
        # result is the whole-array mean of confusion_matrix bit for bit, whatever the chunking
        r = mu.shape[-1]
        for a in range(r):
            sel = true == a
            if sel.any():
                rows = mu[:, sel].reshape(-1, r)
                self._sums[a] = np.concatenate([self._sums[a][None], rows]).sum(axis=0)

    def result(self) -> ModeDiagnosis:
        """The diagnosis figures of every realization added so far.

        Returns
        -------
        ModeDiagnosis
        """
        if not self.runs:
            raise ParameterError("no realization was added to the tally: call add(sim) first")
        runs, T = self.runs, self._t.size
        fs, true, healthy = self._fs, self._true, self._healthy
        det_med: list[float] = []
        det_p90: list[float] = []
        iso_med: list[float] = []
        iso_p90: list[float] = []
        missed = []
        for dparts, iparts in zip(self._dd, self._di, strict=True):
            dd, di = np.concatenate(dparts), np.concatenate(iparts)
            for arr, med, p90 in ((dd, det_med, det_p90), (di, iso_med, iso_p90)):
                ok = arr[np.isfinite(arr)]
                med.append(float(np.median(ok)) if ok.size else float("nan"))
                p90.append(float(np.quantile(ok, 0.9)) if ok.size else float("nan"))
            missed.append(int(np.count_nonzero(~np.isfinite(di))))
        r = len(fs.modes)
        confusion = np.full((r, r), np.nan)
        for a in range(r):
            n = int(np.count_nonzero(true == a)) * runs
            if n:
                confusion[:, a] = 100.0 * (self._sums[a] / n)
        n_healthy = int(np.count_nonzero(healthy))
        return ModeDiagnosis(
            method=self.method,
            modes=tuple(fs.modes),
            runs=runs,
            false_alarm_runs=self._fa_runs,
            false_alarm_rate=self._fa_runs / runs,
            false_alarm_ci=clopper_pearson(self._fa_runs, runs, 0.99),
            healthy_alarm_fraction=self._healthy_alarms / (runs * n_healthy) if n_healthy else float("nan"),
            onsets=tuple(float(v) for v in self._t[self._change]),
            detection_median=tuple(det_med),
            detection_p90=tuple(det_p90),
            isolation_median=tuple(iso_med),
            isolation_p90=tuple(iso_p90),
            missed=tuple(missed),
            confusion=confusion,
            steps_per_second=runs * T / self._wall if self._wall > 0 else float("inf"),
            new_modes=tuple(int(true[k]) for k in self._change),
        )
