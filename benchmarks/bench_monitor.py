"""Throughput of the online monitor on a 1 kHz, 3-channel stream (linear EHA), with file recording.

Not a test: prints x real time and the recording size per minute of data for
four configurations (monitor only / with .rrd file; auxiliary SVSF only / both
SVSFs) plus the analysis stage alone (precomputed chattering).

Usage: ``python benchmarks/bench_monitor.py [--minutes 1] [--chunk 1000]``
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from chatterspec.live import open_sinks, run_monitor
from chatterspec.models import eha_linear
from chatterspec.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.pipeline import chattering_record
from chatterspec.scenarios import Scenario, Segment
from chatterspec.signals import Chirp
from chatterspec.simulate import simulate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=1.0)
    ap.add_argument("--chunk", type=int, default=1000, help="samples per push")
    args = ap.parse_args()
    import rerun  # noqa: F401  (import once up front: ~0.5 s that is not per-run cost)

    T = args.minutes * 60.0
    nominal = eha_linear()
    sc = Scenario(
        "bench",
        nominal,
        Chirp(10.0, 100.0, T, 300.0),
        T,
        windows=(Segment(T / 2, T, eha_linear(leakage=9e-11), "leakage"),),
    )
    sim = simulate(sc, runs=1, seed=1)
    z, u = sim.z[0], sim.u
    rec = chattering_record(nominal, sim.z, sim.u)
    psi = (4.2e-3, 4.8e-3, 4.3e3)
    print(f"{T:g} s of 1 kHz, 3-channel data; chunk {args.chunk} samples")
    with tempfile.TemporaryDirectory() as tmp:
        for label, settings, record, raw in [
            ("analysis only (chattering given), no file", MonitorSettings(), False, False),
            ("analysis only (chattering given), .rrd file", MonitorSettings(), True, False),
            ("aux SVSF + analysis, no file", MonitorSettings(), False, True),
            ("aux SVSF + analysis, .rrd file", MonitorSettings(), True, True),
            ("both SVSFs + analysis, .rrd file", MonitorSettings(psi=psi), True, True),
        ]:
            mon = ChatteringMonitor(nominal, settings, t0=0.0 if raw else rec.t[0])
            path = Path(tmp) / "bench.rrd"
            t0 = time.perf_counter()
            if record:
                sinks = open_sinks(record=path)
                kw = {"z": z, "u": u} if raw else {"chattering": rec.values[0]}
                run_monitor(mon, sinks, chunk_samples=args.chunk, **kw)
            else:
                for lo in range(0, z.shape[0], args.chunk):
                    if raw:
                        mon.push(z[lo : lo + args.chunk], u[lo : lo + args.chunk])
                    else:
                        mon.push_chattering(rec.values[0, lo : lo + args.chunk])
            wall = time.perf_counter() - t0
            size = (
                f", {path.stat().st_size / 1e6 / args.minutes:6.2f} MB per minute of data" if record else ""
            )
            print(f"{label:<48} {T / wall:8.0f} x real time{size}")
            if path.exists():
                path.unlink()


if __name__ == "__main__":
    main()
