"""Benchmark: estimator throughput on the DETC2015 EHA and the ``chatterspec estimate`` wall time.

Measures, in realization-steps per second (one realization advanced by one sample = one step):

* the batched Kalman filter (:class:`chatterspec.filters.kalman.KalmanFilter`: shared,
  data-independent covariance and gain, per-realization state recursion) at 10^4 realizations;
* filterpy's ``KalmanFilter`` predict/update loop on one realization, in the same run (same model,
  same data; the two estimates are checked equal before timing);
* one stream: the Kalman filter on one realization of 10^5 samples (the 100 realizations of the
  first rows put end to end), beside filterpy's loop on the same stream (issue: >= 5 M steps/s);
* a small batch: the Kalman filter on 2 runs x 10^5 samples, ``P0`` shared (one covariance sequence,
  compiled) against ``P0`` per run, CPU time, alternating;
* the SVSF with covariance and the dynamic second-order SVSF (per-run Joseph covariances) at 10^4;
* the wall time of ``chatterspec estimate detc-uncertain --runs 1000`` (subprocess, default filters).

Targets: KF >= 10 M/s and >= 300x filterpy; SVSF-cov and 2nd-order SVSF >= 2 M/s; estimate
< 10 s on 2 cores. Not a timed test: numbers depend on the machine and its load.

Usage::

    python benchmarks/bench_estimators.py            # 10^4 realizations x 1000 steps (~1 min)
    python benchmarks/bench_estimators.py --quick    # 10^3 realizations, no CLI timing
    python benchmarks/bench_estimators.py --json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

from chatterspec.plants.scenarios import scenario
from chatterspec.plants.simulate import simulate
from chatterspec.studies.estimation import build_filter

#: CPU seconds of each best_of call's fastest repeat (wall time is what is reported; CPU time shows the
#: share of the wall time the process actually ran on a loaded machine).
CPU: list[float] = []


def best_of(fn, repeat: int) -> float:
    best, cpu = np.inf, np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = time.perf_counter() - t0
        if wall < best:
            best, cpu = wall, time.process_time() - c0
    CPU.append(cpu)
    return best


def filterpy_loop(model, z, u, x0, P0):
    """filterpy's KalmanFilter predict/update over one realization; returns the posteriors (T, n)."""
    from filterpy.kalman import KalmanFilter as FPKalman

    n, m = model.n_states, model.n_outputs
    kf = FPKalman(dim_x=n, dim_z=m, dim_u=model.n_inputs)
    kf.F, kf.B, kf.H, kf.Q, kf.R = model.A, model.B, model.C, model.Q, model.R
    kf.x, kf.P = x0.copy(), P0.copy()
    out = np.empty((z.shape[0], n))
    for k in range(z.shape[0]):
        kf.predict(u=u[k])
        kf.update(z[k])
        out[k] = kf.x
    return out


