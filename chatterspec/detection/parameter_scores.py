"""Scores of the identified parameters against their tolerance bands, their worst-case law and the
alarm rule's threshold for a budget, and the detectable change.

The pieces of :mod:`chatterspec.detection.parameter_decision` (which takes the decisions per hop) that
do not depend on time: what a window's joint estimate says about each parameter.

**Score.** Parameter ``i`` with band ``[lo, hi]`` (width ``w``; a parameter without a declared
tolerance gets the zero-width band at its nominal value) and the estimate's distance beyond the
band ``d = max(lo - theta, theta - hi)``, ``t = d / sigma``::

    p = Phi_c(t) + Phi_c(t + w / sigma),        score = -log p        (Phi_c: normal upper tail)

is the exact p-value of "the parameter lies inside its band" under the estimate's normal law,
taken at the worst case (the parameter on a band edge): uniform there, larger inside, two-sided
``2 Phi_c(|theta - nominal| / sigma)`` for a zero-width band. A window without an estimate (no
excitation, collinear regressors) scores 0: no evidence.

**Alarm.** The scores (one channel per parameter) go through the monitor's alarm rule
(:mod:`chatterspec.detection.alarms.streams`: frame, persistence or CUSUM, with renewal), whose threshold
is set for the run's budget in false alarms per hour like the spectral scores'
(:func:`calibrate_parameter_rule`): the frame rule from the law (``h = log(F P / X)``), the others
on simulated worst-case streams. Under stationary excitation the estimates of two windows sharing
``k`` of their ``n`` hops are correlated ``k / n`` (the identification sums are additive over
hops), so the worst-case score stream of a parameter is ``-log Phi_c(z_j)`` with ``z_j`` the
normalized sum of ``n`` consecutive independent normals (two-sided for a zero-width band); the
budget counts alarm starts over every parameter.

**Detectable change.** ``delta = (z(1 - a) + z(power)) sigma`` (:func:`detectable_change`): the
change an estimate of standard error ``sigma`` detects at level ``a`` with probability ``power``.
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.special

from .._validate import open_unit, positive, positive_int
from ..errors import IdentifiabilityError
from .alarms.calibration import RuleCalibration, calibrate_rule, check_budget, law_frame_rule
from .alarms.rules import AlarmRule, make_rule, rule_from_dict, rule_spec
from .identification import IdentificationSetup

__all__ = [
    "CALIBRATION_HOURS",
    "DEFAULT_POWER",
    "MISFIT_LEVEL",
    "NOT_EXCITED_MULTIPLE",
    "ParameterBands",
    "band_position",
    "band_scores",
    "calibrate_parameter_rule",
    "detectable_change",
    "detection_level",
    "joint_estimates",
    "joint_hypothesis",
    "parameter_null_scores",
    "status_text",
]

#: Probability that an estimate detects a change of the detectable size.
DEFAULT_POWER = 0.95
#: A parameter without a tolerance is not excited when the detectable change exceeds this multiple of
#: its nominal value (a change of 100 % would go unseen).
NOT_EXCITED_MULTIPLE = 1.0
#: Level of the joint fit's minimum-distance test below which a window gives no evidence
#: (:mod:`chatterspec.detection.parameter_decision`).
MISFIT_LEVEL = 1e-3
#: Hours of worst-case streams a persistence or CUSUM threshold is calibrated on (drawn, not simulated
#: through the plant: a few seconds of CPU).
CALIBRATION_HOURS = 12.0
#: Second entropy word of the worst-case streams' seeds.
PARAMETER_SALT = 0x7A1E


@dataclass(frozen=True, eq=False)
class ParameterBands:
    """The bands of a model's declared parameters, in table order.

    Attributes
    ----------
    names, units : tuple of str
    nominal, low, high : (P,) arrays
        Nominal value and band ends (the parameter's unit); ``low = high = nominal`` without a
        declared tolerance.
    limit : (P,) array
        The detectable change above which a parameter is not excited: the smaller side of its
        tolerance, else ``multiple * |nominal|`` (``inf`` for a zero nominal).
    tolerances : tuple of str
        The tolerance in words (``"+-15 %"``), empty without one.
    """

    names: tuple[str, ...]
    units: tuple[str, ...]
    nominal: np.ndarray
    low: np.ndarray
    high: np.ndarray
    limit: np.ndarray
    tolerances: tuple[str, ...]

    @classmethod
    def from_map(cls, parameter_map: Any, multiple: float = NOT_EXCITED_MULTIPLE) -> ParameterBands:
        """The bands of a :class:`~chatterspec.plants.parameters.ParameterMap`'s parameters."""
        multiple = positive("not-excited multiple", multiple)
        ps = parameter_map.parameters
        nominal = np.array([p.value for p in ps], dtype=float)
        bands = [p.band or (p.value, p.value) for p in ps]
        low = np.array([b[0] for b in bands], dtype=float)
        high = np.array([b[1] for b in bands], dtype=float)
        side = np.minimum(nominal - low, high - nominal)
        fallback = np.where(nominal != 0.0, multiple * np.abs(nominal), np.inf)
        limit = np.where(side > 0, side, fallback)
        return cls(
            names=tuple(p.name for p in ps),
            units=tuple(p.unit for p in ps),
            nominal=nominal,
            low=low,
            high=high,
            limit=limit,
            tolerances=tuple("" if p.tolerance is None else p.tolerance.describe(p.unit) for p in ps),
        )

    @property
    def size(self) -> int:
        """Number of parameters."""
        return len(self.names)

    @property
    def two_sided(self) -> np.ndarray:
        """``(P,)`` bool: zero-width bands (the score's worst case is two-sided)."""
        return self.high <= self.low


def joint_hypothesis(setup: IdentificationSetup) -> tuple[int, np.ndarray]:
    """Index of the hypothesis with every declared parameter free, and where each parameter (table
    order) sits among its parameters.

    Raises
    ------
    IdentifiabilityError
        The setup does not test that hypothesis (hypotheses given explicitly, or the parameters
        cannot be told apart all at once).
    """
    names = setup.parameter_map.parameter_names
    for h, hyp in enumerate(setup.hypotheses):
        if set(hyp.parameters) == set(names):
            return h, np.array([hyp.parameters.index(p) for p in names])
    raise IdentifiabilityError(
        f"decisions on the identified parameters need every declared parameter ({', '.join(names)}) fitted "
        "at once, and this identification does not test that hypothesis (hypotheses given explicitly, or "
        "the parameters cannot all be told apart from the chattering)"
    )


def joint_estimates(identification: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(theta, se, fits)`` of the joint hypothesis: ``(R, P)`` in table order, ``fits`` ``(R,)`` False
    where its minimum-distance test rejects at :data:`MISFIT_LEVEL` (a window the parameters do not describe).

    Parameters
    ----------
    identification : Identification
        Of ``R`` realizations or windows (:mod:`chatterspec.detection.identification`), whose
        setup tests the joint hypothesis.
    """
    h, idx = joint_hypothesis(identification.setup)
    f = identification.fit
    return f["theta"][:, h, idx], f["se"][:, h, idx], ~(f["p"][:, h] <= MISFIT_LEVEL)


def band_scores(theta: np.ndarray, se: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """``-log p`` of "the parameter lies in ``[low, high]``" (module docstring); 0 without an estimate.

    Parameters
    ----------
    theta, se : (..., P) arrays
        Estimates and standard errors (NaN: no estimate).
    low, high : (P,) arrays
        Band ends.
    """
    ok = np.isfinite(theta) & np.isfinite(se) & (se > 0)
    s = np.where(ok, se, 1.0)
    th = np.where(ok, theta, low)
    t = np.maximum(low - th, th - high) / s
    w = (high - low) / s
    with np.errstate(invalid="ignore"):
        logp = np.logaddexp(scipy.special.log_ndtr(-t), scipy.special.log_ndtr(-(t + w)))
    return np.where(ok, np.maximum(-logp, 0.0), 0.0)


def detection_level(false_alarms_per_hour: float, horizon_s: float, n_parameters: int) -> float:
    """``a = X T_h / (3600 P)``: the budget of ``X`` alarms per hour spent on the horizons of ``T_h``
    seconds of an hour and ``P`` parameters (capped at 0.5).

    Parameters
    ----------
    false_alarms_per_hour : float
        The budget ``X``.
    horizon_s : float
        The horizon ``T_h`` (s).
    n_parameters : int
        ``P``.
    """
    return min(0.5, float(false_alarms_per_hour) * float(horizon_s) / (3600.0 * max(1, int(n_parameters))))


def detectable_change(se: np.ndarray, level: float, power: float = DEFAULT_POWER) -> np.ndarray:
    """``(z(1 - level) + z(power)) se``: the change an estimate of standard error ``se`` detects at
    ``level`` with probability ``power`` (``inf`` without an estimate).

    Parameters
    ----------
    se : array
        Standard errors of the estimates (the parameter's unit).
    level : float
        False-alarm probability of the test (:func:`detection_level`).
    power : float
        Detection probability.
    """
    zsum = float(
        scipy.special.ndtri(1.0 - open_unit("level", level)) + scipy.special.ndtri(open_unit("power", power))
    )
    se = np.asarray(se, dtype=float)
    return np.where(np.isfinite(se) & (se > 0), zsum * np.where(np.isfinite(se), se, 0.0), np.inf)


def parameter_null_scores(
    n_parameters: int, window_hops: int, steps: int, seed: int, two_sided: Sequence[bool] | None = None
) -> np.ndarray:
    """Worst-case score streams ``(1, steps, P)`` of ``n_parameters`` parameters (module docstring).

    Parameters
    ----------
    n_parameters : int
    window_hops : int
        Hops per identification window (the overlap of consecutive windows).
    steps : int
        Hops per stream.
    seed : int
        Root seed (drawn from ``SeedSequence([seed, PARAMETER_SALT])``).
    two_sided : sequence of bool, optional
        Per parameter: a zero-width band (default all False).
    """
    P, n = positive_int("n_parameters", n_parameters), positive_int("window_hops", window_hops)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), PARAMETER_SALT]))
    eps = rng.standard_normal((steps + n - 1, P))
    c = np.concatenate([np.zeros((1, P)), np.cumsum(eps, axis=0)])
    z = (c[n:] - c[:-n]) / math.sqrt(n)
    two = np.zeros(P, bool) if two_sided is None else np.asarray(two_sided, dtype=bool)
    logp = np.where(two, np.log(2.0) + scipy.special.log_ndtr(-np.abs(z)), scipy.special.log_ndtr(-z))
    return np.maximum(-logp, 0.0)[None]


@functools.lru_cache(maxsize=32)
def _calibrate_cached(
    rule_key: str, n: int, two: tuple[bool, ...], F: float, X: float, hours: float, seed: int
) -> RuleCalibration:
    rule = rule_from_dict(json.loads(rule_key))
    steps = max(2, round(hours * F))
    scores = parameter_null_scores(len(two), n, steps, seed, two)
    return calibrate_rule(rule, scores, F, X, seed=seed)


def calibrate_parameter_rule(
    rule: AlarmRule | str,
    bands: ParameterBands,
    window_hops: int,
    windows_per_hour: float,
    false_alarms_per_hour: float,
    *,
    hours: float = CALIBRATION_HOURS,
    seed: int = 0,
) -> RuleCalibration:
    """The threshold of ``rule`` on the parameter scores for a budget of ``false_alarms_per_hour``.

    The frame rule from the law (``h = log(F P / X)``, an upper bound on the rate); persistence and
    CUSUM on ``hours`` of worst-case streams (:func:`parameter_null_scores`), counted or extrapolated
    by :func:`~chatterspec.detection.alarms.calibration.calibrate_rule`. Cached in the process.

    Parameters
    ----------
    rule : alarm rule or str
        The rule (its other parameters are kept) or a rule name (table defaults).
    bands : ParameterBands
    window_hops : int
        Hops per identification window.
    windows_per_hour : float
        Hops (windows) per hour: ``3600 / hop_s``.
    false_alarms_per_hour : float
        The budget (alarm starts per hour, every parameter together).
    hours, seed
        Worst-case stream time and seed.
    """
    X = check_budget(false_alarms_per_hour)
    F = positive("windows_per_hour", windows_per_hour)
    rule = make_rule(rule) if isinstance(rule, str) else rule
    if rule_spec(rule).per_step_law:
        return law_frame_rule(F, bands.size, X)
    key = json.dumps(rule.to_dict(), sort_keys=True)
    two = tuple(bool(x) for x in bands.two_sided)
    return _calibrate_cached(
        key, positive_int("window_hops", window_hops), two, F, X, float(hours), int(seed)
    )


def band_position(ci_low: float, ci_high: float, low: float, high: float) -> str:
    """Where an interval lies against a band: ``"inside"``, ``"outside"`` or ``"at the edge of"``; against
    a zero-width band (no tolerance) ``"at"`` or ``"off"`` (its nominal value).

    Parameters
    ----------
    ci_low, ci_high : float
        The interval's ends.
    low, high : float
        The band's ends.
    """
    if not (np.isfinite(ci_low) and np.isfinite(ci_high)):
        return "unknown against"
    if low == high:
        return "at" if ci_low <= low <= ci_high else "off"
    if low <= ci_low and ci_high <= high:
        return "inside"
    if ci_high < low or ci_low > high:
        return "outside"
    return "at the edge of"


def status_text(
    name: str,
    estimate: float,
    std_error: float,
    ci: tuple[float, float],
    nominal: float,
    unit: str,
    tolerance: str = "",
    position: str = "",
) -> str:
    """``"bulk_modulus 1.8642e8 [1.8627e8, 1.8657e8] Pa, 9.94 % below nominal, inside its +-15 %"``.

    Parameters
    ----------
    name, unit : str
    estimate, std_error, nominal : float
    ci : (float, float)
        The estimate's interval.
    tolerance : str
        The tolerance in words (empty: none declared).
    position : str
        :func:`band_position` of the interval (with a tolerance).
    """
    from .identification import format_with_error

    if not np.isfinite(estimate):
        return f"{name}: no estimate"
    u = f" {unit}" if unit else ""
    f = format_with_error
    text = f"{name} {f(estimate, std_error)} [{f(ci[0], std_error)}, {f(ci[1], std_error)}]{u}"
    if nominal != 0:
        ratio = estimate / nominal
        rel = 100.0 * (estimate - nominal) / abs(nominal)
        if abs(rel) < 1000:
            text += f", {abs(rel):.3g} % {'above' if rel >= 0 else 'below'} nominal"
        else:
            text += f", {ratio:.3g} times nominal"
    if tolerance:
        text += f", {position} its {tolerance}"
    elif position in ("at", "off"):
        text += f", {position} its nominal (no tolerance)"
    return text
