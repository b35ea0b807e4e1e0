"""End-to-end Monte Carlo throughput.

simulate (true plant + noise) -> auxiliary SVSF -> periodogram (eq 49) ->
exact-threshold verdict, for the EHA healthy scenario, in realization-steps
per second; and STFT (1 s Hamming, 0.2 s hop) throughput in samples per second.

With numba installed, ``iter_chattering`` runs the fused simulation + auxiliary-SVSF kernel
(:mod:`chatterspec.detection.pipeline`), which draws its noise itself, run by run, through
numba's ``Generator.standard_normal`` (the same numbers as numpy's), and ``detect_spectrum``
its compiled one-pass verdict; the numpy path (``CHATTERSPEC_JIT=0``, selected in this same
process) is the baseline. The random-number bound is the rate at which the block generators
of :mod:`chatterspec.montecarlo` draw the 6 standard normals a step needs (3 process, 3
measurement), measured on one thread in two ways: numpy's ``standard_normal`` filling
``(BLOCK, T, 3)`` arrays (how the numpy path draws; the bound the targets refer to) and
numba's, one number at a time (how the fused kernel draws). Rates are given per wall second
and per CPU second of this process (``time.process_time``, all threads, user + system): on
a shared machine the second is the one to compare with the bounds. The CPU shares of the compiled
path's stages (records: simulation, auxiliary SVSF and their noise draws; periodogram; verdict) are
printed too: they bound what a faster fused kernel can gain.

Run: ``python benchmarks/bench_pipeline.py [--runs 10000] [--threads 2]``.
Targets: >= 5 M realization-steps/s at 10^4 realizations on 2 cores (numpy path); >= 10 M with
2 workers (compiled kernels).
"""

from __future__ import annotations

import argparse
import os
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import chatterspec as cs
from chatterspec import _jit
from chatterspec.detection.pipeline import iter_chattering
from chatterspec.detection.spectral import expected_spectrum, periodogram, periodogram_freqs, spectrogram
from chatterspec.detection.thresholds import exact_threshold
from chatterspec.detection.verdicts import detect_spectrum
from chatterspec.montecarlo import BLOCK, block_generator, root_seed_sequence


def healthy_case() -> tuple[cs.Scenario, int, np.ndarray, np.ndarray]:
    """EHA healthy: the scenario, its N chattering samples, exact thresholds (1e-3) and expected spectrum."""
    sc = cs.scenario("eha-healthy")
    N = sc.n_samples - 1
    f = periodogram_freqs(N, sc.dt)
    return sc, N, exact_threshold(sc.nominal, f, N, 1e-3), expected_spectrum(sc.nominal, f, N)


def end_to_end(runs: int, threads: int, chunk: int, seed: int = 0) -> tuple[float, float, int]:
    """(realization-steps per wall second, per CPU second of this process, records flagged)."""
    sc, N, th, E = healthy_case()

    def work(first: int) -> int:
        n = min(chunk, runs - first)
        detected = 0
        for rec in iter_chattering(sc, n, seed, chunk_runs=n, first_run=first):
            pg = periodogram(rec.values, rec.dt)
            det = detect_spectrum(pg.power, th, E, rec.channels)
            detected += int(det.any_channel.sum())
        return detected

    starts = list(range(0, runs, chunk))
    t0, c0 = time.perf_counter(), time.process_time()
    if threads > 1:
        with ThreadPoolExecutor(threads) as pool:
            flagged = sum(pool.map(work, starts))
    else:
        flagged = sum(map(work, starts))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return runs * N / wall, runs * N / cpu, flagged


def stage_times(runs: int, chunk: int, seed: int = 0) -> dict[str, float]:
    """CPU seconds of each stage of :func:`end_to_end` on one thread: the chunks' records (simulation and
    auxiliary SVSF, the fused kernel when compiled, its noise draws included), periodograms, verdicts."""
    sc, _, th, E = healthy_case()
    times = dict.fromkeys(("records", "periodogram", "verdict"), 0.0)
    records = iter_chattering(sc, runs, seed, chunk_runs=chunk)
    while True:
        c0 = time.process_time()
        rec = next(records, None)
        c1 = time.process_time()
        if rec is None:
            break
        pg = periodogram(rec.values, rec.dt)
        c2 = time.process_time()
        detect_spectrum(pg.power, th, E, rec.channels)
        c3 = time.process_time()
        times["records"] += c1 - c0
        times["periodogram"] += c2 - c1
        times["verdict"] += c3 - c2
    return times


