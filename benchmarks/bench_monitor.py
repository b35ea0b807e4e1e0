"""Throughput of the online monitor on a 1 kHz, 3-channel stream (linear EHA), with file recording.

Not a test. Prints, per configuration, how many times faster than real time the
stream is processed and (with a file) the recording size per minute of data:

(a) analysis only (chattering given), no file
(b) analysis only (chattering given), .rrd file
(c) raw z, u: auxiliary ``sgn`` SVSF + analysis, .rrd file
(d) raw z, u: both SVSFs (``psi`` set) + analysis, .rrd file

plus the auxiliary SVSF without a file for reference, and each case with a file once more on the
numpy path (``CHATTERSPEC_JIT=0``, one run: the same-process baseline). "x real time" counts the
whole run: pushes, logging and closing the file (flush + footer) — everything
that grows with the data. The fixed cost of opening the file and sending the
blueprint and static entities (tens of ms, once per run; including their encoding, which is
waited for with a ``flush`` before the clock starts) is printed separately and also folded into
"incl. setup". Each figure is the best of ``--repeat``
runs (the machine may be shared); "median" is the median of the same runs' "x real time".
One warm-up recording is written first so that one-time imports (pyarrow.compute, ...) are not
charged to the first case.

The last columns split each run's wall time into the monitor's pushes (SVSFs, STFT,
verdicts) and the Rerun logging path (``RerunLogger.log_update`` + ``close`` + closing
the file sink, i.e. everything that waits for the recording), each as x real time.
With ``--cpu`` every figure is process CPU time (all threads) instead of wall time,
which is less disturbed by other jobs on a shared machine. The baselines before the
compiled monitor (same machine class) are printed beside the
targets; the machine's core count and the compiled-kernel switch are printed on top.

``--breakdown`` splits the logging path (updates computed beforehand, so only logging is timed) by
entity group: each group's share is the time saved when its ``send_columns`` / ``log`` calls are
dropped (Rerun's synchronous part, its encoder threads and the final flush), "python side" is what
remains with every call dropped (building the columns, closing the empty stream). ``--live``
times the live path: one hop (200 samples) per push to an in-memory stream, ms per hop.

Usage: ``python benchmarks/bench_monitor.py [--minutes 1] [--chunk 1000] [--repeat 3] [--cases b,d]
[--cpu] [--breakdown] [--live] [--rule cusum]``
"""

from __future__ import annotations

import argparse
import os
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from chatterspec.detection.pipeline import chattering_record
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.plants.models import eha_linear
from chatterspec.plants.scenarios import Scenario, Segment
from chatterspec.plants.signals import Chirp
from chatterspec.plants.simulate import simulate
from chatterspec.viewer.rerun_log import RerunLogger
from chatterspec.viewer.sinks import open_sinks

PSI = (4.2e-3, 4.8e-3, 4.3e3)


class _Setup:
    """A monitor's model and settings (``--breakdown`` builds a fresh monitor per case)."""

    def __init__(self, model, settings) -> None:
        self.model, self.settings = model, settings


#: Measure process CPU time (all threads, incl. Rerun's encoder threads) instead of wall time:
#: less sensitive to other jobs on a shared machine (``--cpu``).
CPU = False
#: Extra ``RerunLogger`` keywords (``--batch-samples``).
LOGGER_KW: dict = {}


def _run(
    mon: ChatteringMonitor, data: dict, chunk: int, path: Path | None
) -> tuple[float, float, int, float, float]:
    """(setup_s, streaming_s, file bytes, push_s, logging_s): streaming = pushes + logging + close."""
    clock = time.perf_counter if not CPU else time.process_time
    t0 = clock()
    sinks = logger = None
    if path is not None:
        sinks = open_sinks(record=path)
        logger = RerunLogger(sinks, mon, **LOGGER_KW)
        sinks.file_stream.flush()  # the blueprint and static entities are encoded here, as setup
    t1 = clock()
    n = next(iter(data.values())).shape[0]
    t_push = t_log = 0.0
    for lo in range(0, n, chunk):
        a = clock()
        if "chattering" in data:
            upd = mon.push_chattering(data["chattering"][lo : lo + chunk])
        else:
            upd = mon.push(data["z"][lo : lo + chunk], data["u"][lo : lo + chunk])
        b = clock()
        t_push += b - a
        if logger is not None:
            logger.log_update(upd)
            t_log += clock() - b
    if logger is not None:
        a = clock()
        logger.close()
        sinks.close()
        t_log += clock() - a
    t2 = clock()
    return t1 - t0, t2 - t1, path.stat().st_size if path is not None else 0, t_push, t_log


