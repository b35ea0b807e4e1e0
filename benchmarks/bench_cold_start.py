"""Benchmark: the first call after a fresh install (empty numba cache) and after it (cache filled).

Each case runs in a fresh Python process twice: **cold** with ``NUMBA_CACHE_DIR`` pointing at a new
empty folder (what the first use after ``pip install`` pays: numba compiles every kernel the call
reaches and writes its cache; the Python bytecode is there, as pip compiles it at install), then
**warm** with the same folder (numba loads the machine code from its cache).
Times are the child's CPU time (user + system, all threads, ``getrusage``) and its wall time, best of
``--repeat`` (each repeat with new empty folders for the cold run). The cases:

* ``kf``: ``KalmanFilter.run`` on 4 runs x 1000 samples (shared P0: the compiled covariance sequence and
  state loop);
* ``kf-online``: ``KalmanFilter.online(...).step`` on 1000 samples;
* ``svsf``: ``SVSF.update`` (sat) on one 1000-sample stream;
* ``svsf-cov``: ``SVSFCov.run`` on 16 runs x 1000 samples storing no log-likelihood (so the covariance
  loop that advances 8 runs at once, as the estimation studies run it: the most inlined steps here);
* ``monitor``: ``ChatteringMonitor.push`` of 2 s of the EHA's 1 kHz data, then 1000 ``step`` calls;
* ``import``: ``import chatterspec`` only (the floor every case pays).

Usage::

    python benchmarks/bench_cold_start.py [--repeat 3] [--cases kf,monitor] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

CASES = {
    "import": "import chatterspec",
    "kf": (
        "import numpy as np, chatterspec as cs\n"
        "m = cs.eha_linear(); kf = cs.KalmanFilter(m)\n"
        "z = np.random.default_rng(0).normal(size=(4, 1000, m.n_outputs))\n"
        "kf.run(z, np.zeros((1000, 1)), x0=np.zeros(3), P0=np.eye(3))\n"
    ),
    "kf-online": (
        "import numpy as np, chatterspec as cs\n"
        "m = cs.eha_linear(); f = cs.KalmanFilter(m).online(np.zeros(3), np.eye(3))\n"
        "z = np.random.default_rng(0).normal(size=(1000, m.n_outputs)); u = np.zeros(1)\n"
        "for k in range(1000): f.step(z[k], u)\n"
    ),
    "svsf": (
        "import numpy as np, chatterspec as cs\n"
        "m = cs.eha_linear(); f = cs.SVSF(m, psi=np.array([4.2e-3, 4.8e-3, 4.3e3]))\n"
        "z = np.random.default_rng(0).normal(size=(1, 1001, 3))\n"
        "f.run(z, np.zeros((1001, 1)))\n"
    ),
    "svsf-cov": (
        "import numpy as np, chatterspec as cs\n"
        "m = cs.eha_linear(); f = cs.SVSFCov(m, psi=np.array([4.2e-3, 4.8e-3, 4.3e3]))\n"
        "z = np.random.default_rng(0).normal(size=(16, 1000, 3))\n"
        "f.run(z, np.zeros((1000, 1)), x0=np.zeros(3), P0=np.eye(3), store=('x_post', 'innovation'))\n"
    ),
    "monitor": (
        "import chatterspec as cs\n"
        "from chatterspec.online.monitor import ChatteringMonitor\n"
        "sim = cs.simulate(cs.scenario('eha-leak-major'), runs=1, seed=1)\n"
        "mon = ChatteringMonitor(sim.scenario.nominal)\n"
        "mon.push(sim.z[0, :2000], sim.u[:2000])\n"
        "for k in range(2000, 3000): mon.step(sim.z[0, k], sim.u[k])\n"
    ),
}


def run(code: str, cache: str) -> tuple[float, float]:
    """CPU and wall seconds of ``python -c code`` with numba's cache in the folder ``cache``."""
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], check=True, env=env)
    wall = time.perf_counter() - t0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime), wall


def main() -> None:
    p = argparse.ArgumentParser(description="first calls, cold and warm numba cache")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    res: dict[str, dict[str, float]] = {}
    for name in args.cases.split(","):
        code = CASES[name.strip()]
        best = {"cold_cpu_s": float("inf"), "cold_wall_s": float("inf"), "warm_cpu_s": float("inf"),
                "warm_wall_s": float("inf")}  # fmt: skip
        for _ in range(args.repeat):
            with tempfile.TemporaryDirectory(prefix="chatterspec-cold-") as cache:
                cpu, wall = run(code, cache)
                best["cold_cpu_s"] = min(best["cold_cpu_s"], cpu)
                best["cold_wall_s"] = min(best["cold_wall_s"], wall)
                cpu, wall = run(code, cache)
                best["warm_cpu_s"] = min(best["warm_cpu_s"], cpu)
                best["warm_wall_s"] = min(best["warm_wall_s"], wall)
        res[name] = best
    out = {"cases": res, "load_average_1min": os.getloadavg()[0], "repeat": args.repeat}
    if args.json:
        print(json.dumps(out, indent=2))
        return
    print(f"best of {args.repeat}; load average {out['load_average_1min']:.1f}")
    print(f"{'case':<10} {'cold CPU s':>10} {'cold wall s':>11} {'warm CPU s':>10} {'warm wall s':>11}")
    for name, b in res.items():
        print(
            f"{name:<10} {b['cold_cpu_s']:10.2f} {b['cold_wall_s']:11.2f} {b['warm_cpu_s']:10.2f} "
            f"{b['warm_wall_s']:11.2f}"
        )


if __name__ == "__main__":
    main()
