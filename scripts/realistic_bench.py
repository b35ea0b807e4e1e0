"""Run the realistic bench (chatterspec.online.realistic_bench) and write its JSON, table and figure.

Usage::

    python scripts/realistic_bench.py [--hours 24] [--nonlinear-hours 4] [--runs-per-phase 25]
        [--recorded-hours 4] [--routes nominal,commissioned,tolerances,commissioned-tolerances,recorded]
        [--cases exact,ar1-0.9,...] [--workers 2] [--json figures/realistic_bench.json]
        [--figure figures/realistic_bench.png]

Every case streams ``--hours`` of fresh healthy data through each route's online monitor and runs
the catalogue faults' onsets (8 chirp phases x ``--runs-per-phase``). The routes
(chatterspec.online.realistic_bench): ``nominal`` (a), the nominal model; ``commissioned`` (b), the
model ``chatterspec.commission`` fits to 10 minutes of the plant's own healthy data (a refusal is
reported with its reason); ``tolerances`` (c), the nominal model with operating tolerances decided on
the identified parameters; ``commissioned-tolerances``, the commissioned model with them;
``recorded``, the nominal model with thresholds from ``--recorded-hours`` of the
plant's recorded healthy data. Each case is written as it finishes to ``JSON.partial.jsonl``; runs made
in pieces (``--cases``, a ``--json`` each) are assembled with ``--from-partial``. The total CPU time
is printed and written to the JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from chatterspec.online.realistic_bench import ROUTES, BenchConfig, bench_cases, route_named, run_bench

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--hours", type=float, default=24.0, help="healthy hours per case (default 24)")
    p.add_argument(
        "--nonlinear-hours", type=float, default=4.0, help="healthy hours of the nonlinear plant (default 4)"
    )
    p.add_argument(
        "--runs-per-phase", type=int, default=25, help="onsets per chirp phase and fault (default 25)"
    )
    p.add_argument(
        "--recorded-hours", type=float, default=4.0, help="recorded healthy hours of the remedy route"
    )
    p.add_argument(
        "--calibration-hours", type=float, default=48.0, help="simulated hours of the alarm calibrations"
    )
    p.add_argument("--cases", default=None, help="comma-separated case names (default: all)")
    p.add_argument(
        "--routes", default=",".join(ROUTES), help=f"comma-separated routes (default {','.join(ROUTES)})"
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1, help="cases in this many processes (same numbers)")
    p.add_argument(
        "--from-partial",
        nargs="+",
        type=Path,
        default=None,
        metavar="JSONL",
        help="assemble the JSON, table and figure from the per-case files of runs made in pieces (each "
        "run's FILE.partial.jsonl, with the same options; the CPU seconds are the cases' own)",
    )
    p.add_argument("--json", type=Path, default=ROOT / "figures" / "realistic_bench.json")
    p.add_argument("--figure", type=Path, default=ROOT / "figures" / "realistic_bench.png")
    args = p.parse_args(argv)
    cfg = BenchConfig(
        hours=args.hours,
        nonlinear_hours=args.nonlinear_hours,
        runs_per_phase=args.runs_per_phase,
        recorded_hours=args.recorded_hours,
        calibration_hours=args.calibration_hours,
        seed=args.seed,
    )
    cases = bench_cases()
    if args.cases:
        names = set(args.cases.split(","))
        unknown = names - {c.name for c in cases}
        if unknown:
            p.error(f"unknown case(s) {sorted(unknown)}; known: {', '.join(c.name for c in cases)}")
        cases = tuple(c for c in cases if c.name in names)
    if args.from_partial:
        return _assemble(args, cfg, cases)
    chosen = args.routes.split(",")
    if set(chosen) - set(ROUTES):
        p.error(f"unknown route(s) {sorted(set(chosen) - set(ROUTES))}; known: {', '.join(ROUTES)}")
    if "recorded" in chosen and cfg.recorded_hours <= 0:
        p.error("the recorded route needs --recorded-hours > 0")
    routes = [route_named(r) for r in chosen]
    t0 = time.perf_counter()
    partial = args.json.with_suffix(".partial.jsonl")  # each case as it finishes (a run cut short keeps them)
    partial.parent.mkdir(parents=True, exist_ok=True)
    partial.write_text("")

    def keep(case) -> None:  # type: ignore[no-untyped-def]
        with partial.open("a") as fh:
            fh.write(json.dumps(case.to_dict(), allow_nan=False) + "\n")

    res = run_bench(routes, cases, cfg, progress=True, workers=args.workers, on_case=keep)
    partial.unlink()
    wall = time.perf_counter() - t0
    doc = res.to_dict() | {"wall_s": wall, "date": time.strftime("%Y-%m-%d")}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1, allow_nan=False))
    print(res.table())
    print(f"\nCPU {res.cpu_s:.0f} s, wall {wall:.0f} s; JSON {args.json}")
    from chatterspec.figures.plot_studies import bench_figure
    from chatterspec.figures.style import save_figure as save

    save(bench_figure(doc), args.figure)
    print(f"figure {args.figure}")
    return 0


def _assemble(args: argparse.Namespace, cfg: BenchConfig, cases: tuple) -> int:  # type: ignore[type-arg]
    """The bench document from per-case outcomes of several runs (the first of each case wins)."""
    import dataclasses

    from chatterspec.online.realistic_bench import bench_table, holds

    got: dict[str, dict] = {}
    for f in args.from_partial:
        for line in f.read_text().splitlines():
            c = json.loads(line)
            got.setdefault(c["case"], c)
    missing = [c.name for c in cases if c.name not in got]
    if missing:
        print(f"note: no outcome for {', '.join(missing)}", file=sys.stderr)
    done = [got[c.name] for c in cases if c.name in got]
    for c in done:  # RouteOutcome.holds' rule (an older version's files said True for a route not run)
        for r in c["routes"]:
            frac = r.get("alarm_fraction", 0.0)
            r["holds"] = holds(r["note"], r["starts"], r["count_interval_99"][1], frac)
    cpu = sum(r["cpu_s"] for c in done for r in c["routes"])
    doc = {"config": dataclasses.asdict(cfg), "cases": done, "cpu_s": cpu, "date": time.strftime("%Y-%m-%d")}
    args.json.write_text(json.dumps(doc, indent=1, allow_nan=False))
    print(bench_table(doc))
    print(f"\nCPU {cpu:.0f} s (the routes' own); JSON {args.json}")
    from chatterspec.figures.plot_studies import bench_figure
    from chatterspec.figures.style import save_figure as save

    save(bench_figure(doc), args.figure)
    print(f"figure {args.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
