"""Benchmark: what fault identification adds to ``chatterspec detect NAME --runs R``.

Runs the command in fresh processes, alternating three variants so that a shared machine's load
hits all of them alike: this checkout with identification (the default), this checkout with
``--no-identify``, and optionally another checkout (``--baseline PATH``, e.g. the branch point,
run with ``PYTHONPATH=PATH``). Reports the median wall time and the median CPU time (user +
system of the child, from ``os.wait4``: does not depend on the load) of each, and the
identification's share. The numba cache is warmed first.

``--in-process`` instead times, inside one process, the part of ``detect``'s work that identification
adds (the identification of every chunk, and the measurements the fused kernel then writes) against
the whole command's CPU time: one run of the same code, so the machine's load hardly matters.

Usage::

    python benchmarks/bench_identification.py [--scenario eha-leak-major] [--runs 10000] [--repeat 5]
        [--baseline /path/to/other/checkout] [--json]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(argv: list[str], pythonpath: str) -> tuple[float, float]:
    env = {**os.environ, "PYTHONPATH": pythonpath}
    t0 = time.perf_counter()
    # run from the checkout itself: ``python -m`` puts the working directory before PYTHONPATH
    proc = subprocess.Popen(
        [sys.executable, "-m", "chatterspec", *argv],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
        cwd=pythonpath,
    )
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    if status != 0:
        raise RuntimeError(f"{argv} failed: {proc.stderr.read().decode() if proc.stderr else status}")
    return wall, usage.ru_utime + usage.ru_stime


def _median(x: list[float]) -> float:
    s = sorted(x)
    n = len(s)
    return s[n // 2] if n % 2 else 0.5 * (s[n // 2 - 1] + s[n // 2])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenario", default="eha-leak-major")
    p.add_argument("--runs", type=int, default=10000)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--baseline", default=None, help="another checkout to compare with (PYTHONPATH)")
    p.add_argument("--json", action="store_true")
    p.add_argument("--in-process", action="store_true", help="time identification's share inside one process")
    args = p.parse_args()
    if args.in_process:
        return _in_process(args)
    base = ["detect", args.scenario, "--runs", str(args.runs), "--no-progress"]
    variants = {"identification": (base, str(ROOT)), "no-identify": ([*base, "--no-identify"], str(ROOT))}
    if args.baseline:
        variants["baseline"] = (base, str(Path(args.baseline).resolve()))
    for argv, path in variants.values():  # warm the numba caches and the page cache
        _run([*argv[:3], "64", *argv[4:]], path)
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in variants}
    for _ in range(args.repeat):
        for name, (argv, path) in variants.items():
            times[name].append(_run(argv, path))
    out = {
        name: {"wall_s": _median([w for w, _ in t]), "cpu_s": _median([c for _, c in t]), "all": t}
        for name, t in times.items()
    }
    with open("/proc/loadavg") as fh:
        load = fh.read().split()[0]
    out["load_average"] = float(load)
    ref = "baseline" if "baseline" in out else "no-identify"
    for k in ("wall_s", "cpu_s"):
        out[f"added_{k[:-2]}_vs_{ref}"] = out["identification"][k] / out[ref][k] - 1.0
    if args.json:
        print(json.dumps(out, indent=1))
        return
    print(f"detect {args.scenario} --runs {args.runs}, {args.repeat} alternating repeats, load {load}")
    for name in variants:
        print(f"  {name:<15} wall {out[name]['wall_s']:6.2f} s   cpu {out[name]['cpu_s']:6.2f} s")
    print(
        f"identification adds {100 * out[f'added_wall_vs_{ref}']:+.1f} % wall, "
        f"{100 * out[f'added_cpu_vs_{ref}']:+.1f} % CPU (vs {ref})"
    )


def _in_process(args: argparse.Namespace) -> None:
    """CPU time of the identification calls within ``detect``, and of the whole command."""
    import chatterspec.detection.identification as ident
    from chatterspec.cli import main as cli_main

    spent = [0.0]
    inner = ident.identify_record

    def timed(*a: object, **kw: object) -> object:
        t = time.process_time()
        try:
            return inner(*a, **kw)
        finally:
            spent[0] += time.process_time() - t

    ident.identify_record = timed  # IdentificationStream.tap calls it once per chunk
    argv = ["detect", args.scenario, "--runs", str(args.runs), "--no-progress", "--json"]
    with open(os.devnull, "w") as devnull, contextlib.redirect_stdout(devnull):
        cli_main([*argv[:3], "64", *argv[4:]])  # warm up (numba cache, imports)
    rows = []
    for _ in range(args.repeat):
        for extra in ([], ["--no-identify"]):
            spent[0] = 0.0
            t0 = time.process_time()
            with open(os.devnull, "w") as devnull, contextlib.redirect_stdout(devnull):
                cli_main([*argv, *extra])
            rows.append((bool(extra), time.process_time() - t0, spent[0]))
    with_id = [(c, s) for no, c, s in rows if not no]
    without = [c for no, c, _ in rows if no]
    c_with, s_med = _median([c for c, _ in with_id]), _median([s for _, s in with_id])
    c_without = _median(without)
    print(
        f"detect {args.scenario} --runs {args.runs} in one process, {args.repeat} alternating repeats: "
        f"CPU {c_with:.2f} s with identification (of which identify_record {s_med:.2f} s), "
        f"{c_without:.2f} s with --no-identify; identification = {100 * s_med / (c_with - s_med):.1f} % "
        f"of the rest; with/without {100 * (c_with / c_without - 1):+.1f} %"
    )


if __name__ == "__main__":
    main()
