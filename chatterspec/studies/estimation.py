"""Estimator comparison study: the DETC2015 table (RMSE / bias / STD, eq 28-30) with NEES/NIS consistency.

:func:`estimation_study` simulates a catalogue scenario's true plant, runs every requested filter
(``kf``, ``ekf``, ``svsf``, ``svsf2``) with the tuning of ``scenario.filter_settings`` on the same
measurements, and reduces the estimation errors chunk by chunk through
:func:`chatterspec.montecarlo.run_study` (constant memory, local workers or Dask, the same
numbers for any chunking or worker count).

Time convention (``chatterspec.filters.protocol``): the filters start from ``x(0|0) = x0`` and
``P(0|0) = P0`` of the settings and process ``z(1) .. z(T-1)`` with ``u(0) .. u(T-2)``; the metrics
are over the ``T - 1`` posterior estimates ``x(k|k)``, ``k = 1 .. T-1`` (the paper's "n time steps"),
with the error ``x - x_hat`` (sign of DETC eq 29).

Filters (names of ``--filters``):

* ``kf``: Kalman filter (:class:`~chatterspec.filters.kalman.KalmanFilter`) on a linear model, the EKF
  on a nonlinear one; ``ekf``: always the EKF.
* ``svsf``: first-order SVSF with covariance ([SMM] eq 2.1-2.10; DETC's "1st-order SVSF"),
  ``psi``, ``gamma`` and ``mapping`` from the settings.
* ``svsf2``: dynamic second-order SVSF ([DETC] eq 5-24), ``gamma``, ``Lambda = cutoff_lambda`` and
  ``mapping`` from the settings.

The first-order SVSF's covariance is bookkeeping (its gain does not use it), so its NEES/NIS say how
well that bookkeeping matches the errors, not whether the filter is optimal.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Unpack, cast

import numpy as np

from .. import filter_registry
from .._repr import short_repr
from .._validate import positive_int
from ..errors import ParameterError
from ..jsonout import fields_dict, finite_or_none
from ..montecarlo import Execution, ExecutionOptions
from ..plants.scenarios import FilterSettings, Scenario
from ..plants.scenarios import scenario as _catalogue_scenario
from ..plants.simulate import iter_simulations
from ..rng import SeedLike, seed_label
from .metrics import (
    ConsistencyTest,
    MonteCarloMean,
    StateErrorMetrics,
    consistency_from_sums,
    nees,
    nis,
    state_error_metrics,
)

if TYPE_CHECKING:  # pragma: no cover
    from ..filters.protocol import Filter

__all__ = [
    "FILTERS",
    "EstimateRecords",
    "EstimationResult",
    "EstimationStudy",
    "FilterMetrics",
    "build_filter",
    "estimate_records",
    "estimation_study",
    "parse_filters",
]

#: Filter names accepted by ``--filters`` and :func:`build_filter`, with a description (the registry's).
FILTERS = filter_registry.FILTERS

#: Samples per filter update inside a study chunk (bounds the stored covariances per chunk).
TIME_BLOCK = 1000

#: Output fields every filter run stores (the covariances feed NEES).
_STORE = ("x_post", "innovation", "S", "P_post")


parse_filters = filter_registry.parse_filters


def _resolve(source: str | Scenario) -> Scenario:
    sc = source if isinstance(source, Scenario) else _catalogue_scenario(str(source))
    fs = sc.filter_settings
    if fs is None or fs.P0 is None:
        raise ParameterError(
            f"scenario {sc.name!r} carries no filter settings (P0, Q, R); use an estimator scenario "
            "such as detc-normal, detc-uncertain or eha4-leak-timeline"
        )
    return sc


def _filter_model(sc: Scenario) -> Any:
    """The nominal model with the filter's Q and R of the settings (when printed)."""
    fs = sc.filter_settings
    assert fs is not None  # (an estimator scenario: _resolve checked)
    model = sc.nominal
    changes = {k: getattr(fs, k) for k in ("Q", "R") if getattr(fs, k) is not None}
    fs.check_dimensions(model.n_states, model.n_outputs)
    return model.replace(**changes) if changes else model


