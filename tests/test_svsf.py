"""SVSF (eq 4-12): eq 23 closed form, vector MA(1) statistics, reduced order, online == batch."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from chatterspec import SVSF, Scenario, auxiliary_svsf, chattering, scenario, simulate
from chatterspec.plants.models import LinearModel, second_order
from chatterspec.plants.signals import Chirp


def _general_C_scenario() -> Scenario:
    base = second_order(10.0, 0.1, R=np.diag([1e-6, 1e-4]))
    C = np.array([[1.0, 0.5], [0.2, 2.0]])
    model = LinearModel(A=base.A, B=base.B, C=C, Q=base.Q, R=base.R, dt=base.dt)
    return Scenario("general-C", model, Chirp(1.0, 20.0, 1.0, 1.0), 1.0)


CLOSED_FORM_CASES = {
    "eha": lambda: scenario("eha-healthy"),
    "second-order": lambda: scenario("so-healthy-high"),
    "general-C": _general_C_scenario,
}


@pytest.mark.parametrize("case", sorted(CLOSED_FORM_CASES))
def test_chattering_equals_eq23_closed_form(case: str) -> None:
    """Healthy, full measurement, x(0|0) = C^-1 z(0): chattering(k+1) = z(k+1) - C A C^-1 z(k) - C B u(k)."""
    sc = CLOSED_FORM_CASES[case]()
    m = sc.nominal
    sim = simulate(sc, runs=3, seed=11)
    e = chattering(m, sim.z, sim.u)
    CACi = m.C @ m.A @ m.C_inv
    closed = sim.z[:, 1:] - sim.z[:, :-1] @ CACi.T - sim.u[:-1] @ (m.C @ m.B).T
    np.testing.assert_array_equal(e[:, 0], 0.0)
    scale = np.abs(closed).max(axis=(0, 1))
    assert np.all(np.abs(e[:, 1:] - closed).max(axis=(0, 1)) <= 1e-12 * scale)
    # gamma has no effect after the first step (e(k|k) = 0 throughout)
    np.testing.assert_allclose(chattering(m, sim.z, sim.u, gamma=0.9), e, rtol=0, atol=1e-12 * scale.max())


def _ma1_stats(e: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Sample variance and lag-1 autocovariance (known zero mean) pooled over runs."""
    runs, N, _ = e.shape
    c0 = np.einsum("rki,rki->i", e, e) / (runs * N)
    c1 = np.einsum("rki,rki->i", e[:, 1:], e[:, :-1]) / (runs * (N - 1))
    return c0, c1, runs * N


@pytest.mark.parametrize("name", ["so-healthy-low", "so-healthy-high", "eha-healthy"])
def test_chattering_is_vector_ma1_with_eq56_moments(name: str) -> None:
    """e(k+1) = C v(k) + w(k+1) + M w(k), M = -C A C^-1: a vector MA(1) process with
    gamma0 = diag(C Q C^T + R + M R M^T) and gamma1 = diag(M R).

    Tolerance (Bartlett's formula, exact for Gaussian MA(1) with known zero mean up to
    O(1/N^2) end effects): the pooled sample variance over N samples has
    Var(c0) = 2 (gamma0^2 + 2 gamma1^2) / N and the lag-1 sample autocovariance has
    Var(c1) = (gamma0^2 + 3 gamma1^2) / N. We accept |c - gamma| <= z sd with the two-sided
    z-quantile at family-wise 1e-3, Bonferroni over 2 statistics x m channels (z ~ 3.8 for m = 3).
    """
    sc = scenario(name)
    m = sc.nominal
    sim = simulate(sc, runs=12, seed=2024)
    e = chattering(m, sim.z, sim.u)[:, 1:]
    M = -m.C @ m.A @ m.C_inv
    g0 = np.diag(m.C @ m.Q @ m.C.T + m.R + M @ m.R @ M.T)
    g1 = np.diag(M @ m.R)
    c0, c1, N = _ma1_stats(e)
    z = scipy.stats.norm.isf(1e-3 / (2 * 2 * m.n_outputs))
    sd0 = np.sqrt(2 * (g0**2 + 2 * g1**2) / N)
    sd1 = np.sqrt((g0**2 + 3 * g1**2) / N)
    assert np.all(np.abs(c0 - g0) <= z * sd0), (c0 / g0, sd0 / g0)
    assert np.all(np.abs(c1 - g1) <= z * sd1), (c1 / g1, sd1 / np.abs(g1))
    # and no lag-2 correlation (MA(1)): Var(c2) = (gamma0^2 + 2 gamma1^2) / N
    c2 = np.einsum("rki,rki->i", e[:, 2:], e[:, :-2]) / (e.shape[0] * (e.shape[1] - 2))
    assert np.all(np.abs(c2) <= z * np.sqrt((g0**2 + 2 * g1**2) / N))


