"""``chatterspec commission`` on 10 minutes of 1 kHz EHA data: wall and CPU time, as a user runs it.

Not a test. Writes the nominal model (``chatterspec scenarios eha-healthy --model-toml``) and 10 minutes of
healthy data of the stand-in rig ``examples/eha_rig.toml`` (``chatterspec simulate --rate 0``) to a
temporary folder once, then runs ``chatterspec commission eha.toml --data healthy.csv --out
fitted.toml`` as a fresh subprocess ``--repeat`` times (and once more from standard input, ``--data -``),
printing per run the wall time and the process CPU time (user + system, all threads, from ``getrusage``
of the child) and the machine's load average: on the shared 2-core machine the wall time mostly measures
the other jobs. The target is below 30 s on 2 cores.

Usage: ``python benchmarks/bench_commission.py [--repeat 3] [--seconds 600]``
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

RIG = Path(__file__).resolve().parents[1] / "examples" / "eha_rig.toml"


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "chatterspec", *args]


def _run(argv: list[str], stdin: Path | None = None) -> tuple[float, float]:
    """Wall and child CPU seconds of one command (its output discarded; a failure stops the benchmark)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with open(stdin, "rb") if stdin else open(os.devnull, "rb") as fh:
        run = subprocess.run(argv, stdin=fh, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if run.returncode != 0:
        raise SystemExit(run.stderr.decode())
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    """Prepare the data once, then time the command."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=600.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        subprocess.run(_cli("scenarios", "eha-healthy", "--model-toml", str(d / "eha.toml")), check=True,
                       capture_output=True)  # fmt: skip
        with open(d / "healthy.csv", "wb") as out:
            subprocess.run(
                _cli("simulate", str(RIG), "--duration", f"{args.seconds:g}", "--rate", "0", "--seed", "1"),
                stdout=out,
                check=True,
            )
        cmd = _cli("commission", str(d / "eha.toml"), "--out", str(d / "fitted.toml"))
        print(f"chatterspec commission on {args.seconds:g} s of 1 kHz EHA data ({os.cpu_count()} cores)")
        for i in range(args.repeat):
            load = os.getloadavg()[0]
            wall, cpu = _run([*cmd, "--data", str(d / "healthy.csv")])
            print(f"  file  run {i + 1}: wall {wall:6.2f} s, CPU {cpu:6.2f} s (load average {load:.1f})")
        load = os.getloadavg()[0]
        wall, cpu = _run([*cmd, "--data", "-"], stdin=d / "healthy.csv")
        print(f"  stdin run  : wall {wall:6.2f} s, CPU {cpu:6.2f} s (load average {load:.1f})")


if __name__ == "__main__":
    main()