def build_filter(name: str, scenario: str | Scenario) -> Any:
    """The filter ``name`` with the tuning of ``scenario.filter_settings``.

    Parameters
    ----------
    name : str
        One of :data:`FILTERS`.
    scenario : str or Scenario
        Catalogue name or scenario with ``filter_settings`` (``P0`` required).

    Returns
    -------
    Filter
        An object of the :class:`~chatterspec.filters.protocol.Filter` protocol.

    Raises
    ------
    ParameterError
        Unknown name, a scenario without settings, or a setting the filter needs but the scenario
        does not give (e.g. ``psi`` for ``svsf``).
    """
    (name,) = parse_filters([name])
    sc = _resolve(scenario)
    return filter_registry.build(name, _filter_model(sc), sc.filter_settings, sc.name)


@dataclass(frozen=True, eq=False)
class EstimateRecords:
    """Truth, measurements and every filter's output for a few realizations (figures, recordings).

    Attributes
    ----------
    t : (T,) array
        Sample times in seconds; filter outputs belong to ``t[1:]``.
    x : (runs, T, n) array
        True states.
    z : (runs, T, m) array
        Measurements.
    u : (T, p) array
        Input.
    outputs : dict of str to FilterOutput
        Per filter name, ``x_post``, ``innovation``, ``S``, ``P_post`` over ``t[1:]``.
    scenario : Scenario
        The scenario simulated.
    first_run : int
        Global index of the first realization.
    """

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    u: np.ndarray
    outputs: dict[str, Any]
    scenario: Scenario
    first_run: int = 0

    def error(self, name: str) -> np.ndarray:
        """Estimation error ``x - x_hat`` of filter ``name`` over ``t[1:]``, shape ``(runs, T-1, n)``.

        Parameters
        ----------
        name : str
            A filter of :attr:`outputs`.
        """
        return self.x[:, 1:] - self.outputs[name].x_post


def estimate_records(
    source: str | Scenario,
    filters: str | Iterable[str] = ("kf", "svsf", "svsf2"),
    runs: int = 1,
    seed: SeedLike = 0,
    *,
    first_run: int = 0,
) -> EstimateRecords:
    """Simulate realizations ``first_run ..`` of a scenario and run every filter on them.

    The realizations are those of :func:`estimation_study` with the same seed (chunk-invariant
    seeding), so a recording or a figure shows runs of the study itself.

    Parameters
    ----------
    source : str or Scenario
        Scenario with filter settings.
    filters : str or iterable of str
        Names from :data:`FILTERS`.
    runs : int
        Realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root seed.
    first_run : int
        Index of the first realization.

    Returns
    -------
    EstimateRecords
    """
    names = parse_filters(filters)
    sc = _resolve(source)
    runs = positive_int("runs", runs)
    built = {n: build_filter(n, sc) for n in names}
    sim = next(iter(iter_simulations(sc, runs, seed, chunk_runs=runs, first_run=first_run)))
    outs = {n: _run(f, sc, sim.z, sim.u) for n, f in built.items()}
    return EstimateRecords(t=sim.t, x=sim.x, z=sim.z, u=sim.u, outputs=outs, scenario=sc, first_run=first_run)


def _run(filt: Filter, sc: Scenario, z: np.ndarray, u: np.ndarray) -> Any:
    fs = sc.filter_settings
    assert fs is not None and fs.P0 is not None  # (an estimator scenario: _resolve checked)
    x0 = np.zeros(sc.nominal.n_states) if fs.x0 is None else fs.x0
    return filt.run(np.ascontiguousarray(z[:, 1:]), u[..., :-1, :], x0=x0, P0=fs.P0, store=_STORE)