def test_reduced_order_fig2_variance() -> None:
    """Reduced-order sgn SVSF on the Fig 2 setup: measured chattering variance 6.02e-8 (not eq 34's 2.02e-8).

    Derivation: e(k+2|k+1) = w(k+2) - (1 + A22) w(k+1) + (A22 - Ts A21) w(k) + v1(k+1) - A22 v1(k)
    + Ts v2(k), an MA(2) with gamma0 = r (1 + (1 + A22)^2 + (A22 - Ts A21)^2) + q1 (1 + A22^2) + Ts^2 q2.
    Tolerance: Var(c0) = 2 (gamma0^2 + 2 gamma1^2 + 2 gamma2^2) / N (Bartlett), 4.4 sd (two-sided 1e-5).
    """
    sc = scenario("so-boundary-layer")
    healthy = Scenario("h", sc.nominal, sc.input, 4.0)
    sim = simulate(healthy, runs=10, seed=5)
    out = auxiliary_svsf(sc.nominal).run(sim.z, sim.u, store={"e_lower", "e_post"})
    e = out.e_prior[:, 5:, 0]
    A = sc.nominal.A
    Ts, A21, A22 = 1e-3, A[1, 0], A[1, 1]
    r, q1, q2 = 1e-8, 1e-10, 1e-8
    cw = np.array([1.0, -(1 + A22), A22 - Ts * A21])
    cv1 = np.array([1.0, -A22])
    g = [
        r * cw @ cw + q1 * cv1 @ cv1 + Ts**2 * q2,
        r * cw[:-1] @ cw[1:] + q1 * cv1[0] * cv1[1],
        r * cw[0] * cw[2],
    ]
    assert g[0] == pytest.approx(6.02e-8, rel=1e-3)
    N = e.size
    sd = np.sqrt(2 * (g[0] ** 2 + 2 * g[1] ** 2 + 2 * g[2] ** 2) / N)
    assert abs(np.mean(e**2) - g[0]) <= 4.4 * sd
    lag1 = np.mean(e[:, 1:] * e[:, :-1])
    assert lag1 == pytest.approx(g[1], rel=0.05)
    # e(k|k) stays 0 for the sgn filter; e_lower = Phi22 Phi12^-1 e = (A22 / Ts) e
    np.testing.assert_array_equal(out.e_post, 0.0)
    np.testing.assert_allclose(out.e_lower[:, 1:, 0], out.e_prior[:, 1:, 0] * A22 / Ts, rtol=1e-12)


def test_reduced_order_sat_filter_runs() -> None:
    sc = scenario("so-boundary-layer")
    sim = simulate(sc, runs=2, seed=1)
    f = SVSF(sc.nominal, psi=8e-4, psi_lower=0.8)
    out = f.run(sim.z, sim.u, store={"x_post"})
    assert out.e_prior.shape == (2, 5001, 1) and out.x_post.shape == (2, 5001, 2)
    err = sim.x - out.x_post
    assert np.sqrt(np.mean(err[..., 0] ** 2)) < 1e-3  # position within a few noise sd
    assert np.sqrt(np.mean(err[:, 100:, 1] ** 2)) < 0.2 * np.sqrt(np.mean(sim.x[..., 1] ** 2))
    np.testing.assert_array_equal(f.boundary_layer, [8e-4, 0.8])


def test_huge_psi_is_a_pure_model_predictor() -> None:
    sc = scenario("so-healthy-low")
    m = sc.nominal
    sim = simulate(sc, runs=2, seed=3)
    x0 = np.array([0.001, -0.01])
    out = SVSF(m, psi=1e12).run(sim.z, sim.u, x0=x0, store={"x_post"})
    pred = np.empty((sim.z.shape[1], 2))
    pred[0] = x0
    for k in range(len(pred) - 1):
        pred[k + 1] = m.A @ pred[k] + m.B @ sim.u[k]
    scale = np.abs(pred).max(axis=0)
    assert np.all(np.abs(out.x_post - pred).max(axis=(0, 1)) <= 1e-9 * scale)


