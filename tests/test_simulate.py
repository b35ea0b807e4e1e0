"""Batched Monte Carlo simulation: shapes, chunk-invariant seeding, noise statistics, segments."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from chatterspec import Scenario, Segment, iter_simulations, scenario, simulate
from chatterspec.plants.models import LinearModel, second_order
from chatterspec.plants.signals import Constant


@pytest.fixture(scope="module")
def short_so() -> Scenario:
    sc = scenario("so-healthy-high")
    return Scenario("short", sc.nominal, sc.input, 0.2)


def test_shapes_eha() -> None:
    sim = simulate(scenario("eha-healthy"), runs=3, seed=0)
    assert sim.t.shape == (4001,) and sim.x.shape == (3, 4001, 3) and sim.z.shape == (3, 4001, 3)
    assert sim.u.shape == (4001, 1) and sim.runs == 3 and sim.first_run == 0
    np.testing.assert_allclose(sim.t[[0, 1, -1]], [0.0, 1e-3, 4.0])
    np.testing.assert_array_equal(sim.x[:, 0], 0.0)  # default x0


def test_shapes_reduced_order() -> None:
    sim = simulate(scenario("so-boundary-layer"), runs=2, seed=0)
    assert sim.x.shape == (2, 5001, 2) and sim.z.shape == (2, 5001, 1)


def _same(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_array_equal(a, b)


def test_same_seed_same_numbers_whatever_the_chunking(short_so: Scenario) -> None:
    ref = simulate(short_so, runs=200, seed=7)
    for chunk in (2, 37, 64, 100, 500):
        other = simulate(short_so, runs=200, seed=7, chunk_runs=chunk)
        _same(other.z, ref.z)
        _same(other.x, ref.x)
    a, b = (next(iter_simulations(short_so, 100, 7, first_run=f)) for f in (0, 100))
    _same(np.concatenate([a.z, b.z]), ref.z)
    assert b.first_run == 100
    # an arbitrary split that cuts a random block (runs 0..69 + 70..199)
    parts = [c.z for f, r in ((0, 70), (70, 130)) for c in iter_simulations(short_so, r, 7, first_run=f)]
    _same(np.concatenate(parts), ref.z)
    one = simulate(short_so, runs=200, seed=7, chunk_runs=1)
    _same(one.z, ref.z)


def test_single_run_chunks_are_bitwise_identical(short_so: Scenario) -> None:
    """One-realization chunks (and a 1-run remainder) avoid BLAS's one-row kernel: identical bits."""
    ref = simulate(short_so, runs=4, seed=7)
    one = simulate(short_so, runs=4, seed=7, chunk_runs=1)
    np.testing.assert_array_equal(one.x, ref.x)
    np.testing.assert_array_equal(one.z, ref.z)
    last = simulate(short_so, runs=3, seed=7, chunk_runs=2)  # chunks of 2 + 1
    np.testing.assert_array_equal(last.z, ref.z[:3])


def test_different_seeds_differ(short_so: Scenario) -> None:
    a = simulate(short_so, runs=4, seed=1).z
    b = simulate(short_so, runs=4, seed=2).z
    assert not np.any(a[:, 1:] == b[:, 1:])
    # distinct realizations within one call are distinct too
    assert not np.any(a[0, 1:] == a[1, 1:])


def test_generator_and_seedsequence_seeds(short_so: Scenario) -> None:
    a = simulate(short_so, runs=3, seed=np.random.default_rng(5)).z
    b = simulate(short_so, runs=3, seed=np.random.default_rng(5)).z
    np.testing.assert_array_equal(a, b)
    ss = np.random.SeedSequence(11)
    np.testing.assert_array_equal(simulate(short_so, 3, ss).z, simulate(short_so, 3, 11).z)
    assert np.all(np.isfinite(simulate(short_so, 2, None).z))


def test_noise_covariance_matches_Q_and_R() -> None:
    """Recovered v(k) and w(k) have covariance Q and R.

    Tolerance: for N independent N(0, s^2) samples the sample variance has standard
    deviation s^2 sqrt(2/N), and a sample covariance of independent channels with
    variances s1^2, s2^2 has standard deviation s1 s2 / sqrt(N). We use a two-sided
    z-quantile at 1e-4 / (number of checked entries) (Bonferroni): about 4.9 sigma.
    """
    base = second_order(10.0, 0.1, Q=np.array([[2e-8, 5e-9], [5e-9, 1e-6]]), R=np.diag([1e-6, 1e-4]))
    sc = Scenario("noise", base, Constant(1.0), 2.0)
    sim = simulate(sc, runs=16, seed=3)
    m = sc.nominal
    v = sim.x[:, 1:] - sim.x[:, :-1] @ m.A.T - sim.u[:-1] @ m.B.T
    w = sim.z - sim.x @ m.C.T
    checks = [(v.reshape(-1, 2), m.Q), (w.reshape(-1, 2), m.R)]
    z = scipy.stats.norm.isf(1e-4 / (2 * 6))
    for samples, cov in checks:
        N = samples.shape[0]
        S = samples.T @ samples / N
        sd = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / N)  # Var(x_i x_j) for Gaussians
        assert np.all(np.abs(S - cov) <= z * sd), (S, cov)
        np.testing.assert_array_less(np.abs(samples.mean(axis=0)), z * np.sqrt(np.diag(cov) / N))


def test_segments_switch_the_true_model_at_the_right_sample() -> None:
    """Noise-free run: x(k+1) = A_seg(k) x(k) + B u(k) with the segment active at t_k = k dt."""
    zero = {"Q": np.zeros((2, 2)), "R": np.zeros((2, 2))}
    nominal = second_order(5.0, 0.1, **zero)
    fast = second_order(8.0, 0.1, **zero)
    sc = Scenario(
        "seg", nominal, Constant(1.0), 0.5, windows=(Segment(0.1, 0.2, fast),), x0=np.array([0.01, 0])
    )
    sim = simulate(sc, 1, 0)
    x, u = sim.x[0], sim.u
    for k, model in ((98, nominal), (99, nominal), (100, fast), (199, fast), (200, nominal), (201, nominal)):
        np.testing.assert_allclose(x[k + 1], model.A @ x[k] + model.B @ u[k], rtol=1e-13, atol=0)
        other = fast if model is nominal else nominal
        assert not np.allclose(x[k + 1], other.A @ x[k] + other.B @ u[k], rtol=1e-9, atol=0)
    np.testing.assert_array_equal(sim.z[0], x)  # R = 0, C = I
    np.testing.assert_array_equal(x[0], [0.01, 0.0])


def test_measurements_use_C() -> None:
    sim = simulate(scenario("so-boundary-layer"), runs=2, seed=4)
    w = sim.z[..., 0] - sim.x[..., 0]
    assert abs(w.std() / 1e-4 - 1) < 0.05  # R = 1e-8 -> sd 1e-4, N = 10002 samples (5 sd = 3.5 %)


def test_noise_is_not_shared_between_runs_or_channels(short_so: Scenario) -> None:
    sim = simulate(short_so, runs=64, seed=9)
    w = (sim.z - sim.x)[:, :, 1].ravel()
    model: LinearModel = short_so.nominal
    assert abs(np.corrcoef(w[:-1], w[1:])[0, 1]) < 5 / np.sqrt(w.size)
    assert w.var() == pytest.approx(model.R[1, 1], rel=5 * np.sqrt(2 / w.size))
