"""Decisions on the identified parameters: tolerance bands, alarms at a budget, detectability.

The chattering detects *any* model mismatch, including a parameter's normal operating variation
(the bulk modulus 10 % low on a warm day). When the model declares operating tolerances
(:mod:`chatterspec.plants.parameters`), the fault decision is taken on the identified parameters
instead (goes beyond the papers):

**Estimate.** Per STFT hop, the identification window ending there (the STFT window, 1 s by
default; :class:`~chatterspec.detection.identification.OnlineIdentifier`) is fitted with
every declared parameter free at once (the joint hypothesis of
:meth:`~chatterspec.plants.parameters.ParameterMap.combinations`): its estimate and standard error
``sigma`` are valid whichever parameters moved.

**Windows the parameters do not describe.** A window that straddles a change of the plant mixes two
regressions, which no constant parameter set reproduces: its joint fit is rejected by its own
minimum-distance test (a bulk modulus dropping 25 % gives ``p < 1e-300`` in the windows across the
change) and the other parameters' estimates absorb the misfit (the leakage reads 2.4 to 5.3 times its
nominal value there). A window whose joint fit is rejected at :data:`MISFIT_LEVEL` gives no evidence
(score 0, no information for the detectability); its estimates are reported with ``fits`` false. So
a change is decided on the first windows entirely after it (about one window after the onset).

**Score and alarm.** Each parameter's joint estimate scores ``-log p`` of "inside its band", 0 without
an estimate (*Scores* below); one score channel per parameter goes
through the monitor's alarm rule (frame, persistence or CUSUM), whose threshold is set for the run's
budget in false alarms per hour on worst-case streams (every parameter on a band edge;
:func:`~chatterspec.detection.parameter_decision.calibrate_parameter_rule`).

**Spectral and parameter alarms.** With tolerances the chattering's spectrum sees every in-tolerance
mismatch (a bulk modulus 3 % low gives a frame ratio of 13 on the pressure channel), so a spectral
alarm cannot tell normal variation from a fault: the decision comes from the parameters alone and
the whole budget goes to them. The spectral detector still runs and is reported as *mismatch*
(its frames, verdicts and events), not as a fault. What this gives up: a change the declared
parameters cannot express (a sensor fault, an undeclared parameter) raises no alarm; declare the
parameter, or monitor without tolerances on a commissioned model.

**Detectability.** Per hop and parameter, the smallest change beyond the band that the data of
the last :data:`DETECTABILITY_HORIZON_S` seconds detect at the run's budget::

    delta = (z(1 - a) + z(power)) sigma_h,     a = X T_h / (3600 P),    power = 0.95

``sigma_h`` is the standard error of an estimate from those ``T_h`` seconds: the identification
sums are additive over hops, so its information is the windows' information ``1 / sigma_j^2``
summed over the horizon and divided by the hops per window (each hop lies in that many windows;
per parameter, which neglects the change of the parameters' correlation over the horizon), and
``a`` spends the budget of ``X`` alarms per hour on the ``3600 / T_h`` horizons of an hour and the
``P`` parameters. The horizon smooths the excitation of a repeated input (the catalogue chirp
carries most of the leakage information in its low-frequency half) and is short enough to say
within seconds that a held actuator has become blind. When ``delta`` exceeds the tolerance (the
smaller of its two sides; for a parameter without one, :data:`NOT_EXCITED_MULTIPLE` times its
nominal value) the parameter is **not excited**: the monitor could miss a change of the size the
tolerance allows, and says so instead of "healthy" (a held actuator carries no information on
its leakage), until the excitation returns.

Scores
------
Scores of the identified parameters against their tolerance bands, their worst-case law and the
alarm rule's threshold for a budget, and the detectable change.

The pieces of the decision that do not depend on time: what a window's joint estimate says about
each parameter.

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

Whole records
-------------
Decisions on the identified parameters over whole records, every record at once.

:func:`monitor_parameters` is what ``chatterspec monitor`` decides per hop with tolerances
(above), on many records together (vectorized over records
and hops): for studies of false alarms and detection delays, and for benches that monitor a model
with tolerances. :func:`record_decisions` decides once per record on its whole-record identification
(``chatterspec detect``).
"""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.special