@pytest.mark.parametrize("name", ["eha-healthy", "so-boundary-layer", "so-f11-high"])
@pytest.mark.parametrize("switching", ["sgn", "sat"])
def test_online_chunks_equal_batch(name: str, switching: str) -> None:
    sc = scenario(name)
    m = sc.nominal
    sim = simulate(sc, runs=3, seed=8)
    z, u = sim.z[:, :1200], sim.u[:1200]
    psi = None if switching == "sgn" else (np.sqrt(np.diag(m.R)) * 3 if m.full_measurement else 8e-4)
    f = SVSF(m, psi=psi, psi_lower=None if m.full_measurement else 0.8, switching=switching)
    batch = f.run(z, u, store={"x_post", "e_post"})
    state = f.initialize(z[:, 0])
    rng = np.random.default_rng(0)
    k, pieces = 0, []
    while k < z.shape[1] - 1:
        K = min(int(rng.choice([1, 1, 2, 7, 50, 333])), z.shape[1] - 1 - k)
        state, out = f.update(state, z[:, k + 1 : k + 1 + K], u[k : k + K], store={"x_post", "e_post"})
        pieces.append(out)
        k += K
    assert state.k == z.shape[1] - 1
    for attr in ("e_prior", "x_post", "e_post"):
        online = np.concatenate([getattr(p, attr) for p in pieces], axis=1)
        np.testing.assert_array_equal(online, getattr(batch, attr)[:, 1:])


@pytest.mark.parametrize("name", ["eha-healthy", "so-boundary-layer"])
def test_vectorized_runs_equal_per_run_calls(name: str) -> None:
    sc = scenario(name)
    sim = simulate(sc, runs=4, seed=9)
    f = SVSF(sc.nominal, psi=1.0, psi_lower=1.0)
    batch = f.run(sim.z, sim.u, store={"x_post"})
    # Per-run calls take one-row BLAS paths on the numpy path (the compiled path gives the same bits), so
    # the two differ by rounding, which the filter then carries on: on the undamped Euler plant of
    # so-boundary-layer a 1e-12 difference grows to ~1e-4 over the record. The bound is the filter's own
    # response to a one-ulp perturbation of every measurement (rounding of the same size as the BLAS
    # paths'), with a factor 4 of margin; a mix-up of realizations gives differences of the signal's size.
    signs = np.random.default_rng(1).choice([-1.0, 1.0], size=sim.z.shape)
    nudged = f.run(sim.z * (1.0 + np.finfo(float).eps * signs), sim.u, store={"x_post"})
    for r in range(sim.runs):
        single = f.run(sim.z[r], sim.u, store={"x_post"})
        assert single.e_prior.shape == sim.z.shape[1:]
        for attr in ("e_prior", "x_post"):
            ref = getattr(batch, attr)[r]
            ulp_response = np.abs(getattr(nudged, attr)[r] - ref).max()
            tol = 4.0 * ulp_response + 1e-12 * np.abs(ref).max()
            assert ulp_response < 1e-4 * np.abs(ref).max(), (attr, ulp_response)
            np.testing.assert_allclose(getattr(single, attr), ref, rtol=0, atol=tol)


def test_per_run_inputs_equal_shared_input() -> None:
    sc = scenario("so-healthy-high")
    sim = simulate(sc, runs=3, seed=1)
    a = chattering(sc.nominal, sim.z, sim.u)
    b = chattering(sc.nominal, sim.z, np.broadcast_to(sim.u, (3, *sim.u.shape)))
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)


def test_boundary_layer_chattering_eq13() -> None:
    from chatterspec import boundary_layer_chattering

    e = np.array([[-3.0, 0.5], [1.0, -2.5], [2.0, 0.1]])
    out = boundary_layer_chattering(e, np.array([2.0, 1.0]))
    np.testing.assert_array_equal(out, [[-1.0, 0.0], [0.0, -1.5], [0.0, 0.0]])


