"""The fits of a commissioning: the physical parameters, then the noise covariances Q and R.

Parameters (:func:`fit_parameters`): every declared physical parameter fitted at once, with its
identifiability checked first.

The fit is fault identification's regression (:mod:`chatterspec.detection.identification`, eq 23:
instrumental variables ``z(k-1)`` for ``z(k)``, the lag-1 sandwich covariance of the MA(1)
chattering, a minimum-distance fit of the parameters to the estimated entries of ``C A C^-1`` and
``C B``) with **one hypothesis holding every declared parameter**: the joint fit. The estimate is
the plant's value of each parameter with a delta-method interval. The entry estimates do not depend
on the nominal values of the entries they estimate (the regression is linear in them); the weights
and the intervals do, through Q and R (eq 58), so :func:`chatterspec.studies.commissioning.commission`
identifies again once its noise fit has moved them.

Identifiability (goes beyond the papers)
    From the joint fit's information matrix ``I = G' V^+ G`` (``G`` the Jacobian of the entries in
    the parameters, ``V`` the entries' sandwich covariance) in **relative units** (each parameter
    scaled by the larger of its nominal and fitted magnitude), the smallest eigenvalue ``l`` names
    the combination the data see worst, its eigenvector, known to a relative standard error
    ``1 / sqrt(l)``. Above :data:`MAX_RELATIVE_SE` the fit is refused with
    :class:`~chatterspec.errors.IdentifiabilityError`, naming the parameter(s) and what would
    identify them: a longer recording (standard errors shrink as ``1 / sqrt(duration)``, so the
    length that would do is ``duration (se / MAX_RELATIVE_SE)^2``) or, when that is out of reach or
    a regressor stays at its noise level, an input that excites the model's modes. Regressors with
    no excitation at all are already left out by the regression (they carry no information).

Noise (:func:`fit_noise`): covariances Q and R from the chattering's autocovariances at lags 0 and 1.

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
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.special

from ...errors import CommissioningError, IdentifiabilityError
from ...plants.models import LinearModel

__all__ = [
    "MAX_RELATIVE_SE",
    "FittedParameter",
    "NoiseFit",
    "ParameterFit",
    "autocovariance_moments",
    "excitation_band",
    "fit_noise",
    "fit_parameters",
    "moment_design",
]

if TYPE_CHECKING:  # pragma: no cover
    from ...detection.identification import IdentificationMoments, IdentificationSetup


#: Largest relative standard error (of the worst-seen combination of parameters, relative to their
#: magnitudes) a commissioning fit accepts: 10 %, a 95 % interval of about +-20 %. Beyond it the
#: data cannot tell the parameter from a guess and nothing is fitted.
MAX_RELATIVE_SE = 0.10
#: A recording this many times longer than the one given counts as out of reach: then the advice is
#: an input that excites the model, not more of the same data.
MAX_LENGTH_FACTOR = 100.0


@dataclass(frozen=True)
class FittedParameter:
    """One physical parameter of the joint fit: the plant's value with its interval.

    Attributes
    ----------
    name, unit : str
    nominal : float
        The value in the nominal model file (its unit).
    estimate : float
        The plant's value (nominal + estimated deviation), in ``unit``.
    std_error : float
    ci_low, ci_high : float
        Delta-method Wald interval at ``confidence``.
    confidence : float
    """

    name: str
    unit: str
    nominal: float
    estimate: float
    std_error: float
    ci_low: float
    ci_high: float
    confidence: float

    @property
    def relative_change(self) -> float:
        """``estimate / nominal - 1`` (NaN for a nominal of 0)."""
        return self.estimate / self.nominal - 1.0 if self.nominal != 0 else float("nan")

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: every field."""
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


@dataclass(frozen=True, eq=False)
class ParameterFit:
    """The joint fit of every declared parameter on one span of data.

    Attributes
    ----------
    parameters : tuple of FittedParameter
        In the model's parameter order.
    model : LinearModel
        The input model with the fitted values (:meth:`~chatterspec.plants.parameters.ParameterMap.apply`).
    covariance : (P, P) array
        Covariance of the estimates (their units).
    statistic : float
        Minimum distance of the entries to the declared parameter map (chi-squared with ``dof``
        degrees of freedom when the map explains the plant).
    dof : int
    p_value : float
    worst_relative_se : float
        Relative standard error of the worst-seen combination (module docstring).
    n_samples : int
        Chattering samples the fit used.
    """

    parameters: tuple[FittedParameter, ...]
    model: LinearModel
    covariance: np.ndarray
    statistic: float
    dof: int
    p_value: float
    worst_relative_se: float
    n_samples: int

    def values(self) -> dict[str, float]:
        """``{name: estimate}``."""
        return {p.name: p.estimate for p in self.parameters}