@dataclass(frozen=True)
class FilterMetrics:
    """One filter's row block of the DETC-style table.

    Attributes
    ----------
    name : str
        Filter name (:data:`FILTERS`).
    rmse, bias, std : MonteCarloMean
        Per state, the Monte Carlo mean over runs of the per-run time statistics of DETC eq 28-30,
        with its standard error (state units, e.g. m, m/s, m/s^2).
    nees, nis : ConsistencyTest
        Chi-squared consistency of the normalized estimation error and innovation squared.
    per_run : StateErrorMetrics
        The per-run values ``(runs, n)`` behind the means (for paired comparisons between filters,
        which ran on the same measurements).
    """

    name: str
    rmse: MonteCarloMean
    bias: MonteCarloMean
    std: MonteCarloMean
    nees: ConsistencyTest
    nis: ConsistencyTest
    per_run: StateErrorMetrics | None = field(repr=False, default=None)

    def to_dict(self, state_names: Sequence[str]) -> dict[str, Any]:
        """JSON-ready dict.

        Parameters
        ----------
        state_names : sequence of str
            Keys of the per-state values.
        """

        def per_state(mc: MonteCarloMean) -> dict[str, dict[str, float | None]]:
            return {
                s: {"mean": float(mc.mean[i]), "stderr": finite_or_none(mc.stderr[i])}
                for i, s in enumerate(state_names)
            }

        return {
            "filter": self.name,
            "description": FILTERS[self.name],
            "rmse": per_state(self.rmse),
            "bias": per_state(self.bias),
            "std": per_state(self.std),
            "nees": fields_dict(self.nees),  # every ConsistencyTest field
            "nis": fields_dict(self.nis),
        }


@dataclass(frozen=True)
class EstimationResult:
    """Result of :func:`estimation_study`.

    Attributes
    ----------
    scenario : str
        Scenario name.
    runs : int
        Monte Carlo realizations.
    seed : int or None
        Root seed (None when a SeedSequence/Generator was passed).
    steps : int
        Time steps per run in the metrics (``T - 1``).
    state_names : tuple of str
        State names (table rows).
    filters : tuple of FilterMetrics
        One block per filter, in the requested order.
    settings : dict
        ``scenario.filter_settings.describe()`` (the tuning used).
    alpha : float
        Two-sided level of the NEES/NIS intervals.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    scenario: str
    runs: int
    seed: int | None
    steps: int
    state_names: tuple[str, ...]
    filters: tuple[FilterMetrics, ...]
    settings: dict[str, Any]
    alpha: float

    def get(self, name: str) -> FilterMetrics:
        """The block of filter ``name``.

        Parameters
        ----------
        name : str
            Filter name.
        """
        for f in self.filters:
            if f.name == name:
                return f
        raise ParameterError(f"no filter {name!r} in this result; it has {[f.name for f in self.filters]}")

    def difference(self, a: str, b: str, metric: str = "rmse") -> MonteCarloMean:
        """Paired Monte Carlo difference ``metric(a) - metric(b)`` per state, with its standard error.

        Both filters ran on the same realizations, so the per-run difference has a much smaller
        standard error than the two means' errors combined.

        Parameters
        ----------
        a, b : str
            Filter names.
        metric : {"rmse", "bias", "std"}
            Which per-run statistic.
        """
        if metric not in ("rmse", "bias", "std"):
            raise ParameterError(f'metric must be "rmse", "bias" or "std"; got {metric!r}')
        return MonteCarloMean.of(getattr(self.get(a).per_run, metric) - getattr(self.get(b).per_run, metric))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (the ``--json`` document of ``chatterspec estimate``)."""
        return {
            "scenario": self.scenario,
            "runs": self.runs,
            "seed": self.seed,
            "steps": self.steps,
            "states": list(self.state_names),
            "alpha": self.alpha,
            "filters": [f.to_dict(self.state_names) for f in self.filters],
            "filter_settings": self.settings,
        }

    def table(self) -> str:
        """The DETC-style text table: rows = states, per filter RMSE / bias / STD (+- standard error)."""
        lines = [
            f"estimation on {self.scenario}: {self.runs} runs, seed {self.seed}, {self.steps} steps per run; "
            "mean over runs +- Monte Carlo standard error (DETC2015 eq 28-30, error = x - x_hat)"
        ]
        w = max(len(s) for s in self.state_names) + 2
        for metric in ("rmse", "bias", "std"):
            lines.append("")
            head = f"{metric.upper():<{w}}" + "".join(f"{f.name:>26}" for f in self.filters)
            lines.append(head)
            for i, s in enumerate(self.state_names):
                row = f"{s:<{w}}"
                for f in self.filters:
                    mc = getattr(f, metric)
                    row += f"{_fmt(mc.mean[i], mc.stderr[i]):>26}"
                lines.append(row)
        lines.append("")
        lines.append(
            f"consistency (two-sided {1 - self.alpha:.0%} chi-squared intervals; "
            "a consistent filter lies inside)"
        )
        for f in self.filters:
            for c, kind in ((f.nees, "NEES"), (f.nis, "NIS")):
                verdict = "consistent" if c.consistent else "INCONSISTENT"
                lines.append(
                    f"  {f.name:<6} {kind:<4} {c.statistic:10.4g}  [{c.lower:.4g}, {c.upper:.4g}]  "
                    f"{verdict:<12}"
                    f" steps inside per-step interval: {c.fraction_inside:.1%}"
                )
        return "\n".join(lines)


