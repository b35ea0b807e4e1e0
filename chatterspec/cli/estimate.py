"""``chatterspec estimate NAME``: the DETC2015-style estimator comparison (RMSE / bias / STD, NEES / NIS)."""

from __future__ import annotations

import argparse

from ..filter_registry import FILTERS
from ._options import (
    OPTIONS,
    add,
    add_execution_args,
    add_name,
    add_report_args,
    add_runs_args,
    alpha_arg,
    command,
    execution,
    round_chunk_runs,
)
from ._report import Outputs, check_record_path, report


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec estimate`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "estimate",
        run,
        help="compare state estimators (KF/EKF, SVSF, 2nd-order SVSF) on Monte Carlo runs",
        description="Runs every filter on the same simulated measurements of an estimator scenario "
        "(detc-normal, detc-uncertain, eha4-leak-timeline, ...) with the tuning the scenario carries, and "
        "prints per state and filter the RMSE, bias and STD of the estimation error (DETC2015 eq 28-30) "
        "with Monte Carlo standard errors, and the NEES / NIS chi-squared consistency. Filters: "
        + "; ".join(f"{k} = {v}" for k, v in FILTERS.items()),
    )
    add_name(p, "scenario with filter settings (see `chatterspec scenarios`)")
    p.add_argument(
        "--filters",
        default="kf,svsf,svsf2",
        help=f"comma-separated filters from {','.join(FILTERS)} (default kf,svsf,svsf2)",
    )
    add_runs_args(p, 100, seed_help="root seed (default 0)")
    add_execution_args(
        p,
        workers_help="local worker processes (default 1)",
        chunk_runs_help=OPTIONS["--chunk-runs"]["help"],
    )
    p.add_argument(
        "--consistency-alpha",
        type=alpha_arg,
        default=0.05,
        metavar="A",
        help="two-sided level of the NEES/NIS chi-squared consistency intervals (default 0.05)",
    )
    add_report_args(p)
    add(
        p,
        "--record",
        help="also write a Rerun recording of realization 0: truth, estimates and innovations per filter",
    )


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec estimate`` with the parsed ``args``; returns the exit status."""
    from ..studies.estimation import estimation_study, parse_filters

    names = parse_filters(args.filters)
    round_chunk_runs(args)  # whole blocks of 64 realizations (with a note), as the other studies
    check_record_path(args.record)  # before the (slow) study: a bad path fails at once
    res = estimation_study(
        args.name, names, runs=args.runs, seed=args.seed, alpha=args.consistency_alpha, **execution(args)
    )
    doc = res.to_dict()
    outputs = Outputs()  # a recording that cannot be written: the table first, then one line, exit 2
    if args.record:
        from ..studies.estimation import estimate_records
        from ..viewer.recordings import record_estimates

        recs = estimate_records(args.name, names, runs=1, seed=args.seed)
        saved = outputs.write("--record", args.record, record_estimates, recs, args.record)
        doc["recording"] = None if saved is None else str(saved)

    def text() -> None:
        print(res.table())
        if args.record and doc["recording"] is not None:
            print(f"recording (realization 0): {doc['recording']}")

    return report(args, doc, outputs, text)