def excitation_band(model: LinearModel) -> tuple[float, float, tuple[float, ...]]:
    """``(lo, hi, modes)`` in Hz: an input band that excites ``model``'s dynamics, and its modes' frequencies.

    The modes are ``|log(lambda)| / (2 pi dt)`` over the eigenvalues ``lambda`` of A that are not
    integrators; the band spans a quarter of the slowest to 1.5 times the fastest, capped at 0.4 / dt
    (below Nyquist). Empty modes give ``(nan, nan, ())``.

    Parameters
    ----------
    model : LinearModel
    """
    lam = np.linalg.eigvals(model.A).astype(complex)
    s = np.abs(np.log(lam[np.abs(lam) > 0])) / model.dt
    f = np.unique(np.round(s[s > 1e-6 / model.dt] / (2 * np.pi), 9))
    if not f.size:
        return float("nan"), float("nan"), ()
    return float(0.25 * f.min()), float(min(1.5 * f.max(), 0.4 / model.dt)), tuple(float(x) for x in f)


def _advice(model: LinearModel) -> str:
    lo, hi, modes = excitation_band(model)
    if not modes:
        return "drive the plant with a rich input (steps, a chirp, noise) and record again"
    shown = ", ".join(f"{f:.3g}" for f in modes[:4])
    return (
        f"drive the plant with a chirp or steps covering ~{lo:.2g}-{hi:.2g} Hz (the model's modes: {shown} "
        "Hz) and record again"
    )


def fit_parameters(
    model: LinearModel,
    z: np.ndarray,
    u: np.ndarray,
    *,
    confidence: float = 0.95,
    t0: float = 0.0,
    record_s: float | None = None,
    nominal: dict[str, float] | None = None,
) -> ParameterFit:
    """Fit every parameter ``model`` declares, at once, to measurements ``z`` and inputs ``u`` (eq 23).

    Parameters
    ----------
    model : LinearModel
        Full-measurement model with a parameter map; its Q and R weight the fit (eq 58).
    z : (T, m) array
        Measurements (output units).
    u : (T, p) array
        Inputs (``u(k)`` drives the plant from sample k to k+1).
    confidence : float
        Level of the intervals.
    t0 : float
        Time (s) of ``z[0]``.
    record_s : float, optional
        Length (s) of the whole recording these data are the fit span of (for the message that says
        how long a recording would do); default the span itself.
    nominal : dict, optional
        The values reported as nominal and scaling the identifiability check (default: the model's),
        e.g. a nominal file's when ``model`` already carries a first fit.

    Raises
    ------
    IdentifiabilityError
        A nonlinear model, reduced-order measurement, parameters that enter the matrices only
        together, a parameter whose regressors carry no excitation, or a combination of parameters
        the data see only to more than :data:`MAX_RELATIVE_SE` (too short, or not excited): the
        message names the parameter(s) and what would identify them.
    """
    from ...detection.identification import identification_moments, identification_setup, identify_moments

    pm = model.parameter_map
    if pm is None:
        raise IdentifiabilityError(f"{model.name}: the model declares no physical parameters to fit")
    names = list(pm.parameter_names)
    setup = identification_setup(model, [names])
    mom = identification_moments(setup, z, u, t0=t0)
    fit = identify_moments(setup, mom, confidence=confidence).fit
    theta, se = fit["theta"][0, 0, : len(names)], fit["se"][0, 0, : len(names)]
    span_s = mom.n_samples * model.dt
    if not np.all(np.isfinite(theta)):
        raise IdentifiabilityError(_unexcited(setup, fit, mom, names, model))
    G = setup.jacobian(0, theta)
    info = _information(G, fit["entry_cov"][0], fit["active"][0])
    given = {p: pm.parameter(p).value for p in names} | dict(nominal or {})
    ref = np.array([given[p] for p in names])
    scale = np.maximum(np.abs(ref), np.abs(theta))
    scale = np.where(scale > 0, scale, 1.0)
    lam, vec = np.linalg.eigh(info * np.outer(scale, scale))
    worst = float(1.0 / np.sqrt(lam[0])) if lam[0] > 0 else float("inf")
    if not worst <= MAX_RELATIVE_SE:
        raise IdentifiabilityError(
            _too_weak(model, setup, mom, names, vec[:, 0], worst, span_s, record_s or span_s)
        )
    cov = np.linalg.inv(info)
    z_q = float(_normal_quantile(confidence))
    params = []
    for i, name in enumerate(names):
        unit, t, s = pm.parameter(name).unit, float(theta[i]), float(se[i])
        params.append(FittedParameter(name, unit, given[name], t, s, t - z_q * s, t + z_q * s, confidence))
    return ParameterFit(
        parameters=tuple(params),
        model=pm.model_with(model, dict(zip(names, theta.tolist(), strict=True)), model.name),
        covariance=cov,
        statistic=float(fit["statistic"][0, 0]),
        dof=int(fit["dof"][0, 0]),
        p_value=float(fit["p"][0, 0]),
        worst_relative_se=worst,
        n_samples=mom.n_samples,
    )


