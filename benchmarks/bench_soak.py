"""Soak run of the live monitor: hours of 1 kHz 3-channel data through standard input.

    python benchmarks/bench_soak.py                    # 60 min of data at full speed, 10-min recordings
    python benchmarks/bench_soak.py --minutes 10       # a shorter soak
    python benchmarks/bench_soak.py --rate 1 --minutes 1 --record-every 0   # latency at real time
    python benchmarks/bench_soak.py --json
    python benchmarks/bench_soak.py --stamped --minutes 0.5 --record-every 0.1   # latency incl. pipe wait
    python benchmarks/bench_soak.py --rotations 30 --record-every 0.05          # RSS per rotation

This process plays the producer: it simulates ``eha-healthy`` block by block
(:func:`chatterspec.online.simulated_stream.simulate_blocks`, the source of ``chatterspec
simulate``) and writes the CSV rows into the standard input of a
``chatterspec monitor --data - --record ... --record-every ...`` subprocess with
both SVSFs (the model file has ``psi``). After each minute of data has been
written it samples the monitor's resident memory (``VmRSS``; the monitor is at
most a pipe buffer, ~1 s of data, behind). At the end it reports the peak RSS
(``ru_maxrss`` of the child), wall time, the monitor's latency figures and the
size of every rotated recording, and checks the soak criterion: RSS at the
last minute within 10 % of RSS at minute 5.

``--stamped`` measures latency *including the time rows wait in the pipe*
(what the monitor itself cannot see: its own figure starts when a read returns).
The monitor runs in this process (the CLI's loop: :func:`~chatterspec.online.stream.read_fd`,
:class:`~chatterspec.online.stream.CsvRows`, :class:`~chatterspec.viewer.live_stream.StreamMonitor`),
reading an ``os.pipe`` that a producer thread writes paced rows into; the producer
notes ``time.perf_counter()`` just before each write and the line numbers it
holds, and every parsed block is split at write boundaries and handed to the
monitor with its write time as arrival. The monitor's latency statistics are then
"from the moment the producer wrote the sample to the verdict of the frame it
completes".

``--rotations N`` runs the same loop at full speed (no pipe) with short
recordings and samples the resident memory and the number of OS threads after
each rotation; it reports the growth per rotation (least-squares slope after the
first 3 rotations). rerun-sdk 0.41 keeps every dropped ``RecordingStream`` with
its two threads (batcher and sink) in a list of "orphaned" recordings until
``rr.init`` sweeps them; :class:`StreamMonitor` sweeps after each rotation.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from chatterspec.cli.scenarios import export_model_toml  # noqa: E402
from chatterspec.online.simulated_stream import csv_header, csv_lines, simulate_blocks  # noqa: E402
from chatterspec.plants.scenarios import scenario  # noqa: E402


def _rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _in_process_monitor(sc_name: str, out: Path, record_every_s: float | None) -> tuple[object, object]:
    from chatterspec.online.monitor import MonitorSettings
    from chatterspec.plants.modelfile import load_model
    from chatterspec.viewer.live_stream import StreamMonitor

    spec = load_model(export_model_toml(sc_name, out / "model.toml"))
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    record = None if record_every_s is None else out / "soak.rrd"
    return spec, StreamMonitor(spec.model, settings, record=record, record_every_s=record_every_s)


def stamped(args: argparse.Namespace, out: Path) -> dict:
    """Latency from the producer's write to the verdict (see the module docstring)."""
    import threading

    import numpy as np

    from chatterspec.online.stream import CsvRows, RowBlock, read_fd

    rate = args.rate if args.rate > 0 else 1.0
    every = 60.0 * args.record_every if args.record_every > 0 else None
    spec, mon = _in_process_monitor(args.scenario, out, every)
    sc = scenario(args.scenario)
    r, w = os.pipe()
    first_line: list[int] = []  # first line number of each write
    stamp: list[float] = []  # perf_counter just before that write

    def produce() -> None:
        try:
            os.write(w, (csv_header(sc.nominal) + "\n").encode())
            line, start = 2, time.perf_counter()
            block_s = max(sc.dt, 0.005 * rate)  # as `chatterspec simulate`: a write every ~5 ms
            for t, z, u in simulate_blocks(sc, args.seed, 60.0 * args.minutes, block_s=block_s):
                delay = start + float(t[-1]) / rate - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                data = csv_lines(t, z, u).encode()
                first_line.append(line)
                stamp.append(time.perf_counter())
                line += t.shape[0]
                view = memoryview(data)
                while view:
                    view = view[os.write(w, view) :]
        finally:
            os.close(w)

    rows = CsvRows(spec.model, "pipe")
    th = threading.Thread(target=produce, daemon=True)
    t0 = time.perf_counter()
    th.start()
    for data, arrival in read_fd(r):
        for item in rows.feed(data, arrival):
            if not isinstance(item, RowBlock):
                mon.process(item)
                continue
            fl = np.asarray(first_line[: len(stamp)])
            k = np.searchsorted(fl, item.lines, side="right") - 1  # the write holding each row
            cuts = np.flatnonzero(np.diff(k)) + 1
            for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, item.n_rows], strict=True):
                sl = slice(int(lo), int(hi))
                tt = None if item.t is None else item.t[sl]
                mon.process(RowBlock(tt, item.z[sl], item.u[sl], item.lines[sl], stamp[int(k[lo])]))
    th.join()
    os.close(r)
    summary = mon.close()
    return {
        "mode": "stamped",
        "minutes_of_data": args.minutes,
        "rate": rate,
        "record_every_min": args.record_every,
        "wall_s": time.perf_counter() - t0,
        "rows": summary.n_rows,
        "latency_from_write": summary.latency,
        "recordings": len(summary.recordings),
        "threads_at_end": _threads(),
    }


