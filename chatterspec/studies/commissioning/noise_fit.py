"""Noise covariances Q and R from the chattering's autocovariances at lags 0 and 1.

The law (goes beyond the paper, which takes Q and R as given)
--------------------------------------------------------------
With full measurement (C invertible) and zero initial error, the auxiliary sgn filter's chattering
at a model that matches the plant is eq (23)::

    eta(k+1) = C v(k) + w(k+1) - Phi w(k),        Phi = C A C^-1,

with ``v ~ N(0, Q)`` the process noise and ``w ~ N(0, R)`` the measurement noise: a vector MA(1)
process, the law behind the expected spectrum of eq (56)-(58), with::

    Gamma0 = E[eta(k) eta(k)']   = C Q C' + R + Phi R Phi'
    Gamma1 = E[eta(k+1) eta(k)'] = -Phi R

(:func:`chatterspec.detection.spectral.chattering_autocovariance` gives their diagonals, which set
the detector's expected spectrum). Both are linear in ``q = diag(Q)`` and ``r = diag(R)``::

    Gamma0[i, j] = sum_k C[i,k] C[j,k] q_k + delta_ij r_i + sum_k Phi[i,k] Phi[j,k] r_k
    Gamma1[i, j] = -Phi[i, j] r_j

so the ``m (m + 1) / 2`` distinct sample autocovariances at lag 0 and the ``m^2`` at lag 1 give a
linear least-squares problem in ``(q, r)``: autocovariance least squares (Odelson, Rajamani and
Rawlings, Automatica 2006) for this filter, whose innovations are MA(1) rather than white.

Weights and intervals
    Each sample autocovariance is the mean of a product series ``eta_i(k + l) eta_j(k)``, ``l`` in
    {0, 1}; for an MA(1) ``eta`` two products more than two samples apart are independent, so the
    covariance of the means is estimated from the products' own autocovariances at lags 0, 1 and 2
    (a truncated long-run variance, exact in expectation for this law; no bootstrap). The fit is
    generalized least squares with that covariance as weight; the intervals are Wald intervals
    from ``(M' W M)^-1``. They ignore the error of the fitted A and B the chattering is computed
    at (its effect on the autocovariances is of the order of the fitted entries' standard errors).
    The weighted residual is Hansen's overidentification statistic: chi-squared with (moments -
    fitted variances) degrees of freedom when the chattering is the MA(1) of eq (23), large when the
    noise is coloured or the model misses a disturbance.

Identifiability
    Only some combinations of Q and R are seen in output data. An entry whose interval holds 0 is
    **not identified**: the data bound it above (the interval's upper end) and no more; the EHA's
    position and pressure process noises are of this kind (``q = 1e-12`` m^2 under ``2e-6`` m^2 of
    measurement-noise contribution). Such an entry keeps its nominal value when the data allow it
    (nominal at most the bound), else the bound, and the identified entries are fitted again with it
    held there: Gamma0 and Gamma1, which the detector needs, stay matched; a Q entry the data put
    below 0 is set to 0 (a valid covariance: nothing needs Q positive definite, and an unidentified
    entry of true value ~0 falls below 0 by chance). R must be positive definite (every sensor has
    noise; eq 23's law and the identification's weights rest on it): an R entry whose whole interval
    lies below 0 means the data contradict the law (a positive lag-1 autocovariance where white
    measurement noise makes it negative: a coloured sensor) and raises
    :class:`~chatterspec.errors.CommissioningError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.special

from ...errors import CommissioningError
from ...plants.models import LinearModel

__all__ = ["NoiseFit", "autocovariance_moments", "fit_noise", "moment_design"]

#: Relative singular-value floor below which a direction of the weighted design carries no information.
SINGULAR_FLOOR = 1e-10


@dataclass(frozen=True, eq=False)
class NoiseFit:
    """Diagonal Q and R fitted to the chattering's lag-0 and lag-1 autocovariances (eq 23, 56).

    Attributes
    ----------
    q, r : (n,), (m,) arrays
        The values the fitted model takes (state and output units squared): the estimate where
        the data identify the entry, else the nominal value clipped to the data's bound.
    q_std_error, r_std_error : arrays
        Standard errors (inf where the design cannot see the entry at all).
    q_ci_low, q_ci_high, r_ci_low, r_ci_high : arrays
        Wald interval at ``confidence`` (identified entries), ``[0, bound]`` (others).
    q_identified, r_identified : bool arrays
        Whether the interval excludes 0.
    q_nominal, r_nominal : arrays
        The nominal model's diagonals.
    statistic : float
        Weighted residual of the autocovariance fit (chi-squared with ``dof`` degrees of freedom
        under the MA(1) law).
    dof : int
    p_value : float
    gamma0_sample, gamma1_sample : (m,) arrays
        The chattering's sample autocovariances at lags 0 and 1, per channel.
    gamma0_model, gamma1_model : (m,) arrays
        The same from the fitted Q and R (eq 58; what sets the expected spectrum).
    n_samples : int
        Chattering samples used.
    confidence : float
    """

    q: np.ndarray
    r: np.ndarray
    q_std_error: np.ndarray
    r_std_error: np.ndarray
    q_ci_low: np.ndarray
    q_ci_high: np.ndarray
    r_ci_low: np.ndarray
    r_ci_high: np.ndarray
    q_identified: np.ndarray
    r_identified: np.ndarray
    q_nominal: np.ndarray
    r_nominal: np.ndarray
    statistic: float
    dof: int
    p_value: float
    gamma0_sample: np.ndarray
    gamma1_sample: np.ndarray
    gamma0_model: np.ndarray
    gamma1_model: np.ndarray
    n_samples: int
    confidence: float

    def apply(self, model: LinearModel) -> LinearModel:
        """``model`` with ``Q = diag(q)`` and ``R = diag(r)`` (off-diagonal entries are not fitted: dropped).

        Parameters
        ----------
        model : LinearModel
            The model the chattering was computed at (same sizes).
        """
        import dataclasses

        return dataclasses.replace(model, Q=np.diag(self.q), R=np.diag(self.r))

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: per covariance the fitted diagonal, standard errors, interval, identified flags,
        nominal; the fit's statistic, dof and p-value; the autocovariances, sample and model."""
        out: dict[str, object] = {}
        for key in ("q", "r"):
            for suffix in ("", "_std_error", "_ci_low", "_ci_high", "_nominal"):
                vals = getattr(self, key + suffix)
                out[key + suffix] = [float(v) if np.isfinite(v) else None for v in vals]
            out[key + "_identified"] = [bool(v) for v in getattr(self, key + "_identified")]
        out.update(statistic=self.statistic, dof=self.dof, p_value=self.p_value)
        for key in ("gamma0_sample", "gamma1_sample", "gamma0_model", "gamma1_model"):
            out[key] = [float(v) for v in getattr(self, key)]
        out.update(n_samples=self.n_samples, confidence=self.confidence)
        return out