def _fmt(mean: float, se: float) -> str:
    if not np.isfinite(se):
        return f"{mean:.4g}"
    return f"{mean:.4g} +- {se:.2g}"


@dataclass(frozen=True, eq=False)
class EstimationStudy:
    """Chunk function of :func:`estimation_study` (picklable; see :mod:`chatterspec.montecarlo`).

    Attributes
    ----------
    scenario : Scenario
        Scenario with filter settings.
    filters : tuple of str
        Filter names.
    """

    scenario: Scenario
    filters: tuple[str, ...]

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, Any]:
        """Per-run RMSE/bias/STD and NEES/NIS sums of realizations ``first_run .. first_run + runs - 1``.

        Parameters
        ----------
        first_run : int
            Index of the first realization.
        runs : int
            Realizations in this chunk.
        seed : numpy.random.SeedSequence
            Root seed sequence of the study.
        """
        sc = self.scenario
        fs = sc.filter_settings
        assert fs is not None and fs.P0 is not None  # (an estimator scenario: _resolve checked)
        sim = next(iter(iter_simulations(sc, runs, seed, chunk_runs=runs, first_run=first_run)))
        z, u, truth = sim.z[:, 1:], sim.u[..., :-1, :], sim.x[:, 1:]  # u: (T, p) or per run (closed loop)
        x0 = np.zeros(sc.nominal.n_states) if fs.x0 is None else fs.x0
        K = z.shape[1]
        out: dict[str, Any] = {}
        for name in self.filters:
            filt = build_filter(name, sc)
            state = filt.initialize(x0, fs.P0, runs=runs)
            err = np.empty_like(truth)
            ne_step, ni_step = np.empty(K), np.empty(K)
            # time blocks through the protocol's update (bit-identical to one pass; tested upstream):
            # covariances are kept only for TIME_BLOCK samples at a time, so memory does not grow with T
            for lo in range(0, K, TIME_BLOCK):
                hi = min(lo + TIME_BLOCK, K)
                state, o = filt.update(
                    state, np.ascontiguousarray(z[:, lo:hi]), u[..., lo:hi, :], store=_STORE
                )
                err[:, lo:hi] = truth[:, lo:hi] - o.x_post
                ne_step[lo:hi] = nees(err[:, lo:hi], o.P_post).sum(axis=0)
                ni_step[lo:hi] = nis(o.innovation, o.S).sum(axis=0)
            m = state_error_metrics(truth, truth - err)
            out[name] = {
                "rmse": m.rmse,
                "bias": m.bias,
                "std": m.std,
                "nees_sum": float(ne_step.sum()),
                "nees_step": ne_step,
                "nis_sum": float(ni_step.sum()),
                "nis_step": ni_step,
            }
        return out

    def reduce(self, acc: dict[str, Any] | None, part: dict[str, Any]) -> dict[str, Any]:
        """Concatenate per-run statistics and add the NEES/NIS sums.

        Parameters
        ----------
        acc : dict or None
            Accumulated summary (None for the first chunk).
        part : dict
            One chunk's summary.
        """
        if acc is None:
            return part
        merged: dict[str, Any] = {}
        for name, a in acc.items():
            b = part[name]
            merged[name] = {
                k: (np.concatenate([a[k], b[k]]) if k in ("rmse", "bias", "std") else a[k] + b[k]) for k in a
            }
        return merged


