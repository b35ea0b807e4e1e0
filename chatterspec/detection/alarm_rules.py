"""The alarm rules (:class:`FrameRule`, :class:`PersistenceRule`, :class:`CusumRule`) and their table
:data:`RULES`, which the CLI choices and the plot styles read.

What each rule does with a score stream is in :mod:`chatterspec.detection.alarms` (the streaming
state machine and its compiled kernel), which re-exports every name here. Adding a rule is its class
here, its entry in :data:`RULES` and its step in the kernel.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, ClassVar, Literal

from ..errors import ParameterError
from ..jsonout import finite_or_none

__all__ = [
    "RULES",
    "AlarmRule",
    "CusumRule",
    "FrameRule",
    "PersistenceRule",
    "RuleName",
    "RuleSpec",
    "alarm_label",
    "make_rule",
    "rule_from_dict",
    "rule_names",
]

RuleName = Literal["frame", "persistence", "cusum"]

# rule codes of the kernel
_FRAME, _PERSISTENCE, _CUSUM = 0, 1, 2


def _threshold(value: float, name: str = "threshold") -> float:
    """A rule threshold: a real number, not NaN (``+inf`` = never alarm, ``-inf`` = always)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} must be a real number; got {value!r}") from None
    if math.isnan(v):
        raise ParameterError(f"{name} must not be NaN")
    return v


@dataclass(frozen=True)
class FrameRule:
    """Single-step rule: alarm while the score is at or above ``threshold``.

    Parameters
    ----------
    threshold : float
        ``h``: a step exceeds when ``s >= h``. With the chattering frame score
        (``-log p``), ``h = -log(alpha)`` is the per-frame rule at level ``alpha``.

    See Also
    --------
    PersistenceRule : k of the last n steps.
    CusumRule : accumulated excess over a drift.
    """

    threshold: float = float("inf")
    name: ClassVar[str] = "frame"

    def __post_init__(self) -> None:
        object.__setattr__(self, "threshold", _threshold(self.threshold))

    def with_threshold(self, threshold: float) -> FrameRule:
        """The same rule at another threshold."""
        return replace(self, threshold=threshold)

    def parameters(self) -> dict[str, Any]:
        """The rule's parameters other than the threshold (none)."""
        return {}

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {"rule": self.name, "threshold": finite_or_none(self.threshold), **self.parameters()}

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"frame rule: alarm while the score is >= {self.threshold:.4g}"


@dataclass(frozen=True)
class PersistenceRule:
    """k-of-n rule: alarm when at least ``k`` of the last ``n`` steps exceed ``threshold``.

    Parameters
    ----------
    threshold : float
        ``h``: a step exceeds when ``s >= h``.
    k, n : int
        ``1 <= k <= n``. The alarm starts at the step where the window of the last ``n`` steps
        (this one included) holds ``k`` exceedances, and ends at the first step whose window
        holds none (``n`` clean steps in a row).

    See Also
    --------
    FrameRule : one step at a time.
    CusumRule : accumulated excess over a drift.
    """

    threshold: float = float("inf")
    k: int = 3
    n: int = 5
    name: ClassVar[str] = "persistence"

    def __post_init__(self) -> None:
        from .._validate import positive_int  # numpy: not when the CLI only builds its parser

        object.__setattr__(self, "threshold", _threshold(self.threshold))
        k = positive_int("persistence k", self.k)
        n = positive_int("persistence n", self.n)
        if k > n:
            raise ParameterError(f"persistence k must be <= n (k of the last n steps); got k = {k}, n = {n}")
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "n", n)

    def with_threshold(self, threshold: float) -> PersistenceRule:
        """The same rule with another threshold."""
        return replace(self, threshold=threshold)

    def parameters(self) -> dict[str, Any]:
        """The rule's parameters besides its threshold (name -> value)."""
        return {"k": self.k, "n": self.n}

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {"rule": self.name, "threshold": finite_or_none(self.threshold), **self.parameters()}

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return (
            f"persistence rule: alarm when {self.k} of the last {self.n} steps have a score >= "
            f"{self.threshold:.4g}; ends after {self.n} clean steps"
        )


@dataclass(frozen=True)
class CusumRule:
    """Page's CUSUM with renewal: ``g = max(0, g + s - drift)``, alarm when ``g >= threshold``.

    Parameters
    ----------
    threshold : float
        ``h`` (> 0 for a useful rule): the alarm starts at the first step with ``g >= h``.
    drift : float
        Subtracted from every score (finite). It must exceed the healthy mean score so that
        ``g`` drifts back to 0 on healthy data (the frame score ``-log p`` has a healthy mean
        below 1); default 3.

    See Also
    --------
    FrameRule : one step at a time.
    PersistenceRule : k of the last n steps.

    Notes
    -----
    While active, ``g`` is capped at ``h`` and the alarm ends when ``g`` is back at 0 (see
    the module docstring); then ``g = 0`` and the next run starts afresh (renewal).
    """

    threshold: float = float("inf")
    drift: float = 3.0
    name: ClassVar[str] = "cusum"

    def __post_init__(self) -> None:
        object.__setattr__(self, "threshold", _threshold(self.threshold))
        d = _threshold(self.drift, "cusum drift")
        if not math.isfinite(d):
            raise ParameterError(f"cusum drift must be finite; got {d!r}")
        object.__setattr__(self, "drift", d)

    def with_threshold(self, threshold: float) -> CusumRule:
        """The same rule with another threshold."""
        return replace(self, threshold=threshold)

    def parameters(self) -> dict[str, Any]:
        """The rule's parameters besides its threshold (name -> value)."""
        return {"drift": self.drift}

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {"rule": self.name, "threshold": finite_or_none(self.threshold), **self.parameters()}

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return (
            f"CUSUM rule: g = max(0, g + score - {self.drift:g}), alarm when g >= {self.threshold:.4g} "
            "(g capped there while active), ends when g is back at 0"
        )


