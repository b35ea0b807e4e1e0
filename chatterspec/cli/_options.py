"""The command-line options the subcommands share: one table, and one function per group of options.

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
  and report groups (``calibrate``, ``far``, ``power``), read back by :func:`study_keywords`.

Building the parser imports nothing heavy (no scipy, matplotlib or scenario catalogue): a bad
option or output path fails before the slow imports.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._common import (
    alpha_arg,
    band_edge_arg,
    confidence_arg,
    live_arg,
    nonnegative_int_arg,
    positive_int_arg,
    rate_arg,
)

if TYPE_CHECKING:  # pragma: no cover
    from collections.abc import Callable

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
    "--figures-dir": {"metavar": "DIR", "help": "where to write the PNGs (default {default})"},
    "--rate": {
        "type": rate_arg,
        "help": "data seconds per wall second (default {default}; 1.0 = real time, 0 = as fast as possible)",
    },
    "--dpi": {"type": positive_int_arg, "default": None, "help": "PNG resolution (default 110)"},
    # the alarm options: checked after parsing (``_alarm_args.alarm_choice``), so strings here; each rule
    # parameter's option (--persistence-k, ...) comes from the rules table (``_alarm_args``)
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
    from ..rng import BLOCK

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
