"""Per-sample scores of the estimator routes, for the alarm rules of :mod:`chatterspec.detection.alarms`.

Every function here is pure and vectorized over any leading axes (Monte Carlo realizations); a
score is larger when the data look less healthy, as the alarm rules expect.

Mode routes (SMM-SVSF, IMM)
    The log posterior odds of the fault modes against the normal mode (mode 0),

        score(k) = log( sum_{j >= 1} mu_j(k) / mu_0(k) ),

    with every probability first raised to a floor ``f`` (the SMM-SVSF's own weight floor, [SMM]
    Table 1 step 3), so the score lies in ``[log f, -log f]``: a few samples of overwhelming
    likelihood cannot build an unbounded statistic, and a CUSUM on it gains at most ``-log f``
    per sample. The argmax rule of the papers is the frame rule at ``h = 0`` (odds 1) on this
    score. Isolation while in alarm: the most probable *fault* mode, :func:`isolated_fault_mode`.

Innovation route (Mehra and Peschon 1971, reference [18] of the core paper)
    A Kalman filter (extended on a nonlinear plant) on the nominal model gives the innovation
    ``e(k) = z(k) - C x(k|k-1)`` and its covariance ``S(k) = C P(k|k-1) C^T + R``; the normalized
    innovation squared

        NIS(k) = e(k)^T S(k)^-1 e(k)

    is chi-square with ``m`` degrees of freedom, independent from sample to sample, when the
    filter's model, ``Q`` and ``R`` are those of the plant. Under a fault that inflates the
    innovation covariance to ``L S`` the log-likelihood ratio of one sample is

        log N(e; 0, L S) - log N(e; 0, S) = (1 - 1/L) NIS / 2 - (m / 2) log L,

    so :func:`inflation_score` (the first term) with the CUSUM drift :func:`inflation_drift` (the
    second) is Page's CUSUM on that likelihood ratio, the textbook form. ``NIS`` is capped at a
    chi-square quantile far in the healthy tail (:data:`NIS_CAP_TAIL`): this changes the healthy
    law by a negligible amount where it holds, and bounds the gain of one sample where it does not
    (the nonlinear EHA's Coulomb friction makes the innovation heavy-tailed at every reversal of
    the piston; a single sample must not raise an alarm there). Isolation while in alarm: the
    measured channel with the largest ``e_i^2 / S_ii``, :func:`innovation_channel`.
"""

from __future__ import annotations

import math

import numpy as np

from .._validate import finite_array, open_unit, positive
from ..errors import ParameterError, ShapeError

__all__ = [
    "DEFAULT_INFLATION",
    "DEFAULT_MODE_FLOOR",
    "NIS_CAP_TAIL",
    "inflation_drift",
    "inflation_score",
    "innovation_channel",
    "isolated_fault_mode",
    "mode_log_odds",
    "nis_cap",
    "normalized_innovation_squared",
]

#: Probability floor of the mode score when the filter has none of its own (IMM): the SMM-SVSF's
#: default weight floor, so that both mode routes' scores live on the same range ``[-6.9, 6.9]``.
DEFAULT_MODE_FLOOR = 1e-3
#: Covariance inflation ``L`` the innovation CUSUM is tuned to by default. The CUSUM gains on average
#: only under a fault whose innovation covariance is inflated by more than about ``L``: 1.5 is below the
#: smallest fault of the catalogue, the linear EHA's minor leakage, whose NIS averages 1.64 m (measured:
#: at one false alarm per hour, 200 runs, L = 1.5 misses 1 onset, L = 2 misses 53, L = 4 misses 187).
DEFAULT_INFLATION = 1.5
#: Healthy chi-square tail probability at which NIS is capped (:func:`nis_cap`): 1e-9 per sample is
#: one capped sample in about 300 hours at 1 kHz.
NIS_CAP_TAIL = 1e-9


def mode_log_odds(mu: np.ndarray, floor: float = DEFAULT_MODE_FLOOR) -> np.ndarray:
    """Log posterior odds of the fault modes against mode 0, per sample (natural log).

    Parameters
    ----------
    mu : (..., r) array
        Mode probabilities (``r >= 2``; mode 0 is the normal mode), e.g.
        :attr:`~chatterspec.filters.bank.MultipleModelOutput.mu` ``(runs, T, r)``.
    floor : float
        Probability floor in (0, 1): ``sum_{j>=1} mu_j`` and ``mu_0`` are raised to it before the
        ratio, so the score lies in ``[log floor, -log floor]``.

    Returns
    -------
    (...) array
        ``log(max(sum_{j>=1} mu_j, floor) / max(mu_0, floor))``.
    """
    f = open_unit("floor", floor)
    mu = finite_array("mu", mu)
    if mu.ndim < 1 or mu.shape[-1] < 2:
        raise ShapeError(f"mu must be (..., r) with r >= 2 modes (mode 0 = normal); got shape {mu.shape}")
    fault = np.maximum(mu[..., 1:].sum(axis=-1), f)
    return np.log(fault) - np.log(np.maximum(mu[..., 0], f))


