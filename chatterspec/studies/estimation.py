"""Estimator comparison: error metrics, the study (DETC2015 table, eq 28-30) and mode outputs.

In order: the error metrics (RMSE, bias, STD, NEES/NIS), the comparison study
(:func:`estimation_study`) and the mode-identification outputs of the multiple-model filters
(:func:`confusion_matrix`, :func:`switch_delays`, :func:`rmse_table`, :func:`mode_report`).

Estimation-error metrics: RMSE, bias and STD per state (DETC2015 eq 28-30), NEES and NIS consistency.

All functions take realizations on a leading axis, ``(runs, T, n)``, and
reduce over time first (one value per run and state, as the paper's eq 28-30
do for one run), then over runs, where the Monte Carlo standard error of the
mean over runs is reported beside every mean.

Consistency
-----------
For a filter whose model matches the plant and whose covariances are right,
the normalized estimation error squared ``NEES_k = e_k^T P_k^-1 e_k`` is
chi-squared with ``n`` degrees of freedom at every step, and the normalized
innovation squared ``NIS_k = nu_k^T S_k^-1 nu_k`` chi-squared with ``m``
(Bar-Shalom, Li and Kirubarajan, *Estimation with Applications to Tracking and
Navigation*, 2001, section 5.4). Averaged over ``R`` independent runs at one
step, ``R * mean NEES_k`` is chi-squared with ``R n`` degrees of freedom, so the
two-sided ``1 - alpha`` acceptance interval of the run-averaged statistic is
``[chi2.ppf(alpha/2, R n), chi2.ppf(1 - alpha/2, R n)] / R``. The time average of
one run's NIS has the same form with ``T m`` degrees of freedom because a
consistent filter's innovations are white; the time-averaged NEES of one run is
only approximately so (estimation errors are correlated in time), which the
per-run NEES bounds say in their ``note``.

Estimator comparison study: the DETC2015 table (RMSE / bias / STD, eq 28-30) with NEES/NIS consistency.

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

Mode-identification outputs of the multiple-model filters (the SMM-SVSF and IMM papers' tables).

* :func:`confusion_matrix`: the IMM paper's Tables 5-7 -- cell ``[i, a]`` is the mean probability of
  mode ``i`` over the samples whose actual mode is ``a``, in percent; every column sums to 100.
* :func:`argmax_accuracy`: fraction of the samples of each actual mode whose most probable mode is the
  actual one.
* :func:`switch_delays`: time for the true mode's probability to pass given levels (0.5, 0.8) after
  each mode switch, per run and for the run-mean probability (the SMM paper's Fig 5 reads the mean).
* :func:`rmse_table`: RMSE per state for several estimators (the SMM paper's SVSF vs SMM-SVSF table).

All functions take the probabilities as ``(runs, T, r)`` (``MultipleModelOutput.mu``) and the true
mode per sample as ``(T,)`` or ``(runs, T)`` integer indices (-1 = no mode, ignored), e.g.
``scenario.filter_settings.mode_index(scenario)``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Unpack, cast

import numpy as np
import numpy.typing as npt
import scipy.stats

from .. import filter_registry
from .._repr import short_repr
from .._validate import finite_array, names_of, open_unit, positive_int
from ..errors import NonFiniteError, ParameterError, ShapeError
from ..jsonout import fields_dict, finite_or_none
from ..montecarlo import Execution, ExecutionOptions, SeedLike, seed_label
from ..plants.scenarios import FilterSettings, Scenario
from ..plants.scenarios import scenario as _catalogue_scenario
from ..plants.simulate import iter_simulations

__all__ = [
    "FILTERS",
    "ConsistencyTest",
    "EstimateRecords",
    "EstimationResult",
    "EstimationStudy",
    "FilterMetrics",
    "ModeReport",
    "MonteCarloMean",
    "StateErrorMetrics",
    "SwitchDelays",
    "argmax_accuracy",
    "build_filter",
    "confusion_matrix",
    "consistency",
    "consistency_from_sums",
    "estimate_records",
    "estimation_study",
    "mode_report",
    "nees",
    "nis",
    "parse_filters",
    "rmse_table",
    "state_error_metrics",
    "switch_delays",
]

if TYPE_CHECKING:  # pragma: no cover
    from ..filters.protocol import Filter


@dataclass(frozen=True)
class MonteCarloMean:
    """Mean of a per-run quantity over runs, with its Monte Carlo standard error.

    Attributes
    ----------
    mean : (n,) array
        Mean over runs.
    stderr : (n,) array
        Standard error of that mean, ``std(ddof=1) / sqrt(runs)`` (NaN for one run).
    runs : int
        Number of runs averaged.
    """

    mean: np.ndarray
    stderr: np.ndarray
    runs: int

    @classmethod
    def of(cls, per_run: np.ndarray) -> MonteCarloMean:
        """Mean and standard error over the leading axis of ``per_run`` ``(runs, n)``.

        Parameters
        ----------
        per_run : (runs, n) array
            One value per run and state.
        """
        per_run = np.asarray(per_run, dtype=float)
        runs = per_run.shape[0]
        mean = per_run.mean(axis=0)
        if runs > 1:
            stderr = per_run.std(axis=0, ddof=1) / np.sqrt(runs)
        else:
            stderr = np.full_like(mean, np.nan)
        return cls(mean=mean, stderr=stderr, runs=runs)


@dataclass(frozen=True)
class StateErrorMetrics:
    """Per-state RMSE, bias and STD of the estimation error (DETC2015 eq 28-30).

    Attributes
    ----------
    rmse, bias, std : (runs, n) arrays
        Per run, over the time steps used: ``RMSE = sqrt(mean(e^2))`` (eq 28),
        ``bias = mean(e)`` with ``e = x - x_hat`` (eq 29) and
        ``STD = sqrt(mean((e - bias)^2))`` (eq 30), so ``RMSE^2 = bias^2 + STD^2``.
    state_names : tuple of str
        Names of the states (columns).
    """

    rmse: np.ndarray
    bias: np.ndarray
    std: np.ndarray
    state_names: tuple[str, ...] = ()

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.rmse.shape[0]

    def summary(self) -> dict[str, MonteCarloMean]:
        """Monte Carlo means with standard errors: ``{"rmse": ..., "bias": ..., "std": ...}``."""
        return {k: MonteCarloMean.of(getattr(self, k)) for k in ("rmse", "bias", "std")}

    @staticmethod
    def concatenate(parts: list[StateErrorMetrics]) -> StateErrorMetrics:
        """Join metrics of consecutive chunks of runs (constant memory per run).

        Parameters
        ----------
        parts : list of StateErrorMetrics
            Chunks in run order, with the same states.
        """
        if not parts:
            raise ShapeError("no metrics to concatenate")
        return StateErrorMetrics(
            rmse=np.concatenate([p.rmse for p in parts]),
            bias=np.concatenate([p.bias for p in parts]),
            std=np.concatenate([p.std for p in parts]),
            state_names=parts[0].state_names,
        )


def _finite(name: str, a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=float)
    if not np.all(np.isfinite(a)):
        raise NonFiniteError(f"{name} contains NaN or inf; a diverged filter has no error metrics")
    return a


def state_error_metrics(
    x_true: np.ndarray,
    x_est: np.ndarray,
    *,
    skip: int = 0,
    state_names: tuple[str, ...] = (),
) -> StateErrorMetrics:
    """RMSE, bias and STD of the estimation error per run and state (DETC2015 eq 28-30).

    Parameters
    ----------
    x_true, x_est : (runs, T, n) arrays
        True and estimated states (a single record ``(T, n)`` is taken as one run).
    skip : int
        Leading samples excluded (e.g. the initial transient); 0 as in the paper.
    state_names : tuple of str
        Names for reports.

    Returns
    -------
    StateErrorMetrics

    Raises
    ------
    ShapeError
        If the shapes differ or ``skip`` leaves no sample.
    NonFiniteError
        If either array has NaN or inf.
    """
    x_true = _finite("x_true", x_true)
    x_est = _finite("x_est", x_est)
    if x_true.shape != x_est.shape:
        raise ShapeError(f"x_true has shape {x_true.shape} but x_est has {x_est.shape}; they must match")
    if x_true.ndim == 2:
        x_true, x_est = x_true[None], x_est[None]
    if x_true.ndim != 3:
        raise ShapeError(f"states must be (runs, T, n) or (T, n); got shape {x_true.shape}")
    if not 0 <= skip < x_true.shape[1]:
        raise ShapeError(f"skip={skip} must be in [0, T) with T = {x_true.shape[1]}")
    e = (x_true - x_est)[:, skip:]
    bias = e.mean(axis=1)
    std = np.sqrt(np.mean((e - bias[:, None]) ** 2, axis=1))
    rmse = np.sqrt(np.mean(e**2, axis=1))
    return StateErrorMetrics(rmse=rmse, bias=bias, std=std, state_names=tuple(state_names))


def _quadratic_form(v: np.ndarray, M: np.ndarray, what: str) -> np.ndarray:
    """``v^T M^-1 v`` over leading axes; ``M`` broadcasts (shared ``(d, d)``, ``(T, d, d)`` or full)."""
    v = _finite(what, v)
    M = _finite(f"covariance of the {what}", M)
    d = v.shape[-1]
    if M.shape[-2:] != (d, d):
        raise ShapeError(f"covariance of the {what} must end in ({d}, {d}); got {M.shape}")
    try:
        if M.ndim == 2:
            return np.einsum("...i,ij,...j->...", v, np.linalg.inv(M), v)
        M = np.broadcast_to(M, (*v.shape[:-1], d, d))
        sol = np.linalg.solve(M, v[..., None])[..., 0]
    except np.linalg.LinAlgError as exc:
        raise ShapeError(f"covariance of the {what} is singular: {exc}") from None
    return np.einsum("...i,...i->...", v, sol)


def nees(error: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Normalized estimation error squared ``e^T P^-1 e`` per run and step.

    Parameters
    ----------
    error : (runs, T, n) array
        Estimation error ``x - x_hat``.
    P : (n, n), (T, n, n) or (runs, T, n, n) array
        The filter's posterior covariance (broadcast against ``error``).

    Returns
    -------
    (runs, T) array
    """
    return _quadratic_form(error, np.asarray(P, dtype=float), "estimation error")