#: Entity groups of ``--breakdown``: regular expressions matched against the entity path, written for
#: the current layout (every per-sample series in ``/chattering/e``), the one before it (a separate
#: ``/signal``) and the per-channel one (``/chattering/<c>/e``), so the script also splits the time of
#: an older checkout.
GROUPS = {
    "chattering e (1 row/sample)": r"/chattering(/[^/]+)?/e$",
    "/signal (older checkouts only)": r"/signal(/|$)",
    "spectrum/<c> (1 tensor/frame)": r"/spectrum/",
    "spectrogram/<c> (file block)": r"/spectrogram/",
    "per-frame series, psi, events, lanes": r"/(detection|frequency|events|state)|psi",
    "alarm series (1 row/frame)": r"/alarm/",
}


def _logging_only(mon: ChatteringMonitor, ups: list, path: Path, drop: str) -> float:
    """Time of logging ``ups`` (log_update + close + closing the file) with the calls whose entity path
    matches the regular expression ``drop`` skipped."""
    clock = time.perf_counter if not CPU else time.process_time
    sinks = open_sinks(record=path)
    logger = RerunLogger(sinks, mon, **LOGGER_KW)
    s = sinks.file_stream
    s.flush()  # the static entities and the blueprint are encoded before the clock starts
    if drop:
        send, log = s.send_columns, s.log
        skip = re.compile(drop).search
        s.send_columns = lambda p, *a, **k: None if skip(p) else send(p, *a, **k)
        s.log = lambda p, *a, **k: None if skip(p) else log(p, *a, **k)
    t0 = clock()
    for u in ups:
        logger.log_update(u)
    logger.close()
    sinks.close()
    return clock() - t0


def _breakdown(cases: list, chunk: int, repeat: int, path: Path, T: float) -> None:
    print(f"\nwhere the logging time goes (ms per {T:g} s of data, best of {repeat}; updates precomputed)")
    for label, settings, data, record, t0 in cases:
        if not record:
            continue
        mon = ChatteringMonitor(settings.model, settings.settings, t0=t0)
        n = next(iter(data.values())).shape[0]
        if "chattering" in data:
            ups = [mon.push_chattering(data["chattering"][lo : lo + chunk]) for lo in range(0, n, chunk)]
        else:
            z, u = data["z"], data["u"]
            ups = [mon.push(z[lo : lo + chunk], u[lo : lo + chunk]) for lo in range(0, n, chunk)]
        rest = "python side (every call dropped)"
        variants = {"all": "", **GROUPS, rest: "."}
        best = {k: np.inf for k in variants}
        for _ in range(repeat):  # interleaved, so a burst of load hits every variant alike
            for k, drop in variants.items():
                best[k] = min(best[k], _logging_only(mon, ups, path, drop))
                path.unlink()
        print(f"{label}: all {best['all'] * 1e3:.1f} ms ({T / best['all']:.0f}x real time)")
        for k in GROUPS:
            print(f"    {k:<40}{(best['all'] - best[k]) * 1e3:7.1f}")
        print(f"    {rest:<40}{best[rest] * 1e3:7.1f}")


