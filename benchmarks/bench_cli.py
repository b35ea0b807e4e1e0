"""The command line itself: start-up of light commands and ``chatterspec monitor`` on 300 s of data.

Not a test. Runs each command as a fresh subprocess (what a user runs) ``--repeat`` times and prints,
per command, the best and median wall time and the process CPU time (user + system, all threads, from
``getrusage`` of the child: less disturbed by other jobs on a shared machine than wall time):

* start-up: ``chatterspec --help``, ``chatterspec scenarios``, argument errors (``detect NO-SUCH``,
  ``simulate eha-healthy --rate -1``, ``monitor`` with a missing model file), which should not wait for
  the heavy modules (scipy.signal, scipy.stats, numba, rerun);
* the monitor path: ``chatterspec monitor examples/eha_model.toml --data FILE.npz --record X.rrd
  --json`` on 300 s of 1 kHz, 3-channel EHA data (written once to a temporary folder), with the loop time
  the command reports (``wall_s``: pushes, logging, closing the file) as x real time; beside it the same
  run in-process after a warm-up run (``--in-process``), i.e. the figure ``bench_monitor.py`` measures.

``--baseline PATH`` runs every command a second time with ``PYTHONPATH=PATH`` (e.g. a checkout of the
previous ``main``), alternating with the current code in the same period, so both see the same load.
Bytecode and compiled kernels are cached in a temporary folder per version (``PYTHONPYCACHEPREFIX``,
``NUMBA_CACHE_DIR``; ``PYTHONDONTWRITEBYTECODE`` is dropped), filled by one uncounted warm-up run per
command: the figures are those of an installed package, not of a first run.

Usage: ``python benchmarks/bench_cli.py [--repeat 5] [--seconds 300] [--baseline /path/to/checkout]
[--only startup|monitor]``
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "examples" / "eha_model.toml"

STARTUP = {
    "--help": ["--help"],
    "scenarios": ["scenarios"],
    "detect NO-SUCH": ["detect", "no-such-scenario"],
    "simulate --rate -1": ["simulate", "eha-healthy", "--rate", "-1"],
    "monitor, no model": ["monitor", "no-such.toml", "--data", "x.csv"],
}


def _data(path: Path, seconds: float) -> None:
    """``seconds`` of the example model's plant under a 10-100 Hz chirp (300 rad/s), seed 7."""
    from chatterspec.plants.modelfile import load_model
    from chatterspec.plants.scenarios import Scenario
    from chatterspec.plants.signals import Chirp
    from chatterspec.plants.simulate import simulate

    model = load_model(MODEL).model
    sc = Scenario(name="bench", nominal=model, input=Chirp(10.0, 100.0, 4.0, 300.0), duration=seconds)
    sim = simulate(sc, 1, seed=7)
    cols = {"time": sim.t, "pump_speed": sim.u[:, 0]}
    cols.update({name: sim.z[0, :, i] for i, name in enumerate(model.output_names)})
    np.savez(path, **cols)


def _run(argv: list[str], pythonpath: str | None) -> tuple[float, float, str]:
    """(wall s, child CPU s, stdout) of ``python -m chatterspec ARGV``."""
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = pythonpath
    # bytecode and compiled kernels cached outside the checkouts (as an installed package has them),
    # per version; the first (warm-up) run of each version fills them
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    cache = Path(tempfile.gettempdir()) / "chatterspec-bench-cli" / str(abs(hash(pythonpath)))
    env["PYTHONPYCACHEPREFIX"] = str(cache / "pycache")
    env["NUMBA_CACHE_DIR"] = str(cache / "numba")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    # cwd outside any checkout: `python -m` puts the cwd first on sys.path, before PYTHONPATH
    cmd = [sys.executable, "-m", "chatterspec", *argv]
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, out.stdout


def _fmt(values: list[float]) -> str:
    return f"{min(values):6.2f} {statistics.median(values):6.2f}"


