"""``chatterspec estimate NAME``: the DETC2015-style estimator comparison (RMSE / bias / STD, NEES / NIS)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..errors import ParameterError
from ..filter_registry import FILTERS
from ._common import Outputs, alpha_arg, check_record_path, nonnegative_int_arg, positive_int_arg


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec estimate`` and its options to the subcommand parsers ``sub``."""
    p = sub.add_parser(
        "estimate",
        help="compare state estimators (KF/EKF, SVSF, 2nd-order SVSF) on Monte Carlo runs",
        description="Runs every filter on the same simulated measurements of an estimator scenario "
        "(detc-normal, detc-uncertain, eha4-leak-timeline, ...) with the tuning the scenario carries, and "
        "prints per state and filter the RMSE, bias and STD of the estimation error (DETC2015 eq 28-30) "
        "with Monte Carlo standard errors, and the NEES / NIS chi-squared consistency. Filters: "
        + "; ".join(f"{k} = {v}" for k, v in FILTERS.items()),
    )
    p.add_argument("name", metavar="NAME", help="scenario with filter settings (see `chatterspec scenarios`)")
    p.add_argument(
        "--filters",
        default="kf,svsf,svsf2",
        help=f"comma-separated filters from {','.join(FILTERS)} (default kf,svsf,svsf2)",
    )
    p.add_argument(
        "--runs", type=positive_int_arg, default=100, help="Monte Carlo realizations (default 100)"
    )
    p.add_argument("--seed", type=nonnegative_int_arg, default=0, help="root seed (default 0)")
    p.add_argument("--workers", type=positive_int_arg, default=1, help="local worker processes (default 1)")
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on Dask: 'local-dask' or a scheduler address (needs chatterspec[distributed])",
    )
    p.add_argument(
        "--chunk-runs", type=positive_int_arg, default=None, help="realizations per chunk (multiple of 64)"
    )
    p.add_argument(
        "--alpha",
        type=alpha_arg,
        default=0.05,
        help="two-sided level of the NEES/NIS intervals (default 0.05)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument(
        "--record",
        metavar="FILE.rrd",
        help="also write a Rerun recording of realization 0: truth, estimates and innovations per filter",
    )
    p.set_defaults(func=run)


def _check_output(path: str | None) -> None:
    """Fail before any computation if the recording cannot be written."""
    check_record_path(path)
    if path is None:
        return
    target = Path(path)
    if target.is_dir():
        raise ParameterError(f"--record {path!r} is a directory; give a file name ending in .rrd")
    parent = target.parent if str(target.parent) else Path(".")
    if parent.exists() and not parent.is_dir():
        raise ParameterError(f"--record: {str(parent)!r} is not a directory")
    existed = target.exists()
    try:
        parent.mkdir(parents=True, exist_ok=True)
        with open(target, "ab"):
            pass
    except OSError as exc:
        raise ParameterError(f"--record: cannot write {path!r}: {exc.strerror or exc}") from None
    if not existed:
        target.unlink()


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec estimate`` with the parsed ``args``; returns the exit status."""
    from ..studies.estimation import estimation_study, parse_filters

    names = parse_filters(args.filters)
    _check_output(args.record)
    res = estimation_study(
        args.name,
        names,
        runs=args.runs,
        seed=args.seed,
        alpha=args.alpha,
        workers=args.workers,
        scheduler=args.scheduler,
        chunk_runs=args.chunk_runs,
        progress=False if args.no_progress else None,
    )
    doc = res.to_dict()
    outputs = Outputs()  # a recording that cannot be written: the table first, then one line, exit 2
    if args.record:
        from ..studies.estimation import estimate_records
        from ..viewer.estimates_log import record_estimates

        recs = estimate_records(args.name, names, runs=1, seed=args.seed)
        saved = outputs.write("--record", args.record, record_estimates, recs, args.record)
        doc["recording"] = None if saved is None else str(saved)
    if args.json:
        from ._common import print_json

        print_json(doc)
        outputs.finish()
        return 0
    print(res.table())
    if args.record and doc["recording"] is not None:
        print(f"recording (realization 0): {doc['recording']}")
    outputs.finish()
    return 0