AlarmRule = FrameRule | PersistenceRule | CusumRule


@dataclass(frozen=True)
class RuleSpec:
    """One entry of the rules table :data:`RULES`.

    Attributes
    ----------
    name : str
        The rule's name (CLI ``--rule`` value).
    cls : type
        Its class; ``cls(threshold=h, **parameters)`` builds it.
    summary : str
        One line for ``--help`` and the docs.
    parameters : dict
        Parameter name -> default (besides the threshold).
    statistic : str
        What :attr:`AlarmBlock.statistic` holds for this rule (axis label of a plot).
    style : dict
        Matplotlib / viewer style of the rule's curves: ``color`` (hex), ``marker``, ``linestyle``.
    """

    name: str
    cls: type
    summary: str
    parameters: Mapping[str, Any] = field(default_factory=dict)
    statistic: str = "score"
    style: Mapping[str, str] = field(default_factory=dict)


#: The rules table: adding a rule is one entry here (plus its class and its branch of the kernel).
RULES: Mapping[str, RuleSpec] = MappingProxyType(
    {
        "frame": RuleSpec(
            "frame",
            FrameRule,
            "alarm while the step's score is >= h (per-frame rule)",
            {},
            "score",
            {"color": "#1f77b4", "marker": "o", "linestyle": "-"},
        ),
        "persistence": RuleSpec(
            "persistence",
            PersistenceRule,
            "alarm when k of the last n steps have a score >= h; ends after n clean steps",
            {"k": 3, "n": 5},
            "exceedances in the last n steps",
            {"color": "#ff7f0e", "marker": "s", "linestyle": "--"},
        ),
        "cusum": RuleSpec(
            "cusum",
            CusumRule,
            "CUSUM g = max(0, g + score - drift), alarm when g >= h; ends when g is back at 0",
            {"drift": 3.0},
            "CUSUM g",
            {"color": "#2ca02c", "marker": "^", "linestyle": "-."},
        ),
    }
)


def alarm_label(rule: str, false_alarms_per_hour: float | None) -> str:
    """``"cusum rule, 1 false alarm per 24 h"``: the rule and its budget in words.

    Parameters
    ----------
    rule : str
        The rule's name.
    false_alarms_per_hour : float or None
        Its budget (alarm starts per hour); None: a per-frame alpha.
    """
    if false_alarms_per_hour is None:
        return f"{rule} rule, per-frame alpha"
    x = float(false_alarms_per_hour)
    per = f"1 false alarm per {1 / x:.3g} h" if x < 1 else f"{x:.3g} false alarms per hour"
    return f"{rule} rule, {per}"


def rule_names() -> tuple[str, ...]:
    """Names of the rules, in table order (the CLI's ``--rule`` choices)."""
    return tuple(RULES)


def make_rule(name: str, threshold: float = float("inf"), **parameters: float) -> AlarmRule:
    """Build a rule by name: ``make_rule("cusum", 12.0, drift=3.0)``.

    Parameters
    ----------
    name : {"frame", "persistence", "cusum"}
        A key of :data:`RULES`.
    threshold : float
        The rule's threshold ``h`` (default ``inf``: calibrate it, e.g. with
        :func:`chatterspec.detection.alarm_calibration.calibrate_rule`).
    **parameters
        The rule's other parameters (``k``, ``n``; ``drift``); missing ones take the table's defaults.

    Raises
    ------
    ParameterError
        Unknown rule name (the message lists the valid ones), unknown parameter or bad value.
    """
    spec = RULES.get(name)
    if spec is None:
        raise ParameterError(f"unknown alarm rule {name!r}; choose one of {', '.join(RULES)}")
    unknown = set(parameters) - set(spec.parameters)
    if unknown:
        allowed = ", ".join(spec.parameters) or "none"
        raise ParameterError(
            f"rule {name!r} has no parameter(s) {', '.join(sorted(unknown))} (parameters: {allowed})"
        )
    return spec.cls(threshold=threshold, **{**spec.parameters, **parameters})


def rule_from_dict(d: Mapping[str, Any]) -> AlarmRule:
    """Inverse of ``rule.to_dict()`` (``threshold`` ``None`` reads as ``inf``).

    Parameters
    ----------
    d : mapping
        ``{"rule": name, "threshold": h or None, **parameters}``.
    """
    d = dict(d)
    name = d.pop("rule", None)
    if not isinstance(name, str):
        raise ParameterError(f"an alarm rule needs a 'rule' name; got {name!r}")
    th = d.pop("threshold", None)
    return make_rule(name, float("inf") if th is None else float(th), **d)
