"""One name per concept: an option means the same thing, takes the same values and has the same
default in every command that has it (read from the argparse parser itself).

For each option string the test collects, over all subcommands, what a user sees and what the
parser does: the action (flag or value), type, number of values, choices, metavar, and the default
-- argparse's, or where that is None ("not given": e.g. refused with --calibration), the
``(default X)`` that the help text states. Every difference must be listed in ``INTENDED`` below
with the reason it is intended; a difference that is not listed fails.
"""

from __future__ import annotations

import argparse
import re
from collections import Counter, defaultdict
from typing import Any

from chatterspec.cli import build_parser

#: (option, command) -> why that command's option differs from the other commands' (and in what).
INTENDED: dict[tuple[str, str], str] = {
    # --runs: the Monte Carlo realizations; each study has the count its result needs
    ("--runs", "calibrate"): "1000: an empirical quantile at alpha 0.01 from 10 expected exceedances",
    ("--runs", "far"): "1000: a false-alarm rate at alpha 0.01 from 10 expected alarms",
    ("--runs", "power"): "200 per fault size: detection rates within +-0.1 (99 % Clopper-Pearson)",
    ("--runs", "estimate"): "100: Monte Carlo standard errors of the RMSE within a few percent",
    ("--runs", "diagnose"): "10 runs of 9 s records: delays per onset (the budget's healthy runs apart)",
    ("--runs", "figures"): "None: each figure's own count (the papers' settings)",
    # --alpha: the detector's false-alarm probability (0.001 wherever one record or frame is tested)
    ("--alpha", "monitor"): "default: the model file's [detector] alpha (0.001 in the examples)",
    ("--alpha", "calibrate"): "0.01: an empirical quantile from 1000 records needs alpha * runs >= 10",
    ("--alpha", "far"): "0.01, several levels (nargs +): a measured rate needs alpha * runs >= 10",
    # --band: the tested frequency band
    ("--band", "monitor"): "default: the model file's [detector] band",
    # --alarm-hours: hours of healthy data for the rule's threshold
    ("--alarm-hours", "calibrate"): "48 h: a calibration file is made once for all-day use (in-call 12/m h)",
    # --false-alarms-per-hour: the alarm budget
    ("--false-alarms-per-hour", "diagnose"): "1 per hour: routes are compared on short records; "
    "one per day (the monitor's) needs a calibration longer than the study",
    # --rate: data seconds per wall second, 0 = as fast as possible
    ("--rate", "simulate"): "1.0 (real time): simulate generates live data for a monitor to follow",
    # --threshold: the spectral detector's threshold
    ("--threshold", "spectrum"): "a drawing: 'both' (the default) draws the paper's and the exact one",
    # --plot: a figure file
    ("--plot", "spectrum"): "the figure is spectrum's result: written by default, figures/NAME-spectrum.png",
    # --figures-dir: where PNGs go
    ("--figures-dir", "figures"): "the paper figures go to figures/ (committed), the demo's to figures/demo",
    # NAME: a catalogue scenario (or a model file)
    ("<name>", "scenarios"): "optional: without NAME every scenario is listed",
}

#: Options whose help states a default that is not argparse's (a None that means "not given").
_DEFAULT = re.compile(r"\(default:? ([^;,)]+)")


def _effective_default(action: argparse.Action) -> Any:
    if action.default is not None or not action.help:
        return action.default
    m = _DEFAULT.search(action.help)
    if m is None:
        return None
    text = m.group(1).strip()
    try:
        return float(text)
    except ValueError:
        return text


def _describe(action: argparse.Action) -> dict[str, Any]:
    kind = type(action).__name__
    return {
        "action": kind,
        "type": getattr(action.type, "__name__", action.type),
        "nargs": action.nargs,
        "choices": None if action.choices is None else tuple(action.choices),
        "metavar": action.metavar,
        "default": _effective_default(action),
    }


def option_table() -> dict[str, dict[str, dict[str, Any]]]:
    """option string -> command -> its description (positionals under their dest, as '<dest>')."""
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    table: dict[str, dict[str, dict[str, Any]]] = defaultdict(dict)
    for command, p in sub.choices.items():
        for action in p._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            for name in action.option_strings or [f"<{action.dest}>"]:
                table[name][command] = _describe(action)
    return table


def _usual(option: str, by_command: dict[str, dict[str, Any]]) -> tuple[str, dict[str, Any]]:
    """The description most commands give ``option`` (outside ``INTENDED``), and one command with it."""
    counted = Counter(repr(d) for c, d in by_command.items() if (option, c) not in INTENDED)
    top = counted.most_common(1)[0][0]
    return next((c, d) for c, d in by_command.items() if repr(d) == top)


def test_one_option_one_meaning_and_default_everywhere() -> None:
    problems = []
    for option, by_command in sorted(option_table().items()):
        first, usual = _usual(option, by_command)
        for command, desc in by_command.items():
            differs = {k: (desc[k], usual[k]) for k in desc if desc[k] != usual[k]}
            if differs and (option, command) not in INTENDED:
                problems.append(f"{option}: {command} differs from {first}: {differs}")
    assert not problems, "\n".join(problems)


def test_every_intended_difference_is_still_there() -> None:
    table = option_table()
    for option, command in INTENDED:
        by_command = table.get(option, {})
        assert command in by_command, (option, command)
        assert len(by_command) > 1 and by_command[command] != _usual(option, by_command)[1], (option, command)


def test_each_concept_has_one_name() -> None:
    """Names that once meant something else in some command are gone: the concept has one name."""
    table = option_table()
    assert "--confidence" in table and "--mc-confidence" in table
    for retired in ("--figure", "--hours", "--model", "--out"):
        owners = set(table.get(retired, {}))
        # --out: a data file the command computes (a calibration, a fitted model), never a figure
        assert owners <= {"calibrate", "commission"} if retired == "--out" else not owners, (retired, owners)
    # --confidence: the identified parameters' interval level; --mc-confidence: the Monte Carlo
    # intervals' (rates, quantiles); --alpha: a detector's false-alarm probability, never a test of
    # estimator consistency (that is estimate's --consistency-alpha)
    assert set(table["--confidence"]) == {"demo", "detect", "monitor", "diagnose", "commission"}
    assert set(table["--mc-confidence"]) == {"calibrate", "far", "power"}
    assert "estimate" not in table["--alpha"] and "estimate" in table["--consistency-alpha"]
    assert set(table["--plot"]) == {"calibrate", "far", "power", "spectrum", "diagnose"}
    # a model file, positional like every command's NAME
    assert set(table["<model>"]) == {"monitor", "commission"}
