"""Benchmark: ``chatterspec diagnose NAME --false-alarms-per-hour X --runs N`` (every route), by stage.

Runs the command's study in one process and prints, per route, the seconds of each stage (the route's
scores on the healthy calibration streams, the alarm layer's calibration, the starts at every threshold
of the delay-against-false-alarms curve, the scores of the diagnosed runs, the rule at every threshold
on them) and the realization-samples per second of its scores, then the comparison itself: the threshold
at the budget, the realized false alarms and their Poisson interval, the delay per onset. With
``--per-record`` it times the former table instead (each route's own rule).

Usage::

    python benchmarks/bench_diagnose.py [NAME] [--budget 1] [--rule cusum] [--runs 100] [--seed 0]
        [--calibration-runs 1000] [--onset S] [--workers 1] [--json]
"""

from __future__ import annotations

import argparse
import json
import resource
import time

import chatterspec as cs


def _routes(sc: object, alpha: float, calibration_runs: int) -> dict:
    from chatterspec.detection.spectral import STFTConfig
    from chatterspec.detection.thresholds import frame_threshold
    from chatterspec.studies.budget_diagnosis import (
        ChatteringRoute,
        InnovationRoute,
        ModeRoute,
        supported_methods,
    )
    from chatterspec.studies.diagnosis import calibrate_for_diagnosis

    routes = {}
    for m in supported_methods(sc):
        if m == "chattering":
            if sc.is_linear:  # type: ignore[attr-defined]
                model, cfg = sc.nominal, STFTConfig()  # type: ignore[attr-defined]
                law = frame_threshold(model, cfg.freqs_hz(model.dt), cfg, model.dt, alpha)
            else:
                law = calibrate_for_diagnosis(sc, 0, runs=calibration_runs, alpha=alpha)  # type: ignore[arg-type]
                law = law.threshold("frame-family-wise")
            routes[m] = ChatteringRoute(sc, law)
        elif m == "innovation":
            routes[m] = InnovationRoute(sc)
        else:
            routes[m] = ModeRoute(sc, m)
    return routes


def main() -> None:
    from chatterspec.studies.budget_diagnosis import BudgetSettings, diagnose_at_budget

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("name", nargs="?", default="eha4-leak-timeline")
    p.add_argument("--budget", type=float, default=1.0, help="false alarms per hour")
    p.add_argument("--rule", default="cusum")
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--calibration-runs", type=int, default=1000)
    p.add_argument("--onset", type=float, default=None)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    sc = cs.scenario(args.name)
    if args.onset is not None:
        from chatterspec.studies.diagnosis import with_onset

        sc = with_onset(sc, args.onset)
    t0 = time.perf_counter()
    c0 = time.process_time()
    routes = _routes(sc, 1e-3, args.calibration_runs)  # as the CLI: the normalization on the same runs
    setup_s = time.perf_counter() - t0
    settings = BudgetSettings(args.budget, args.rule, calibration_runs=args.calibration_runs)
    res = diagnose_at_budget(sc, routes, args.runs, args.seed, settings, workers=args.workers, progress=False)
    out = {
        "scenario": sc.name,  # type: ignore[attr-defined]
        "runs": args.runs,
        "calibration_runs": args.calibration_runs,
        "budget_per_hour": args.budget,
        "rule": args.rule,
        "setup_s (chattering law)": setup_s,
        "wall_s": time.perf_counter() - t0,
        "cpu_s (this process)": time.process_time() - c0,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "routes": {
            r.method: {
                **{k: round(v, 2) for k, v in r.timings.items()},
                "steps_per_s": r.steps_per_second,
                "threshold": r.rule.get("threshold"),
                "calibration": r.calibration.get("method"),
                "false_alarms": f"{r.false_alarms} in {r.healthy_hours:.3g} h",
                "rate_ci99": [round(v, 3) for v in r.rate_ci],
                "delay_median_s": [o.delay_median_s for o in r.onsets],
                "delay_p90_s": [o.delay_p90_s for o in r.onsets],
                "missed": [o.missed for o in r.onsets],
            }
            for r in res
        },
    }
    if args.json:
        print(json.dumps(out, indent=2, default=str))
        return
    for k, v in out.items():
        if k != "routes":
            print(f"{k:>26}: {v:.4g}" if isinstance(v, float) else f"{k:>26}: {v}")
    for m, d in out["routes"].items():
        print(f"{m}:")
        for k, v in d.items():
            print(f"{k:>26}: {v:.4g}" if isinstance(v, float) else f"{k:>26}: {v}")


if __name__ == "__main__":
    main()
