"""Benchmark: SMM-SVSF on ``eha4-leak-timeline`` (psi sweep) and IMM banks on ``eha4-imm-analogue``.

``smm``: for each velocity/acceleration boundary-layer scale, the SMM-SVSF (Table 1 reading) and the
plain SVSF-cov on the same realizations: velocity RMSE of both and their ratio, the pressure RMSE
against sqrt(R), the worst per-segment argmax accuracy and the delay of the run-mean weight to pass 0.8
after each onset. ``imm``: one IMM bank type over the whole analogue record: the confusion matrix
(percent, rows predicted, columns actual), argmax accuracy, RMSE per state and the wall time.

``rate``: realization-steps per second of the SMM-SVSF (Table 1) on ``eha4-leak-timeline``, compiled
(:mod:`chatterspec.filters.smm_svsf`) and its numpy path in the same run (outputs compared first),
and the SVSF-cov alone on the same data for scale.

Usage::

    python benchmarks/bench_multiple_model.py smm --runs 2 --scales 0.1 1 10
    python benchmarks/bench_multiple_model.py rate --runs 20
    python benchmarks/bench_multiple_model.py imm --bank ekf --runs 10 [--steps 60000] [--path protocol]

``imm`` reports the wall and CPU time of the filter call alone (after a 2-sample warm-up that
compiles or loads the kernels, reported as ``warmup_seconds``) and the 1-minute load average.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

import chatterspec as cs
from chatterspec import _jit
from chatterspec.filters import ExtendedKalmanFilter, SecondOrderSVSF, SVSFCov
from chatterspec.filters.imm import IMM
from chatterspec.filters.smm_svsf import SMMSVSF
from chatterspec.studies.estimation import argmax_accuracy, confusion_matrix, rmse_table, switch_delays


def smm(runs: int, seed: int, scales: list[float]) -> list[dict[str, object]]:
    sc = cs.scenario("eha4-leak-timeline")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=runs, seed=seed)
    z, u, truth = sim.z[:, 1:], sim.u[:-1], sim.x[:, 1:]
    true = fs.mode_index(sc)[1:]
    rows = []
    for s in scales:
        psi = np.array(fs.psi) * np.array([1.0, s, s, 1.0])
        t0 = time.perf_counter()
        out = SMMSVSF(fs.mode_models, psi=psi, gamma=fs.gamma, mapping=fs.mapping).run(
            z, u, x0=fs.x0, P0=fs.P0
        )
        t_smm = time.perf_counter() - t0
        ref = SVSFCov(fs.mode_models[0], psi=psi, gamma=fs.gamma, mapping=fs.mapping).run(
            z, u, x0=fs.x0, P0=fs.P0, store=["x_post"]
        )
        tab = rmse_table({"svsf": ref.x_post, "smm": out.x_post}, truth, sc.nominal.state_names)
        d = switch_delays(out.mu, true, sim.t[1:], levels=(0.5, 0.8))
        rows.append(
            {
                "psi": psi.tolist(),
                "rmse": tab,
                "velocity_ratio": tab["smm"]["velocity"] / tab["svsf"]["velocity"],
                "pressure_over_sqrtR": {k: v["pressure"] / np.sqrt(fs.R[3, 3]) for k, v in tab.items()},
                "min_segment_argmax_accuracy": float(np.nanmin(argmax_accuracy(out.mu, true))),
                "delay_of_mean_s(0.5, 0.8)": d.of_mean.tolist(),
                "smm_seconds": t_smm,
            }
        )
        print(json.dumps(rows[-1]), flush=True)
    return rows


def rate(runs: int, seed: int) -> dict[str, object]:
    """SMM-SVSF realization-steps per CPU second: compiled loop vs numpy path (same run, same data)."""
    sc = cs.scenario("eha4-leak-timeline")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=runs, seed=seed)
    z, u = sim.z[:, 1:], sim.u[:-1]
    f = SMMSVSF(fs.mode_models, psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping)
    numpy_path = SMMSVSF(fs.mode_models, psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping)
    object.__setattr__(numpy_path, "_compiled", None)
    f.run(z[:1, :2], u[:2], x0=fs.x0, P0=fs.P0)  # compile or load the kernel
    steps = z.shape[0] * z.shape[1]

    def cpu(fn) -> float:  # type: ignore[no-untyped-def]
        best = np.inf
        for _ in range(3):
            c0 = time.process_time()
            fn()
            best = min(best, time.process_time() - c0)
        return best

    a = f.run(z, u, x0=fs.x0, P0=fs.P0)
    n_np = min(runs, 2)
    b = numpy_path.run(z[:n_np], u, x0=fs.x0, P0=fs.P0)
    gap = float(np.max(np.abs(a.x_post[:n_np] - b.x_post) / np.max(np.abs(b.x_post), axis=(0, 1))))
    svsf = SVSFCov(fs.mode_models[0], psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping)
    t_numpy = cpu(lambda: numpy_path.run(z[:n_np], u, x0=fs.x0, P0=fs.P0))
    t_svsf = cpu(lambda: svsf.run(z, u, x0=fs.x0, P0=fs.P0, store=["x_post"]))
    row = {
        "runs": runs,
        "steps": z.shape[1],
        "smm_compiled_Msteps_per_cpu_s": steps / cpu(lambda: f.run(z, u, x0=fs.x0, P0=fs.P0)) / 1e6,
        "smm_numpy_Msteps_per_cpu_s": n_np * z.shape[1] / t_numpy / 1e6,
        "svsf_cov_Msteps_per_cpu_s": steps / t_svsf / 1e6,
        "max_rel_gap_x_post": gap,
        "loadavg_1min": os.getloadavg()[0],
    }
    print(json.dumps(row), flush=True)
    return row


def bank(kind: str, fs: object) -> list[object]:
    def make(m: object) -> object:
        if kind == "ekf":
            return ExtendedKalmanFilter(m)
        if kind == "svsf-cov":
            return SVSFCov(m, psi=np.array(fs.psi), gamma=fs.gamma, mapping="cov")
        if kind == "svsf-luen":
            return SVSFCov(m, psi=np.array(fs.psi + fs.psi_lower), gamma=fs.gamma, mapping="luen")
        if kind == "svsf2-cov":
            return SecondOrderSVSF(m, gamma=fs.gamma, lam=np.array(fs.cutoff_lambda), mapping="cov")
        if kind == "svsf2-luen":
            return SecondOrderSVSF(m, gamma=fs.gamma, lam=np.array(fs.cutoff_lambda), mapping="luen")
        raise SystemExit(f"unknown bank {kind!r}")

    return [make(m) for m in fs.mode_models]  # type: ignore[attr-defined]


def imm(kind: str, runs: int, seed: int, steps: int | None, path: str = "auto") -> dict[str, object]:
    sc = cs.scenario("eha4-imm-analogue")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=runs, seed=seed)
    T = sim.z.shape[1] - 1 if steps is None else steps
    z, u, truth = sim.z[:, 1 : T + 1], sim.u[:T], sim.x[:, 1 : T + 1]
    f = IMM(bank(kind, fs), fs.transition_matrix, mu0=np.array(fs.mu0), modes=fs.modes)
    fused = getattr(f, "_fused", None) is not None and path == "auto" and _jit.enabled()
    if path == "protocol":  # the per-mode Filter.update path (the fused kernel's reference)
        object.__setattr__(f, "_fused", None)
    # warm-up on 2 samples: compiles the kernels (or loads them from numba's cache), not timed
    t0 = time.perf_counter()
    f.run(z[:1, :2], u[:2], x0=fs.x0, P0=fs.P0)
    warm = time.perf_counter() - t0
    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    out = f.run(z, u, x0=fs.x0, P0=fs.P0)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    true = fs.mode_index(sc)[1 : T + 1]
    row = {
        "bank": kind,
        "path": "fused" if fused else ("protocol" if _jit.enabled() else "numpy"),
        "runs": runs,
        "steps": T,
        "seconds": wall,
        "cpu_seconds": cpu,
        "warmup_seconds": warm,
        "loadavg_1min_before_after": [load0[0], os.getloadavg()[0]],
        "confusion_percent": np.round(confusion_matrix(out.mu, true), 2).tolist(),
        "argmax_accuracy": np.round(argmax_accuracy(out.mu, true), 4).tolist(),
        "rmse": rmse_table({kind: out.x_post}, truth, sc.nominal.state_names)[kind],
    }
    print(json.dumps(row), flush=True)
    return row


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=["smm", "imm", "rate"])
    p.add_argument("--runs", type=int, default=2)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--scales", type=float, nargs="+", default=[0.01, 0.1, 1.0, 10.0])
    p.add_argument("--bank", default="ekf")
    p.add_argument("--steps", type=int, default=None)
    p.add_argument(
        "--path",
        choices=["auto", "protocol"],
        default="auto",
        help="auto: the compiled fused IMM step when the bank supports it; protocol: per-mode "
        "Filter.update calls (CHATTERSPEC_JIT=0 in the environment gives the numpy path)",
    )
    args = p.parse_args(argv)
    if args.what == "smm":
        smm(args.runs, args.seed, args.scales)
    elif args.what == "rate":
        rate(args.runs, args.seed)
    else:
        imm(args.bank, args.runs, args.seed, args.steps, args.path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
