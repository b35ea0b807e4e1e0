"""Benchmark: compiled per-sample kernels (chatterspec._jit) against the numpy path, in one process.

1. The smoothing (sat) SVSF on one EHA stream, 60 s at 1 kHz (60 000 steps, 3 channels),
   through :meth:`chatterspec.SVSF.update` as the monitor calls it: whole stream in one
   call, and 1000-sample chunks. The numpy path is selected in the same process with
   ``CHATTERSPEC_JIT=0`` (read at every call); both outputs are compared before timing.
2. The reduced-order sat SVSF (second-order plant, 1 measured of 2 states), same length.
3. Compile / cache cost: a fresh Python process calling the kernel once with the numba
   cache deleted (cold: compiles and writes the cache), then a second fresh process
   (warm: loads it), each against the same process with ``CHATTERSPEC_JIT=0``.

Targets: >= 10 M steps/s and >= 50x the numpy path on the EHA stream.

Usage::

    python benchmarks/bench_kernels.py [--seconds 60] [--repeat 5] [--no-compile]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from chatterspec import _jit
from chatterspec.filters.svsf import SVSF
from chatterspec.plants.scenarios import Scenario, scenario
from chatterspec.plants.simulate import simulate

ROOT = Path(__file__).resolve().parents[1]


def best_of(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def stream(name: str, seconds: float, psi, psi_lower=None):
    base = scenario(name)
    sc = Scenario("bench", base.nominal, base.input, seconds)
    sim = simulate(sc, 1, seed=0)
    f = SVSF(sc.nominal, psi=psi, psi_lower=psi_lower)
    return f, sim.z[0], sim.u


def time_paths(f: SVSF, z: np.ndarray, u: np.ndarray, chunk: int | None, repeat: int) -> tuple[float, float]:
    """Steps per second (compiled, numpy) of f.update over the stream, in chunks of ``chunk``."""
    K = len(z) - 1

    def run() -> np.ndarray:
        state = f.initialize(z[0])
        if chunk is None:
            return f.update(state, z[1:], u[:-1], check=False)[1].e_prior
        outs = []
        for k in range(0, K, chunk):
            state, out = f.update(state, z[1 + k : 1 + k + chunk], u[k : k + chunk], check=False)
            outs.append(out.e_prior)
        return np.concatenate(outs, axis=1)

    rates = []
    results = []
    for flag in ("1", "0"):
        os.environ["CHATTERSPEC_JIT"] = flag
        results.append(run())  # also compiles / loads the kernel
        rates.append(K / best_of(run, repeat if flag == "1" else max(1, repeat // 3)))
    os.environ.pop("CHATTERSPEC_JIT", None)
    scale = np.abs(z).max()
    assert np.abs(results[0] - results[1]).max() <= 1e-12 * scale, "compiled != numpy path"
    return rates[0], rates[1]


PROBE = (
    "import time; t0 = time.perf_counter(); import numpy as np; "
    "from chatterspec.filters.svsf import SVSF; from chatterspec.plants.scenarios import scenario; "
    "m = scenario('eha-healthy').nominal; f = SVSF(m, psi=3 * np.sqrt(np.diag(m.R))); "
    "s = f.initialize(np.zeros(3)); t1 = time.perf_counter(); "
    "f.update(s, np.zeros((1, 2, 3)), np.zeros((2, 1)), check=False); t2 = time.perf_counter(); "
    "from chatterspec.detection.pipeline import iter_chattering; "
    "next(iter_chattering(scenario('eha-healthy'), 1, 0)); "
    "print(t1 - t0, t2 - t1, time.perf_counter() - t2)"
)


def probe(env_jit: str) -> tuple[float, float, float]:
    """(import + setup, first SVSF.update, first 1-run iter_chattering) in seconds, fresh process."""
    env = dict(os.environ, CHATTERSPEC_JIT=env_jit, PYTHONPATH=str(ROOT))
    out = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    a, b, c = out.stdout.split()
    return float(a), float(b), float(c)


def clear_cache() -> int:
    n = 0
    for pat in ("*.nbi", "*.nbc"):
        for p in (ROOT / "chatterspec").rglob(pat):
            p.unlink()
            n += 1
    return n


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=60.0, help="stream length in s (1 kHz)")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--no-compile", action="store_true", help="skip the cold/warm process timings")
    args = p.parse_args(argv)
    print(f"cores: {os.cpu_count()}, numba: {_jit.HAVE_NUMBA}, stream: {args.seconds:g} s at 1 kHz")
    if not _jit.HAVE_NUMBA:
        print("numba is not installed: nothing to compare (pip install '.[fast]')")
        return 1
    eha = scenario("eha-healthy").nominal
    cases = [
        ("sat SVSF, EHA (n=m=3)", stream("eha-healthy", args.seconds, 3 * np.sqrt(np.diag(eha.R)))),
        ("sat SVSF, reduced order (n=2, m=1)", stream("so-boundary-layer", args.seconds, 8e-4, 0.8)),
    ]
    print(f"{'case':<38} {'chunk':>6} {'compiled':>14} {'numpy':>12} {'ratio':>7}")
    for label, (f, z, u) in cases:
        for chunk in (None, 1000):
            fast, slow = time_paths(f, z, u, chunk, args.repeat)
            size = chunk or "all"
            print(f"{label:<38} {size:>6} {fast / 1e6:10.2f} M/s {slow / 1e6:8.3f} M/s {fast / slow:6.0f}x")
    if not args.no_compile:
        n = clear_cache()
        cold = probe("1")
        warm = probe("1")
        off = probe("0")
        print(f"first calls in a fresh process (numba cache: {n} file(s) deleted first); seconds")
        print(f"  {'':<48} {'SVSF.update':>12} {'1-run chattering':>17}")
        for label, r in (
            ("cold cache (numba import + compile + cache write)", cold),
            ("warm cache (numba import + cache load)", warm),
            ("numpy path (CHATTERSPEC_JIT=0)", off),
        ):
            print(f"  {label:<48} {r[1]:12.3f} {r[2]:17.3f}")
        print(f"  (import chatterspec + setup: {cold[0]:.2f} / {warm[0]:.2f} / {off[0]:.2f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
