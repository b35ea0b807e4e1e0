"""Benchmark: ``chatterspec diagnose eha4-leak-timeline --runs N`` (all supported methods), split by stage.

Times, in one process, the stages the command runs: the chattering threshold's in-call calibration (healthy
runs of the 9 s healthy version, plus the pilot runs of the empirical normalization), the simulation of the
diagnosed runs, the chattering route (auxiliary SVSF + STFT + verdicts) and the SMM-SVSF, and the total.
Target: 100 runs, all methods, under 60 s on 2 cores.

Usage::

    python benchmarks/bench_diagnose.py [--runs 100] [--seed 0] [--calibration-runs 500] [--json]
"""

from __future__ import annotations

import argparse
import json
import time

import chatterspec as cs
from chatterspec.studies.chattering_diagnosis import calibrate_for_diagnosis, diagnose_chattering
from chatterspec.studies.mode_diagnosis import diagnose_modes


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=100)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--calibration-runs", type=int, default=500)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    sc = cs.scenario("eha4-leak-timeline")
    t = {}
    t0 = time.perf_counter()
    cal = calibrate_for_diagnosis(sc, args.seed, runs=args.calibration_runs)
    t["calibration_s"] = time.perf_counter() - t0
    t1 = time.perf_counter()
    sim = cs.simulate(sc, runs=args.runs, seed=args.seed)
    t["simulation_s"] = time.perf_counter() - t1
    t2 = time.perf_counter()
    chat = diagnose_chattering(sim, cal.threshold("frame-family-wise"))
    t["chattering_s"] = time.perf_counter() - t2
    t3 = time.perf_counter()
    (smm,) = diagnose_modes(sim, ("smm",))
    t["smm_s"] = time.perf_counter() - t3
    t["total_s"] = time.perf_counter() - t0
    out = {
        "runs": args.runs,
        "steps": sim.z.shape[1],
        **t,
        "chattering_steps_per_s": chat.steps_per_second,
        "smm_steps_per_s": smm.steps_per_second,
    }
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        for k, v in out.items():
            print(f"{k:>24}: {v:.4g}" if isinstance(v, float) else f"{k:>24}: {v}")


if __name__ == "__main__":
    main()