def _pairs(m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lag-0 pairs ``i <= j`` and lag-1 pairs (every ``i, j``): the moments' order."""
    i0, j0 = np.triu_indices(m)
    i1, j1 = np.divmod(np.arange(m * m), m)
    return i0, j0, i1, j1


def autocovariance_moments(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample autocovariances of ``e`` at lags 0 and 1 and the covariance of their estimates.

    Parameters
    ----------
    e : (N, m) array
        Chattering samples (output units), zero mean under the law.

    Returns
    -------
    g : (K,) array
        ``Gamma0_hat[i, j]`` for ``i <= j`` (row-major), then ``Gamma1_hat[i, j] = mean e_i(k+1) e_j(k)``
        for every ``i, j``; ``K = m (m + 1) / 2 + m^2``. Both are means over the same ``N - 1`` pairs.
    cov : (K, K) array
        Covariance of ``g``: the product series' autocovariances at lags 0 to 2 summed, over ``N - 1``
        (the products of an MA(1) process are 2-dependent).
    """
    e = np.asarray(e, dtype=float)
    m = e.shape[1]
    i0, j0, i1, j1 = _pairs(m)
    later, earlier = e[1:], e[:-1]
    P = np.concatenate([later[:, i0] * later[:, j0], later[:, i1] * earlier[:, j1]], axis=1)
    g = P.mean(axis=0)
    P -= g
    n = P.shape[0]
    S = P.T @ P
    for h in (1, 2):
        G = P[h:].T @ P[:-h]
        S += G + G.T
    return g, S / (n * n)


def moment_design(model: LinearModel) -> np.ndarray:
    """``(K, n + m)`` matrix ``M`` with ``g = M [q; r]`` under the MA(1) law (module docstring).

    Parameters
    ----------
    model : LinearModel
        Full-measurement model (its C and ``Phi = C A C^-1``).
    """
    C, n, m = model.C, model.n_states, model.n_outputs
    Phi = C @ model.A @ model.C_inv
    i0, j0, i1, j1 = _pairs(m)
    M = np.zeros((i0.size + i1.size, n + m))
    M[: i0.size, :n] = C[i0] * C[j0]
    M[: i0.size, n:] = Phi[i0] * Phi[j0]
    M[np.flatnonzero(i0 == j0), n + i0[i0 == j0]] += 1.0
    M[i0.size + np.arange(i1.size), n + j1] = -Phi[i1, j1]
    return M


def _whiten(cov: np.ndarray) -> np.ndarray:
    """``L^-1`` with ``L L' = cov`` (eigenvalues floored at a relative 1e-12 when not positive definite)."""
    try:
        L = np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        lam, V = np.linalg.eigh(cov)
        lam = np.maximum(lam, 1e-12 * max(float(lam.max()), 1e-300))
        L = np.linalg.cholesky((V * lam) @ V.T)
    return scipy.linalg.solve_triangular(L, np.eye(cov.shape[0]), lower=True)


def _gls(Mw: np.ndarray, gw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unconstrained weighted least squares: estimate and standard errors (inf where not seen)."""
    s = np.linalg.norm(Mw, axis=0)
    s = np.where(s > 0, s, 1.0)
    U, sv, Vt = np.linalg.svd(Mw / s, full_matrices=False)
    keep = sv > SINGULAR_FLOOR * sv[0]
    coef = Vt[keep].T @ ((U[:, keep].T @ gw) / sv[keep])
    var = (Vt[keep].T ** 2) @ (1.0 / sv[keep] ** 2)
    unseen = (Vt[~keep] ** 2).sum(axis=0) > 1e-8
    return coef / s, np.where(unseen, np.inf, np.sqrt(var) / s)


def _nnls(Mw: np.ndarray, gw: np.ndarray) -> np.ndarray:
    """Non-negative weighted least squares (columns scaled)."""
    if Mw.shape[1] == 0:
        return np.zeros(0)
    s = np.linalg.norm(Mw, axis=0)
    s = np.where(s > 0, s, 1.0)
    x, _ = scipy.optimize.nnls(Mw / s, gw)
    return x / s


def fit_noise(
    model: LinearModel, e: np.ndarray, *, confidence: float = 0.95, nominal: LinearModel | None = None
) -> NoiseFit:
    """Fit diag(Q) and diag(R) to the chattering ``e`` computed at ``model`` (module docstring).

    Parameters
    ----------
    model : LinearModel
        Full-measurement model whose A, B, C produced ``e`` (eq 23); its Q and R are the nominal
        values non-identified entries fall back on.
    e : (N, m) array
        Chattering ``z(k+1) - C A C^-1 z(k) - C B u(k)`` (output units).
    confidence : float
        Level of the intervals (and of the identified / not-identified decision).
    nominal : LinearModel, optional
        The model whose Q and R diagonals are the nominal values (default ``model``'s), e.g. the
        nominal file's when ``model`` carries a first fit.

    Returns
    -------
    NoiseFit

    Raises
    ------
    CommissioningError
        An entry whose whole interval lies below 0 (the data contradict the MA(1) law there), or an
        R entry the data do not identify whose nominal value is 0 (R must be positive definite: the
        detector's and the identification's noise law needs every sensor's noise).
    """
    n, m = model.n_states, model.n_outputs
    g, cov = autocovariance_moments(e)
    M = moment_design(model)
    Wi = _whiten(cov)
    Mw, gw = Wi @ M, Wi @ g
    z = float(scipy.special.ndtri(0.5 + confidence / 2))
    theta_u, se_u = _gls(Mw, gw)
    hi_u, lo_u = theta_u + z * se_u, theta_u - z * se_u
    ref = model if nominal is None else nominal
    nominal_qr = np.concatenate([np.diag(ref.Q), np.diag(ref.R)])
    _refuse_negative_r(model, theta_u, hi_u, g)
    ident = lo_u > 0
    value = np.where(ident, 0.0, np.clip(nominal_qr, 0.0, np.maximum(hi_u, 0.0)))
    if np.any(~ident[n:] & (value[n:] <= 0)):
        c = int(np.flatnonzero(~ident[n:] & (value[n:] <= 0))[0])
        raise CommissioningError(
            f"the fitted R is not positive definite: the data do not identify R on "
            f"{model.output_names[c]} (its interval holds 0) and the nominal R there is 0; give the "
            "sensor's noise variance in the model file"
        )
    free = np.flatnonzero(ident)
    fixed = np.flatnonzero(~ident)
    resid_target = gw - Mw[:, fixed] @ value[fixed]
    value[free] = _nnls(Mw[:, free], resid_target)
    se = se_u.copy()
    if free.size:
        se[free] = _gls(Mw[:, free], resid_target)[1]
    lo = np.where(ident, np.maximum(value - z * se, 0.0), 0.0)
    hi = np.where(ident, value + z * se, np.maximum(hi_u, 0.0))
    res = gw - Mw @ value
    stat = float(res @ res)
    dof = int(g.size - free.size)
    p = float(scipy.special.chdtrc(dof, stat)) if dof > 0 else 1.0
    Phi = model.C @ model.A @ model.C_inv
    R, CQC = np.diag(value[n:]), model.C @ np.diag(value[:n]) @ model.C.T
    g0m = np.diag(CQC + R + Phi @ R @ Phi.T)
    g1m = np.diag(-Phi @ R)
    i0, j0, _, _ = _pairs(m)
    diag0 = np.flatnonzero(i0 == j0)
    return NoiseFit(
        q=value[:n],
        r=value[n:],
        q_std_error=se[:n],
        r_std_error=se[n:],
        q_ci_low=lo[:n],
        q_ci_high=hi[:n],
        r_ci_low=lo[n:],
        r_ci_high=hi[n:],
        q_identified=ident[:n],
        r_identified=ident[n:],
        q_nominal=nominal_qr[:n],
        r_nominal=nominal_qr[n:],
        statistic=stat,
        dof=dof,
        p_value=p,
        gamma0_sample=g[diag0],
        gamma1_sample=g[i0.size + np.arange(m) * (m + 1)],
        gamma0_model=g0m,
        gamma1_model=g1m,
        n_samples=int(np.asarray(e).shape[0]),
        confidence=float(confidence),
    )


def _refuse_negative_r(model: LinearModel, theta: np.ndarray, hi: np.ndarray, g: np.ndarray) -> None:
    """:class:`CommissioningError` naming the R entries whose whole interval (upper end ``hi``) is below 0."""
    n, m = model.n_states, model.n_outputs
    bad = np.flatnonzero(hi[n:] < 0)
    if not bad.size:
        return
    i0, _, _, _ = _pairs(m)
    parts = []
    for c in bad:
        name = model.output_names[c]
        g1 = g[i0.size + c * (m + 1)]
        parts.append(
            f"R on {name} = {theta[n + c]:.3g} (interval below 0): the {name} chattering's lag-1 "
            f"autocovariance is {g1:+.3g}, where white measurement noise makes it -Phi R (eq 23): the sensor "
            "noise is coloured (filtered, AR) or the recording holds a disturbance the model lacks"
        )
    raise CommissioningError("the fitted R is not positive definite: " + "; ".join(parts))