def normals_rate(seconds: float = 2.0, T: int = 4001) -> float:
    """Standard normals per CPU second drawn block by block as the simulation draws them (one thread)."""
    root = root_seed_sequence(0)
    n, b, t0 = 0, 0, time.process_time()
    while time.process_time() - t0 < seconds:
        block_generator(root, b, 0).standard_normal((BLOCK, T, 3))
        block_generator(root, b, 1).standard_normal((BLOCK, T, 3))
        n += 2 * BLOCK * T * 3
        b += 1
    return n / (time.process_time() - t0)


def numba_normals_rate(seconds: float = 2.0, T: int = 4001) -> float:
    """Standard normals per CPU second drawn one at a time by numba from the block generators."""
    import numba

    @numba.njit(nogil=True)
    def draw(g: np.random.Generator, count: int) -> float:
        s = 0.0
        for _ in range(count):
            s += g.standard_normal()
        return s

    root = root_seed_sequence(0)
    draw(block_generator(root, 0, 0), 10)  # compile
    n, b, t0 = 0, 0, time.process_time()
    while time.process_time() - t0 < seconds:
        draw(block_generator(root, b, 0), BLOCK * T * 3)
        draw(block_generator(root, b, 1), BLOCK * T * 3)
        n += 2 * BLOCK * T * 3
        b += 1
    return n / (time.process_time() - t0)


def stft_throughput(n_samples: int = 4_000_000, channels: int = 3) -> float:
    rng = np.random.default_rng(0)
    x = rng.standard_normal((n_samples, channels))
    t0 = time.perf_counter()
    spectrogram(x, 1e-3)
    return n_samples / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=10_000)
    ap.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    ap.add_argument(
        "--chunk",
        type=int,
        default=512,
        help="realizations per chunk (multiple of 64; the Monte Carlo studies use 128, detect 256)",
    )
    ap.add_argument(
        "--baseline-runs", type=int, default=2048, help="realizations for the (slower) numpy-path baseline"
    )
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    print(f"cores: {os.cpu_count()}, numba: {_jit.HAVE_NUMBA}, load average at start: {load0:.2f}")
    print(f"EHA healthy, {args.runs} realizations x 4000 steps, chunks of {args.chunk}")
    paths = (("compiled (fused)", "1"), ("numpy", "0")) if _jit.HAVE_NUMBA else (("numpy", "0"),)
    one_thread = {}
    for label, flag in paths:
        os.environ["CHATTERSPEC_JIT"] = flag
        end_to_end(min(args.runs, 2 * args.chunk), 1, args.chunk)  # warm-up (kernel load)
        runs = args.runs if flag == "1" else min(args.runs, args.baseline_runs)
        for threads in sorted({1, args.threads}):
            rate, cpu_rate, flagged = end_to_end(runs, threads, args.chunk)
            if threads == 1:
                one_thread[label] = cpu_rate
            print(
                f"  {label:<16} {threads} thread(s): {rate / 1e6:6.2f} M realization-steps/s wall, "
                f"{cpu_rate / 1e6:6.2f} M per CPU-second (runs: {runs}; records flagged on any of "
                f"3 channels: {flagged}; nominal 0.1 % per channel)"
            )
    os.environ.pop("CHATTERSPEC_JIT", None)
    if _jit.HAVE_NUMBA:
        shares = stage_times(min(args.runs, 4 * args.chunk), args.chunk)
        total = sum(shares.values())
        print(
            "  compiled, one thread, CPU shares: "
            + ", ".join(f"{name} {t / total:.0%}" for name, t in shares.items())
        )
    bounds = {"numpy standard_normal": normals_rate() / 6}
    if _jit.HAVE_NUMBA:
        bounds["numba standard_normal"] = numba_normals_rate() / 6
    for name, bound in bounds.items():
        print(f"  random-number bound ({name}): {bound / 1e6:6.2f} M steps per CPU-second (6 normals/step)")
        for label, rate in one_thread.items():
            print(f"    {label}, one thread: {rate / bound:5.1%} of this bound (CPU time)")
    print(f"  load average while measuring: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(
        f"  STFT (1 s Hamming, 0.2 s hop, 3 channels): {stft_throughput() / 1e6:6.2f} M samples/s per channel"
    )


if __name__ == "__main__":
    main()
