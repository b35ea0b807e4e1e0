"""The alarm rules (:class:`FrameRule`, :class:`PersistenceRule`, :class:`CusumRule`) and their table
:data:`RULES`: the one place that knows a rule by its name.

Everything that differs between rules is read from a rule's :class:`RuleSpec` or its class: the CLI
options of its parameters (``--persistence-k``, ``--cusum-drift``: ``--{rule}-{parameter}``), what
its statistic is called in plots and recordings, whether its threshold applies to each step's score
or to an accumulated statistic, whether the per-step law gives its threshold, and its state machine
(:class:`~chatterspec.detection.alarms.steps.RuleSteps`: a compiled loop and its numpy form,
loaded lazily so that building the CLI parser imports no numpy). Adding a rule is its class (and its
steps) plus one :func:`register_rule` call; ``docs/design.md`` shows a whole one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, ClassVar, Protocol

from ...errors import ParameterError
from ...jsonout import finite_or_none

if TYPE_CHECKING:  # pragma: no cover
    from .steps import RuleSteps

__all__ = [
    "RULES",
    "AlarmRule",
    "CusumRule",
    "FrameRule",
    "PersistenceRule",
    "RuleOption",
    "RuleSpec",
    "alarm_label",
    "is_rule",
    "make_rule",
    "register_rule",
    "rule_from_dict",
    "rule_names",
    "rule_spec",
    "unregister_rule",
]


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

    def view_label(self) -> str:
        """What an alarm view draws against the threshold."""
        return "score"


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
        from ..._validate import positive_int  # numpy: not when the CLI only builds its parser

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

    def view_label(self) -> str:
        """What an alarm view draws against the threshold (the score: the window count is not drawn)."""
        return f"score ({self.k} of {self.n})"


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

    def view_label(self) -> str:
        """What an alarm view draws against the threshold."""
        return "CUSUM g"


class AlarmRule(Protocol):
    """What every alarm rule is: a frozen object with a ``name`` (its key in :data:`RULES`), a
    ``threshold`` and the methods below (:class:`FrameRule` is the smallest example)."""

    name: ClassVar[str]

    @property
    def threshold(self) -> float:
        """The threshold ``h`` (``inf``: never alarms)."""

    def with_threshold(self, threshold: float) -> AlarmRule:
        """The same rule at another threshold."""

    def parameters(self) -> dict[str, Any]:
        """The rule's parameters besides its threshold, in the order of its :class:`RuleSpec`."""

    def to_dict(self) -> dict[str, Any]:
        """``{"rule": name, "threshold": h or None, **parameters}``."""

    def describe(self) -> str:
        """A short description for reports and recordings."""

    def view_label(self) -> str:
        """What an alarm view draws against the threshold (``"score"``, ``"CUSUM g"``)."""


@dataclass(frozen=True)
class RuleOption:
    """The command-line option ``--{rule}-{parameter}`` of one rule parameter.

    Attributes
    ----------
    help : str
        Help text; ``{default}`` is the parameter's default, ``{step}`` / ``{steps}`` what a step is
        for the command (``frame`` / ``frames``; ``diagnose``: ``step`` / ``steps (frames or samples)``).
    unit : str
        Unit named in the error message of a bad value (``"nats"``), or ``""``.
    metavar : str
        The value's name in ``--help`` (default: the parameter's name in capitals).
    """

    help: str
    unit: str = ""
    metavar: str = ""


@dataclass(frozen=True)
class RuleSpec:
    """One entry of the rules table :data:`RULES`: everything that differs between rules.

    Attributes
    ----------
    name : str
        The rule's name (CLI ``--rule`` value).
    cls : type
        Its class (an :class:`AlarmRule`); ``cls(threshold=h, **parameters)`` builds it.
    summary : str
        One line for ``--help`` and the docs.
    parameters : dict
        Parameter name -> default (besides the threshold), in the order of ``rule.parameters()``.
        An ``int`` default makes the CLI option an integer >= 1, a ``float`` one a positive number.
    statistic : str
        What :attr:`AlarmBlock.statistic` holds for this rule (axis label of a plot or recording).
    style : dict
        Matplotlib / viewer style of the rule's curves: ``color`` (hex), ``marker``, ``linestyle``.
    steps : callable
        ``steps() -> RuleSteps``: the rule's state machine (compiled loop and numpy form,
        :mod:`chatterspec.detection.alarms.steps`), imported only when alarms run.
    options : dict
        Parameter name -> :class:`RuleOption` (its CLI option ``--{name}-{parameter}``); a parameter
        without one has no CLI option.
    accumulates : bool
        The threshold applies to a statistic accumulated over steps (CUSUM ``g``), not to each
        step's score: the alarm view draws the statistic, a threshold above the largest score can
        still alarm, threshold grids span the statistic's range, and scores may be capped
        (robust form) without changing which thresholds are reachable.
    per_step_law : bool
        The rule alarms at each step whose score is over the threshold, so on a p-value score
        (``-log p``) the healthy law alone gives the threshold for a budget
        (:func:`~chatterspec.detection.alarms.calibration.law_frame_rule`), no simulation.
    """

    name: str
    cls: type
    summary: str
    parameters: Mapping[str, Any] = field(default_factory=dict)
    statistic: str = "score"
    style: Mapping[str, str] = field(default_factory=dict)
    steps: Callable[[], RuleSteps] | None = None
    options: Mapping[str, RuleOption] = field(default_factory=dict)
    accumulates: bool = False
    per_step_law: bool = False

    def flag(self, parameter: str) -> str:
        """The CLI option of ``parameter``: ``--{rule}-{parameter}``."""
        return f"--{self.name}-{parameter}".replace("_", "-")

    def load_steps(self) -> RuleSteps:
        """The rule's :class:`~chatterspec.detection.alarms.steps.RuleSteps`."""
        if self.steps is None:
            raise ParameterError(f"the {self.name} rule has no state machine (RuleSpec.steps)")
        return self.steps()


