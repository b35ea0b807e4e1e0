"""The alarm-rule options shared by ``monitor``, ``detect --record`` and ``calibrate``, and how the rule in
use is reported (:func:`alarm_doc`, one stderr line).

``--rule {frame,persistence,cusum}``, ``--false-alarms-per-hour X``, per rule parameter its option
``--{rule}-{parameter}`` (``--persistence-k K``, ``--persistence-n N``, ``--cusum-drift D``: read from
the rules table, :func:`add_rule_parameter_args`), ``--alarm-hours H``. Their values are checked
after parsing (:func:`alarm_choice`), so that a bad one is one line naming the option (exit 2), not
an argparse usage block.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..detection.alarms.rules import RULES, rule_names, rule_spec  # no numpy: the parser is built for --help
from ..errors import ParameterError
from ._options import add

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    from ..detection.alarms.calibration import MonitorSettings, RuleCalibration

__all__ = [
    "AlarmChoice",
    "add_alarm_args",
    "add_rule_parameter_args",
    "alarm_choice",
    "alarm_doc",
    "check_file_alarm",
    "positive_number",
]

#: The rule when ``--rule`` is not given (and no calibration file names one).
DEFAULT_RULE = "cusum"
_DEFAULT_BUDGET = 1.0 / 24.0


#: ``--alarm-hours``'s help; ``{default}``: what the command simulates when it is not given.
ALARM_HOURS_HELP = (
    "hours of healthy data simulated to set the threshold of the persistence and CUSUM rules (default "
    "{default}; the threshold is cached per model and settings in the user cache, see "
    "CHATTERSPEC_CACHE_DIR); at least two STFT frames, at most what fits in 256 MiB of frame scores "
    "(621 h for the EHA)"
)
#: The in-call default of ``--alarm-hours`` (monitor, detect --record), as ``--help`` says it.
IN_CALL_HOURS_DEFAULT = (
    "12 / channels, 4 for the EHA: a few seconds; a calibration file from `chatterspec calibrate --rule "
    "...` (48 h) gives a tighter one"
)


def add_alarm_args(
    p: argparse.ArgumentParser, *, what: str = "the monitor", hours_default: str = IN_CALL_HOURS_DEFAULT
) -> None:
    """Add the alarm options to ``p`` (``what`` names the monitor in the help texts; ``hours_default``
    says the default of ``--alarm-hours``)."""
    rules = "; ".join(f"{name}: {spec.summary}" for name, spec in RULES.items())
    add(p, "--rule", choices=rule_names(), help=f"alarm rule of {what} (default {DEFAULT_RULE}): {rules}")
    add(
        p,
        "--false-alarms-per-hour",
        help=f"false-alarm budget of {what}: alarm starts per hour of healthy data, all channels together "
        f"(default {_DEFAULT_BUDGET:.4g} = one per day); the rule's threshold is set for it",
    )
    add_rule_parameter_args(p)
    add(p, "--alarm-hours", help=ALARM_HOURS_HELP.format(default=hours_default))


def add_rule_parameter_args(
    p: argparse.ArgumentParser, *, step: str = "frame", steps: str = "frames", skip: tuple[str, ...] = ()
) -> None:
    """Add ``--{rule}-{parameter}`` for every parameter of every rule in the rules table that has a
    :class:`~chatterspec.detection.alarms.rules.RuleOption` (``step`` / ``steps``: what a step is in the
    help texts; ``skip``: parameters the command sets itself, whose options default to None unseen)."""
    for spec in RULES.values():
        for name, option in spec.options.items():
            flag = spec.flag(name)
            if name in skip:
                p.set_defaults(**{_dest(flag): None})
                continue
            default = spec.parameters[name]
            text = option.help.format(default=default, step=step, steps=steps)
            p.add_argument(flag, default=None, metavar=option.metavar or name.upper(), help=text)


def _dest(flag: str) -> str:
    return flag.lstrip("-").replace("-", "_")


@dataclass(frozen=True)
class AlarmChoice:
    """The parsed alarm options.

    Attributes
    ----------
    rule : str
        Rule name (the default when not given).
    budget : float
        False alarms per hour (the default when not given).
    parameters : dict
        The rule's parameters given on the command line (``k``, ``n``; ``drift``).
    explicit_rule, explicit_budget : bool
        Whether ``--rule`` / ``--false-alarms-per-hour`` were given.
    hours : float or None
        ``--alarm-hours``.
    """

    rule: str
    budget: float
    parameters: dict[str, Any]
    explicit_rule: bool
    explicit_budget: bool
    hours: float | None = None

    def describe(self) -> str:
        """A short description for reports and recordings."""
        return f"{self.rule} rule at {self.budget:g} false alarms per hour"


def _int(value: Any, option: str) -> int:
    try:
        v = int(str(value))
    except ValueError:
        raise ParameterError(f"{option} must be an integer >= 1; got {value!r}") from None
    if v < 1:
        raise ParameterError(f"{option} must be an integer >= 1; got {v}")
    return v


def positive_number(value: Any, option: str, what: str, unit: str = "") -> float:
    """``value`` as a positive, finite float, else one ``ParameterError`` line naming ``option``
    (``what``: the number it must be, e.g. ``"a number of hours"``; ``unit`` follows "finite")."""
    try:
        x = float(value)
    except ValueError:
        raise ParameterError(f"{option} must be {what}; got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise ParameterError(f"{option} must be positive and finite{unit}; got {x!r}")
    return x


def alarm_choice(
    args: argparse.Namespace, *, alpha_given: bool = False, default_rule: str | None = None
) -> AlarmChoice:
    """Check the alarm options of ``args`` (one ``ParameterError`` line naming the option).

    ``alpha_given``: an explicit per-frame ``--alpha`` (the frame rule at that level), which
    only the frame rule takes and which excludes ``--false-alarms-per-hour``. ``default_rule``:
    the rule when ``--rule`` is not given (a calibration file's; else cusum).
    """
    from ..detection.alarms.calibration import check_budget  # scipy: not at parser build time

    rule = args.rule or default_rule or DEFAULT_RULE
    if alpha_given and args.rule not in (None, "frame"):
        raise ParameterError(
            f"--alpha sets the per-frame level of the frame rule; the {args.rule} rule takes "
            "--false-alarms-per-hour instead"
        )
    if alpha_given and args.false_alarms_per_hour is not None:
        raise ParameterError(
            "--alpha and --false-alarms-per-hour both set the frame rule's threshold: give one of them"
        )
    budget = (
        _DEFAULT_BUDGET
        if args.false_alarms_per_hour is None
        else check_budget(args.false_alarms_per_hour, "--false-alarms-per-hour")
    )
    params = _rule_parameters(args, rule)
    hours = getattr(args, "alarm_hours", None)
    if hours is not None:
        hours = positive_number(hours, "--alarm-hours", "a number of hours")
    return AlarmChoice(
        rule=rule,
        budget=budget,
        parameters=params,
        explicit_rule=args.rule is not None,
        explicit_budget=args.false_alarms_per_hour is not None,
        hours=hours,
    )


def _rule_parameters(args: argparse.Namespace, rule: str) -> dict[str, Any]:
    """The parameters of ``rule`` given as ``--{rule}-{parameter}`` options, checked (one line naming the
    option); an option of another rule is an error."""
    from ..detection.alarms.rules import make_rule

    params: dict[str, Any] = {}
    for spec in RULES.values():
        given = {
            name: getattr(args, _dest(spec.flag(name)), None)
            for name in spec.options
            if getattr(args, _dest(spec.flag(name)), None) is not None
        }
        if given and spec.name != rule:
            flags = " / ".join(spec.flag(name) for name in spec.options)
            verb = "applies" if len(spec.options) == 1 else "apply"
            raise ParameterError(f"{flags} {verb} to --rule {spec.name} (rule: {rule})")
        for name, value in given.items():
            flag, unit = spec.flag(name), spec.options[name].unit
            if isinstance(spec.parameters[name], int):
                params[name] = _int(value, flag)
            else:
                params[name] = positive_number(
                    value, flag, f"a number ({unit})" if unit else "a number", f" ({unit})" if unit else ""
                )
    if params:
        try:  # the rule's own checks between parameters (persistence: k <= n)
            make_rule(rule, **params)
        except ParameterError as exc:
            flags = ", ".join(rule_spec(rule).flag(name) for name in params)
            raise ParameterError(f"{flags}: {exc}") from None
    return params


def check_file_alarm(choice: AlarmChoice, cal_alarm: RuleCalibration, path: str | Path) -> RuleCalibration:
    """The calibration file's rule calibration if it fits ``choice`` (the options given on the command
    line), else ``CalibrationMismatchError``
    (:func:`chatterspec.studies.alarm_budget.check_alarm_calibration`)."""
    from ..studies.alarm_budget import check_alarm_calibration

    return check_alarm_calibration(
        cal_alarm,
        choice.rule if choice.explicit_rule else None,
        choice.budget if choice.explicit_budget else None,
        choice.parameters,
        path,
    )


def alarm_doc(settings: MonitorSettings) -> dict:
    """The ``alarm`` entry of the JSON summary: rule, threshold, budget and how it was set."""
    import math

    b = getattr(settings, "budget", None)
    rule = getattr(settings, "rule", None)
    if rule is None:
        a = float(settings.alpha)
        return {
            "rule": {"rule": "frame", "threshold": -math.log(a)},
            "alpha": a,
            "false_alarms_per_hour": None,
            "calibration": None,
        }
    return {
        "rule": rule.to_dict(),
        "alpha": None,
        "false_alarms_per_hour": None if b is None else b.false_alarms_per_hour,
        "calibration": None if b is None else b.to_dict(),
    }


def _alarm_short(settings: MonitorSettings) -> str:
    from ..detection.alarms.rules import alarm_label

    rule = getattr(settings, "rule", None)
    if rule is None:
        return f"frame rule, per-frame alpha {settings.alpha:g}"
    return alarm_label(rule.name, settings.false_alarms_per_hour)


def _alarm_line(settings: MonitorSettings) -> str:
    """One stderr line on the rule in use and where its threshold comes from."""
    rule = getattr(settings, "rule", None)
    if rule is None:
        return f"alarms: {_alarm_short(settings)} (every frame a test)"
    b = settings.budget
    return f"alarms: {b.describe()}" if b is not None else f"alarms: {rule.describe()}"