def isolated_fault_mode(mu: np.ndarray) -> np.ndarray:
    """The most probable fault mode per sample: ``1 + argmax_{j >= 1} mu_j`` (an index into the modes).

    Parameters
    ----------
    mu : (..., r) array
        Mode probabilities, mode 0 normal.

    Returns
    -------
    (...) int array
    """
    mu = np.asarray(mu, dtype=float)
    if mu.ndim < 1 or mu.shape[-1] < 2:
        raise ShapeError(f"mu must be (..., r) with r >= 2 modes; got shape {mu.shape}")
    return 1 + np.argmax(mu[..., 1:], axis=-1)


def normalized_innovation_squared(e: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``NIS = e^T S^-1 e`` per sample (Mehra and Peschon 1971).

    Parameters
    ----------
    e : (..., K, m) array
        Innovations ``z(k) - C x(k|k-1)``.
    S : (..., K, m, m) or (K, m, m) array
        Their covariances (symmetric positive definite); ``(K, m, m)`` when shared by every
        realization (the linear Kalman filter from a shared ``P0`` returns it as a broadcast view
        ``(runs, K, m, m)``, factored once here).

    Returns
    -------
    (..., K) array
        Chi-square with ``m`` degrees of freedom per sample when the filter's model and noise
        covariances are the plant's.

    Notes
    -----
    Computed through the Cholesky factor ``S = L L^T``: ``NIS = |L^-1 e|^2``.
    """
    e = np.asarray(e, dtype=float)
    S = np.asarray(S, dtype=float)
    while S.ndim > 3 and S.strides[0] == 0:  # the shared KF's runs axis is a broadcast view: factor once
        S = S[0]
    if e.ndim < 2 or S.shape[-2:] != (e.shape[-1], e.shape[-1]) or S.shape[-3] != e.shape[-2]:
        raise ShapeError(f"S must be (..., K, m, m) matching e (..., K, m); got e {e.shape}, S {S.shape}")
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise ParameterError("S must be symmetric positive definite (an innovation covariance)") from None
    w = np.linalg.solve(L, e[..., None])[..., 0] if L.ndim == e.ndim + 1 else _solve_shared(L, e)
    return np.einsum("...i,...i->...", w, w)


def _solve_shared(L: np.ndarray, e: np.ndarray) -> np.ndarray:
    """``L^-1 e`` for a shared ``L`` (K, m, m) and ``e`` (..., K, m)."""
    Linv = np.linalg.inv(L)  # (K, m, m): lower triangular, small m
    return np.einsum("kij,...kj->...ki", Linv, e)


def innovation_channel(e: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Index of the channel with the largest normalized innovation ``e_i^2 / S_ii`` per sample.

    Parameters
    ----------
    e : (..., K, m) array
    S : (..., K, m, m) or (K, m, m) array

    Returns
    -------
    (..., K) int array
    """
    e = np.asarray(e, dtype=float)
    d = np.diagonal(np.asarray(S, dtype=float), axis1=-2, axis2=-1)
    return np.argmax(e * e / d, axis=-1)


def nis_cap(m: int, tail: float = NIS_CAP_TAIL) -> float:
    """The chi-square (``m`` degrees of freedom) quantile exceeded with probability ``tail``.

    Parameters
    ----------
    m : int
        Measured channels.
    tail : float
        Upper tail probability in (0, 1).

    Returns
    -------
    float
    """
    from scipy.stats import chi2

    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
        raise ParameterError(f"m must be an integer >= 1 (measured channels); got {m!r}")
    return float(chi2.isf(open_unit("tail", tail), int(m)))


def inflation_score(
    nis: np.ndarray, inflation: float = DEFAULT_INFLATION, cap: float | None = None
) -> np.ndarray:
    """The data term of the covariance-inflation log-likelihood ratio: ``(1 - 1/L) min(NIS, cap) / 2``.

    Parameters
    ----------
    nis : array
        Normalized innovations squared (:func:`normalized_innovation_squared`).
    inflation : float
        ``L > 1``: the innovation covariance ``L S`` of the fault alternative.
    cap : float, optional
        Upper bound applied to ``NIS`` first (e.g. :func:`nis_cap`); ``None``: no cap.

    Returns
    -------
    array
        Same shape as ``nis``; with the CUSUM drift :func:`inflation_drift` this is the per-sample
        log-likelihood ratio of ``N(0, L S)`` against ``N(0, S)``.
    """
    L = _inflation(inflation)
    x = np.asarray(nis, dtype=float)
    if cap is not None:
        x = np.minimum(x, positive("cap", cap))
    return (0.5 * (1.0 - 1.0 / L)) * x


def inflation_drift(m: int, inflation: float = DEFAULT_INFLATION) -> float:
    """The constant term ``(m / 2) log L`` of the covariance-inflation log-likelihood ratio.

    It exceeds the healthy mean of :func:`inflation_score` (``(1 - 1/L) m / 2``) for every ``L > 1``,
    so a CUSUM with this drift drifts back to 0 on healthy data.

    Parameters
    ----------
    m : int
        Measured channels (degrees of freedom of NIS).
    inflation : float
        ``L > 1``.

    Returns
    -------
    float
    """
    if isinstance(m, bool) or not isinstance(m, int | np.integer) or m < 1:
        raise ParameterError(f"m must be an integer >= 1 (measured channels); got {m!r}")
    return 0.5 * int(m) * math.log(_inflation(inflation))


def _inflation(value: float) -> float:
    L = positive("inflation", value)
    if not L > 1.0:
        raise ParameterError(f"inflation must be > 1 (the fault's innovation covariance is L S); got {L!r}")
    return L
