"""Benchmark: a healthy EHA false-alarm study at Monte Carlo scale (default 10^5 runs on 2 workers).

Reports wall time, peak memory (``ru_maxrss`` of this process and, separately,
of its largest worker; workers run in their own processes) and runs per second.
Memory is constant in the number of runs: each chunk returns count arrays only.

Usage::

    python benchmarks/bench_far.py --runs 100000 --workers 2
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100_000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--scenario", default="eha-healthy")
    p.add_argument("--alpha", type=float, nargs="+", default=[1e-2, 1e-3])
    p.add_argument("--chunk-runs", type=int, default=256)
    p.add_argument("--scheduler", default=None)
    p.add_argument("--no-frames", action="store_true")
    args = p.parse_args(argv)

    from chatterspec.studies.detection_rates import false_alarm_study

    t0 = time.perf_counter()
    res = false_alarm_study(
        args.scenario,
        alpha=args.alpha,
        runs=args.runs,
        seed=20240501,
        frames=not args.no_frames,
        workers=args.workers,
        scheduler=args.scheduler,
        chunk_runs=args.chunk_runs,
        progress=True,
    )
    wall = time.perf_counter() - t0
    kib = 1024 if sys.platform != "darwin" else 1
    self_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * kib / 2**20
    child_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * kib / 2**20
    summary = {
        "scenario": args.scenario,
        "runs": args.runs,
        "workers": args.workers,
        "scheduler": args.scheduler,
        "wall_s": round(wall, 2),
        "runs_per_s": round(args.runs / wall, 1),
        "peak_rss_main_mb": round(self_mb, 1),
        "peak_rss_largest_worker_mb": round(child_mb, 1),
        "rates": {
            f"{r.kind}@{r.alpha:g}": {
                "per_bin": [r.per_bin.rate, r.per_bin.ci_low, r.per_bin.ci_high],
                "family_wise_or_per_frame_worst_channel": max(
                    ([e.rate, e.ci_low, e.ci_high] for e in (r.family_wise or r.per_frame)),
                    key=lambda v: v[0],
                ),
                "verdict": r.verdict,
            }
            for r in res.rates
        },
    }
    print(json.dumps(summary, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
