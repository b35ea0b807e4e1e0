"""Benchmark: auxiliary-SVSF throughput (realization-steps per second) on the linear EHA.

Times only the filter update (:meth:`chatterspec.SVSF.update`, the single kernel used
for batch and online filtering) on measurements produced by :func:`chatterspec.plants.simulate`
(already time-major in memory), for 1, 100 and 10^4 realizations x 4000 steps, beside a
straightforward per-step loop over one realization (plain numpy on 1-D arrays, eq 4-12
written literally). Also tries splitting the realization axis over a 2-thread
``ThreadPoolExecutor`` (numpy releases the GIL inside ufuncs/matmul).

The "recursion" columns force ``closed_form=False``: with numba installed that is the
compiled kernel of :mod:`chatterspec._jit` (``CHATTERSPEC_JIT=0`` selects the numpy loop);
``benchmarks/bench_kernels.py`` compares the two paths directly.

Targets: >= 15 M realization-steps/s at 10^4 realizations and >= 300x the loop.

Usage::

    python benchmarks/bench_svsf.py            # full: 1, 100, 10000 realizations x 4000 steps
    python benchmarks/bench_svsf.py --quick    # 1, 100, 1000 realizations x 1000 steps
"""

from __future__ import annotations

import argparse
import json
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from chatterspec import SVSF, Scenario, scenario, simulate


def naive_svsf(A, B, C, z, u, gamma=0.1):
    """The obvious per-step SVSF (sgn switching) on one realization: eq 4-12 literally.

    ``z`` is (T, m), ``u`` is (T, p); returns the chattering e(k|k-1), (T-1, m).
    """
    Cinv = np.linalg.inv(C)
    x = Cinv @ z[0]
    e_post = z[0] - C @ x
    out = np.empty((z.shape[0] - 1, C.shape[0]))
    for k in range(z.shape[0] - 1):
        x_prior = A @ x + B @ u[k]  # eq 4
        z_prior = C @ x_prior  # eq 5
        e_prior = z[k + 1] - z_prior  # eq 6
        K = Cinv @ ((np.abs(e_prior) + gamma * np.abs(e_post)) * np.sign(e_prior))  # eq 8 (sgn)
        x = x_prior + K  # eq 12
        e_post = z[k + 1] - C @ x  # eq 7
        out[k] = e_prior
    return out


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="smaller sizes (CI smoke run)")
    p.add_argument("--json", action="store_true", help="print one JSON document instead of a table")
    args = p.parse_args(argv)
    steps = 1000 if args.quick else 4000
    sizes = (1, 100, 1000) if args.quick else (1, 100, 10_000)
    base = scenario("eha-healthy")
    sc = Scenario("bench", base.nominal, base.input, steps * base.dt)
    model = sc.nominal
    filt = SVSF(model, switching="sgn")

    # the obvious loop, one realization
    sim1 = simulate(sc, 1, seed=0)
    A, B, C = np.array(model.A), np.array(model.B), np.array(model.C)
    z1, u1 = np.ascontiguousarray(sim1.z[0]), np.ascontiguousarray(sim1.u)
    naive_s = best_of(lambda: naive_svsf(A, B, C, z1, u1), 3)
    naive_rate = steps / naive_s
    ref = naive_svsf(A, B, C, z1, u1)
    got = filt.run(sim1.z, sim1.u).e_prior[0, 1:]
    assert np.allclose(got, ref, rtol=1e-9, atol=1e-12 * np.abs(ref).max()), "kernel != naive loop"

    rows = []
    for runs in sizes:
        sim = simulate(sc, runs, seed=1)
        z, u = sim.z[:, 1:], sim.u[:-1]

        def one(z=z, u=u, sim=sim):
            filt.update(filt.initialize(sim.z[:, 0]), z, u, check=False)

        secs = best_of(one, 3 if runs * steps <= 4e6 else 2)
        rate = runs * steps / secs

        def rec(z=z, u=u, sim=sim):  # the sample-by-sample recursion (used for sat / non-zero e(k|k))
            filt.update(filt.initialize(sim.z[:, 0]), z, u, check=False, closed_form=False)

        rec_rate = runs * steps / best_of(rec, 3 if runs * steps <= 4e6 else 2)
        row = {
            "runs": runs,
            "steps": steps,
            "seconds": secs,
            "rs_per_s": rate,
            "x_loop": rate / naive_rate,
            "recursion_rs_per_s": rec_rate,
            "recursion_x_loop": rec_rate / naive_rate,
        }
        if runs >= 100:
            half = runs // 2
            parts = [(sim.z[:half], z[:half]), (sim.z[half:], z[half:])]

            def two(parts=parts, u=u):
                with ThreadPoolExecutor(2) as ex:
                    list(
                        ex.map(
                            lambda pz: filt.update(filt.initialize(pz[0][:, 0]), pz[1], u, check=False), parts
                        )
                    )

            secs2 = best_of(two, 2)
            row["threads2_rs_per_s"] = runs * steps / secs2
            row["threads2_speedup"] = secs / secs2
        rows.append(row)
        del sim, z

    result = {"naive_loop_rs_per_s": naive_rate, "sizes": rows}
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f"naive per-step loop (1 realization): {naive_rate:,.0f} realization-steps/s")
    print("default = eq 23 closed-form path of SVSF.update; recursion = closed_form=False")
    print(
        f"{'runs':>7} {'steps':>6} {'seconds':>9} {'r-steps/s':>14} {'x loop':>8} "
        f"{'recursion':>14} {'x loop':>8} {'2 threads':>14} {'speedup':>8}"
    )
    for r in rows:
        t2 = (
            f"{r['threads2_rs_per_s']:14,.0f} {r['threads2_speedup']:7.2f}x"
            if "threads2_rs_per_s" in r
            else ""
        )
        print(
            f"{r['runs']:>7} {r['steps']:>6} {r['seconds']:9.4f} {r['rs_per_s']:14,.0f} "
            f"{r['x_loop']:7.0f}x {r['recursion_rs_per_s']:14,.0f} {r['recursion_x_loop']:7.0f}x {t2}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