@pytest.mark.parametrize("name", ["eha-healthy", "so-f11-high", "eha-bulk-50up"])
def test_closed_form_path_equals_recursion(name: str) -> None:
    """The eq (22)-(23) closed-form evaluation of the sgn filter equals the sample-by-sample recursion.

    Both evaluate the same algebra; they differ only in the order of floating-point
    operations, so agreement is to rounding: 1e-12 of each channel's scale is ~1e4 ulps.
    """
    sc = scenario(name)
    sim = simulate(sc, runs=4, seed=21)
    f = auxiliary_svsf(sc.nominal)
    state = f.initialize(sim.z[:, 0])
    s_fast, fast = f.update(state, sim.z[:, 1:], sim.u[:-1], store={"x_post", "e_post"})
    s_loop, loop = f.update(state, sim.z[:, 1:], sim.u[:-1], store={"x_post", "e_post"}, closed_form=False)
    scale = np.abs(loop.e_prior).max(axis=(0, 1))
    assert np.all(np.abs(fast.e_prior - loop.e_prior).max(axis=(0, 1)) <= 1e-12 * scale)
    # the recursion keeps e(k|k) exactly zero, as the closed form assumes (eq 21 with e(0|0) = 0)
    assert not np.any(loop.e_post) and not np.any(fast.e_post)
    xs = np.abs(loop.x_post).max(axis=(0, 1))
    assert np.all(np.abs(fast.x_post - loop.x_post).max(axis=(0, 1)) <= 1e-12 * xs)
    np.testing.assert_array_equal(s_fast.y, s_loop.y)


def test_closed_form_is_bitwise_chunk_and_run_invariant() -> None:
    """Online (any chunk sizes, one run at a time) and batch give identical bits on the closed-form path."""
    sc = scenario("eha-leak-major")
    sim = simulate(sc, runs=3, seed=5)
    f = auxiliary_svsf(sc.nominal)
    batch = f.run(sim.z, sim.u).e_prior[:, 1:]
    rng = np.random.default_rng(1)
    for r in range(sim.runs):
        state = f.initialize(sim.z[r : r + 1, 0])
        k, pieces = 1, []
        while k < sim.z.shape[1]:
            K = min(int(rng.integers(1, 400)), sim.z.shape[1] - k)
            state, out = f.update(state, sim.z[r : r + 1, k : k + K], sim.u[k - 1 : k - 1 + K])
            pieces.append(out.e_prior)
            k += K
        np.testing.assert_array_equal(np.concatenate(pieces, axis=1)[0], batch[r])


def test_nonzero_initial_error_uses_recursion_and_converges() -> None:
    """With x0 != C^-1 z(0) the a-posteriori error decays at rate gamma (eq 21) through the recursion."""
    sc = scenario("so-healthy-low")
    sim = simulate(sc, runs=2, seed=3)
    f = auxiliary_svsf(sc.nominal, gamma=0.5)
    out = f.run(sim.z, sim.u, x0=np.array([0.1, -0.2]), store={"e_post"})
    e_post = np.abs(out.e_post)
    # |e(k|k)| = gamma^k |e(0|0)| exactly in exact arithmetic (eq 21); compare the first 20 steps
    ratios = e_post[:, 1:21] / e_post[:, :20]
    np.testing.assert_allclose(ratios, 0.5, rtol=1e-9)


def test_closed_form_is_layout_invariant() -> None:
    """Time-major (simulate's output) and realization-major arrays take different loops: same bits."""
    sc = scenario("eha-bulk-25up")
    sim = simulate(sc, runs=5, seed=2)
    f = auxiliary_svsf(sc.nominal)
    assert sim.z.strides[1] > sim.z.strides[0]  # a (runs, T, m) view of time-major storage
    a = f.run(sim.z, sim.u).e_prior
    b = f.run(np.ascontiguousarray(sim.z), sim.u).e_prior
    np.testing.assert_array_equal(a, b)


def test_per_run_input_of_length_one_broadcasts_on_both_layouts() -> None:
    """u of shape (1, K, p) applies to every realization, whatever the memory layout of z."""
    sc = scenario("eha-healthy")
    sim = simulate(sc, runs=12, seed=4)
    f = auxiliary_svsf(sc.nominal)
    ref = f.run(sim.z, sim.u).e_prior
    for z in (sim.z, np.ascontiguousarray(sim.z)):
        np.testing.assert_array_equal(f.run(z, sim.u[None]).e_prior, ref)