def nis(innovation: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Normalized innovation squared ``nu^T S^-1 nu`` per run and step.

    Parameters
    ----------
    innovation : (runs, T, m) array
        Innovations ``z - C x(k|k-1)``.
    S : (m, m), (T, m, m) or (runs, T, m, m) array
        Their covariances.

    Returns
    -------
    (runs, T) array
    """
    return _quadratic_form(innovation, np.asarray(S, dtype=float), "innovation")


@dataclass(frozen=True)
class ConsistencyTest:
    """Two-sided chi-squared consistency test of an averaged NEES or NIS.

    Attributes
    ----------
    statistic : float
        The averaged normalized statistic (its expectation is ``dim`` when consistent).
    lower, upper : float
        Acceptance interval at confidence ``1 - alpha``.
    dof : int
        Degrees of freedom of ``statistic * n_averaged``.
    alpha : float
        Two-sided significance level.
    consistent : bool
        ``lower <= statistic <= upper``.
    fraction_inside : float
        Share of steps whose run-averaged value lies in the per-step interval
        (its expectation is ``1 - alpha`` when consistent).
    note : str
        What was averaged, and any approximation.
    """

    statistic: float
    lower: float
    upper: float
    dof: int
    alpha: float
    consistent: bool
    fraction_inside: float
    note: str


def consistency(values: np.ndarray, dim: int, *, alpha: float = 0.05, kind: str = "NIS") -> ConsistencyTest:
    """Two-sided chi-squared consistency test of NEES or NIS values over runs and steps.

    The statistic is the mean of ``values`` over runs and steps; ``R T`` times it is
    chi-squared with ``R T dim`` degrees of freedom when the values are independent
    (exact for the NIS of a consistent filter, whose innovations are white;
    approximate for NEES, whose errors correlate in time: the note says so).
    ``fraction_inside`` is the share of steps whose run-averaged value lies in the
    per-step interval ``chi2.ppf([alpha/2, 1-alpha/2], R dim) / R`` (expected ``1 - alpha``).

    Parameters
    ----------
    values : (runs, T) or (T,) array
        NEES (``dim = n``) or NIS (``dim = m``) per run and step.
    dim : int
        State or measurement dimension (> 0).
    alpha : float
        Two-sided significance level in (0, 1).
    kind : {"NIS", "NEES"}
        Which statistic the values are (sets the note on exactness).

    Returns
    -------
    ConsistencyTest
    """
    values = _finite("values", values)  # alpha, kind and dim: checked by consistency_from_sums
    if values.ndim == 1:
        values = values[None]
    if values.ndim != 2:
        raise ShapeError(f"values must be (runs, T) or (T,); got shape {values.shape}")
    runs = values.shape[0]
    return consistency_from_sums(float(values.sum()), values.sum(axis=0), runs, dim, alpha=alpha, kind=kind)


def consistency_from_sums(
    total: float,
    per_step_sum: np.ndarray,
    runs: int,
    dim: int,
    *,
    alpha: float = 0.05,
    kind: str = "NIS",
) -> ConsistencyTest:
    """:func:`consistency` from running sums (chunked Monte Carlo studies, constant memory).

    Parameters
    ----------
    total : float
        Sum of the NEES or NIS values over all runs and steps.
    per_step_sum : (T,) array
        Sum over runs at each step.
    runs : int
        Number of runs summed (>= 1).
    dim : int
        State or measurement dimension (> 0).
    alpha : float
        Two-sided significance level in (0, 1).
    kind : {"NIS", "NEES"}
        Which statistic the values are.

    Returns
    -------
    ConsistencyTest
    """
    alpha = open_unit("alpha", alpha)
    per_step_sum = _finite("per_step_sum", np.atleast_1d(per_step_sum))
    if kind not in ("NIS", "NEES"):
        raise ShapeError(f'kind must be "NIS" or "NEES"; got {kind!r}')
    if dim < 1:
        raise ShapeError(f"dim must be a positive dimension; got {dim}")
    if runs < 1 or per_step_sum.ndim != 1:
        raise ShapeError(
            f"need runs >= 1 and a (T,) per-step sum; got runs={runs}, shape {per_step_sum.shape}"
        )
    if not np.isfinite(total):
        raise NonFiniteError(f"the {kind} total is not finite")
    steps = per_step_sum.shape[0]
    dof = runs * steps * dim
    lo, hi = scipy.stats.chi2.ppf([alpha / 2, 1 - alpha / 2], dof) / (runs * steps)
    stat = float(total) / (runs * steps)
    step_lo, step_hi = scipy.stats.chi2.ppf([alpha / 2, 1 - alpha / 2], runs * dim) / runs
    per_step = per_step_sum / runs
    inside = float(np.mean((per_step >= step_lo) & (per_step <= step_hi)))
    exact = (
        "exact for a consistent filter (white innovations)"
        if kind == "NIS"
        else ("approximate: estimation errors correlate in time, so the interval is too narrow")
    )
    note = f"{kind} averaged over {runs} runs x {steps} steps; chi2({dof}) interval, {exact}"
    return ConsistencyTest(
        statistic=stat,
        lower=float(lo),
        upper=float(hi),
        dof=int(dof),
        alpha=alpha,
        consistent=bool(lo <= stat <= hi),
        fraction_inside=inside,
        note=note,
    )


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
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

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


def _inputs(mu: npt.ArrayLike, true_mode: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    mu = finite_array("mu", mu, ndim=(2, 3))
    if mu.ndim == 2:
        mu = mu[None]
    runs, T, r = mu.shape
    tm = np.asarray(true_mode)
    if not np.issubdtype(tm.dtype, np.integer):
        raise ParameterError(f"true_mode must hold integer mode indices; got dtype {tm.dtype}")
    if tm.shape == (T,):
        tm = np.broadcast_to(tm, (runs, T))
    if tm.shape != (runs, T):
        raise ShapeError(f"true_mode must have shape ({T},) or ({runs}, {T}) like mu; got {tm.shape}")
    if np.any(tm >= r) or np.any(tm < -1):
        raise ParameterError(f"true_mode entries must lie in -1 .. {r - 1} (-1 = no mode)")
    return mu, tm


def confusion_matrix(mu: np.ndarray, true_mode: np.ndarray) -> np.ndarray:
    """Mean mode probability per actual mode, in percent (IMM paper Tables 5-7).

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) or (runs, T) int array
        Actual mode index per sample (-1: ignored).

    Returns
    -------
    (r, r) ndarray
        ``C[i, a]`` = mean of ``mu[..., i]`` over the samples of actual mode ``a``, x 100; rows =
        predicted, columns = actual; every column sums to 100 (NaN for a mode that never occurs).
    """
    mu, tm = _inputs(mu, true_mode)
    r = mu.shape[-1]
    out = np.full((r, r), np.nan)
    for a in range(r):
        sel = tm == a
        if sel.any():
            out[:, a] = 100.0 * mu[sel].mean(axis=0)
    return out


def argmax_accuracy(mu: np.ndarray, true_mode: np.ndarray) -> np.ndarray:
    """Fraction of the samples of each actual mode whose most probable mode is that mode.

    Parameters
    ----------
    mu, true_mode
        Mode probabilities ``(runs, T, r)`` and actual modes, as in :func:`confusion_matrix`.

    Returns
    -------
    (r,) ndarray
        In [0, 1]; NaN for a mode that never occurs.
    """
    mu, tm = _inputs(mu, true_mode)
    r = mu.shape[-1]
    hit = np.argmax(mu, axis=-1) == tm
    return np.array([hit[tm == a].mean() if np.any(tm == a) else np.nan for a in range(r)])


@dataclass(frozen=True, eq=False)
class SwitchDelays:
    """Time for the new mode's probability to pass given levels after each switch.

    Attributes
    ----------
    onsets : (s,) array
        Switch times in seconds (first sample of the new mode).
    new_modes : (s,) int array
        Index of the mode switched to.
    levels : (L,) array
        Probability levels (e.g. 0.5, 0.8).
    per_run : (runs, s, L) array
        Delay in seconds per run (NaN: never passed before the next switch or the end).
    of_mean : (s, L) array
        Delay of the run-mean probability (NaN: never passed).
    """

    onsets: np.ndarray
    new_modes: np.ndarray
    levels: np.ndarray
    per_run: np.ndarray
    of_mean: np.ndarray


def _first_crossing(p: np.ndarray, level: float) -> np.ndarray:
    """Index of the first sample with ``p >= level`` along the last axis (-1 if none)."""
    hit = p >= level
    idx = np.argmax(hit, axis=-1)
    return np.where(hit.any(axis=-1), idx, -1)


def switch_delays(
    mu: np.ndarray, true_mode: np.ndarray, t: np.ndarray, levels: Sequence[float] = (0.5, 0.8)
) -> SwitchDelays:
    """Delays from each mode switch until the new mode's probability passes each level.

    A switch is a sample where the (shared) true mode changes to another valid mode. The search
    runs until the next switch or the end of the record.

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) int array
        Actual mode per sample, shared by all runs.
    t : (T,) array
        Sample times in seconds (same samples as ``mu``).
    levels : sequence of float
        Probability levels in (0, 1].

    Returns
    -------
    SwitchDelays
    """
    mu, tm = _inputs(mu, true_mode)
    tm1 = tm[0]
    if np.any(tm != tm1):
        raise ParameterError("switch_delays needs one true-mode sequence shared by all runs")
    t = finite_array("t", t, shape=(mu.shape[1],))
    lev = finite_array("levels", levels, ndim=1)
    if np.any((lev <= 0) | (lev > 1)):
        raise ParameterError(f"levels must lie in (0, 1]; got {lev.tolist()}")
    change = np.flatnonzero((tm1[1:] != tm1[:-1]) & (tm1[1:] >= 0)) + 1
    ends = np.append(change[1:], len(tm1))
    runs = mu.shape[0]
    per_run = np.full((runs, len(change), len(lev)), np.nan)
    of_mean = np.full((len(change), len(lev)), np.nan)
    for s, (k0, k1) in enumerate(zip(change, ends, strict=True)):
        p = mu[:, k0:k1, tm1[k0]]
        pm = p.mean(axis=0)
        for li, level in enumerate(lev):
            idx = _first_crossing(p, level)
            per_run[:, s, li] = np.where(idx >= 0, t[k0 + np.maximum(idx, 0)] - t[k0], np.nan)
            im = int(_first_crossing(pm, level))
            if im >= 0:
                of_mean[s, li] = t[k0 + im] - t[k0]
    return SwitchDelays(t[change], tm1[change], lev, per_run, of_mean)


def rmse_table(
    estimates: Mapping[str, np.ndarray], truth: np.ndarray, state_names: Sequence[str] | None = None
) -> dict[str, dict[str, float]]:
    """RMSE per state over all runs and samples, for each estimator (the SMM paper's RMSE table).

    Parameters
    ----------
    estimates : mapping of str to (runs, T, n) array
        Estimator name -> estimates aligned with ``truth``.
    truth : (runs, T, n) array
        True states.
    state_names : sequence of str, optional
        Names of the n states (default ``x1 .. xn``).

    Returns
    -------
    dict
        ``{estimator: {state: rmse}}`` in the states' units.
    """
    truth = finite_array("truth", truth, ndim=3)
    n = truth.shape[-1]
    names = names_of("state_names", state_names, n, "x", what="states")
    table: dict[str, dict[str, float]] = {}
    for key, est in estimates.items():
        est = finite_array(f"estimates[{key!r}]", est, shape=truth.shape)
        rm = np.sqrt(np.mean((est - truth) ** 2, axis=(0, 1)))
        table[str(key)] = {nm: float(v) for nm, v in zip(names, rm, strict=True)}
    return table


@dataclass(frozen=True, eq=False)
class ModeReport:
    """Confusion matrix, argmax accuracy and switch delays of one multiple-model run.

    Attributes
    ----------
    modes : tuple of str
        Mode names.
    confusion : (r, r) array
        :func:`confusion_matrix` (percent; rows predicted, columns actual).
    accuracy : (r,) array
        :func:`argmax_accuracy`.
    delays : SwitchDelays
        :func:`switch_delays` at levels 0.5 and 0.8.
    """

    modes: tuple[str, ...]
    confusion: np.ndarray
    accuracy: np.ndarray
    delays: SwitchDelays

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""

        def clean(a: np.ndarray) -> object:
            return np.where(np.isnan(a), None, np.round(a, 10)).tolist()  # type: ignore[call-overload]  # numpy's stubs: no None in where (an object array)

        return {
            "modes": list(self.modes),
            "confusion_percent": clean(self.confusion),
            "argmax_accuracy": clean(self.accuracy),
            "switch_onsets_s": self.delays.onsets.tolist(),
            "switch_to": [self.modes[i] for i in self.delays.new_modes],
            "levels": self.delays.levels.tolist(),
            "delay_of_mean_s": clean(self.delays.of_mean),
            "delay_median_s": clean(np.nanmedian(self.delays.per_run, axis=0))
            if self.delays.per_run.size and not np.all(np.isnan(self.delays.per_run))
            else None,
        }


def mode_report(
    mu: np.ndarray,
    true_mode: np.ndarray,
    t: np.ndarray,
    modes: Sequence[str],
    levels: Sequence[float] = (0.5, 0.8),
) -> ModeReport:
    """All mode outputs at once.

    Parameters
    ----------
    mu : (runs, T, r) array
        Mode probabilities per sample.
    true_mode : (T,) int array
        Actual mode per sample.
    t : (T,) array
        Sample times in seconds.
    modes : sequence of str
        Mode names (r of them).
    levels : sequence of float
        Levels of :func:`switch_delays`.

    Returns
    -------
    ModeReport
    """
    names = names_of("modes", modes, np.shape(mu)[-1], "mode", first=0)
    return ModeReport(
        names,
        confusion_matrix(mu, true_mode),
        argmax_accuracy(mu, true_mode),
        switch_delays(mu, true_mode, t, levels),
    )