from .._validate import open_unit, positive, positive_int
from ..errors import IdentifiabilityError
from ..jsonout import finite_or_none
from .alarms.calibration import RuleCalibration, calibrate_rule, check_budget, law_frame_rule
from .alarms.rules import AlarmRule, make_rule, rule_from_dict, rule_spec
from .alarms.streams import AlarmStream
from .identification import IdentificationSetup

__all__ = [
    "CALIBRATION_HOURS",
    "DEFAULT_POWER",
    "DETECTABILITY_HORIZON_S",
    "MISFIT_LEVEL",
    "NOT_EXCITED_MULTIPLE",
    "STATES",
    "ParameterAlarmSettings",
    "ParameterBands",
    "ParameterDecision",
    "ParameterDecisions",
    "ParameterEvent",
    "band_position",
    "band_scores",
    "calibrate_parameter_rule",
    "decide",
    "detectable_change",
    "detection_level",
    "joint_estimates",
    "joint_hypothesis",
    "monitor_parameters",
    "parameter_alarm_settings",
    "parameter_null_scores",
    "record_decisions",
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
    """The tolerance bands of a model's declared parameters, in table order (parameter units; not the
    tested frequency band of the spectral detector, :data:`~chatterspec.detection.thresholds.Band`).

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


#: The three states of a parameter (and of a channel): index = the code in ``ParameterDecisions.state``.
STATES = ("healthy", "fault", "not-excited")
#: Seconds of data the detectable change is computed from (see the module docstring).
DETECTABILITY_HORIZON_S = 5.0


@dataclass(frozen=True, eq=False)
class ParameterAlarmSettings:
    """How the identified parameters are decided (see the module docstring).

    Attributes
    ----------
    bands : ParameterBands
    calibration : RuleCalibration or None
        The alarm rule with its threshold for the budget; None: no parameter alarms (no tolerance
        declared: only the estimates, detectability and excitation are reported).
    window_hops : int
        Hops per identification window.
    hop_s : float
        Hop (s).
    false_alarms_per_hour : float
        The run's budget (sets the detectability's level even without parameter alarms).
    horizon_hops : int
        Hops of data the detectable change is computed from.
    power : float
        Detection probability of the detectable change.
    """

    bands: ParameterBands
    calibration: RuleCalibration | None
    window_hops: int
    hop_s: float
    false_alarms_per_hour: float
    horizon_hops: int
    power: float = DEFAULT_POWER

    def __post_init__(self) -> None:
        object.__setattr__(self, "false_alarms_per_hour", check_budget(self.false_alarms_per_hour))

    @property
    def alarms(self) -> bool:
        """Whether the parameters raise alarms (tolerances declared)."""
        return self.calibration is not None

    @property
    def windows_per_hour(self) -> float:
        """Identification windows (hops) per hour."""
        return 3600.0 / self.hop_s

    @property
    def level(self) -> float:
        """Level of the detectable change: the budget's share of one horizon and parameter."""
        return detection_level(self.false_alarms_per_hour, self.horizon_hops * self.hop_s, self.bands.size)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the bands, the rule and its budget, the detectability's level and power."""
        b = self.bands
        return {
            "decision": "parameters (tolerances)" if self.alarms else "spectral (no tolerance declared)",
            "parameters": [
                {
                    "parameter": n,
                    "unit": u,
                    "nominal": float(b.nominal[i]),
                    "tolerance": b.tolerances[i] or None,
                    "band": [float(b.low[i]), float(b.high[i])],
                    "not_excited_above": finite_or_none(float(b.limit[i])),
                }
                for i, (n, u) in enumerate(zip(b.names, b.units, strict=True))
            ],
            "alarm": None if self.calibration is None else self.calibration.to_dict(),
            "window_s": self.window_hops * self.hop_s,
            "detectable": {
                "horizon_s": self.horizon_hops * self.hop_s,
                "level": self.level,
                "power": self.power,
            },
        }


