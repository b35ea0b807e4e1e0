"""The command-line options the subcommands share: their argparse types, one table, one function per
group of options, the alarm options and the identification options.

:data:`OPTIONS` holds, per option, what every command gives it (type, metavar, choices, default) and
the help text most commands use; a command that means something narrower passes its own ``help``
(or default) to :func:`add`. The group functions add the options that always travel together, in the
order ``--help`` lists them:

* :func:`add_runs_args`: ``--runs``, ``--seed`` (the Monte Carlo realizations and their root seed);
* :func:`add_execution_args`: ``--workers``, ``--scheduler`` and optionally ``--chunk-runs`` (where
  the realizations run; the numbers do not depend on them), read back by :func:`execution`;
* :func:`add_report_args`: ``--json`` and optionally ``--no-progress`` (what goes to stdout / stderr);
* :func:`add_detector_args`: the spectral detector's ``--alpha``, ``--threshold``, ``--correction``,
  ``--band`` with the runs group (``detect``, ``demo``);
* :func:`add_live_args`: ``--record FILE.rrd`` and ``--live URL|spawn``;
* :func:`add_study_args`: the Monte Carlo study commands' ``--alpha``, runs, execution, ``--mc-confidence``
  and report groups (``calibrate``, ``far``, ``power``), read back by :func:`study_keywords`;
* :func:`add_alarm_args`: the alarm-rule options of ``monitor``, ``detect --record`` and ``calibrate``:
  ``--rule {frame,persistence,cusum}``, ``--false-alarms-per-hour X``, per rule parameter its option
  ``--{rule}-{parameter}`` (``--persistence-k K``, ``--persistence-n N``, ``--cusum-drift D``: read
  from the rules table, :func:`add_rule_parameter_args`), ``--alarm-hours H``. Their values are
  checked after parsing (:func:`alarm_choice`), so that a bad one is one line naming the option
  (exit 2), not an argparse usage block;
* :func:`add_identification_args` (``--no-identify``, ``--confidence``) and
  :func:`add_tolerance_args` (``--tolerance NAME=SPEC``) of ``detect``, ``demo``, ``monitor`` and
  ``diagnose``, read back by :func:`setup_or_reason` and :func:`with_tolerance_args`.

Building the parser imports nothing heavy (no numpy, scipy, matplotlib or scenario catalogue): a bad
option or output path fails before the slow imports.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from ..detection.alarms.rules import RULES, rule_names, rule_spec
from ..errors import ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.calibration import RuleCalibration
    from ..detection.identification import IdentificationSetup
    from ..plants.nonlinear import Model
    from ..plants.scenarios import Scenario

T = TypeVar("T")


# --- argparse types --------------------------------------------------------------------------------------
def parsed_arg(
    text: str, convert: Callable[[str], T], ok: Callable[[T], bool], not_a_number: str, out_of_range: str
) -> T:
    """``convert(text)`` if it works and ``ok`` accepts it, else ``argparse.ArgumentTypeError``.

    The messages are templates: ``{text}`` is the text given, ``{value}`` the converted value.
    """
    try:
        value = convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(not_a_number.format(text=text, value=None)) from None
    if not ok(value):
        raise argparse.ArgumentTypeError(out_of_range.format(text=text, value=value))
    return value


def _open_unit_arg(what: str, name: str) -> Any:
    """argparse type ``name``: a number in the open interval (0, 1), named ``what`` in messages."""

    def parse(text: str) -> float:
        return parsed_arg(
            text,
            float,
            lambda v: 0.0 < v < 1.0,
            f"{what} must be a number in (0, 1); got {{text!r}}",
            f"{what} must lie in the open interval (0, 1); got {{value}}",
        )

    parse.__name__ = parse.__qualname__ = name
    parse.__doc__ = f"argparse type: {what}, a number in the open interval (0, 1)."
    return parse


alpha_arg = _open_unit_arg("alpha", "alpha_arg")

confidence_arg = _open_unit_arg("confidence", "confidence_arg")


def rate_arg(text: str) -> float:
    """argparse type of ``--rate``: data seconds per wall second, finite and >= 0 (0: as fast as possible)."""
    return parsed_arg(
        text,
        float,
        lambda v: 0.0 <= v < float("inf"),
        "--rate must be a number (1.0 = real time, 0 = as fast as possible); got {text!r}",
        "--rate must be finite and >= 0 (1.0 = real time, 0 = as fast as possible); got {value}",
    )


def _integer_arg(minimum: int, name: str) -> Callable[[str], int]:
    """argparse type ``name``: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        expected = f"expected an integer >= {minimum}; got "
        return parsed_arg(text, int, lambda v: v >= minimum, expected + "{text!r}", expected + "{value}")

    parse.__name__ = parse.__qualname__ = name
    parse.__doc__ = f"argparse type: an integer >= {minimum}."
    return parse