def estimation_study(
    source: str | Scenario,
    filters: str | Iterable[str] = ("kf", "svsf", "svsf2"),
    runs: int = 100,
    seed: SeedLike = 0,
    *,
    alpha: float = 0.05,
    **execution: Unpack[ExecutionOptions],
) -> EstimationResult:
    """Monte Carlo comparison of estimators on a scenario (the DETC2015 Tables 1-3 and consistency).

    Parameters
    ----------
    source : str or Scenario
        Catalogue name or scenario with ``filter_settings`` (e.g. ``detc-normal``, ``detc-uncertain``,
        ``eha4-leak-timeline``).
    filters : str or iterable of str
        Names from :data:`FILTERS` (``"kf,svsf,svsf2"`` or a sequence).
    runs : int
        Monte Carlo realizations (>= 1; the paper uses 1000).
    seed : int, SeedSequence, Generator or None
        Root seed; the result does not depend on ``workers`` or ``scheduler``.
    alpha : float
        Two-sided level of the NEES/NIS chi-squared intervals, in (0, 1).
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    EstimationResult

    Raises
    ------
    ParameterError
        Bad filter names, a scenario without filter settings, bad execution options.
    NonFiniteError
        A filter diverged (its estimates are not finite).
    """
    ex = Execution(**execution)
    names = parse_filters(filters)
    runs = positive_int("runs", runs)
    sc = _resolve(source)
    for name in names:  # fail on a missing setting before simulating anything
        build_filter(name, sc)
    from .._validate import open_unit

    alpha = open_unit("alpha", alpha)
    if ex.chunk_runs is None and sc.n_samples * sc.nominal.n_states**2 > 50_000:
        # long records (e.g. eha4: 9001 x 4x4 covariances per run): keep chunks ~100 MB
        ex = dataclasses.replace(ex, chunk_runs=64)
    study = EstimationStudy(scenario=sc, filters=names)
    out = ex.run(study, runs, seed, f"estimate {sc.name}")
    steps = sc.n_samples - 1
    n, m = sc.nominal.n_states, sc.nominal.n_outputs
    blocks = []
    for name in names:
        s = out[name]
        blocks.append(
            FilterMetrics(
                name=name,
                rmse=MonteCarloMean.of(s["rmse"]),
                bias=MonteCarloMean.of(s["bias"]),
                std=MonteCarloMean.of(s["std"]),
                nees=consistency_from_sums(s["nees_sum"], s["nees_step"], runs, n, alpha=alpha, kind="NEES"),
                nis=consistency_from_sums(s["nis_sum"], s["nis_step"], runs, m, alpha=alpha, kind="NIS"),
                per_run=StateErrorMetrics(
                    rmse=s["rmse"], bias=s["bias"], std=s["std"], state_names=tuple(sc.nominal.state_names)
                ),
            )
        )
    return EstimationResult(
        scenario=sc.name,
        runs=runs,
        seed=seed_label(seed),
        steps=steps,
        state_names=tuple(sc.nominal.state_names),
        filters=tuple(blocks),
        settings=cast(FilterSettings, sc.filter_settings).describe(),  # (checked by _resolve)
        alpha=alpha,
    )