def parameter_alarm_settings(
    setup: IdentificationSetup,
    *,
    hop_s: float,
    window_hops: int,
    rule: AlarmRule | str = "cusum",
    false_alarms_per_hour: float = 1.0 / 24.0,
    power: float = DEFAULT_POWER,
    not_excited_multiple: float = NOT_EXCITED_MULTIPLE,
    horizon_s: float = DETECTABILITY_HORIZON_S,
    seed: int = 0,
) -> ParameterAlarmSettings:
    """Settings of the parameter decision of ``setup``'s model: alarms when tolerances are declared.

    Parameters
    ----------
    setup : IdentificationSetup
        Must test the joint hypothesis (:func:`joint_hypothesis`); the default setup does.
    hop_s : float
        The STFT hop (s): one decision per hop.
    window_hops : int
        Hops per identification window (the STFT window's: 5 at 1 s / 0.2 s).
    rule : alarm rule or str
        The monitor's rule (its threshold is set here for the budget).
    false_alarms_per_hour : float
        The run's budget (default one per day), every parameter together.
    power : float
        Detection probability of the reported detectable change.
    not_excited_multiple : float
        See :data:`NOT_EXCITED_MULTIPLE`.
    horizon_s : float
        Seconds of data the detectable change is computed from (at least one window).
    seed : int
        Seed of the calibration streams.

    Raises
    ------
    IdentifiabilityError
        The setup cannot fit every parameter at once.
    """
    joint_hypothesis(setup)
    bands = ParameterBands.from_map(setup.parameter_map, not_excited_multiple)
    hop_s = positive("hop_s", hop_s, unit="s")
    window_hops = positive_int("window_hops", window_hops)
    cal = None  # (the budget: checked by calibrate_parameter_rule and by ParameterAlarmSettings)
    if setup.parameter_map.has_tolerances:
        cal = calibrate_parameter_rule(
            rule, bands, window_hops, 3600.0 / hop_s, false_alarms_per_hour, seed=seed
        )
    horizon = max(window_hops, round(positive("horizon_s", horizon_s, unit="s") / hop_s))
    power = open_unit("power", power)
    return ParameterAlarmSettings(bands, cal, window_hops, hop_s, false_alarms_per_hour, horizon, power)


