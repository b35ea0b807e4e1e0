"""Closed-loop simulation throughput against the open-loop simulation, in the same run.

``simulate(eha-cl-healthy)`` (the linear EHA under its PI loop: the simulation loop with the
controller as its input step) against ``simulate(eha-healthy)`` (the same loop with the input
table), both compiled, alternating one repetition of each so that a change of load on a shared
machine hits both; rates in realization-steps per CPU second of this process
(``time.process_time``) and per wall second. Also the numpy path of the closed loop
(``CHATTERSPEC_JIT=0``: the same steps on rows of realizations) and the chattering of the
closed loop (simulate + auxiliary SVSF, the per-run input path) against the open loop's fused
kernel, and the nonlinear EHA's closed loop (numpy path). Last, the stream that ``chatterspec simulate
NAME --rate 0`` writes (one realization, state carried block to block, with its CSV text), closed
against open loop, in times real time per CPU second (best of ``--repeat``, alternating).

Run: ``python benchmarks/bench_closed_loop.py [--runs 512] [--repeat 5]``.
Target: the closed-loop simulation within 2x the open-loop simulation's rate (compiled).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

import chatterspec as cs
from chatterspec.detection.pipeline import iter_chattering
from chatterspec.online.simulated_stream import csv_lines, simulate_blocks
from chatterspec.plants.simulate import simulate


def _rate(fn, steps: int) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    c0, w0 = time.process_time(), time.perf_counter()
    fn()
    return steps / (time.process_time() - c0), steps / (time.perf_counter() - w0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=512)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    closed, opened = cs.scenario("eha-cl-healthy"), cs.scenario("eha-healthy")
    steps = args.runs * closed.n_samples
    simulate(closed, 64, 0), simulate(opened, 64, 0)  # compile / load the kernels
    out: dict[str, list[tuple[float, float]]] = {}
    cases = {
        "simulate, closed loop": lambda: simulate(closed, args.runs, 1),
        "simulate, open loop": lambda: simulate(opened, args.runs, 1),
        "chattering, closed loop (simulate + aux SVSF)": lambda: list(iter_chattering(closed, args.runs, 1)),
        "chattering, open loop (fused kernel)": lambda: list(iter_chattering(opened, args.runs, 1)),
    }
    for _ in range(args.repeat):
        for name, fn in cases.items():
            out.setdefault(name, []).append(_rate(fn, steps))
    stream: dict[str, float] = {}
    for _ in range(args.repeat):
        for sc in (closed, opened):
            c0 = time.process_time()
            for t, z, u in simulate_blocks(sc, 0, 120.0):
                csv_lines(t, z, u)
            stream[sc.name] = max(stream.get(sc.name, 0.0), 120.0 / (time.process_time() - c0))
    os.environ["CHATTERSPEC_JIT"] = "0"
    numpy_rate = [_rate(lambda: simulate(closed, 128, 1), 128 * closed.n_samples) for _ in range(2)]
    nonlinear = cs.scenario("eha4-cl-healthy")
    nl_rate = [_rate(lambda: simulate(nonlinear, 128, 1), 128 * nonlinear.n_samples) for _ in range(2)]
    os.environ["CHATTERSPEC_JIT"] = "1"
    print(f"{args.runs} realizations x {closed.n_samples} steps, {args.repeat} alternating repetitions")
    print(f"{'case':<48} {'M/CPU-s (median, range)':>26} {'M/wall-s (median)':>18}")
    for name, rates in out.items():
        cpu = np.array([r[0] for r in rates]) / 1e6
        wall = np.array([r[1] for r in rates]) / 1e6
        print(f"{name:<48} {np.median(cpu):>8.2f} ({cpu.min():.2f}-{cpu.max():.2f}) {np.median(wall):>18.2f}")
    cl = np.median([r[0] for r in out["simulate, closed loop"]])
    ol = np.median([r[0] for r in out["simulate, open loop"]])
    print(f"open-loop / closed-loop simulation rate (CPU time, medians): {ol / cl:.2f} (target <= 2)")
    print(f"closed loop, numpy path (128 runs): {max(r[0] for r in numpy_rate) / 1e6:.2f} M/CPU-s")
    print(f"nonlinear EHA closed loop, numpy path (128 runs): {max(r[0] for r in nl_rate) / 1e6:.2f} M/CPU-s")
    print(
        f"stream with its CSV text (simulate --rate 0), 120 s: {closed.name} {stream[closed.name]:.0f}x, "
        f"{opened.name} {stream[opened.name]:.0f}x real time per CPU second (target >= 200x)"
    )


if __name__ == "__main__":
    main()
