"""Before / after commissioning: the monitor on plants that differ from their nominal model, from the CLI.

The nominal model is ``chatterspec scenarios eha-healthy --model-toml eha.toml``. Each plant is a copy
of it with the catalogue chirp (10-100 Hz over 4 s, 300 rad/s, repeating) in its ``[simulation]`` table
and one change (A and B recomputed from the parameter map): exact, bulk modulus 3 % low, 10 % low,
friction 10 % high, sensor noise 1.5 x R. For each plant, with the command line only:

    chatterspec simulate PLANT.toml --duration 600 --rate 0 --seed 1 \\
        | chatterspec commission eha.toml --data - --out PLANT-fitted.toml
    chatterspec simulate PLANT.toml --duration 120 --rate 0 \\
        | chatterspec monitor X --data - --events jsonl

with X the nominal ``eha.toml`` (before) and the commissioned ``PLANT-fitted.toml`` (after); the
commissioning recording (seed 1) and the monitored stream (seed 0) are different noise. The table
gives the fault starts of each run (time and channel of the first), the commissioning verdict and its
wall / CPU time (the machine's load average is printed: the wall time depends on it).

    python scripts/commissioning_before_after.py [--out-dir DIR] [--duration 120] [--commission-s 600]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import chatterspec as cs

CHIRP = {"kind": "chirp", "f_start_hz": 10.0, "f_stop_hz": 100.0, "sweep_time": 4.0, "amplitude": 300.0}
PLANTS = {
    "exact": ({}, 1.0),
    "bulk modulus 3 % low": ({"bulk_modulus": 0.97}, 1.0),
    "bulk modulus 10 % low": ({"bulk_modulus": 0.90}, 1.0),
    "friction 10 % high": ({"friction": 1.10}, 1.0),
    "sensor noise 1.5 x R": ({}, 1.5),
}


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "chatterspec", *args]


def write_plant(nominal_path: Path, path: Path, factors: dict[str, float], r_scale: float) -> Path:
    """The nominal file's model with parameters scaled by ``factors`` and R by ``r_scale``, the catalogue
    chirp in its ``[simulation]`` table."""
    spec = cs.load_model(nominal_path)
    m = spec.model
    pm = m.parameter_map
    plant = pm.apply(m, {k: pm.parameter(k).value * f for k, f in factors.items()})
    import dataclasses

    plant = dataclasses.replace(plant, R=plant.R * r_scale)
    return cs.write_model_toml(
        path, plant, spec.psi, gamma=spec.gamma, tables={"simulation": {"duration_s": 4.0, "input": CHIRP}}
    )


def _children_cpu() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def commission(nominal: Path, plant: Path, out: Path, seconds: float) -> tuple[dict, float, float]:
    """``simulate | commission`` for ``plant``: the JSON report, wall and CPU seconds of ``commission``."""
    sim = subprocess.Popen(
        _cli("simulate", str(plant), "--duration", f"{seconds:g}", "--rate", "0", "--seed", "1"),
        stdout=subprocess.PIPE,
    )
    data = sim.communicate()[0]
    cpu0, t0 = _children_cpu(), time.perf_counter()
    run = subprocess.run(
        _cli("commission", str(nominal), "--data", "-", "--out", str(out), "--json"),
        input=data,
        capture_output=True,
    )
    wall, cpu = time.perf_counter() - t0, _children_cpu() - cpu0
    if not run.stdout:
        raise SystemExit(f"commission failed on {plant}: {run.stderr.decode()}")
    if run.returncode != 0:  # the report came, but the check failed: nothing was written
        print(f"note: {plant.name}: {run.stderr.decode().strip()}", file=sys.stderr)
    return json.loads(run.stdout), wall, cpu


def monitor(model: Path, plant: Path, seconds: float) -> list[dict]:
    """Fault starts of ``simulate PLANT --duration S --rate 0 | monitor MODEL --data - ...``."""
    sim = subprocess.Popen(
        _cli("simulate", str(plant), "--duration", f"{seconds:g}", "--rate", "0"), stdout=subprocess.PIPE
    )
    mon = subprocess.Popen(
        _cli("monitor", str(model), "--data", "-", "--events", "jsonl"),
        stdin=sim.stdout,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    sim.stdout.close()  # the monitor holds the pipe now: simulate sees it close if the monitor stops
    out, err = mon.communicate()
    sim.wait()
    if mon.returncode != 0:
        raise SystemExit(f"monitor {model} on {plant} failed: {err.strip()}")
    events = [json.loads(line) for line in out.splitlines() if line.startswith("{")]
    return [e for e in events if e.get("event") == "fault-start"]


def _starts(events: list[dict]) -> str:
    if not events:
        return "0"
    first = events[0]
    return f"{len(events)} (first at {first['sample_time_s']:.2f} s, {first['channel']})"


def main(argv: list[str] | None = None) -> None:
    """Run every plant and print the table (markdown)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out-dir", type=Path, default=Path("commissioning-before-after"))
    ap.add_argument("--duration", type=float, default=120.0, help="seconds of the monitored stream")
    ap.add_argument(
        "--commission-s", type=float, default=600.0, help="seconds of the commissioning recording"
    )
    args = ap.parse_args(argv)
    d = args.out_dir
    d.mkdir(parents=True, exist_ok=True)
    nominal = d / "eha.toml"
    subprocess.run(
        _cli("scenarios", "eha-healthy", "--model-toml", str(nominal)), check=True, capture_output=True
    )
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(
        f"| plant vs model | nominal model: fault starts in {args.duration:g} s | commissioned from "
        f"{args.commission_s:g} s: fault starts | commissioning: verdict, fitted change | wall / CPU s |"
    )
    print("|---|---|---|---|---|")
    for label, (factors, r_scale) in PLANTS.items():
        stem = label.replace(" ", "-").replace("%", "pc").replace(".", "_")
        plant = write_plant(nominal, d / f"{stem}.toml", factors, r_scale)
        fitted = d / f"{stem}-fitted.toml"
        rep, wall, cpu = commission(nominal, plant, fitted, args.commission_s)
        before, after = monitor(nominal, plant, args.duration), monitor(fitted, plant, args.duration)
        change = ", ".join(
            f"{p['name']} {100 * (p['estimate'] / p['nominal'] - 1):+.2f} %"
            for p in rep["parameters"]["estimates"]
            if abs(p["estimate"] / p["nominal"] - 1) > 0.02
        )
        r = np.array(rep["noise"]["r"]) / np.array(rep["noise"]["r_nominal"])
        if np.any(np.abs(r - 1) > 0.1):
            change = ", ".join(filter(None, [change, "R x " + "/".join(f"{x:.2f}" for x in r)]))
        verdict = "adequate" if rep["adequate"] else "NOT adequate"
        print(
            f"| {label} | {_starts(before)} | {_starts(after)} | {verdict}; {change or 'no change > 2 %'} "
            f"| {wall:.1f} / {cpu:.1f} |"
        )


if __name__ == "__main__":
    main()