@dataclass(frozen=True)
class ParameterEvent:
    """A parameter's alarm starting or ending (tolerances declared).

    Attributes
    ----------
    kind : {"fault-start", "fault-end"}
    parameter : str
    index : int
        The parameter's position in the table.
    time_s : float
        Centre time of the identification window where the alarm changed (s).
    alarm_time_s : float
        When the alarm changed: the last sample of that window (s), where the fault state of the
        channels carrying the parameter changes (:mod:`chatterspec.online.fault_state`).
    frame : int
        Hop (window) number: the monitor's frame number.
    estimate, std_error, ci_low, ci_high : float
        That window's joint estimate (the plant's value), its standard error and interval.
    nominal : float
    unit, tolerance : str
    band : (float, float)
    score, statistic, threshold : float
        The window's score ``-log p``, the rule's statistic and threshold.
    rule : str
    false_alarms_per_hour : float
    detectable : float
        The window's detectable change (the parameter's unit).
    """

    kind: str
    parameter: str
    index: int
    time_s: float
    alarm_time_s: float
    frame: int
    estimate: float
    std_error: float
    ci_low: float
    ci_high: float
    nominal: float
    unit: str
    tolerance: str
    band: tuple[float, float]
    score: float
    statistic: float
    threshold: float
    rule: str
    false_alarms_per_hour: float
    detectable: float

    def describe(self) -> str:
        """``"fault start on bulk_modulus: alarm raised at t = 3.10 s (end of the deciding window):
        bulk_modulus 1.55e8 Pa, 25 % below nominal, outside its +-15 % [cusum rule, 1 false alarm per
        24 h]"``."""
        from .alarms.rules import alarm_label

        what = "fault start" if self.kind == "fault-start" else "fault end"
        pos = band_position(self.ci_low, self.ci_high, *self.band)
        st = status_text(self.parameter, self.estimate, self.std_error, (self.ci_low, self.ci_high),
                         self.nominal, self.unit, self.tolerance, pos)  # fmt: skip
        label = alarm_label(self.rule, self.false_alarms_per_hour)
        raised = "raised" if self.kind == "fault-start" else "cleared"
        return (
            f"{what} on {self.parameter}: alarm {raised} at t = {self.alarm_time_s:.2f} s (end of the "
            f"deciding window): {st} [{label}]"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (``channel`` is the parameter: the decision's channel; non-finite numbers None)."""
        return {
            "kind": self.kind,
            "channel": self.parameter,
            "parameter": self.parameter,
            "time_s": self.time_s,
            "alarm_time_s": self.alarm_time_s,
            "frame": self.frame,
            "estimate": finite_or_none(self.estimate),
            "std_error": finite_or_none(self.std_error),
            "ci_low": finite_or_none(self.ci_low),
            "ci_high": finite_or_none(self.ci_high),
            "nominal": self.nominal,
            "unit": self.unit,
            "tolerance": self.tolerance or None,
            "band": list(self.band),
            "score": finite_or_none(self.score),
            "statistic": finite_or_none(self.statistic),
            "threshold": finite_or_none(self.threshold),
            "rule": self.rule,
            "false_alarms_per_hour": self.false_alarms_per_hour,
            "detectable": finite_or_none(self.detectable),
        }


@dataclass(frozen=True, eq=False)
class ParameterDecisions:
    """Decisions on the identified parameters, one per window: arrays ``(..., W, P)`` (parameters in table
    order; no leading axis for the windows of one push, ``(runs,)`` for whole records).

    Attributes
    ----------
    times_s : (W,) array
        Window centre times (s).
    frames : (W,) int array
        Window (hop) numbers: the monitor's frame numbers.
    estimate, std_error, ci_low, ci_high : (..., W, P) arrays
        The joint estimate (the plant's value) and its interval, NaN without one.
    fits : (..., W) bool array
        The joint fit is not rejected (False: the window gives no evidence, e.g. it straddles a change).
    score : (..., W, P) array
        ``-log p`` of "inside its band" (0: no evidence).
    alarm : (..., W, P) bool array
        The parameter's alarm after each window (all False without tolerances).
    statistic : (..., W, P) array
        The rule's statistic (NaN without tolerances).
    detectable : (..., W, P) array
        The detectable change (``inf`` without an estimate).
    excited : (..., W, P) bool array
        ``detectable <= bands.limit``.
    state : (..., W, P) int array
        Index into :data:`STATES`: fault (alarm), else not excited, else healthy.
    events : tuple of ParameterEvent
        The alarm starts and ends of one push (online decisions; empty for whole records).
    settings : ParameterAlarmSettings or None
        The settings of whole records.
    """

    times_s: np.ndarray
    frames: np.ndarray
    estimate: np.ndarray
    std_error: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    fits: np.ndarray
    score: np.ndarray
    alarm: np.ndarray
    statistic: np.ndarray
    detectable: np.ndarray
    excited: np.ndarray
    state: np.ndarray
    events: tuple[ParameterEvent, ...] = field(default=())
    settings: ParameterAlarmSettings | None = None

    @classmethod
    def from_block(
        cls,
        times_s: np.ndarray,
        frames: np.ndarray,
        block: Sequence[np.ndarray],
        *,
        events: tuple[ParameterEvent, ...] = (),
        settings: ParameterAlarmSettings | None = None,
    ) -> ParameterDecisions:
        """The decisions from :func:`decide`'s arrays ``block`` (estimate ... state, in field order)."""
        est, se, lo, hi, fits, score, alarm, stat, det, exc, state = block
        return cls(
            times_s, frames, est, se, lo, hi, fits, score, alarm, stat, det, exc, state, events, settings
        )

    @property
    def n_windows(self) -> int:
        """Number of windows."""
        return int(self.frames.size)

    @property
    def starts(self) -> np.ndarray:
        """``(..., W, P)`` bool: windows where a parameter's alarm starts (from no alarm before the first)."""
        prev = np.concatenate([np.zeros_like(self.alarm[..., :1, :]), self.alarm[..., :-1, :]], axis=-2)
        return self.alarm & ~prev

    def first_start(self, after_s: float = -np.inf) -> np.ndarray:
        """``(...)``: time (s) of the first alarm start (any parameter) from ``after_s`` on; NaN: none."""
        s = self.starts.any(axis=-1) & (self.times_s >= after_s)
        first = np.argmax(s, axis=-1)
        return np.where(s.any(axis=-1), self.times_s[first], np.nan)


class ParameterDecision:
    """Per-hop decisions on the identified parameters, fed with the online identification's windows.

    Parameters
    ----------
    setup : IdentificationSetup
        The identification's setup (testing the joint hypothesis).
    settings : ParameterAlarmSettings
    """

    def __init__(self, setup: IdentificationSetup, settings: ParameterAlarmSettings) -> None:
        joint_hypothesis(setup)
        self.setup, self.settings = setup, settings
        self.bands = settings.bands
        cal = settings.calibration
        self._stream = None if cal is None else AlarmStream(cal.rule, (self.bands.size,))
        self._horizon = _Horizon(settings.horizon_hops)
        self._last = np.zeros((1, self.bands.size), dtype=bool)  # alarm state after the last window

    def reset(self) -> None:
        """A gap or restart: the alarm state starts over (no alarm)."""
        if self._stream is not None:
            self._stream.reset()
        self._horizon.reset()
        self._last[:] = False

    @property
    def active(self) -> np.ndarray:
        """``(P,)``: whether each parameter's alarm is active."""
        if self._stream is None:
            return np.zeros(self.bands.size, dtype=bool)
        return self._stream.active

    def update(self, found: Any) -> ParameterDecisions:
        """Decide on the windows of one push (:class:`~chatterspec.detection.identification.
        OnlineIdentification`)."""
        P = self.bands.size
        W = found.n_windows
        if W == 0 or found.result is None:
            e = np.zeros((0, P))
            return ParameterDecisions(np.zeros(0), np.zeros(0, int), e, e, e, e, np.zeros(0, bool), e,
                                      e.astype(bool), e, e, e.astype(bool), e.astype(int))  # fmt: skip
        theta, se, fits = joint_estimates(found.result)
        block = decide(theta, se, fits, self.settings, found.result.confidence, self._stream, self._horizon)
        events = self._events(block, found)
        return ParameterDecisions.from_block(
            np.asarray(found.times_s), np.asarray(found.frames), block, events=events
        )

    def _events(self, block: tuple[np.ndarray, ...], found: Any) -> tuple[ParameterEvent, ...]:
        if self._stream is None:
            return ()
        theta, se, lo, hi, _, score, alarm, stat, det, _, _ = block
        prev = np.concatenate([self._last, alarm[:-1]])
        self._last = alarm[-1:].copy()
        cal, b = self.settings.calibration, self.bands
        assert cal is not None
        out = []
        for j, i in zip(*np.nonzero(alarm != prev), strict=True):
            out.append(
                ParameterEvent(
                    kind="fault-start" if alarm[j, i] else "fault-end",
                    parameter=b.names[i],
                    index=int(i),
                    time_s=float(found.times_s[j]),
                    alarm_time_s=float(found.window_s[j, 1]) - self.setup.model.dt,
                    frame=int(found.frames[j]),
                    estimate=float(theta[j, i]),
                    std_error=float(se[j, i]),
                    ci_low=float(lo[j, i]),
                    ci_high=float(hi[j, i]),
                    nominal=float(b.nominal[i]),
                    unit=b.units[i],
                    tolerance=b.tolerances[i],
                    band=(float(b.low[i]), float(b.high[i])),
                    score=float(score[j, i]),
                    statistic=float(stat[j, i]),
                    threshold=float(cal.threshold),
                    rule=cal.rule.name,
                    false_alarms_per_hour=cal.false_alarms_per_hour,
                    detectable=float(det[j, i]),
                )
            )
        return tuple(out)


class _Horizon:
    """The information ``1 / sigma^2`` of the last ``K`` windows, summed per stream and parameter
    (continues across calls; arrays ``(..., W, P)``).

    Each window's sum adds its ``K`` terms oldest first, so its bits do not depend on how the stream
    was cut into calls (a running sum, with a subtraction, would carry the rounding of the call's
    first windows).
    """

    def __init__(self, K: int) -> None:
        self.K = K
        self._tail: np.ndarray | None = None

    def reset(self) -> None:
        self._tail = None

    def sums(self, info: np.ndarray) -> np.ndarray:
        x = info if self._tail is None else np.concatenate([self._tail, info], axis=-2)
        n, w = x.shape[-2], info.shape[-2]
        out = np.zeros(info.shape)
        for k in range(self.K - 1, -1, -1):  # the term k windows back, oldest first
            j0 = max(0, k - (n - w))  # the first new window that has it (x starts at the stream's start)
            if j0 < w:
                out[..., j0:, :] += x[..., n - w + j0 - k : n - k, :]
        self._tail = x[..., max(0, n - (self.K - 1)) :, :].copy() if self.K > 1 else x[..., :0, :]
        return out


def decide(
    theta: np.ndarray,
    se: np.ndarray,
    fits: np.ndarray,
    settings: ParameterAlarmSettings,
    confidence: float,
    stream: AlarmStream | None,
    horizon: _Horizon,
) -> tuple[np.ndarray, ...]:
    """Scores, alarms, detectability and states of joint estimates ``theta``, ``se`` ``(..., W, P)``.

    ``fits`` ``(..., W)``: windows whose joint fit is not rejected (the others give no evidence).
    ``settings`` give the bands, the detectability's level and power; ``confidence`` the intervals'
    level. ``stream`` (shape ``(..., P)``; None: no alarms) and ``horizon`` carry the alarm state and
    the horizon's information across calls. Returns ``(theta, se, ci_low, ci_high, fits, score, alarm,
    statistic, detectable, excited, state)``.
    """
    b = settings.bands
    zq = float(scipy.special.ndtri(0.5 + confidence / 2))
    used = np.where(fits[..., None], se, np.nan)  # a window the parameters do not describe: no evidence
    score = band_scores(theta, used, b.low, b.high)
    if stream is not None:
        blk = stream.update(score)
        alarm, stat = blk.active, blk.statistic
    else:
        alarm, stat = np.zeros(score.shape, bool), np.full(score.shape, np.nan)
    ok = np.isfinite(used) & (used > 0)
    info = horizon.sums(np.where(ok, 1.0 / np.where(ok, used, 1.0) ** 2, 0.0)) / settings.window_hops
    se_h = np.where(info > 0, 1.0 / np.sqrt(np.where(info > 0, info, 1.0)), np.nan)
    det = detectable_change(se_h, settings.level, settings.power)
    excited = det <= b.limit
    state = np.where(alarm, 1, np.where(excited, 0, 2))
    return theta, se, theta - zq * se, theta + zq * se, fits, score, alarm, stat, det, excited, state


def monitor_parameters(
    model: Any,
    z: np.ndarray,
    u: np.ndarray,
    settings: ParameterAlarmSettings | None = None,
    *,
    hop_s: float = 0.2,
    window_s: float = 1.0,
    rule: AlarmRule | str = "cusum",
    false_alarms_per_hour: float = 1.0 / 24.0,
    t0: float = 0.0,
    confidence: float = 0.95,
    chunk_runs: int = 64,
) -> ParameterDecisions:
    """The monitor's decisions on the identified parameters over whole records, every record at once.

    What ``chatterspec monitor`` decides per hop with tolerances (the module docstring), on many
    records together (vectorized over records and hops; each record starts from no alarm): for
    studies of the false alarms and detection delays of a model with tolerances.

    Parameters
    ----------
    model : LinearModel
        Nominal model with a parameter map (tolerances in its parameters: alarms; none: only the
        estimates, detectability and excitation).
    z : (runs, T, m) or (T, m) array
        Measurements (finite).
    u : (T, p), (runs, T, p) or (T,) array
        Inputs.
    settings : ParameterAlarmSettings, optional
        Default :func:`parameter_alarm_settings` with ``hop_s``, ``window_s``, ``rule`` and
        ``false_alarms_per_hour``.
    hop_s, window_s : float
        Hop and identification window (s), multiples of ``model.dt`` (the monitor's STFT hop and
        window; ignored with ``settings``, which fixes them).
    rule : alarm rule or str
    false_alarms_per_hour : float
    t0 : float
        Time (s) of ``z[:, 0]``.
    confidence : float
        Level of the intervals.
    chunk_runs : int
        Records per vectorized block (bounds the memory; the numbers do not depend on it).

    Returns
    -------
    ParameterDecisions
    """
    from .._validate import finite_array
    from .identification import hop_windows, identification_setup, identify_moments

    full = identification_setup(model, [list(model.parameter_map.parameter_names)])  # the joint fit only
    if settings is None:
        H = max(1, round(positive("hop_s", hop_s, unit="s") / model.dt))
        n = max(1, round(positive("window_s", window_s, unit="s") / (H * model.dt)))
        settings = parameter_alarm_settings(
            full, hop_s=H * model.dt, window_hops=n, rule=rule, false_alarms_per_hour=false_alarms_per_hour
        )
    H = max(1, round(settings.hop_s / model.dt))
    z = finite_array("z", z, ndim=(2, 3))
    z = z[None] if z.ndim == 2 else z
    u = finite_array("u", u, ndim=(1, 2, 3))
    u = u[:, None] if u.ndim == 1 else u
    confidence = open_unit("confidence", confidence)
    runs = z.shape[0]
    cal = settings.calibration
    parts: list[tuple[np.ndarray, ...]] = []
    times = np.zeros(0)
    for lo in range(0, runs, positive_int("chunk_runs", chunk_runs)):
        hi = min(runs, lo + chunk_runs)
        uc = u if u.ndim == 2 else u[lo:hi]
        _, times, mom = hop_windows(
            full, z[lo:hi], uc, hop_samples=H, window_hops=settings.window_hops, t0=t0
        )
        res = identify_moments(full, mom, confidence=confidence)
        theta, se, fits = joint_estimates(res)
        W = times.size
        theta, se, fits = theta.reshape(hi - lo, W, -1), se.reshape(hi - lo, W, -1), fits.reshape(hi - lo, W)
        stream = None if cal is None else AlarmStream(cal.rule, (hi - lo, settings.bands.size))
        parts.append(decide(theta, se, fits, settings, confidence, stream, _Horizon(settings.horizon_hops)))
    arrays = [np.concatenate([p[k] for p in parts]) for k in range(11)]
    frames = np.arange(times.size)
    return ParameterDecisions.from_block(times, frames, arrays, settings=settings)


def record_decisions(identification: Any, alpha: float) -> dict[str, np.ndarray]:
    """Whole-record decisions on the identified parameters, one per realization.

    Each parameter's joint estimate is tested against its band (the p-value of :func:`band_scores`)
    at ``alpha / P`` (Bonferroni over the ``P`` parameters: a healthy record, every parameter inside
    its band, is declared faulty with probability at most ``alpha``, the detector's per-record level).

    Parameters
    ----------
    identification : Identification
        Whole-record identification (the default setup: it tests the joint hypothesis).
    alpha : float
        Per-record level.

    Returns
    -------
    dict
        ``estimate``, ``std_error``, ``p_value`` and ``outside`` (bool), arrays ``(runs, P)`` in table
        order, and ``fits`` ``(runs,)``: False where the record is not described by constant parameters
        (a change within it: no decision, ``p_value`` NaN).
    """
    setup = identification.setup
    theta, se, fits = joint_estimates(identification)
    bands = ParameterBands.from_map(setup.parameter_map)
    ok = np.isfinite(se) & fits[:, None]
    p = np.where(ok, np.exp(-band_scores(theta, se, bands.low, bands.high)), np.nan)
    a = open_unit("alpha", alpha) / bands.size
    return {"estimate": theta, "std_error": se, "p_value": p, "outside": ok & (p <= a), "fits": fits}
