"""Benchmark: one sample per call, against filterpy in the same process.

The loop a real-time user writes: one measurement in, one estimate out, per call. Timed per call
(``time.perf_counter_ns`` around each call: median and 99th percentile, wall time) and per loop in
CPU time (``time.process_time`` over the whole stream divided by its samples), best of ``--repeat``
rounds, the libraries alternating inside each round:

* KF: :class:`chatterspec.KalmanFilter` ``.online(x0, P0).step(z, u)`` against filterpy's
  ``KalmanFilter`` ``predict(u); update(z)`` on the DETC2015 EHA (3 states, 1 output);
* EKF with a nonlinear measurement ``h(x)``: a model from one-sample functions
  (:meth:`chatterspec.NonlinearModel.from_steps`, compiled by chatterspec) against filterpy's
  ``ExtendedKalmanFilter`` ``predict(u); update(z, HJacobian, Hx)`` (2 states, a range-like ``h``);
* IMM of 2 KFs: :class:`chatterspec.IMM` against filterpy's ``IMMEstimator``;
* chatterspec only: SVSF with covariance, the 2nd-order SVSF, the SMM-SVSF (2 modes), the chattering
  SVSF (sat) and the chattering monitor's ``step`` (the EHA, 3 channels, frames included).

Before timing, each pair is checked to give the same estimates (tolerances printed). Not a test:
the numbers depend on the machine and its load (printed).

Usage::

    python benchmarks/bench_one_sample.py [--samples 20000] [--repeat 5] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable

import numpy as np

import chatterspec as cs
from chatterspec.plants.models import LinearModel

DT = 0.01


# ------------------------------------------------------------------ models
def detc_model(a21: float = -557.02) -> LinearModel:
    """The DETC2015 linear EHA (eq 25-27) with the filter's Q, R."""
    A = np.array([[1.0, 0.001, 0.0], [0.0, 1.0, 0.001], [a21, -28.616, 0.9418]])
    B = np.array([[0.0], [0.0], [557.02]])
    return LinearModel(
        A, B, np.array([[1.0, 0.0, 0.0]]), np.diag([1e-6, 1e-4, 1e-2]), np.array([[1e-4]]), 1e-3
    )


A2 = np.array([[1.0, DT], [-4.0 * DT, 1.0 - 0.2 * DT]])
B2 = np.array([[0.0], [DT]])


def range_f(x, u, out):  # type: ignore[no-untyped-def]
    """Linear oscillator dynamics written for one sample (the same A2, B2 filterpy uses)."""
    out[0] = (u[0] * B2[0, 0] + A2[0, 0] * x[0]) + A2[0, 1] * x[1]
    out[1] = (u[0] * B2[1, 0] + A2[1, 0] * x[0]) + A2[1, 1] * x[1]


def range_f_jac(x, u, out):  # type: ignore[no-untyped-def]
    out[0, 0] = A2[0, 0]
    out[0, 1] = A2[0, 1]
    out[1, 0] = A2[1, 0]
    out[1, 1] = A2[1, 1]


def range_h(x, out):  # type: ignore[no-untyped-def]
    """Distance to a point 1 unit off the position axis."""
    out[0] = np.sqrt(x[0] * x[0] + 1.0)


def range_h_jac(x, out):  # type: ignore[no-untyped-def]
    out[0, 0] = x[0] / np.sqrt(x[0] * x[0] + 1.0)
    out[0, 1] = 0.0


def _hx(x: np.ndarray) -> np.ndarray:
    return np.array([np.sqrt(x[0] * x[0] + 1.0)])


def _H(x: np.ndarray) -> np.ndarray:
    return np.array([[x[0] / np.sqrt(x[0] * x[0] + 1.0), 0.0]])


# ------------------------------------------------------------------ timing
def per_call(fn: Callable[[int], object], T: int) -> tuple[np.ndarray, float]:
    """Per-call wall times (ns) of ``fn(k)``, k = 0 .. T-1, and the CPU seconds of the loop."""
    ns = np.empty(T, dtype=np.int64)
    clock = time.perf_counter_ns
    c0 = time.process_time()
    for k in range(T):
        t0 = clock()
        fn(k)
        ns[k] = clock() - t0
    return ns, time.process_time() - c0


