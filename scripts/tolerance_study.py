"""Measure the decisions on the identified parameters (tolerances) and draw their figures.

Sections (all by default; ``--only a,b`` for some):

``false-alarms``
    24 h (``--hours``) of each plant under the repeated catalogue chirp, the linear EHA's model with
    tolerances bulk modulus +-15 %, friction +-30 %, leakage +-100 % at one false alarm per day
    (CUSUM): the nominal plant, bulk -10 % with friction +20 % (inside), and every parameter on a band
    edge (bulk -15 %, friction +30 %, leakage x2: the worst case the threshold is set for), the last
    also at one false alarm per hour (the calibration checked on the real identification). Alarm starts
    against the budget's 99 % Poisson interval; the fraction of windows whose interval lies inside the
    band.
``onsets``
    ``--onsets`` records of 30 s with a change at 20 s: bulk modulus -25 %, the catalogue's minor leak
    (6.25 x the nominal: outside +-100 %), minor leak with friction +40 %: detected onsets (99 %
    Clopper-Pearson), median and 90th-percentile delay (onset to the end of the deciding window), the
    parameter of the first alarm, false alarms before the onset.
``joint``
    ``--records`` 4 s records of the catalogue chirp with the minor leak and friction +40 % together,
    no tolerance (model selection over every combination): records naming both, and each interval's
    coverage (99 % Clopper-Pearson).
``events``
    ``--event-hours`` one-hour healthy recordings through ``chatterspec monitor --events jsonl
    --identification-events changes --false-alarms-per-hour 1`` (exact model): identification events
    that name a fault against the budget's 99 % Poisson interval.
``excitation``
    The closed-loop EHA held still (``eha-cl-hold-healthy``, ``eha-cl-hold-leak-medium``): fraction of
    the windows where the leakage is not excited; a hold-move-hold cycle without and with the closed-loop
    study's multisine (20/30/40 Hz, 6 rad/s per tone; also 8 rad/s and a 10 s horizon): the detectable
    leakage change held still against the minor leak's.

Figures (``--out figures``): ``tolerance_band.png`` (a drifting plant's estimates against their bands)
and ``tolerance_excitation.png`` (the detectable leakage over the hold-move-hold cycle).

Usage: ``python scripts/tolerance_study.py [--only ...] [--hours 24] [--onsets 500] [--records 1000]
[--event-hours 6] [--seed 0] [--out figures] [--json FILE]`` (about 25 min on 2 cores with the defaults,
most of it the 4 x 24 h of false-alarm data). The numbers are quoted in ``docs/paper-notes.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from chatterspec.detection.alarms.calibration import poisson_count_interval
from chatterspec.studies.intervals import clopper_pearson
from chatterspec.studies.tolerance_study import (
    CYCLE_MOVES,
    drift_record,
    eha_with_tolerances,
    excitation_cycle,
    false_alarm_study,
    onset_study,
    study_settings,
)

BE, A, L = 2.07e8, 2144.0, 4.8e-12
MINOR_LEAK = 3e-11
PLANTS = {
    "nominal": None,
    "inside (bulk -10 %, friction +20 %)": {"bulk_modulus": 0.9 * BE, "friction": 1.2 * A},
    "on the band edges (bulk -15 %, friction +30 %, leakage x2)": {
        "bulk_modulus": 0.85 * BE,
        "friction": 1.3 * A,
        "leakage": 2 * L,
    },
}


def false_alarms(hours: float, seed: int) -> list[dict]:
    model = eha_with_tolerances()
    rows = []
    cases = [(name, plant, 1 / 24) for name, plant in PLANTS.items()]
    cases.append(("on the band edges, at one per hour", PLANTS[list(PLANTS)[2]], 1.0))
    for k, (name, plant, budget) in enumerate(cases):
        t0 = time.perf_counter()
        r = false_alarm_study(model, plant, hours, seed=seed + k, settings=study_settings(model, budget))
        lo, hi = poisson_count_interval(r["expected"], 0.99)
        r.update({"plant": name, "poisson99": [lo, hi], "within": lo <= r["total_starts"] <= hi})
        r["wall_s"] = time.perf_counter() - t0
        print(
            f"{name}: {r['total_starts']} alarm starts in {r['hours']:.1f} h at {budget:g}/h "
            f"({r['starts']}); "
            f"99 % Poisson interval of the budget [{lo}, {hi}]: {'within' if r['within'] else 'OUTSIDE'}; "
            f"intervals inside the band: {', '.join(f'{p} {v:.3f}' for p, v in r['inside'].items())} "
            f"({r['wall_s']:.0f} s)"
        )
        rows.append(r)
    return rows


def onsets(runs: int, seed: int) -> list[dict]:
    model = eha_with_tolerances()
    rows = []
    for k, (name, fault) in enumerate(
        [
            ("bulk modulus -25 %", {"bulk_modulus": 0.75 * BE}),
            ("minor leak", {"leakage": MINOR_LEAK}),
            ("minor leak + friction +40 %", {"leakage": MINOR_LEAK, "friction": 1.4 * A}),
        ]
    ):
        r = onset_study(model, fault, runs, seed=seed + 10 + k)
        r["fault"] = name
        lo, hi = r["detected_ci99"]
        print(
            f"{name}: detected {r['detected']} of {r['runs']} onsets [{lo:.4f}, {hi:.4f}], delay median "
            f"{r['delay_median_s']:.2f} s, p90 {r['delay_p90_s']:.2f} s; first alarm {r['first_parameter']}; "
            f"in alarm at the end {r['named']}; alarms before the onset {r['alarms_before_onset']}"
        )
        rows.append(r)
    return rows


def joint(records: int, seed: int) -> dict:
    from chatterspec.detection.identification import identify
    from chatterspec.plants.scenarios import _eha
    from chatterspec.plants.simulate import simulate

    truth = {"leakage": MINOR_LEAK, "friction": 1.4 * A}
    sc = _eha("eha-leak-minor+friction-40up", "leakage+friction", "", None, **truth)
    sim = simulate(sc, records, seed)
    idn = identify(sc.nominal, sim.z, sim.u)
    rate = idn.selection_rate()
    k = round(rate["leakage+friction"] * records)
    out = {"records": records, "named_both": k, "named_both_ci99": list(clopper_pearson(k, records))}
    out["selection_rate"] = rate
    for p, v in truth.items():
        lo, hi = idn.interval("leakage+friction", p)
        c = int(np.sum((lo <= v) & (v <= hi)))
        out[f"coverage_{p}"] = [c / records, *clopper_pearson(c, records)]
    lo, hi = out["named_both_ci99"]
    print(
        f"leak + friction: 'leakage+friction' selected in {k} of {records} records [{lo:.4f}, {hi:.4f}]; "
        f"95 % interval coverage leakage {out['coverage_leakage'][0]:.3f} [{out['coverage_leakage'][1]:.3f}, "
        f"{out['coverage_leakage'][2]:.3f}], friction {out['coverage_friction'][0]:.3f} "
        f"[{out['coverage_friction'][1]:.3f}, {out['coverage_friction'][2]:.3f}]"
    )
    return out


def events(hours: int, seed: int) -> dict:
    from chatterspec.cli import main
    from chatterspec.online.simulated_stream import simulate_blocks
    from chatterspec.plants.scenarios import scenario

    sc = scenario("eha-healthy")
    named = alarms = total = 0
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "eha.toml"
        with contextlib.redirect_stdout(io.StringIO()):
            main(["scenarios", "eha-healthy", "--model-toml", str(model)])
        for h in range(hours):
            blocks = list(simulate_blocks(sc, seed + 100 + h, 3600.0, block_s=600.0))
            t = np.concatenate([b[0] for b in blocks])
            z = np.concatenate([b[1] for b in blocks])
            u = np.concatenate([b[2] for b in blocks])
            data = Path(tmp) / "h.npz"
            np.savez(data, time=t, position=z[:, 0], velocity=z[:, 1], pressure=z[:, 2], pump_speed=u[:, 0])
            out = io.StringIO()
            argv = ["monitor", str(model), "--data", str(data), "--events", "jsonl",
                    "--identification-events", "changes", "--false-alarms-per-hour", "1"]  # fmt: skip
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
                main(argv)
            evs = [json.loads(line) for line in out.getvalue().splitlines()]
            ids = [e for e in evs if e["event"] == "identification"]
            named += sum(e["fault"] not in (None, "no fault") for e in ids)
            alarms += sum(e["event"] == "fault-start" for e in evs)
            total += len(ids)
    lo, hi = poisson_count_interval(float(hours), 0.99)
    r = {"hours": hours, "fault_naming_events": named, "identification_events": total, "alarm_starts": alarms}
    # the budget bounds false alarms from above: fault names within it means at most its upper end
    r.update({"poisson99": [lo, hi], "within": named <= hi, "alarms_within": lo <= alarms <= hi})
    print(
        f"healthy, {hours} h at 1 false alarm/h: {alarms} alarm starts, {total} identification events, "
        f"{named} naming a fault; 99 % Poisson interval of the budget [{lo}, {hi}]: alarms "
        f"{'within' if r['alarms_within'] else 'OUTSIDE'}, fault names {'within' if r['within'] else 'ABOVE'}"
    )
    return r


def excitation(seed: int) -> tuple[dict, dict]:
    from chatterspec.detection.parameter_decision import monitor_parameters
    from chatterspec.plants.parameters import with_tolerances
    from chatterspec.plants.scenarios import scenario
    from chatterspec.plants.simulate import simulate
    from chatterspec.studies.tolerance_study import EHA_TOLERANCES

    out: dict = {}
    for name in ("eha-cl-hold-healthy", "eha-cl-hold-leak-medium"):
        sc = scenario(name)
        model = with_tolerances(sc.nominal, dict(EHA_TOLERANCES))
        sim = simulate(sc, 200, seed)
        rec = monitor_parameters(model, sim.z, sim.u, study_settings(model))
        frac = float(np.mean(rec.state[:, :, 0] == 2))
        out[name] = {"leakage_not_excited": frac, "alarm_starts": int(rec.starts.sum())}
        print(
            f"{name} (200 runs of 4 s): leakage not excited in {frac:.4f} of the windows, "
            f"{int(rec.starts.sum())} alarm starts"
        )
    records = {}
    minor = MINOR_LEAK - L
    cases = (
        ("no dither", None, None),
        ("multisine 6 rad/s per tone", 6.0, None),
        ("multisine 8 rad/s per tone", 8.0, None),
        ("multisine 6 rad/s, 10 s horizon", 6.0, 10.0),
    )
    for label, amp, horizon in cases:
        rec = excitation_cycle(amp, 64, seed=seed, horizon_s=horizon)
        held = (rec.times_s >= 11.0) & (rec.times_s < CYCLE_MOVES[0] - 0.5)  # held, a full horizon of data
        det = float(np.median(rec.detectable[:, held, 0]))
        hold = (rec.times_s < CYCLE_MOVES[0]) | (rec.times_s > CYCLE_MOVES[-1] + 0.5)
        ne = float(np.mean(rec.state[:, hold, 0] == 2))
        out[label] = {"detectable_leakage_change_held": det, "below_minor_leak_change": det < minor,
                      "leakage_not_excited_of_hold_time": ne}  # fmt: skip
        print(
            f"hold-move-hold, {label}: detectable leakage change held still {det:.3g} (leakage "
            f"{L + det:.3g}; the minor leak's change {minor:.3g}: {'below' if det < minor else 'ABOVE'}); "
            f"not excited in {ne:.3f} of the "
            "hold windows"
        )
        records[label] = rec
    return out, records


def figures(out: Path, seed: int, cycle: dict) -> None:
    from chatterspec.figures.plot_diagnosis import excitation_figure, tolerance_band_figure
    from chatterspec.figures.plot_studies import save

    rec, truth = drift_record(seed=seed)
    fig = tolerance_band_figure(
        rec, truth, ("bulk_modulus", "friction"),
        "A drifting EHA: bulk modulus to -25 %, friction to +20 %, against tolerances of +-15 % and +-30 %",
    )  # fmt: skip
    print(f"wrote {save(fig, out / 'tolerance_band.png')}")
    if not cycle:
        cycle = {
            k: excitation_cycle(a, 64, seed=seed)
            for k, a in (("no dither", None), ("multisine 6 rad/s per tone", 6.0))
        }
    sets = {k: cycle[k] for k in ("no dither", "multisine 6 rad/s per tone")}
    fig = excitation_figure(
        sets, "leakage", {"minor leak's change": MINOR_LEAK - L}, (CYCLE_MOVES[0], CYCLE_MOVES[-1] + 0.5),
        "Closed-loop EHA held, moved (four 10 mm moves), held: detectable leakage change, 64 runs",
    )  # fmt: skip
    print(f"wrote {save(fig, out / 'tolerance_excitation.png')}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="false-alarms,onsets,joint,events,excitation,figures")
    ap.add_argument("--hours", type=float, default=24.0)
    ap.add_argument("--onsets", type=int, default=500)
    ap.add_argument("--records", type=int, default=1000)
    ap.add_argument("--event-hours", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("figures"))
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    only = set(args.only.split(","))
    doc: dict = {}
    cycle: dict = {}
    if "false-alarms" in only:
        doc["false_alarms"] = false_alarms(args.hours, args.seed)
    if "onsets" in only:
        doc["onsets"] = onsets(args.onsets, args.seed)
    if "joint" in only:
        doc["joint"] = joint(args.records, args.seed + 20)
    if "events" in only:
        doc["events"] = events(args.event_hours, args.seed)
    if "excitation" in only:
        doc["excitation"], cycle = excitation(args.seed + 30)
    if "figures" in only:
        figures(args.out, args.seed, cycle)
    if args.json is not None:
        args.json.write_text(json.dumps(doc, indent=2, default=float))


if __name__ == "__main__":
    main()