positive_int_arg = _integer_arg(1, "positive_int_arg")

nonnegative_int_arg = _integer_arg(0, "nonnegative_int_arg")


def band_edge_arg(text: str) -> float:
    """argparse type: one edge of ``--band LO HI``, a finite frequency >= 0 in Hz."""
    return parsed_arg(
        text,
        float,
        lambda v: v >= 0.0 and v < float("inf"),
        "--band edges are frequencies in Hz; got {text!r}",
        "--band edges must be finite and >= 0 Hz; got {text!r}",
    )


def live_arg(text: str) -> str:
    """argparse type of ``--live``: ``spawn``, a port, ``host:port`` or a viewer URL (not a bare word)."""
    if text == "spawn":
        return text
    from ..viewer.sinks import viewer_url

    try:
        viewer_url(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--live {text!r} ")) from None
    return text


# --- the option table and the groups of options -------------------------------------------------------------
#: The positional NAME of the commands that study a healthy scenario (calibrate, far).
HEALTHY_NAME_HELP = "healthy scenario name or model file (.toml)"

#: Per option: the argparse keywords every command uses (``help`` the most common text; ``{default}``
#: in it is filled with the command's default).
OPTIONS: dict[str, dict[str, Any]] = {
    "--runs": {"type": positive_int_arg, "help": "Monte Carlo realizations (default {default})"},
    "--seed": {"type": nonnegative_int_arg, "default": 0, "help": "random seed (default 0)"},
    "--workers": {
        "type": positive_int_arg,
        "default": 1,
        "help": "local worker processes (default 1; the results do not depend on it)",
    },
    "--scheduler": {
        "metavar": "ADDRESS",
        "help": "run on Dask: 'local-dask' or a scheduler address (needs chatterspec[distributed])",
    },
    "--chunk-runs": {
        "type": positive_int_arg,
        "default": None,
        "help": "realizations per chunk (rounded up to a multiple of 64, with a note)",
    },
    # the identified parameters' interval level (the identification's, a physical parameter's spread) ...
    "--confidence": {
        "type": confidence_arg,
        "default": 0.95,
        "help": "confidence level of the identified parameters' intervals (default 0.95); the hypothesis "
        "tests use --alpha",
    },
    # ... is not the Monte Carlo intervals' (a rate or quantile estimated from --runs realizations)
    "--mc-confidence": {
        "type": confidence_arg,
        "default": 0.99,
        "help": "confidence level of the Monte Carlo intervals (rates: Clopper-Pearson, quantiles: order "
        "statistics) (default 0.99)",
    },
    "--json": {"action": "store_true", "help": "print one JSON document on stdout"},
    "--no-progress": {"action": "store_true", "help": "no progress bar on stderr"},
    "--alpha": {"type": alpha_arg},
    "--threshold": {
        "choices": ("exact", "paper"),
        "default": "exact",
        "help": "'exact': per-bin chi-squared thresholds from the expected spectrum with family-wise "
        "control; 'paper': the paper's flat bound (eq 58-62) at per-bin alpha (default exact)",
    },
    "--correction": {
        "choices": ("bonferroni", "sidak", "none"),
        "default": "bonferroni",
        "help": "family-wise correction over the tested bins for 'exact' and for the averaged verdict "
        "of every threshold with --runs > 1 (default bonferroni)",
    },
    "--band": {
        "nargs": 2,
        "type": band_edge_arg,
        "metavar": ("LO", "HI"),
        "help": "test only the bins with LO <= f <= HI (Hz), for every threshold (single, averaged, STFT "
        "frames); the correction counts only these bins; DC and Nyquist stay excluded",
    },
    "--calibration": {"type": Path, "metavar": "FILE"},
    "--record": {
        "type": Path,
        "metavar": "FILE.rrd",
        "help": "write a Rerun recording of the run to FILE.rrd",
    },
    "--live": {
        "type": live_arg,
        "metavar": "URL|spawn",
        "help": "stream to a running Rerun viewer (gRPC URL such as rerun+http://127.0.0.1:9876/proxy) "
        "or 'spawn' one (needs a display)",
    },
    "--plot": {"metavar": "FILE"},
    # a data file the command computes (a calibration, a fitted model file); figures are --plot
    "--out": {"type": Path, "metavar": "FILE"},
    # a data file the command reads (a healthy recording), or '-' for CSV rows on standard input
    "--data": {"type": Path},
    "--figures-dir": {"metavar": "DIR", "help": "where to write the PNGs (default {default})"},
    "--rate": {
        "type": rate_arg,
        "help": "data seconds per wall second (default {default}; 1.0 = real time, 0 = as fast as possible)",
    },
    "--dpi": {"type": positive_int_arg, "default": None, "help": "PNG resolution (default 110)"},
    # the alarm options: checked after parsing (:func:`alarm_choice`), so strings here; each rule
    # parameter's option (--persistence-k, ...) comes from the rules table (:func:`add_rule_parameter_args`)
    "--rule": {"default": None},
    "--false-alarms-per-hour": {"default": None, "metavar": "X"},
    "--alarm-hours": {"default": None, "metavar": "H"},
}


def add(p: argparse.ArgumentParser, flag: str, **changes: Any) -> argparse.Action:
    """Add the option ``flag`` of :data:`OPTIONS` to ``p``; ``changes`` replace its keywords.

    ``{default}`` in the help text is replaced by the option's default (``--runs``).
    """
    kwargs = {**OPTIONS[flag], **changes}
    if "help" in kwargs and "{default}" in kwargs["help"]:
        kwargs["help"] = kwargs["help"].format(default=kwargs["default"])
    return p.add_argument(flag, **kwargs)


def command(
    sub: argparse._SubParsersAction,
    name: str,
    run: Callable[[argparse.Namespace], int],
    *,
    help: str,
    description: str,
) -> argparse.ArgumentParser:
    """Add the subcommand ``name`` to ``sub``, run by ``run(args) -> int`` (its ``func``)."""
    p = sub.add_parser(name, help=help, description=description)
    p.set_defaults(func=run)
    return p


def add_name(p: argparse.ArgumentParser, help: str = HEALTHY_NAME_HELP) -> None:
    """The positional ``NAME``: a catalogue scenario or a model file (``help`` says which it accepts)."""
    p.add_argument("name", metavar="NAME", help=help)


def load_scenario(name: str) -> Scenario:
    """A catalogue scenario, or the healthy scenario of a model file (``NAME.toml``, linear or nonlinear).

    A model file's scenario is its ``[simulation]`` table (input, initial state, duration; zero input
    and 4 s by default) with the file's model as nominal model and true plant.
    """
    from ..plants.simulate import as_scenario

    return as_scenario(name)


def add_runs_args(
    p: argparse.ArgumentParser,
    runs: int | None,
    *,
    runs_help: str | None = None,
    seed_help: str | None = None,
) -> None:
    """``--runs`` (default ``runs``; None: the command's own, said in ``runs_help``) and ``--seed``."""
    add(p, "--runs", default=runs, **({} if runs_help is None else {"help": runs_help}))
    add(p, "--seed", **({} if seed_help is None else {"help": seed_help}))


def add_execution_args(
    p: argparse.ArgumentParser, *, workers_help: str | None = None, chunk_runs_help: str | None = None
) -> None:
    """``--workers N`` and ``--scheduler ADDRESS``; with ``chunk_runs_help``, ``--chunk-runs`` too.

    The numbers of a Monte Carlo command do not depend on them (see :func:`execution`).
    """
    add(p, "--workers", **({} if workers_help is None else {"help": workers_help}))
    add(p, "--scheduler")
    if chunk_runs_help is not None:
        add(p, "--chunk-runs", help=chunk_runs_help)


def add_report_args(
    p: argparse.ArgumentParser, *, progress: bool = True, json_help: str | None = None
) -> None:
    """``--json`` (one JSON document on stdout) and, with ``progress``, ``--no-progress``."""
    add(p, "--json", **({} if json_help is None else {"help": json_help}))
    if progress:
        add(p, "--no-progress")


def add_detector_args(p: argparse.ArgumentParser) -> None:
    """--alpha, --threshold, --correction, --band, --runs, --seed (``detect``, ``demo``)."""
    add(
        p,
        "--alpha",
        default=1e-3,
        help="false-alarm probability: family-wise for 'exact' (default 0.001), per bin for 'paper'",
    )
    add(p, "--threshold")
    add(p, "--correction")
    add(p, "--band")
    add_runs_args(p, 1)


def add_live_args(p: argparse.ArgumentParser) -> None:
    """--record FILE.rrd and --live URL|spawn."""
    add(p, "--record")
    add(p, "--live")


def add_study_args(p: argparse.ArgumentParser, *, alpha: float, runs: int, multi_alpha: bool = False) -> None:
    """The options of the Monte Carlo study commands (``calibrate``, ``far``, ``power``).

    ``--alpha`` (default ``alpha``; several with ``multi_alpha``), ``--runs`` (default ``runs``),
    ``--seed``, the execution options with ``--chunk-runs``, ``--mc-confidence``, ``--json`` and
    ``--no-progress``.
    """
    if multi_alpha:
        add(p, "--alpha", nargs="+", default=[alpha], help=f"nominal level(s) (default {alpha:g})")
    else:
        add(p, "--alpha", default=alpha, help=f"false-alarm probability (default {alpha:g})")
    add_runs_args(p, runs, seed_help="root seed (default 0)")
    add_execution_args(
        p,
        workers_help="local worker processes (default 1)",
        chunk_runs_help=OPTIONS["--chunk-runs"]["help"],
    )
    add(p, "--mc-confidence")
    add_report_args(p)


def execution(args: argparse.Namespace) -> dict[str, Any]:
    """The execution keywords of ``args`` for the studies: workers, scheduler, chunk_runs, progress."""
    return {
        "workers": args.workers,
        "scheduler": args.scheduler,
        "chunk_runs": args.chunk_runs,
        "progress": False if args.no_progress else None,
    }


def study_execution(args: argparse.Namespace) -> dict[str, Any]:
    """:func:`execution` of a study command, with ``confidence`` (``--mc-confidence``) and
    :func:`round_chunk_runs`."""
    round_chunk_runs(args)
    return {**execution(args), "confidence": args.mc_confidence}


def round_chunk_runs(args: argparse.Namespace) -> None:
    """``--chunk-runs`` rounded up to whole blocks of realizations (with a note on stderr), so that the
    results do not depend on the chunking."""
    from ..montecarlo import BLOCK

    if args.chunk_runs is not None and args.chunk_runs % BLOCK:
        rounded = -(-args.chunk_runs // BLOCK) * BLOCK
        print(
            f"chatterspec: note: --chunk-runs {args.chunk_runs} rounded up to {rounded} (chunks are whole "
            f"blocks of {BLOCK} realizations, so results do not depend on the chunking)",
            file=sys.stderr,
        )
        args.chunk_runs = rounded


def study_keywords(args: argparse.Namespace) -> dict[str, Any]:
    """Everything :func:`add_study_args` reads, as the studies take it: ``alpha``, ``runs``, ``seed`` and
    :func:`study_execution`."""
    return {"alpha": args.alpha, "runs": args.runs, "seed": args.seed, **study_execution(args)}


# --- the alarm options (checked after parsing) --------------------------------------------------------------
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
    from ..detection.alarms.calibration import check_budget

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


# --- the identification options -----------------------------------------------------------------------------
def add_identification_args(p: argparse.ArgumentParser) -> None:
    """``--no-identify`` and ``--confidence``."""
    p.add_argument(
        "--no-identify",
        action="store_true",
        help="skip fault identification (which parameter changed, in physical units)",
    )
    add(p, "--confidence")


def add_tolerance_args(p: argparse.ArgumentParser) -> None:
    """``--tolerance NAME=SPEC`` (repeatable): a parameter's operating tolerance."""
    p.add_argument(
        "--tolerance",
        action="append",
        default=[],
        metavar="NAME=SPEC",
        help="operating tolerance of the declared parameter NAME (repeat per parameter; beside or instead "
        "of the model file's): 15%% (relative), 3e7 (absolute, the parameter's unit), -10%%,+20%% or "
        "1.8e8,2.3e8 (a band). With tolerances the fault decision is taken on the identified parameters: "
        "inside its band a parameter raises no alarm",
    )


def with_tolerance_args(model: Model, args: argparse.Namespace) -> Model:
    """``model`` with the ``--tolerance NAME=SPEC`` of ``args`` (unchanged without any)."""
    given = getattr(args, "tolerance", None) or []
    if not given:
        return model
    from ..errors import ParameterError
    from ..plants.parameters import with_tolerances

    spec = {}
    for item in given:
        name, sep, value = str(item).partition("=")
        if not sep or not name.strip() or not value.strip():
            raise ParameterError(f"--tolerance expects NAME=SPEC (e.g. bulk_modulus=15%); got {item!r}")
        spec[name.strip()] = value.strip()
    return with_tolerances(model, spec)


def setup_or_reason(model: Model, args: argparse.Namespace) -> tuple[IdentificationSetup | None, str | None]:
    """The identification setup of ``model``, or why there is none (``--no-identify``, reduced order, ...)."""
    if getattr(args, "no_identify", False):
        return None, "skipped (--no-identify)"
    from ..detection.identification import identification_setup
    from ..errors import IdentifiabilityError

    try:
        return identification_setup(model), None
    except IdentifiabilityError as exc:
        return None, str(exc)
