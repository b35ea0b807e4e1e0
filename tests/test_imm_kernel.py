"""The compiled fused IMM step (chatterspec.filters.imm) against the protocol path.

The fused kernel sums the mixing, the combination and the likelihood in loop order, where the
protocol path uses BLAS (``mu @ pi``), ``einsum`` and LAPACK ``eigh``: the two differ by a few
ulps per sample, not bit for bit. The tolerances below are stated against that: each is about
100x the largest difference measured on these inputs (see the comments), and far below any
difference that would change a reported number (confusion percentages are printed to 0.01 %).
Chunking, in contrast, must give the same bits: every sample starts from the stored state.
"""

from __future__ import annotations

import numpy as np
import pytest

import chatterspec as cs
from chatterspec import _jit
from chatterspec.filters import ExtendedKalmanFilter, KalmanFilter, SecondOrderSVSF, SVSFCov, bank
from chatterspec.filters.bank import log_gaussian
from chatterspec.filters.imm import IMM, run_fused
from chatterspec.plants.models import LinearModel

needs_numba = pytest.mark.skipif(not _jit.enabled(), reason="numba not installed or CHATTERSPEC_JIT=0")


def analogue(T: int, runs: int):  # type: ignore[no-untyped-def]
    sc = cs.scenario("eha4-imm-analogue")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=runs, seed=3)
    return fs, sim.z[:, 1 : T + 1], sim.u[:T]


def make_bank(kind: str, fs) -> tuple[list[object], np.ndarray]:  # type: ignore[no-untyped-def]
    """The bank of ``kind`` on the analogue's mode models and its transition matrix.

    ``"ekf"``: the EKF bank of ``diagnose`` (one correction kind); ``"every-kind"``: one mode of each
    correction the compiled IMM supports (KF, SVSF with a constant and with the ``cov`` map, the
    second-order SVSF, both with the ``luen`` map), so that one compiled loop covers them all.
    """
    ms = fs.mode_models
    if kind == "ekf":
        return [ExtendedKalmanFilter(m) for m in ms], fs.transition_matrix
    assert kind == "every-kind", kind
    psi, lam, gamma = np.array(fs.psi), np.array(fs.cutoff_lambda), fs.gamma
    bank = [
        ExtendedKalmanFilter(ms[0]),
        SVSFCov(ms[1], psi=psi, gamma=gamma, mapping="cov"),
        SecondOrderSVSF(ms[2], gamma=gamma, lam=lam, mapping="cov"),
        SVSFCov(ms[0], psi=np.array(fs.psi + fs.psi_lower), gamma=gamma, mapping="luen"),
        SecondOrderSVSF(ms[1], gamma=gamma, lam=lam, mapping="luen"),
        SVSFCov(ms[2], psi=psi, gamma=gamma, mapping="pinv"),
    ]
    r = len(bank)
    return bank, np.full((r, r), 0.01) + (1.0 - 0.01 * r) * np.eye(r)


def imm(kind: str, fs) -> IMM:  # type: ignore[no-untyped-def]
    bank, pi = make_bank(kind, fs)
    mu0 = np.array(fs.mu0) if kind == "ekf" else None
    return IMM(bank, pi, mu0=mu0, modes=fs.modes if kind == "ekf" else None)


def protocol(f: IMM) -> IMM:
    """The same IMM forced onto the protocol path (the reference)."""
    g = IMM(f.filters, f.transition_matrix, mu0=f.mu0, weight_floor=f.weight_floor, modes=f.modes)
    object.__setattr__(g, "_fused", None)
    return g


