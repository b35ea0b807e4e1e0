"""Every declared physical parameter fitted at once, with its identifiability checked first.

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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ...errors import IdentifiabilityError
from ...plants.models import LinearModel

if TYPE_CHECKING:  # pragma: no cover
    from ...detection.identification import IdentificationMoments, IdentificationSetup

__all__ = ["MAX_RELATIVE_SE", "FittedParameter", "ParameterFit", "excitation_band", "fit_parameters"]

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
    import scipy.special

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