def max_abs_diff(ours: Callable[[int], object], theirs: Callable[[int], object], n: int = 2000) -> float:
    """Largest ``|x_ours - x_theirs|`` over the first ``n`` calls of two fresh per-sample loops
    (each call returns its estimate): the pair is checked equal before it is timed."""
    return max(float(np.max(np.abs(np.asarray(ours(k)) - np.asarray(theirs(k))))) for k in range(n))


def measure(cases: dict[str, Callable[[], Callable[[int], object]]], T: int, repeat: int) -> dict[str, dict]:
    """Best of ``repeat`` rounds per case (median, p99 of the per-call wall time; CPU per call).

    The cases alternate inside each round, so a change of load hits all of them."""
    best: dict[str, dict] = {}
    for _ in range(repeat):
        for name, make in cases.items():
            fn = make()
            fn(0)  # compile / warm
            ns, cpu = per_call(fn, T)
            us = ns[1:] / 1e3
            row = {
                "median_us": float(np.median(us)),
                "p99_us": float(np.percentile(us, 99)),
                "cpu_us": cpu / T * 1e6,
            }
            old = best.get(name)
            if old is None:
                best[name] = row
            else:
                best[name] = {k: min(old[k], row[k]) for k in row}
    return best


def main() -> None:
    p = argparse.ArgumentParser(description="one sample per call, against filterpy")
    p.add_argument("--samples", type=int, default=20_000)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--json", action="store_true")
    args = p.parse_args()
    from filterpy.kalman import ExtendedKalmanFilter as FPEKF
    from filterpy.kalman import IMMEstimator
    from filterpy.kalman import KalmanFilter as FPKF

    T = args.samples
    rng = np.random.default_rng(0)
    res: dict[str, object] = {"samples": T, "repeat": args.repeat}

    # ---- KF on the DETC EHA
    model = detc_model()
    sim_u = rng.uniform(-0.01, 0.01, size=(T, 1))
    z = rng.normal(scale=0.01, size=(T, 1))
    x0, P0 = np.zeros(3), np.diag([1e-4, 1e-2, 1.0])

    def fp_kf() -> FPKF:
        kf = FPKF(dim_x=3, dim_z=1, dim_u=1)
        kf.F, kf.B, kf.H, kf.Q, kf.R = model.A, model.B, model.C, model.Q, model.R
        kf.x, kf.P = x0.copy(), P0.copy()
        return kf

    kf_ours = cs.KalmanFilter(model)

    def make_kf_ours() -> Callable[[int], object]:
        f = kf_ours.online(x0, P0)
        step = f.step
        return lambda k: step(z[k], sim_u[k])

    def make_kf_fp() -> Callable[[int], object]:
        kf = fp_kf()

        def call(k: int) -> np.ndarray:
            kf.predict(u=sim_u[k])
            kf.update(z[k])
            return kf.x

        return call

    res["kf_max_abs_diff_vs_filterpy"] = max_abs_diff(make_kf_ours(), make_kf_fp())

    # ---- EKF with h(x)
    ekf_model = cs.NonlinearModel.from_steps(
        range_f, range_f_jac, np.diag([1e-6, 1e-4]), np.eye(1) * 1e-4, DT, h=range_h, h_jac=range_h_jac
    )
    ze = 1.0 + 0.01 * rng.standard_normal((T, 1))
    ue = np.sin(0.05 * np.arange(T))[:, None]
    xe0, Pe0 = np.array([0.2, 0.0]), np.eye(2) * 0.1
    ekf_ours = cs.ExtendedKalmanFilter(ekf_model)

    def fp_ekf() -> FPEKF:
        f = FPEKF(dim_x=2, dim_z=1, dim_u=1)
        f.F, f.B, f.Q, f.R = A2, B2, ekf_model.Q, ekf_model.R
        f.x, f.P = xe0.copy(), Pe0.copy()
        return f

    def make_ekf_ours() -> Callable[[int], object]:
        step = ekf_ours.online(xe0, Pe0).step
        return lambda k: step(ze[k], ue[k])

    def make_ekf_fp() -> Callable[[int], object]:
        f = fp_ekf()

        def call(k: int) -> np.ndarray:
            f.predict(u=ue[k])
            f.update(ze[k], _H, _hx)
            return f.x

        return call

    res["ekf_max_abs_diff_vs_filterpy"] = max_abs_diff(make_ekf_ours(), make_ekf_fp())

    # ---- IMM of 2 KFs
    m0, m1 = detc_model(), detc_model(a21=-450.0)
    pi = np.array([[0.97, 0.03], [0.03, 0.97]])
    imm_ours = cs.IMM((cs.KalmanFilter(m0), cs.KalmanFilter(m1)), pi)

    def fp_imm() -> IMMEstimator:
        fs = []
        for mdl in (m0, m1):
            kf = FPKF(dim_x=3, dim_z=1, dim_u=1)
            kf.F, kf.B, kf.H, kf.Q, kf.R = mdl.A, mdl.B, mdl.C, mdl.Q, mdl.R
            kf.x, kf.P = x0.copy(), P0.copy()
            fs.append(kf)
        return IMMEstimator(fs, np.array([0.5, 0.5]), pi)

    def make_imm_ours() -> Callable[[int], object]:
        step = imm_ours.online(x0, P0).step
        return lambda k: step(z[k], sim_u[k])

    def make_imm_fp() -> Callable[[int], object]:
        imm = fp_imm()

        def call(k: int) -> np.ndarray:
            imm.predict(u=sim_u[k])
            imm.update(z[k])
            return imm.x

        return call

    res["imm_max_abs_diff_vs_filterpy"] = max_abs_diff(make_imm_ours(), make_imm_fp())

    # ---- chatterspec only
    svsf_cov = cs.SVSFCov(model, psi=0.05, gamma=0.2)
    svsf2 = cs.SecondOrderSVSF(model, gamma=0.2, lam=0.5)
    smm = cs.SMMSVSF((m0, m1), psi=0.05, gamma=0.2)
    sc = cs.scenario("eha-leak-major")
    sim = cs.simulate(sc, runs=1, seed=1)
    ze3, ue3 = sim.z[0], sim.u
    n3 = ze3.shape[0] - 1
    svsf = cs.SVSF(sc.nominal, psi=np.array([4.2e-3, 4.8e-3, 4.3e3]), gamma=0.1)

    def make_filter(filt: object) -> Callable[[], Callable[[int], object]]:
        def make() -> Callable[[int], object]:
            step = filt.online(x0, P0).step  # type: ignore[attr-defined]
            return lambda k: step(z[k], sim_u[k])

        return make

    def make_svsf() -> Callable[[int], object]:
        step = svsf.online(ze3[0]).step
        return lambda k: step(ze3[1 + k % n3], ue3[k % n3])

    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings

    def make_monitor() -> Callable[[int], object]:
        mon = ChatteringMonitor(sc.nominal, MonitorSettings())
        mon.push(ze3[:1], ue3[:1])
        step = mon.step
        return lambda k: step(ze3[1 + k % n3], ue3[1 + k % n3])

    cases = {
        "kf chatterspec": make_kf_ours,
        "kf filterpy": make_kf_fp,
        "ekf chatterspec": make_ekf_ours,
        "ekf filterpy": make_ekf_fp,
        "imm chatterspec": make_imm_ours,
        "imm filterpy": make_imm_fp,
        "svsf-cov chatterspec": make_filter(svsf_cov),
        "svsf2 chatterspec": make_filter(svsf2),
        "smm chatterspec": make_filter(smm),
        "sat svsf chatterspec": make_svsf,
        "monitor step chatterspec": make_monitor,
    }
    res["cases"] = measure(cases, T, args.repeat)
    try:
        res["load_average_1min"] = os.getloadavg()[0]
    except OSError:  # pragma: no cover
        pass
    if args.json:
        print(json.dumps(res, indent=2))
        return
    print(
        f"{T} samples per round, best of {args.repeat} rounds; "
        f"load average {res.get('load_average_1min', 0):.1f}"
    )
    print(
        f"estimates equal to filterpy's: KF {res['kf_max_abs_diff_vs_filterpy']:.1e}, EKF "
        f"{res['ekf_max_abs_diff_vs_filterpy']:.1e}, IMM {res['imm_max_abs_diff_vs_filterpy']:.1e} (max abs)"
    )
    print(f"{'case':<26} {'median us':>10} {'p99 us':>10} {'CPU us/call':>12}")
    for name, row in res["cases"].items():  # type: ignore[attr-defined]
        print(f"{name:<26} {row['median_us']:10.2f} {row['p99_us']:10.2f} {row['cpu_us']:12.2f}")


if __name__ == "__main__":
    main()