def _normal_quantile(confidence: float) -> float:
    return float(scipy.special.ndtri(0.5 + confidence / 2))


def _information(G: np.ndarray, V: np.ndarray, active: np.ndarray) -> np.ndarray:
    """``G' V^+ G`` over the active entries (pseudo-inverse of the entries' correlation matrix at a
    relative 1e-10, as the fit's own weights)."""
    Va = V[np.ix_(active, active)]
    T = np.sqrt(np.diag(Va))
    T = np.where(T > 0, T, 1.0)
    lam, Q = np.linalg.eigh(Va / np.outer(T, T))
    keep = lam > 1e-10 * lam[-1]
    W = (Q[:, keep] / np.sqrt(lam[keep])).T @ (G[active] / T[:, None])
    return W.T @ W


def _regressor_names(setup: IdentificationSetup, model: LinearModel) -> list[str]:
    J, L = setup.J, setup.L
    return [model.output_names[j] for j in J] + [f"input {model.input_names[l_]}" for l_ in L]


def _signal_to_noise(
    setup: IdentificationSetup, mom: IdentificationMoments, model: LinearModel
) -> np.ndarray:
    """Per regressor: its mean square over the span divided by its measurement noise's (inf for inputs)."""
    n = mom.n_samples
    ms = np.diag(mom.s0[0]) / max(n, 1)
    r = np.concatenate([np.diag(model.R)[setup.J], np.zeros(setup.L.size)])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(r > 0, ms / np.where(r > 0, r, 1.0), np.where(ms > 0, np.inf, 0.0))


def _parameter_regressors(setup: IdentificationSetup, names: list[str], which: int) -> np.ndarray:
    """Regressor columns of the entries parameter ``names[which]`` moves."""
    touched = np.abs(setup.slopes[0][:, which]) > 0
    return np.unique(setup.cols[touched])


def _unexcited(
    setup: IdentificationSetup,
    fit: dict[str, Any],
    mom: IdentificationMoments,
    names: list[str],
    model: LinearModel,
) -> str:
    """The message of a joint fit that has no estimate: which parameter, which regressor, what to do."""
    reasons = fit["entry_reason"][0]
    regs = _regressor_names(setup, model)
    snr = _signal_to_noise(setup, mom, model)
    parts = []
    for i, name in enumerate(names):
        cols = _parameter_regressors(setup, names, i)
        bad = [c for c in cols if np.any(reasons[setup.cols == c] != 0)]
        if not bad or len(bad) < len(cols):
            continue
        why = []
        for c in bad:
            code = int(np.max(reasons[setup.cols == c]))
            if code == 2:
                why.append(f"{regs[c]} moves only together with the other regressors (collinear)")
            elif c >= setup.J.size:
                why.append(f"the {regs[c]} is zero over the fit span")
            else:
                why.append(
                    f"{regs[c]} never leaves its noise level (mean square {snr[c]:.3g} x its measurement "
                    "noise's)"
                )
        parts.append(f"{name} is not identifiable: {'; '.join(why)}")
    what = "; ".join(parts) or f"{', '.join(names)} cannot be fitted from these data"
    return f"{what}; {_advice(model)}"


def _too_weak(
    model: LinearModel,
    setup: IdentificationSetup,
    mom: IdentificationMoments,
    names: list[str],
    v: np.ndarray,
    worst: float,
    span_s: float,
    record_s: float,
) -> str:
    """The message of a combination the data see only to ``worst`` (relative standard error)."""
    order = np.argsort(-np.abs(v))
    main = [i for i in order if abs(v[i]) >= 0.3] or [int(order[0])]
    if len(main) == 1:
        what = f"{names[main[0]]} is known only to a standard error of {worst:.0%} of its value"
    else:
        combo = " ".join(f"{v[i]:+.2f} {names[i]}" for i in main).lstrip("+")
        what = (
            f"{' and '.join(names[i] for i in main)} are not separately identifiable: the combination "
            f"{combo} (relative to their values) is known only to a standard error of {worst:.0%}"
        )
    factor = (worst / MAX_RELATIVE_SE) ** 2
    head = f"over the fit span ({span_s:.3g} s) {what} (at most {MAX_RELATIVE_SE:.0%} is accepted)"
    snr = _signal_to_noise(setup, mom, model)
    cols = sorted({int(c) for i in main for c in _parameter_regressors(setup, names, i)})
    quiet = [c for c in cols if snr[c] < 4.0]  # regressor power within a few noise powers: barely excited
    if factor <= MAX_LENGTH_FACTOR and not quiet:
        return f"the recording is too short: {head}; a recording of about {factor * record_s:.3g} s would do"
    regs = _regressor_names(setup, model)
    why = (
        "; ".join(
            f"{regs[c]} barely leaves its noise level (mean square {snr[c]:.3g} x the noise's)" for c in quiet
        )
        if quiet
        else f"it would take a recording {factor:.3g} times as long"
    )
    return f"not identifiable from these data: {head} ({why}); {_advice(model)}"


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