def assert_close(a, b) -> None:  # type: ignore[no-untyped-def]
    # Measured over 3000 samples x 10 runs (fused vs protocol): x_post 1.5e-11 of each state's
    # range, mu 1.5e-8 absolute, loglik 2.5e-11 relative, diag P 1e-6 relative (svsf2-cov, whose
    # covariance gain dz/e is ill-conditioned where e ~ 0; the protocol path's own compiled vs
    # numpy branches differ by the same order, 2.4e-9 / 1.3e-7). Tolerances about 100x that.
    # loglik: 1e-9 relative plus 1e-7 absolute. It is a sum of terms of order 10-30 (the log-variances
    # of the scaled innovation covariance: position ~1e-14 m^2, pressure ~4e4 Pa^2, log 2 pi, the
    # quadratic form) that cancel to |loglik| ~ 1 where a mode fits well, so its rounding is a few
    # ulps of those terms, an absolute difference, not one relative to the result: the every-kind
    # bank measured 2.0e-9 absolute at loglik = -0.85 (svsf2-cov and pinv modes), 50x below 1e-7.
    scale = np.max(np.abs(b.x_post), axis=(0, 1))
    gap = np.max(np.abs(a.x_post - b.x_post), axis=(0, 1))
    assert np.all(gap <= 1e-9 * scale), (gap, scale)
    np.testing.assert_allclose(a.mu, b.mu, rtol=0, atol=1e-6)
    np.testing.assert_allclose(a.loglik, b.loglik, rtol=1e-9, atol=1e-7)
    da = np.diagonal(a.P_post, axis1=-2, axis2=-1)
    db = np.diagonal(b.P_post, axis1=-2, axis2=-1)
    np.testing.assert_allclose(da, db, rtol=1e-4, atol=0)
    gap = np.max(np.abs(a.mode_x_post - b.mode_x_post), axis=(0, 1, 2))
    assert np.all(gap <= 1e-8 * scale), (gap, scale)


@needs_numba
@pytest.mark.parametrize("kind", ["ekf", "every-kind"])
def test_fused_imm_matches_the_protocol_path_on_the_analogue(kind: str) -> None:
    # one bank with every correction kind instead of one bank per kind: a bank compiles one loop for
    # its set of kinds (tens of seconds each), and each mode's correction is chosen at run time
    # (measured on the every-kind bank: x_post 6e-12 of the range, mode_x_post 6e-11, mu 6e-11,
    # diag P 5e-9 relative: within the tolerances of the single-kind banks)
    fs, z, u = analogue(600, 3)
    f = imm(kind, fs)
    assert f._fused is not None
    kw = dict(x0=fs.x0, P0=fs.P0, store={"P_post", "mode_x_post"})
    a = f.run(z, u, **kw)
    b = protocol(f).run(z, u, **kw)
    assert a.modes == b.modes
    assert_close(a, b)