def _startup(repeat: int, versions: dict[str, str | None]) -> None:
    print(f"start-up (s; best / median of {repeat}; cpu = user + system of the process)")
    print(f"{'command':<24}" + "".join(f"{v:>15} wall {v:>9} cpu" for v in versions))
    for label, argv in STARTUP.items():
        res: dict[str, tuple[list[float], list[float]]] = {v: ([], []) for v in versions}
        for pp in versions.values():
            _run(argv, pp)  # warm-up: bytecode and kernel caches
        for _ in range(repeat):
            for v, pp in versions.items():  # alternating: both versions see the same load
                w, c, _out = _run(argv, pp)
                res[v][0].append(w)
                res[v][1].append(c)
        print(f"{label:<24}" + "".join(f"  {_fmt(res[v][0])}  {_fmt(res[v][1])}" for v in versions))


def _in_process(data: Path, rrd: Path, repeat: int) -> list[float]:
    """Loop time (the command's ``wall_s``) of the same command in this process, after a warm-up run."""
    from chatterspec.cli import main

    argv = ["monitor", str(MODEL), "--data", str(data), "--record", str(rrd), "--json"]
    out = []
    for i in range(repeat + 1):
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
            main(argv)
        if i:  # the first run loads kernels, FFT plans and Rerun's encoders: the warm-up
            out.append(json.loads(buf.getvalue())["wall_s"])
    return out


def _monitor(repeat: int, seconds: float, versions: dict[str, str | None], in_process: bool) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        data, rrd = Path(tmp) / "eha.npz", Path(tmp) / "x.rrd"
        _data(data, seconds)
        argv = ["monitor", str(MODEL), "--data", str(data), "--record", str(rrd), "--json"]
        what = f"{seconds:g} s of 1 kHz 3-channel data, --record"
        print(f"\nchatterspec monitor, {what} (best / median of {repeat})")
        head = ("version", "process wall s", "process cpu s", "loop s", "loop x real time")
        print(f"{head[0]:<10} {head[1]:>15} {head[2]:>15} {head[3]:>13} {head[4]:>17}")
        res: dict[str, tuple[list[float], list[float], list[float]]] = {v: ([], [], []) for v in versions}
        for pp in versions.values():
            _run(argv, pp)  # warm-up: bytecode and kernel caches
        for _ in range(repeat):
            for v, pp in versions.items():
                w, c, out = _run(argv, pp)
                res[v][0].append(w)
                res[v][1].append(c)
                res[v][2].append(json.loads(out)["wall_s"])
        for v, (w, c, loop) in res.items():
            xs = [seconds / s for s in loop]
            best, med = max(xs), statistics.median(xs)
            print(f"{v:<10} {_fmt(w):>15} {_fmt(c):>15} {_fmt(loop):>13} {best:8.0f} {med:7.0f}")
        if in_process:
            loop = _in_process(data, rrd, repeat)
            xs = [seconds / s for s in loop]
            best, med = max(xs), statistics.median(xs)
            print(f"in-process, warm (this code): loop {_fmt(loop)} s = {best:.0f}x ({med:.0f}x median)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=300.0, help="seconds of data for the monitor run")
    ap.add_argument("--baseline", default=None, help="PYTHONPATH of a previous version, run alternately")
    ap.add_argument("--only", choices=("startup", "monitor"), default=None)
    ap.add_argument("--no-in-process", action="store_true", help="skip the warm in-process monitor figure")
    args = ap.parse_args()
    versions: dict[str, str | None] = {"this": str(ROOT)}
    if args.baseline:
        versions["baseline"] = args.baseline
    print(
        f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}, compiled kernels "
        f"{'off' if os.environ.get('CHATTERSPEC_JIT') == '0' else 'on'}"
    )
    if args.only in (None, "startup"):
        _startup(args.repeat, versions)
    if args.only in (None, "monitor"):
        _monitor(args.repeat, args.seconds, versions, not args.no_in_process)


if __name__ == "__main__":
    main()