def _stock_steps(attribute: str) -> Callable[[], RuleSteps]:
    """The steps of a stock rule, from :mod:`chatterspec.detection.alarms.steps` (numpy: imported late)."""

    def load() -> RuleSteps:
        from . import steps as alarm_steps

        steps: RuleSteps = getattr(alarm_steps, attribute)
        return steps

    return load


_RULES: dict[str, RuleSpec] = {}

#: The rules table (read-only view; :func:`register_rule` adds to it).
RULES: Mapping[str, RuleSpec] = MappingProxyType(_RULES)


def register_rule(spec: RuleSpec) -> RuleSpec:
    """Add a rule to :data:`RULES` (its name becomes a ``--rule`` choice); returns ``spec``.

    Raises
    ------
    ParameterError
        A name already registered, or a class whose ``name`` is not the spec's.
    """
    if spec.name in _RULES:
        raise ParameterError(f"an alarm rule named {spec.name!r} is already registered")
    if getattr(spec.cls, "name", None) != spec.name:
        raise ParameterError(f"rule class {spec.cls.__name__} must have name = {spec.name!r}")
    _RULES[spec.name] = spec
    return spec


def unregister_rule(name: str) -> None:
    """Remove the rule ``name`` from :data:`RULES` (what a test that registered one does after it)."""
    _RULES.pop(name, None)


register_rule(
    RuleSpec(
        "frame",
        FrameRule,
        "alarm while the step's score is >= h (per-frame rule)",
        {},
        "score",
        {"color": "#1f77b4", "marker": "o", "linestyle": "-"},
        _stock_steps("FRAME"),
        per_step_law=True,
    )
)
register_rule(
    RuleSpec(
        "persistence",
        PersistenceRule,
        "alarm when k of the last n steps have a score >= h; ends after n clean steps",
        {"k": 3, "n": 5},
        "exceedances in the last n steps",
        {"color": "#ff7f0e", "marker": "s", "linestyle": "--"},
        _stock_steps("PERSISTENCE"),
        {
            "k": RuleOption(
                "persistence rule: {steps} over the threshold among the last N (default {default})"
            ),
            "n": RuleOption("persistence rule: window in {steps} (default {default})"),
        },
    )
)
register_rule(
    RuleSpec(
        "cusum",
        CusumRule,
        "CUSUM g = max(0, g + score - drift), alarm when g >= h; ends when g is back at 0",
        {"drift": 3.0},
        "CUSUM g",
        {"color": "#2ca02c", "marker": "^", "linestyle": "-."},
        _stock_steps("CUSUM"),
        {
            "drift": RuleOption(
                "CUSUM rule: drift subtracted from each {step} score, nats (default {default:g})", "nats", "D"
            )
        },
        accumulates=True,
    )
)


def rule_spec(rule: AlarmRule | str) -> RuleSpec:
    """The :class:`RuleSpec` of a rule or rule name (``ParameterError`` listing the names if unknown)."""
    name = rule if isinstance(rule, str) else rule.name
    spec = RULES.get(name)
    if spec is None:
        raise ParameterError(f"unknown alarm rule {name!r}; choose one of {', '.join(RULES)}")
    return spec


def is_rule(obj: object) -> bool:
    """Whether ``obj`` is an instance of a registered rule class."""
    return any(isinstance(obj, spec.cls) for spec in RULES.values())


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
    name : str
        A key of :data:`RULES` (``"frame"``, ``"persistence"``, ``"cusum"`` or a registered one).
    threshold : float
        The rule's threshold ``h`` (default ``inf``: calibrate it, e.g. with
        :func:`chatterspec.detection.alarms.calibration.calibrate_rule`).
    **parameters
        The rule's other parameters (``k``, ``n``; ``drift``); missing ones take the table's defaults.

    Raises
    ------
    ParameterError
        Unknown rule name (the message lists the valid ones), unknown parameter or bad value.
    """
    spec = rule_spec(name)
    unknown = set(parameters) - set(spec.parameters)
    if unknown:
        allowed = ", ".join(spec.parameters) or "none"
        raise ParameterError(
            f"rule {name!r} has no parameter(s) {', '.join(sorted(unknown))} (parameters: {allowed})"
        )
    rule: AlarmRule = spec.cls(threshold=threshold, **{**spec.parameters, **parameters})
    return rule


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