def linear_model(b3: float) -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, -0.1, 0.95]])
    B = np.array([[0.0], [0.01], [b3]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return LinearModel(A, B, C, np.diag([1e-3, 2e-3, 1e-3]), 0.01 * np.eye(2), 0.01)


@needs_numba
def test_fused_imm_matches_on_a_linear_bank_with_per_run_inputs() -> None:
    rng = np.random.default_rng(5)
    ms = [linear_model(b) for b in (0.05, 0.2)]
    runs, T = 4, 200
    z = rng.normal(scale=0.3, size=(runs, T, 2))
    u = rng.uniform(-1, 1, size=(runs, T, 1))
    # Kalman-type modes: the loop of the other 3-state, 2-output Kalman banks of the tests (the
    # corrections are compared on the analogue; here the per-run inputs and the floor are the point)
    filters = [KalmanFilter(ms[0]), ExtendedKalmanFilter(ms[1])]
    f = IMM(filters, np.array([[0.95, 0.05], [0.1, 0.9]]), weight_floor=1e-4)
    assert f._fused is not None
    kw = dict(x0=np.zeros(3), P0=0.1 * np.eye(3), store={"P_post", "mode_x_post"})
    assert_close(f.run(z, u, **kw), protocol(f).run(z, u, **kw))


@needs_numba
def test_fused_imm_is_chunk_invariant_bit_for_bit() -> None:
    fs, z, u = analogue(400, 3)
    f = imm("every-kind", fs)
    whole = f.run(z, u, x0=fs.x0, P0=fs.P0, store={"P_post", "mode_x_post"})
    state = f.initialize(fs.x0, fs.P0, runs=3)
    parts = []
    for a, b in ((0, 1), (1, 137), (137, 138), (138, 400)):
        state, out = f.update(state, z[:, a:b], u[a:b], store={"P_post", "mode_x_post"})
        parts.append(out)
    for name in ("x_post", "mu", "loglik", "P_post", "mode_x_post"):
        np.testing.assert_array_equal(
            np.concatenate([getattr(o, name) for o in parts], axis=1), getattr(whole, name)
        )
    # one run at a time gives the same bits as all runs together
    one = f.run(z[1:2], u, x0=fs.x0, P0=fs.P0)
    np.testing.assert_array_equal(one.x_post[0], whole.x_post[1])
    np.testing.assert_array_equal(one.mu[0], whole.mu[1])


def test_unsupported_banks_take_the_protocol_path() -> None:
    fs, _, _ = analogue(10, 1)
    ms = fs.mode_models
    vbl = [SVSFCov(m, psi=np.array(fs.psi), gamma=fs.gamma, mapping="cov", vbl=True) for m in ms]
    assert IMM(vbl, fs.transition_matrix)._fused is None
    assert IMM([ExtendedKalmanFilter(m) for m in ms], fs.transition_matrix)._fused is not None


def test_kernel_python_function_matches_the_protocol_path(monkeypatch) -> None:  # type: ignore[no-untyped-def]
    # the kernel's own Python function, so the test does not depend on the compiler for its meaning
    fs, z, u = analogue(6, 2)
    f = imm("every-kind", fs)
    state = f.initialize(fs.x0, fs.P0, runs=2)
    zz, uu = z, u[None]
    _st, o = run_fused(f._fused, f.transition_matrix, 0.0, state, zz, uu, True, True, python=True)
    ref = protocol(f).run(z, u, x0=fs.x0, P0=fs.P0, store={"P_post", "mode_x_post"})
    np.testing.assert_allclose(o["mu"], ref.mu, rtol=0, atol=1e-9)
    np.testing.assert_allclose(o["x"], ref.x_post, rtol=1e-9, atol=0)
    np.testing.assert_allclose(o["ll"], ref.loglik, rtol=1e-9)


@pytest.mark.parametrize("compiled", [False, True])
def test_kernel_likelihood_equals_log_gaussian_including_the_eigenvalue_floor(compiled: bool) -> None:
    if compiled and not _jit.enabled():
        pytest.skip("numba not installed")
    step = bank.log_gaussian_step
    fn = step if compiled else getattr(step, "py_func", step)
    rng = np.random.default_rng(2)
    cases = []
    for _ in range(20):  # well conditioned: the Cholesky branch
        G = rng.normal(size=(3, 3))
        cases.append((rng.normal(size=3), G @ G.T + 0.1 * np.eye(3)))
    scale = np.diag([1e-10, 1.0, 1e10])  # 20 decades (design.md S3), still well conditioned once scaled
    cases.append((np.array([1e-5, 0.3, 2e4]), scale @ (np.eye(3) + 0.2) @ scale))
    # nearly singular correlation: the eigh branch with the 1e-12 floor active
    v = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)
    Sc = np.outer(v, v) * 3.0 + 1e-15 * np.eye(3)
    cases.append((np.array([0.1, -0.2, 0.05]), Sc))
    for e, S in cases:
        m = 3
        got = fn(e, S, m, np.empty((m, m)), np.zeros((m, m)), np.empty(m), np.empty(m), np.empty(2 * m))
        want = float(log_gaussian(e, S))
        # Cholesky vs eigh: same quantity, different rounding (a few ulps of each term; the
        # quadratic form reaches 1e13 in the floored case, hence the relative tolerance)
        assert got == pytest.approx(want, rel=1e-9, abs=1e-9)


def test_shared_input_uses_the_compiled_transition_with_the_same_bits() -> None:
    # _base._advance passes a shared input as (p,), so eha4's compiled step applies; a per-run
    # input takes the numpy formulas. Same formulas in the same order: identical bits.
    fs, z, u = analogue(300, 2)
    f = ExtendedKalmanFilter(fs.mode_models[1])
    a = f.run(z, u, x0=fs.x0, P0=fs.P0, store=["x_post", "P_post", "loglik"])
    b = f.run(
        z, np.broadcast_to(u, (2, *u.shape)).copy(), x0=fs.x0, P0=fs.P0, store=["x_post", "P_post", "loglik"]
    )
    np.testing.assert_array_equal(a.x_post, b.x_post)
    np.testing.assert_array_equal(a.P_post, b.P_post)
    np.testing.assert_array_equal(a.loglik, b.loglik)
