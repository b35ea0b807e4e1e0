"""Alarms over days: false-alarm budgets verified through the online monitor, and detection delays.

Not a test (the default suite runs a one-hour version, tests/test_alarm_monitor.py). Two parts:

``verify``
    Healthy streams (``--streams`` of ``--days * 24 / streams`` hours each, seeds 1, 2, ...) of the
    linear EHA (``eha-healthy``: 1 kHz, 3 channels) and of the second-order plant
    (``so-healthy-high``: 10 Hz, zeta 0.1, 2 channels; see :func:`plant`) are simulated block by block
    (:func:`chatterspec.online.simulated_stream.simulate_blocks`, constant memory) and pushed, one minute per
    push, through one :class:`~chatterspec.online.monitor.ChatteringMonitor` per rule, each with
    its threshold for the budget (``--budget``, default one false alarm per day, all channels
    together; from :func:`chatterspec.studies.alarm_budget.calibrate_alarm`, ``--calibration-hours``
    of other healthy data, as ``chatterspec calibrate --alarm-hours`` does). Counted: the monitors'
    fault-start events. Reported per plant and rule: the count, the two-sided 99 % Poisson interval
    of the count the budget predicts, whether the count lies inside, and the CPU time (process
    time of that rule's monitor plus its share of the simulation). The monitors' frame scores are
    kept (float32) to count, with the same layer on the same scores, the starts of thresholds for
    ``--extra-budgets`` (a sharper check: more expected alarms) and of the monitor's in-call
    thresholds (12 channel-hours of simulation).

``delays``
    Every fault of the EHA catalogue and the two second-order timelines as onset scenarios
    (:func:`chatterspec.studies.alarm_budget.onset_scenarios`: 6 s healthy, then the fault; the
    EHA at 8 phases of its 4 s chirp), ``--runs`` realizations each, per rule at the budget and
    for today's per-frame rule at alpha 0.1 %: detection rate, median and p90 delay (s, to the end
    of the frame that raised the alarm), alarms on the fault's channel, false starts in the
    healthy stretches.

Usage::

    python benchmarks/bench_alarms.py verify [--days 7] [--streams 7] [--workers 2] [--json FILE]
    python benchmarks/bench_alarms.py delays [--runs 25] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from chatterspec.detection.alarms.calibration import poisson_count_interval
from chatterspec.detection.alarms.rules import FrameRule, make_rule
from chatterspec.detection.alarms.streams import run_rule
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.online.simulated_stream import simulate_blocks
from chatterspec.plants.scenarios import Scenario, scenario
from chatterspec.studies.alarm_budget import alarm_settings, calibrate_alarm, in_call_hours

RULES = ("frame", "persistence", "cusum")
CAL_SEED = 12345


def plant(name: str) -> Scenario:
    """The healthy scenario of a plant: ``eha`` (eha-healthy) or ``so`` (so-healthy-high).

    The second-order timelines' nominal model (5 Hz, zeta 0, explicit Euler) is unstable
    (eigenvalue modulus 1.0005: its state grows e-fold every 2 s), so no healthy stream of days
    exists for it; ``so-healthy-high`` is the paper's stable second-order plant (10 Hz, zeta 0.1)
    with the timelines' high measurement noise.
    """
    return scenario("eha-healthy" if name == "eha" else "so-healthy-high")


def _stream(job: tuple) -> dict:
    """One healthy stream through one monitor per rule (worker process)."""
    plant_name, seed, hours, settings_by_rule = job
    sc = plant(plant_name)
    model = sc.nominal
    mons = {r: ChatteringMonitor(model, s, t0=0.0) for r, s in settings_by_rule.items()}
    starts = dict.fromkeys(mons, 0)
    cpu = dict.fromkeys(mons, 0.0)
    scores: list[np.ndarray] = []
    t_sim = 0.0
    t0 = time.process_time()
    first = next(iter(mons))
    for _, z, u in simulate_blocks(sc, seed, hours * 3600.0, block_s=60.0):
        t1 = time.process_time()
        t_sim += t1 - t0
        for r, mon in mons.items():
            a = time.process_time()
            upd = mon.push(z, u)
            cpu[r] += time.process_time() - a
            starts[r] += sum(e.kind == "fault-start" for e in upd.events)
            if r == first and upd.frames.n_frames:
                scores.append(upd.frames.score.astype(np.float32))
        t0 = time.process_time()
    return {
        "starts": starts,
        "cpu": cpu,
        "sim_cpu": t_sim,
        "frames": mons[first].n_frames,
        "scores": np.concatenate(scores),
    }


def verify(args: argparse.Namespace) -> dict:
    out: dict = {"budget_per_hour": args.budget, "days": args.days, "plants": {}}
    for pname in args.plants.split(","):
        sc = plant(pname)
        model = sc.nominal
        base = MonitorSettings()
        t = time.process_time()
        cals = {
            r: calibrate_alarm(model, base, r, args.budget, hours=args.calibration_hours, seed=CAL_SEED)
            for r in args.rules.split(",")
        }
        cal_cpu = time.process_time() - t
        settings = {r: alarm_settings(model, base, calibration=c) for r, c in cals.items()}
        hours = args.days * 24.0 / args.streams
        jobs = [(pname, s + 1, hours, settings) for s in range(args.streams)]
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            res = list(pool.map(_stream, jobs))
        total_h = hours * args.streams
        sim_cpu = sum(r["sim_cpu"] for r in res)
        scores = [r["scores"][None].astype(float) for r in res]
        F = 3600.0 / (base.stft.n_hop(model.dt) * model.dt)
        rows = {}
        for r, cal in cals.items():
            n = sum(x["starts"][r] for x in res)
            mu = args.budget * total_h
            lo, hi = poisson_count_interval(mu, 0.99)
            cpu = sum(x["cpu"][r] for x in res) + sim_cpu / len(cals)
            row = {
                "threshold": cal.threshold,
                "calibration": cal.to_dict(),
                "starts": n,
                "hours": total_h,
                "expected": mu,
                "interval_99": [lo, hi],
                "inside": bool(lo <= n <= hi),
                "cpu_s": cpu,
                "cpu_s_per_7_days": cpu * 7 * 24 / total_h,
            }
            extra = {}
            for x in [float(v) for v in args.extra_budgets.split(",") if v]:
                c2 = calibrate_alarm(model, base, cal.rule, x, hours=args.calibration_hours, seed=CAL_SEED)
                n2 = int(sum(run_rule(c2.rule, s).starts.sum() for s in scores))
                lo2, hi2 = poisson_count_interval(x * total_h, 0.99)
                extra[f"{x:g}"] = {"threshold": c2.threshold, "starts": n2, "interval_99": [lo2, hi2],
                                   "inside": bool(lo2 <= n2 <= hi2), "method": c2.method,
                                   "rate_interval": list(c2.rate_interval)}  # fmt: skip
            c3 = calibrate_alarm(model, base, cal.rule, args.budget, hours=in_call_hours(model.n_outputs))
            n3 = int(sum(run_rule(c3.rule, s).starts.sum() for s in scores))
            row["extra_budgets"] = extra
            row["in_call"] = {"threshold": c3.threshold, "method": c3.method, "starts": n3,
                              "rate_interval": list(c3.rate_interval)}  # fmt: skip
            rows[r] = row
        out["plants"][pname] = {
            "hours": total_h,
            "frames_per_hour": F,
            "channels": model.n_outputs,
            "sim_cpu_s": sim_cpu,
            "calibration_cpu_s": cal_cpu,
            "rules": rows,
        }
        print(f"\n{pname}: {total_h:g} h of healthy data ({args.streams} streams), budget {args.budget:g}/h, "
              f"simulation {sim_cpu:.0f} s CPU, "
              f"calibration ({args.calibration_hours:g} h) {cal_cpu:.0f} s CPU")  # fmt: skip
        print(f"{'rule':<12}{'h':>8}{'starts':>8}{'expected':>10}{'99% interval':>15}{'inside':>8}"
              f"{'CPU s/7 d':>11}   extra budgets (starts / interval)   in-call 4 h threshold")  # fmt: skip
        for r, row in rows.items():
            ex = "; ".join(
                f"{k}/h: {v['starts']} in {v['interval_99']}" for k, v in row["extra_budgets"].items()
            )
            ic = row["in_call"]
            print(f"{r:<12}{row['threshold']:>8.2f}{row['starts']:>8d}{row['expected']:>10.1f}"
                  f"{row['interval_99']!s:>15}{'yes' if row['inside'] else 'NO':>8}"
                  f"{row['cpu_s_per_7_days']:>11.0f}   {ex}   "
                  f"h {ic['threshold']:.2f}: {ic['starts']} starts")  # fmt: skip
    return out


def delays(args: argparse.Namespace) -> dict:
    from chatterspec.studies.alarm_budget import alarm_delays, onset_scenarios

    faults = args.faults.split(",") + [f for f in args.extra.split(",") if f]
    out: dict = {"budget_per_hour": args.budget, "runs_per_scenario": args.runs, "faults": {}}
    rules_by_model: dict[str, dict] = {}
    print(
        f"{'fault':<22}{'rule':<22}{'detected':>9}{'median s':>10}{'p90 s':>8}{'max s':>8}"
        f"{'fault ch':>9}{'false':>7}"
    )
    for name in faults:
        if name.startswith("eha-leak=") or name.startswith("eha-leak-"):
            base = _leak(name)
        else:
            base = scenario(name)
        scs = onset_scenarios(base)
        model = scs[0].nominal
        key = model.fingerprint()
        if key not in rules_by_model:
            base = MonitorSettings()
            rules = {"frame 0.1% per frame": FrameRule(-math.log(1e-3))}
            for r in RULES:
                c = calibrate_alarm(
                    model, base, make_rule(r), args.budget, hours=args.calibration_hours, seed=CAL_SEED
                )
                rules[f"{r} {args.budget:.3g}/h"] = c.rule
            rules_by_model[key] = rules
        rules = rules_by_model[key]
        res = alarm_delays(scs, rules, args.runs, seed=7)
        out["faults"][name] = {k: {**v.to_dict(), "rule": rules[k].to_dict()} for k, v in res.items()}
        for k, v in res.items():
            d = v.to_dict()
            med = "miss" if d["median_s"] is None else f"{d['median_s']:.2f}"
            p90 = "miss" if d["p90_s"] is None else f"{d['p90_s']:.2f}"
            mx = "miss" if d["max_s"] is None else f"{d['max_s']:.2f}"
            print(f"{name:<22}{k:<22}{d['detected']:>9.3f}{med:>10}{p90:>8}{mx:>8}{d['on_fault_channel']:>9.3f}"
                  f"{d['false_starts_before_onset']:>7d}")  # fmt: skip
    return out


def _leak(name: str) -> Scenario:
    """``eha-leak=1e-11``: the catalogue's leakage scenario with another leakage coefficient."""
    if "=" not in name:
        return scenario(name)
    import dataclasses

    from chatterspec.plants.models import eha_linear

    L = float(name.split("=", 1)[1])
    return dataclasses.replace(scenario("eha-leak-minor"), name=name, plant=eha_linear(leakage=L), level=name)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    v = sub.add_parser("verify")
    v.add_argument("--days", type=float, default=7.0)
    v.add_argument("--streams", type=int, default=7)
    v.add_argument("--plants", default="eha,so")
    v.add_argument("--rules", default=",".join(RULES))
    v.add_argument("--extra-budgets", default="1", help="comma-separated budgets (per hour) also checked")
    v.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1))
    d = sub.add_parser("delays")
    d.add_argument("--runs", type=int, default=25, help="realizations per onset scenario")
    d.add_argument(
        "--extra", default="eha-leak=1e-11", help="more faults, e.g. eha-leak=1e-11 (a weak leakage)"
    )
    d.add_argument(
        "--faults",
        default="eha-leak-minor,eha-leak-medium,eha-leak-major,eha-friction-minor,eha-friction-major,"
        "eha-bulk-50down,eha-bulk-25down,eha-bulk-25up,eha-bulk-50up,so-timeline-constant,so-timeline-step",
    )
    for p in (v, d):
        p.add_argument(
            "--budget", type=float, default=1.0 / 24.0, help="false alarms per hour (default 1/24)"
        )
        p.add_argument("--calibration-hours", type=float, default=48.0)
        p.add_argument("--json", default=None, metavar="FILE")
    args = ap.parse_args()
    t = time.perf_counter()
    doc = verify(args) if args.what == "verify" else delays(args)
    doc["wall_s"] = time.perf_counter() - t
    print(f"\n{doc['wall_s']:.0f} s wall")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(doc, f, indent=1, default=float)


if __name__ == "__main__":
    main()