def rotations(args: argparse.Namespace, out: Path) -> dict:
    """RSS and OS threads after each of ``args.rotations`` rotations (full speed, no pipe)."""
    import numpy as np

    from chatterspec.online.stream import RowBlock

    every = 60.0 * args.record_every
    _, mon = _in_process_monitor(args.scenario, out, every)
    sc = scenario(args.scenario)
    samples: list[tuple[int, float, int]] = []
    line, t0 = 2, time.perf_counter()
    rotated = 0
    for t, z, u in simulate_blocks(sc, args.seed, every * args.rotations, block_s=0.2):
        mon.process(RowBlock(t, z, u, np.arange(line, line + t.shape[0]), time.perf_counter()))
        line += t.shape[0]
        if (line - 2) // mon.record_every > rotated:  # a rotation happened in this block
            rotated = (line - 2) // mon.record_every
            mon.wait_closed()
            samples.append((mon.n_recordings, _rss_mb(os.getpid()), _threads()))
            for r in mon.recordings:  # disk is not what is measured
                Path(r["path"]).unlink(missing_ok=True)
    summary = mon.close()
    k = np.array([s[0] for s in samples[3:]], float)
    mb = np.array([s[1] for s in samples[3:]])
    slope = float(np.polyfit(k, mb, 1)[0]) if k.size >= 2 else float("nan")
    return {
        "mode": "rotations",
        "rotations": len(samples),
        "data_s_per_file": every,
        "wall_s": time.perf_counter() - t0,
        "rss_mb_per_rotation": slope,
        # the loop's longest stop at a rotation (a rename and a hand-off to the rotation thread)
        "rotation_max_ms": summary.latency["rotation_max_ms"],
        "rss_mb": [round(s[1], 1) for s in samples],
        "threads": [s[2] for s in samples],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=60.0, help="minutes of data (default 60)")
    ap.add_argument(
        "--record-every", type=float, default=10.0, help="minutes per recording (0: no recording)"
    )
    ap.add_argument("--rate", type=float, default=0.0, help="data s per wall s (0 = full speed)")
    ap.add_argument("--scenario", default="eha-healthy")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="folder for the recordings (default: a temp dir)")
    ap.add_argument("--keep", action="store_true", help="keep the recordings")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--stamped", action="store_true", help="latency from the producer's write, in process")
    ap.add_argument("--rotations", type=int, default=0, help="RSS / threads over N short rotations")
    args = ap.parse_args()

    tmp = tempfile.TemporaryDirectory(prefix="soak-")
    out = args.out or Path(tmp.name)
    out.mkdir(parents=True, exist_ok=True)
    if args.stamped or args.rotations:
        res = stamped(args, out) if args.stamped else rotations(args, out)
        print(json.dumps(res, indent=None if args.json else 2))
        tmp.cleanup()
        return
    model = export_model_toml(args.scenario, out / "model.toml")
    cmd = [sys.executable, "-m", "chatterspec", "monitor", str(model), "--data", "-", "--json"]
    if args.record_every > 0:
        cmd += ["--record", str(out / "soak.rrd"), "--record-every", str(args.record_every)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    err_path = out / "monitor.stderr"
    sc = scenario(args.scenario)
    with err_path.open("w") as err:
        t0 = time.perf_counter()
        mon = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=err, env=env)
        rss: list[tuple[float, float]] = []
        next_minute = 1.0
        mon.stdin.write((csv_header(sc.nominal) + "\n").encode())
        start = time.perf_counter()
        # paced: rows go out every ~5 ms of wall time as `chatterspec simulate` writes them
        block_s = max(sc.dt, 0.005 * args.rate) if args.rate > 0 else 1.0
        for t, z, u in simulate_blocks(sc, args.seed, 60.0 * args.minutes, block_s=block_s):
            if args.rate > 0:
                delay = start + float(t[-1]) / args.rate - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            mon.stdin.write(csv_lines(t, z, u).encode())
            mon.stdin.flush()
            if t[-1] >= 60.0 * next_minute - 1e-9:
                rss.append((next_minute, _rss_mb(mon.pid)))
                next_minute += 1.0
        produced = time.perf_counter() - t0
        mon.stdin.close()
        stdout = mon.stdout.read()
        _, status, usage = os.wait4(mon.pid, 0)
        mon.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t0
    if mon.returncode != 0:
        sys.exit(f"monitor failed ({mon.returncode}):\n{err_path.read_text()[-3000:]}")
    doc = json.loads(stdout)
    at = dict(rss)
    m5 = at.get(5.0)
    last = rss[-1] if rss else (None, None)
    result = {
        "minutes_of_data": args.minutes,
        "rate": args.rate,
        "rows": doc["n_rows"],
        "wall_s": wall,
        "producer_s": produced,
        "x_real_time": doc["duration_s"] / wall,
        "peak_rss_mb": usage.ru_maxrss / 1024.0,
        "rss_mb_by_minute": rss,
        "rss_5min_mb": m5,
        "rss_last_mb": last[1],
        "rss_growth_5_to_last": None if m5 is None else last[1] / m5 - 1.0,
        "within_10_percent": None if m5 is None else abs(last[1] / m5 - 1.0) <= 0.10,
        "latency": doc["latency"],
        "frames": doc["n_frames"],
        "events": doc["counts"],
        "recordings": [{"file": Path(r["path"]).name, "bytes": r["bytes"]} for r in doc["recordings"]],
    }
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{args.minutes:g} min of 1 kHz 3-channel data ({result['rows']} rows), rate {args.rate:g}")
        xrt = result["x_real_time"]
        print(f"wall {wall:.1f} s ({xrt:.1f}x real time); producer done at {produced:.1f} s")
        print(f"peak RSS {result['peak_rss_mb']:.1f} MB; RSS at 5 min {m5} MB, at {last[0]} min {last[1]} MB")
        if m5 is not None:
            growth = 100 * result["rss_growth_5_to_last"]
            print(f"growth 5 min -> end: {growth:+.1f} % (criterion: within 10 %)")
        print("RSS by minute (MB): " + ", ".join(f"{m:g}:{v:.0f}" for m, v in rss))
        lat = doc["latency"]
        print(
            f"latency over {lat['frames']} frames: median {lat['median_ms']:.2f} ms, "
            f"max {lat['max_ms']:.2f} ms; longest rotation {lat.get('rotation_max_ms', 0):.0f} ms"
        )
        print(f"events: {doc['counts']}")
        for r in result["recordings"]:
            print(f"  {r['file']}: {r['bytes'] / 1e6:.1f} MB")
    if args.keep and args.out is None:
        print(f"kept in {out}", file=sys.stderr)
    elif not args.keep:
        tmp.cleanup()


if __name__ == "__main__":
    main()
