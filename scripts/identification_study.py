"""Validate fault identification on the catalogue and draw figures/identification_sweep.png.

For every EHA and second-order catalogue fault (one 4 s record per realization): the
estimate of the true parameter against its value in the scenario's plant (median relative
error), the coverage of the 95 % intervals and the isolation rate (fraction of records
selecting the true hypothesis), both with 99 % Clopper-Pearson intervals; the healthy
records' "no fault" rate; the second-order timeline's natural frequency in the faulty
segment; least squares against instrumental variables (the errors-in-variables bias); then
the sweep figure over the power-study families.

Usage: ``python scripts/identification_study.py [--runs 1000] [--healthy-runs 20000] [--seed 23]
[--sweep-runs 300] [--out figures] [--json FILE]`` (about 2 min on 2 cores with the defaults).
The numbers are quoted in ``docs/paper-notes.md``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from chatterspec.detection.identification import identification_setup, identify
from chatterspec.figures.plot_diagnosis import identification_sweep_figure
from chatterspec.figures.plot_studies import save
from chatterspec.plants.scenarios import scenario
from chatterspec.plants.simulate import simulate
from chatterspec.studies.identification_study import identification_sweep, identification_validation
from chatterspec.studies.intervals import clopper_pearson

CATALOGUE = (
    "eha-leak-minor",
    "eha-leak-medium",
    "eha-leak-major",
    "eha-friction-minor",
    "eha-friction-major",
    "eha-bulk-50down",
    "eha-bulk-25down",
    "eha-bulk-25up",
    "eha-bulk-50up",
    "so-f9-low",
    "so-f11-low",
    "so-f12-low",
    "so-f15-low",
    "so-f9-high",
    "so-f11-high",
    "so-f12-high",
    "so-f15-high",
)
HEALTHY = ("eha-healthy", "so-healthy-low", "so-healthy-high")


def _fmt(v: list) -> str:
    return f"{v[0]:.4f} [{v[1]:.4f}, {v[2]:.4f}]"


def catalogue_table(runs: int, seed: int) -> list[dict]:
    rows = []
    print(f"catalogue faults, {runs} records each (seed {seed}); 99 % Clopper-Pearson intervals")
    print(
        f"{'scenario':<20} {'true':<18} {'value':>10} {'median est':>11} {'med rel err':>11}  "
        f"{'95% CI coverage':<26} isolation"
    )
    for name in CATALOGUE:
        r = identification_validation(scenario(name), runs, seed).row()
        rows.append(r)
        print(
            f"{name:<20} {r['true_hypothesis']:<18} {r['true_value']:>10.4g} {r['median_estimate']:>11.5g} "
            f"{r['median_relative_error']:>11.2e}  {_fmt(r['coverage']):<26} {_fmt(r['isolation'])}",
            flush=True,
        )
    return rows


def healthy_table(runs: int, seed: int) -> list[dict]:
    rows = []
    print(f"healthy records, {runs} each: fraction selecting 'no fault' (alpha = 0.001: expected 0.999)")
    for name in HEALTHY:
        r = identification_validation(scenario(name), runs, seed).row()
        k = round(r["selection_rate"].get("no fault", 0.0) * runs)
        lo, hi = clopper_pearson(runs - k, runs, 0.99)
        r["false_selection"] = [(runs - k) / runs, lo, hi]
        rows.append(r)
        print(
            f"  {name:<18} no fault {k}/{runs}; other selections {(runs - k) / runs:.5f} [{lo:.5f}, {hi:.5f}]"
        )
    return rows


def timeline(runs: int, seed: int) -> dict:
    sc = scenario("so-timeline-constant")
    sim = simulate(sc, runs, seed)
    idn = identify(sc.nominal, sim.z, sim.u, window_s=(0.2, 1.8))  # the 8 Hz segment, a hop inside
    f0 = idn.estimate("natural_frequency")
    lo, hi = idn.interval("natural_frequency")
    damp = identify(sc.nominal, sim.z, sim.u, window_s=(4.2, 5.8))
    out = {
        "runs": runs,
        "f0_max_abs_error_hz": float(np.max(np.abs(f0 - 8.0))),
        "f0_median": float(np.median(f0)),
        "f0_coverage": float(np.mean((lo <= 8.0) & (8.0 <= hi))),
        "f0_selected": idn.selection_rate()["natural_frequency"],
        "damping_median": float(np.median(damp.estimate("damping"))),
        "damping_selected": damp.selection_rate()["damping"],
    }
    print(f"so-timeline-constant, {runs} records: {json.dumps(out)}")
    return out


def least_squares_vs_iv(runs: int, seed: int) -> dict:
    """Bias of the leakage entry A33 (pressure chattering on z2, z3, u) by plain least squares, least
    squares corrected with the known R and the nominal Phi, and instrumental variables."""
    out = {}
    for name in ("eha-healthy", "eha-leak-minor", "eha-leak-major"):
        sc = scenario(name)
        sim = simulate(sc, runs, seed)
        A, B, R = sc.nominal.A, sc.nominal.B, sc.nominal.R
        true = sc.segments[0].model.A[2, 2] - A[2, 2]
        e3 = sim.z[:, 2:, 2] - sim.z[:, 1:-1] @ A[2] - sim.u[1:-1, 0] * B[2, 0]
        X = np.stack(
            [sim.z[:, 1:-1, 1], sim.z[:, 1:-1, 2], np.broadcast_to(sim.u[1:-1, 0], e3.shape)], axis=-1
        )
        n = e3.shape[1]
        xx = np.einsum("rka,rkb->rab", X, X)
        xe = np.einsum("rka,rk->ra", X, e3)
        ls = np.linalg.solve(xx, xe[..., None])[:, 1, 0]
        # known-R correction: E[x x'] noise part diag(R22, R33, 0), E[x eta3] = (-Phi32 R22, -Phi33 R33, 0)
        corr_xx = np.diag([R[1, 1], R[2, 2], 0.0]) * n
        corr_xe = np.array([-A[2, 1] * R[1, 1], -A[2, 2] * R[2, 2], 0.0]) * n
        cls = np.linalg.solve(xx - corr_xx, (xe - corr_xe)[..., None])[:, 1, 0]
        setup = identification_setup(sc.nominal)
        iv = identify(sc.nominal, sim.z, sim.u).fit["entries"][:, setup.labels.index("A[3,3]")]
        out[name] = {
            "true_deviation": true,
            **{
                k: {"mean_error": float(v.mean() - true), "std": float(v.std(ddof=1))}
                for k, v in (("least_squares", ls), ("corrected_least_squares", cls), ("iv", iv))
            },
        }
        print(
            f"  {name}: dA33 {true:.4e}; "
            + "; ".join(
                f"{k} error {out[name][k]['mean_error']:+.2e} (sd {out[name][k]['std']:.1e})"
                for k in ("least_squares", "corrected_least_squares", "iv")
            )
        )
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--runs", type=int, default=1000)
    p.add_argument("--healthy-runs", type=int, default=20000)
    p.add_argument("--sweep-runs", type=int, default=300)
    p.add_argument("--seed", type=int, default=23)
    p.add_argument("--out", default="figures")
    p.add_argument("--json", default=None)
    p.add_argument(
        "--only",
        default="catalogue,healthy,timeline,ls,sweep",
        help="comma-separated parts to run (default all: catalogue,healthy,timeline,ls,sweep)",
    )
    args = p.parse_args()
    parts = set(args.only.split(","))
    t0 = time.perf_counter()
    doc: dict = {}
    if "catalogue" in parts:
        doc["catalogue"] = catalogue_table(args.runs, args.seed)
    if "healthy" in parts:
        doc["healthy"] = healthy_table(args.healthy_runs, args.seed + 1)
    if "timeline" in parts:
        doc["timeline"] = timeline(200, args.seed + 2)
    if "ls" in parts:
        print("least squares vs instrumental variables (500 records):")
        doc["least_squares_vs_iv"] = least_squares_vs_iv(500, args.seed + 3)
    if "sweep" in parts:
        sweeps = {
            fam: identification_sweep(fam, runs=args.sweep_runs, seed=args.seed + 4)
            for fam in ("leakage", "friction", "bulk-modulus", "f0")
        }
        doc["sweeps"] = {fam: [r.row() for r in rows] for fam, rows in sweeps.items()}
        path = save(identification_sweep_figure(sweeps), Path(args.out) / "identification_sweep.png")
        print(f"figure: {path}")
    print(f"{time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