def _live(nominal, raw: dict, repeat: int) -> None:
    import rerun as rr

    from chatterspec.viewer.sinks import Sinks

    mon = ChatteringMonitor(nominal, MonitorSettings(psi=PSI), t0=0.0)
    ups = [mon.push(raw["z"][lo : lo + 200], raw["u"][lo : lo + 200]) for lo in range(0, 20_000, 200)]
    clock = time.perf_counter if not CPU else time.process_time
    best = np.inf
    for _ in range(repeat):
        s = rr.RecordingStream("bench-live", recording_id="live")
        mem = s.memory_recording()  # noqa: F841  (kept alive: a dropped memory sink discards the data)
        sinks = Sinks(live_stream=s)
        logger = RerunLogger(sinks, mon)
        t0 = clock()
        for u in ups:
            logger.log_update(u)
        best = min(best, clock() - t0)
        logger.close()
        sinks.close()
    ms = best / len(ups) * 1e3
    print(f"\nlive path (in-memory stream, both SVSFs, one hop per push): {ms:.2f} ms per hop")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=1.0)
    ap.add_argument("--chunk", type=int, default=1000, help="samples per push (one hop = 200)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per configuration; the best is shown")
    ap.add_argument("--cpu", action="store_true", help="process CPU time (all threads) instead of wall time")
    ap.add_argument(
        "--batch-samples",
        type=int,
        default=None,
        help="RerunLogger batch_samples (file batches; batch_frames follows at one frame per hop)",
    )
    ap.add_argument("--cases", default="", help="comma-separated subset of the cases to run, e.g. b,d")
    ap.add_argument("--breakdown", action="store_true", help="split the logging time by entity group")
    ap.add_argument("--live", action="store_true", help="time the live path per hop")
    ap.add_argument(
        "--no-baseline", action="store_true", help="skip the numpy-path runs of the cases with a file"
    )
    ap.add_argument(
        "--rule",
        default=None,
        help="alarm rule of every case (frame, persistence, cusum; threshold fixed at its 1-per-day value "
        "for the EHA, no calibration); default: the per-frame rule at alpha 0.001",
    )
    args = ap.parse_args()
    global CPU
    CPU = args.cpu
    if args.batch_samples is not None:
        LOGGER_KW.update(batch_samples=args.batch_samples, batch_frames=max(1, args.batch_samples // 200))
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
    raw = {"z": sim.z[0], "u": sim.u}
    rec = chattering_record(nominal, sim.z, sim.u)
    chat = {"chattering": rec.values[0]}
    rule = None
    if args.rule:
        from chatterspec.detection.alarms.rules import make_rule

        rule = make_rule(args.rule, {"frame": 14.07, "persistence": 6.8, "cusum": 20.0}[args.rule])
    cases = [
        ("(a) chattering given, no file", MonitorSettings(rule=rule), chat, False),
        ("(b) chattering given, .rrd file", MonitorSettings(rule=rule), chat, True),
        ("    aux SVSF, no file", MonitorSettings(rule=rule), raw, False),
        ("(c) raw z,u: aux SVSF, .rrd file", MonitorSettings(rule=rule), raw, True),
        ("(d) raw z,u: both SVSFs, .rrd file", MonitorSettings(psi=PSI, rule=rule), raw, True),
    ]
    if args.cases:
        keep = {f"({c.strip()})" for c in args.cases.split(",")}
        cases = [case for case in cases if case[0].split()[0] in keep]
    from chatterspec import _jit

    print(
        f"{T:g} s of 1 kHz, 3-channel data; chunk {args.chunk} samples; best of {args.repeat}; "
        f"{os.cpu_count()} cores; compiled kernels {'on' if _jit.enabled() else 'off'}; "
        f"{'process CPU time' if CPU else 'wall time'}"
    )
    print("before the compiled monitor: (d) 87x real time, (b) 910x; target >= 2000x for both")
    print(
        "before the one-row-per-sample layout (idle machine): (b) 1756x, 6.3 MB/min; (d) 1023x, 11.7 MB/min"
    )
    print(
        "'push x' before the one-call-per-push kernel (idle machine): (a) ~4400x, (d) ~2350x; "
        "target (a) >= 8000x, (d) >= 5000x"
    )
    print(
        f"{'':<38}{'x real time':>12}{'median':>9}{'incl. setup':>13}{'setup ms':>10}{'MB/min':>9}"
        f"{'push x':>9}{'logging x':>11}"
    )
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench.rrd"
        warm = ChatteringMonitor(nominal, MonitorSettings(), t0=rec.t[0])
        _run(warm, {"chattering": rec.values[0, :5000]}, args.chunk, path)  # one-time imports
        for label, settings, data, record in cases:
            best = (np.inf, np.inf, 0, np.inf, np.inf)
            streams = []
            for _ in range(args.repeat):
                mon = ChatteringMonitor(nominal, settings, t0=rec.t[0] if "chattering" in data else 0.0)
                setup, stream, size, t_push, t_log = _run(mon, data, args.chunk, path if record else None)
                best = min(best, (stream, setup, size, t_push, t_log))
                streams.append(stream)
                if path.exists():
                    path.unlink()
            stream, setup, size, t_push, t_log = best
            mb = f"{size / 1e6 / args.minutes:9.2f}" if record else f"{'-':>9}"
            log_x = f"{T / t_log:11.0f}" if record else f"{'-':>11}"
            print(
                f"{label:<38}{T / stream:12.0f}{T / np.median(streams):9.0f}{T / (stream + setup):13.0f}"
                f"{setup * 1e3:10.1f}{mb}{T / t_push:9.0f}{log_x}"
            )
        if _jit.enabled() and not args.no_baseline:
            # the same-process baseline: every case with a file on the numpy path
            # (CHATTERSPEC_JIT=0 switches the kernels at run time); one run each, they are 25-50x slower
            for label, settings, data, record in cases:
                if not record:
                    continue
                os.environ["CHATTERSPEC_JIT"] = "0"
                try:
                    mon = ChatteringMonitor(nominal, settings, t0=rec.t[0] if "chattering" in data else 0.0)
                    setup, stream, size, t_push, t_log = _run(mon, data, args.chunk, path)
                    path.unlink()
                finally:
                    os.environ.pop("CHATTERSPEC_JIT", None)
                name = f"{label.split()[0]} numpy path (baseline, 1 run)"
                print(
                    f"{name:<38}{T / stream:12.0f}{'-':>9}"
                    f"{T / (stream + setup):13.0f}{setup * 1e3:10.1f}{size / 1e6 / args.minutes:9.2f}"
                    f"{T / t_push:9.0f}{T / t_log:11.0f}"
                )
        if args.breakdown:
            jobs = [
                (label, _Setup(nominal, settings), data, record, rec.t[0] if "chattering" in data else 0.0)
                for label, settings, data, record in cases
            ]
            _breakdown(jobs, args.chunk, args.repeat, path, T)
    if args.live:
        _live(nominal, raw, args.repeat)


if __name__ == "__main__":
    main()
