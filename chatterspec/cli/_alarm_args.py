"""The alarm-rule options shared by ``monitor``, ``detect --record`` and ``calibrate``, and how the rule in
use is reported (:func:`alarm_doc`, one stderr line).

``--rule {frame,persistence,cusum}``, ``--false-alarms-per-hour X``, ``--persistence-k K``,
``--persistence-n N``, ``--cusum-drift D``, ``--alarm-hours H``. Their values are checked after
parsing (:func:`alarm_choice`), so that a bad one is one line naming the option (exit 2), not an
argparse usage block.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from ..detection.alarm_rules import RULES, rule_names  # no numpy: the parser is built for --help
from ..errors import ParameterError
from ._options import add

if TYPE_CHECKING:  # pragma: no cover
    from pathlib import Path

    from ..detection.alarm_calibration import RuleCalibration
    from ..detection.monitor_settings import MonitorSettings

__all__ = [
    "AlarmChoice",
    "add_alarm_args",
    "alarm_choice",
    "alarm_doc",
    "check_file_alarm",
    "positive_number",
]

_DEFAULT_RULE = "cusum"
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
    k, n = RULES["persistence"].parameters["k"], RULES["persistence"].parameters["n"]
    drift = RULES["cusum"].parameters["drift"]
    add(p, "--rule", choices=rule_names(), help=f"alarm rule of {what} (default {_DEFAULT_RULE}): {rules}")
    add(
        p,
        "--false-alarms-per-hour",
        help=f"false-alarm budget of {what}: alarm starts per hour of healthy data, all channels together "
        f"(default {_DEFAULT_BUDGET:.4g} = one per day); the rule's threshold is set for it",
    )
    add(
        p,
        "--persistence-k",
        help=f"persistence rule: frames over the threshold among the last N (default {k})",
    )
    add(p, "--persistence-n", help=f"persistence rule: window in frames (default {n})")
    add(
        p,
        "--cusum-drift",
        help=f"CUSUM rule: drift subtracted from each frame score, nats (default {drift:g})",
    )
    add(p, "--alarm-hours", help=ALARM_HOURS_HELP.format(default=hours_default))


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
    from ..detection.alarm_calibration import check_budget  # scipy: not at parser build time

    rule = args.rule or default_rule or _DEFAULT_RULE
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
    params: dict[str, Any] = {}
    k = None if args.persistence_k is None else _int(args.persistence_k, "--persistence-k")
    n = None if args.persistence_n is None else _int(args.persistence_n, "--persistence-n")
    if (k is not None or n is not None) and rule != "persistence":
        raise ParameterError(f"--persistence-k / --persistence-n apply to --rule persistence (rule: {rule})")
    if rule == "persistence":
        kk = RULES["persistence"].parameters["k"] if k is None else k
        nn = RULES["persistence"].parameters["n"] if n is None else n
        if kk > nn:
            raise ParameterError(
                f"--persistence-k must be <= --persistence-n (k of the last n frames); got k = {kk}, n = {nn}"
            )
        if k is not None:
            params["k"] = k
        if n is not None:
            params["n"] = n
    if args.cusum_drift is not None:
        if rule != "cusum":
            raise ParameterError(f"--cusum-drift applies to --rule cusum (rule: {rule})")
        params["drift"] = positive_number(args.cusum_drift, "--cusum-drift", "a number (nats)", " (nats)")
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
    from ..detection.alarm_rules import alarm_label

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
