"""Estimation-error metrics: RMSE, bias and STD per state (DETC2015 eq 28-30), NEES and NIS consistency.

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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.stats

from .._validate import open_unit
from ..errors import NonFiniteError, ShapeError

__all__ = [
    "ConsistencyTest",
    "MonteCarloMean",
    "StateErrorMetrics",
    "consistency",
    "consistency_from_sums",
    "nees",
    "nis",
    "state_error_metrics",
]


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
    alpha = open_unit("alpha", alpha)
    values = _finite("values", values)
    if values.ndim == 1:
        values = values[None]
    if values.ndim != 2:
        raise ShapeError(f"values must be (runs, T) or (T,); got shape {values.shape}")
    if kind not in ("NIS", "NEES"):
        raise ShapeError(f'kind must be "NIS" or "NEES"; got {kind!r}')
    if dim < 1:
        raise ShapeError(f"dim must be a positive dimension; got {dim}")
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