def main() -> None:
    p = argparse.ArgumentParser(description="estimator throughput")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    runs = 1000 if args.quick else 10_000
    sc = scenario("detc-uncertain")
    fs = sc.filter_settings
    sim = simulate(sc, runs=runs, seed=0)
    z = np.ascontiguousarray(sim.z[:, 1:])
    u = sim.u[:-1]
    T = z.shape[1]
    steps = runs * T
    res: dict[str, object] = {"cores": os.cpu_count(), "realizations": runs, "steps_per_run": T}

    kf = build_filter("kf", sc)
    # equal to filterpy on realization 0 (filterpy uses x P x^T + Q and the plain update; the Joseph
    # form differs by rounding only)
    ref = filterpy_loop(kf.model, z[0], u, fs.x0, fs.P0)
    ours = kf.run(z[:1], u, x0=fs.x0, P0=fs.P0, store={"x_post"}).x_post[0]
    res["max_abs_diff_vs_filterpy"] = float(np.max(np.abs(ref - ours)))
    assert res["max_abs_diff_vs_filterpy"] < 1e-6 * max(1.0, float(np.max(np.abs(ref))))
    kf.run(z[:2], u, x0=fs.x0, P0=fs.P0, store={"x_post"})  # compile / warm up
    t_kf = best_of(lambda: kf.run(z, u, x0=fs.x0, P0=fs.P0, store={"x_post"}), 3)
    t_fp = best_of(lambda: filterpy_loop(kf.model, z[0], u, fs.x0, fs.P0), 3)
    res["kf_Msteps_per_s"] = steps / t_kf / 1e6
    res["kf_Msteps_per_cpu_s"] = steps / CPU[-2] / 1e6
    res["filterpy_ksteps_per_s"] = T / t_fp / 1e3
    res["kf_speedup_vs_filterpy"] = (steps / t_kf) / (T / t_fp)

    # one stream of 10^5 samples: realizations 0..99 end to end (the filter does not know)
    zs = np.ascontiguousarray(z[:100].reshape(1, -1, z.shape[2]))
    us = np.tile(u, (100, 1))
    one = kf.run(zs, us, x0=fs.x0, P0=fs.P0, store={"x_post"}).x_post[0]
    ref1 = filterpy_loop(kf.model, zs[0, :2000], us[:2000], fs.x0, fs.P0)
    res["stream_max_abs_diff_vs_filterpy"] = float(np.max(np.abs(ref1 - one[:2000])))
    t_one = best_of(lambda: kf.run(zs, us, x0=fs.x0, P0=fs.P0, store={"x_post"}), 3)
    t_fp1 = best_of(lambda: filterpy_loop(kf.model, zs[0, :20000], us[:20000], fs.x0, fs.P0), 1) * 5
    res["kf_stream_Msteps_per_s"] = zs.shape[1] / t_one / 1e6
    res["filterpy_stream_ksteps_per_s"] = zs.shape[1] / t_fp1 / 1e3

    # a small batch: 2 runs x 10^5 samples, P0 shared (one covariance sequence) against P0 per run,
    # alternating, CPU time (the shared path took a numpy loop over samples before)
    z2 = np.ascontiguousarray(np.tile(z[:2], (1, 100, 1))[:, :100_000])
    u2 = np.tile(u, (100, 1))[:100_000]
    P0_runs = np.broadcast_to(fs.P0, (2, *np.shape(fs.P0)))
    kf.run(z2[:, :10], u2[:10], x0=fs.x0, P0=fs.P0)
    kf.run(z2[:, :10], u2[:10], x0=fs.x0, P0=P0_runs)
    cpu_shared, cpu_runs = np.inf, np.inf
    for _ in range(3):
        c0 = time.process_time()
        kf.run(z2, u2, x0=fs.x0, P0=fs.P0, store={"x_post"})
        c1 = time.process_time()
        kf.run(z2, u2, x0=fs.x0, P0=P0_runs, store={"x_post"})
        c2 = time.process_time()
        cpu_shared, cpu_runs = min(cpu_shared, c1 - c0), min(cpu_runs, c2 - c1)
    res["kf_2x1e5_shared_P0_cpu_s"] = cpu_shared
    res["kf_2x1e5_per_run_P0_cpu_s"] = cpu_runs

    for name in ("svsf", "svsf2"):
        f = build_filter(name, sc)
        f.run(z[:2], u, x0=fs.x0, P0=fs.P0, store={"x_post"})
        t = best_of(lambda f=f: f.run(z, u, x0=fs.x0, P0=fs.P0, store={"x_post"}), 2)
        res[f"{name}_Msteps_per_s"] = steps / t / 1e6
        res[f"{name}_Msteps_per_cpu_s"] = steps / CPU[-1] / 1e6

    if not args.quick:
        cmd = [sys.executable, "-m", "chatterspec", "estimate", "detc-uncertain", "--runs", "1000", "--json"]
        cmd += ["--no-progress"]
        subprocess.run(cmd, check=True, capture_output=True)  # warm the compile cache
        import resource

        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        res["estimate_detc_uncertain_1000_runs_s"] = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        res["estimate_cpu_s"] = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    try:
        res["load_average_1min"] = os.getloadavg()[0]
    except OSError:  # pragma: no cover
        pass

    if args.json:
        print(json.dumps(res, indent=2))
        return
    print(f"cores: {res['cores']}, load average (1 min): {res.get('load_average_1min', float('nan')):.1f}")
    print(f"DETC2015 EHA, {runs} realizations x {T} steps")
    print(
        f"  batched KF         {res['kf_Msteps_per_s']:8.1f} M realization-steps/s "
        f"({res['kf_speedup_vs_filterpy']:.0f}x filterpy; target >= 10 M/s and >= 300x); "
        f"{res['kf_Msteps_per_cpu_s']:.1f} M per CPU-second"
    )
    print(f"  filterpy KF loop   {res['filterpy_ksteps_per_s']:8.1f} k steps/s (one realization)")
    print(
        f"  KF, one stream of 10^5 samples {res['kf_stream_Msteps_per_s']:6.2f} M steps/s (target >= 5 M/s); "
        f"filterpy on the same stream {res['filterpy_stream_ksteps_per_s']:.1f} k steps/s "
        f"(max |x - x_filterpy| {res['stream_max_abs_diff_vs_filterpy']:.1e})"
    )
    print(
        f"  KF, 2 runs x 10^5 samples: shared P0 {res['kf_2x1e5_shared_P0_cpu_s']:.3f} s CPU, P0 per run "
        f"{res['kf_2x1e5_per_run_P0_cpu_s']:.3f} s (target: within 2x)"
    )
    print(
        f"  SVSF with cov      {res['svsf_Msteps_per_s']:8.2f} M realization-steps/s (target >= 2 M/s); "
        f"{res['svsf_Msteps_per_cpu_s']:.2f} M per CPU-second"
    )
    print(
        f"  2nd-order SVSF     {res['svsf2_Msteps_per_s']:8.2f} M realization-steps/s (target >= 2 M/s); "
        f"{res['svsf2_Msteps_per_cpu_s']:.2f} M per CPU-second"
    )
    if "estimate_detc_uncertain_1000_runs_s" in res:
        print(
            f"  chatterspec estimate detc-uncertain --runs 1000: "
            f"{res['estimate_detc_uncertain_1000_runs_s']:.1f} s wall, {res['estimate_cpu_s']:.1f} s CPU "
            "(target < 10 s)"
        )
    print(f"  (KF max |x - x_filterpy| on realization 0: {res['max_abs_diff_vs_filterpy']:.2e})")


if __name__ == "__main__":
    main()
