"""Simulation of nonlinear plants: chunk-invariant seeding identical to the linear scheme, segments, noise."""

from __future__ import annotations

from functools import partial

import numpy as np
import pytest
import scipy.stats

from chatterspec import Scenario, Segment, iter_simulations, simulate
from chatterspec.errors import NonFiniteError, ParameterError
from chatterspec.plants.eha4 import eha4, eha4_jacobian, eha4_transition
from chatterspec.plants.models import LinearModel, second_order
from chatterspec.plants.nonlinear import NonlinearModel
from chatterspec.plants.signals import Constant, Sine


def _lin_f(x: np.ndarray, u: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return x @ A.T + u @ B.T


def _lin_jac(x: np.ndarray, u: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return np.broadcast_to(A, (*np.broadcast_shapes(x.shape[:-1], u.shape[:-1]), *A.shape)).copy()


def wrap(m: LinearModel) -> NonlinearModel:
    """A LinearModel written as a NonlinearModel (f = A x + B u)."""
    return NonlinearModel(
        f=partial(_lin_f, A=m.A, B=m.B), jac=partial(_lin_jac, A=m.A, B=m.B), C=m.C, Q=m.Q, R=m.R, dt=m.dt
    )


@pytest.fixture(scope="module")
def short_eha4() -> Scenario:
    """0.3 s of the SMM plant with a minor-leak window on [0.1, 0.2) s."""
    normal, minor = eha4(), eha4("leak-minor")
    return Scenario(
        "short-eha4", normal, Sine(94.25, 5.0), 0.3, windows=(Segment(0.1, 0.2, minor, "leak-minor"),)
    )


def test_shapes_and_kind(short_eha4: Scenario) -> None:
    sim = simulate(short_eha4, runs=3, seed=0)
    assert short_eha4.plant_kind == "nonlinear" and not short_eha4.is_linear
    assert sim.x.shape == (3, 301, 4) and sim.z.shape == (3, 301, 4) and sim.u.shape == (301, 1)
    np.testing.assert_array_equal(sim.x[:, 0], 0.0)
    assert np.all(np.isfinite(sim.z))


def test_same_seed_same_numbers_whatever_the_chunking(short_eha4: Scenario) -> None:
    ref = simulate(short_eha4, runs=150, seed=7)
    for chunk in (1, 2, 37, 64, 100):
        other = simulate(short_eha4, runs=150, seed=7, chunk_runs=chunk)
        np.testing.assert_array_equal(other.x, ref.x)
        np.testing.assert_array_equal(other.z, ref.z)
    # an arbitrary split that cuts a random block (workers doing runs 0..69 and 70..149)
    parts = [c for f, r in ((0, 70), (70, 80)) for c in iter_simulations(short_eha4, r, 7, first_run=f)]
    np.testing.assert_array_equal(np.concatenate([c.z for c in parts]), ref.z)
    np.testing.assert_array_equal(np.concatenate([c.x for c in parts]), ref.x)
    assert parts[-1].first_run == 70
    other = simulate(short_eha4, runs=3, seed=8).z
    assert not np.any(other[:, 1:] == ref.z[:3, 1:])


def test_same_numbers_as_the_linear_simulation() -> None:
    """A linear model written as a NonlinearModel draws exactly the linear scheme's noise:
    the trajectories agree to rounding (the linear code folds B u into one matmul, so the sums
    are ordered differently: a few ulp per step, amplified at most by the stable A)."""
    base = second_order(10.0, 0.1, Q=np.array([[2e-8, 5e-9], [5e-9, 1e-6]]), R=np.diag([1e-6, 1e-4]))
    lin = Scenario("lin", base, Constant(1.0), 0.5, windows=(Segment(0.2, 0.3, second_order(12.0, 0.1)),))
    nl = Scenario(
        "nl", wrap(base), Constant(1.0), 0.5, windows=(Segment(0.2, 0.3, wrap(second_order(12.0, 0.1))),)
    )
    a, b = simulate(lin, runs=70, seed=3), simulate(nl, runs=70, seed=3)
    scale = np.abs(a.x).max(axis=(0, 1))
    np.testing.assert_allclose(b.x, a.x, rtol=0, atol=1e-12 * scale.max())
    np.testing.assert_allclose(b.z - b.x, a.z - a.x, rtol=0, atol=1e-12 * np.abs(a.z).max())


def test_segments_switch_the_true_model_at_the_right_sample() -> None:
    """Noise-free: x(k+1) = f_seg(k)(x(k), u(k)) exactly, with the segment active at t_k = k dt."""
    zero = {"Q": np.zeros((4, 4)), "R": np.zeros((4, 4))}
    normal, major = eha4(**zero), eha4("leak-major", **zero)
    sc = Scenario("seg", normal, Sine(94.25, 0.5), 0.5, windows=(Segment(0.1, 0.2, major),))
    sim = simulate(sc, 2, 0)
    x, u = sim.x[0], sim.u
    for k, model in ((98, normal), (99, normal), (100, major), (199, major), (200, normal), (201, normal)):
        np.testing.assert_array_equal(x[k + 1], model.transition(x[k], u[k]))
        other = major if model is normal else normal
        assert not np.allclose(x[k + 1], other.transition(x[k], u[k]), rtol=1e-9, atol=0)
    np.testing.assert_array_equal(sim.z[0], x)  # R = 0, C = I
    np.testing.assert_array_equal(sim.x[1], x)  # no noise: every realization is the same


def test_noise_covariance_matches_Q_and_R() -> None:
    """Recovered v(k) = x(k+1) - f(x(k), u(k)) and w(k) = z(k) - C x(k) have covariance Q and R.

    Same tolerance as tests/test_simulate.py: Var(x_i x_j) = (s_i^2 s_j^2 + c_ij^2) / N for
    Gaussians, two-sided z-quantile at 1e-4 / (number of checked entries) (Bonferroni), about
    4.9 sigma. Rounding in the recovery is ~eps |x| = 2e-16 * 4e5 Pa = 1e-10, against sd 3e-5.
    """
    Q = np.diag([1e-9, 2e-9, 1e-8, 1e-9])
    Q[1, 2] = Q[2, 1] = 5e-10
    R = np.diag([1e-6, 4e-6])
    m = eha4(measure="position-pressure", Q=Q, R=R)
    sc = Scenario("noise", m, Sine(94.25, 0.5), 1.0)
    sim = simulate(sc, runs=8, seed=5)
    v = sim.x[:, 1:] - m.transition(sim.x[:, :-1], sim.u[:-1])
    w = sim.z - sim.x @ m.C.T
    z = scipy.stats.norm.isf(1e-4 / (2 * (10 + 3)))
    for samples, cov in ((v.reshape(-1, 4), Q), (w.reshape(-1, 2), R)):
        N = samples.shape[0]
        S = samples.T @ samples / N
        sd = np.sqrt((np.outer(np.diag(cov), np.diag(cov)) + cov**2) / N)
        assert np.all(np.abs(S - cov) <= z * sd), (S, cov)


def test_divergence_is_a_specific_error() -> None:
    """dt = 20 ms breaks Euler's 2 dt a1 |v| / M < 1 as soon as |v| > 2.8 mm/s: the state overflows."""
    m = eha4(dt=2e-2)
    sc = Scenario("unstable", m, Sine(300.0, 0.5), 5.0)
    with pytest.raises(NonFiniteError, match="diverged"):
        simulate(sc, 2, 0)


def test_scenario_rejects_mismatched_nonlinear_windows() -> None:
    with pytest.raises(ParameterError, match="dimensions and dt"):
        Scenario("x", eha4(), Constant(0.0), 1.0, windows=(Segment(0.1, 0.2, eha4(dt=1e-4)),))
    with pytest.raises(ParameterError, match="dimensions and dt"):
        Scenario("x", eha4(), Constant(0.0), 1.0, plant=eha4(measure="position-pressure"))


def test_compiled_step_equals_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled batch step (one input for all rows) and the numpy formula give the same numbers."""
    m = eha4("friction-imm-minor", dt=1e-4)
    c = m.f.keywords
    x = np.random.default_rng(1).normal(size=(33, 4)) * [0.01, 0.02, 2.0, 3e5]
    x[0, 1] = 0.0  # sgn(0) = 0 on both paths
    u = np.array([57.0])
    fast = eha4_transition(x, u, **c)
    ref = eha4_transition(x, np.broadcast_to(u, (33, 1)), **c)  # 2-D u: numpy path
    np.testing.assert_allclose(fast, ref, rtol=1e-15, atol=0)
    jfast = eha4_jacobian(x, u, **c)
    jref = eha4_jacobian(x, np.broadcast_to(u, (33, 1)), **c)
    np.testing.assert_allclose(jfast, jref, rtol=1e-15, atol=0)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    np.testing.assert_array_equal(eha4_transition(x, u, **c), ref)
    np.testing.assert_array_equal(eha4_jacobian(x, u, **c), jref)


def test_scenarios_pickle_for_workers() -> None:
    """Process pools and Dask ship the scenario by pickle: the copy simulates the same numbers."""
    import pickle

    from chatterspec import scenario

    for name in ("eha4-leak-timeline", "eha4-imm-analogue", "detc-uncertain"):
        sc = scenario(name)
        fs = sc.filter_settings
        kw = {"plant": sc.plant, "windows": sc.windows, "filter_settings": fs}
        short = Scenario(name, sc.nominal, sc.input, 0.05, **kw)
        copy = pickle.loads(pickle.dumps(short))
        assert copy.filter_settings.source == sc.filter_settings.source
        np.testing.assert_array_equal(simulate(copy, 3, 11).z, simulate(short, 3, 11).z)
