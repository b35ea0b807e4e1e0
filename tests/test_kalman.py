"""Kalman filter and EKF: exact identities against filterpy, the EKF on a linear model, and a
hand-written EKF on a small nonlinear (pendulum) model."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from chatterspec import _jit
from chatterspec.errors import NonFiniteError, ParameterError, ShapeError
from chatterspec.filters import ExtendedKalmanFilter, KalmanFilter
from chatterspec.plants.models import LinearModel


def detc_model() -> LinearModel:
    """The DETC2015 linear EHA (eq 25-27) with the filter's Q, R."""
    A = np.array([[1.0, 0.001, 0.0], [0.0, 1.0, 0.001], [-557.02, -28.616, 0.9418]])
    B = np.array([[0.0], [0.0], [557.02]])
    return LinearModel(
        A, B, np.array([[1.0, 0.0, 0.0]]), np.diag([1.0, 10.0, 100.0]), np.array([[0.1]]), 1e-3
    )


def two_output_model() -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, 0.0, 0.95]])
    B = np.array([[0.0, 0.0], [0.01, 0.0], [0.0, 0.05]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Q = np.diag([1e-4, 1e-3, 1e-3])
    Q[0, 1] = Q[1, 0] = 2e-5
    R = np.array([[0.01, 0.002], [0.002, 0.02]])
    return LinearModel(A, B, C, Q, R, 0.01)


def data(model: LinearModel, runs: int, T: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    z = rng.normal(scale=0.3, size=(runs, T, model.n_outputs))
    u = rng.uniform(-1.0, 1.0, size=(T, model.n_inputs))
    return z, u


class Pendulum:
    """x = (angle [rad], rate [rad/s]); Euler step of theta'' = -(g/l) sin theta - b theta' + u."""

    def __init__(self) -> None:
        self.dt = 0.01
        self.n_states, self.n_outputs, self.n_inputs = 2, 1, 1
        self.C = np.array([[1.0, 0.0]])
        self.Q = np.diag([1e-6, 1e-4])
        self.R = np.array([[1e-3]])

    def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        th, w = x[..., 0], x[..., 1]
        uu = np.broadcast_to(u, (*x.shape[:-1], 1))[..., 0]
        return np.stack([th + self.dt * w, w + self.dt * (-9.81 * np.sin(th) - 0.3 * w + uu)], axis=-1)

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        J = np.empty((*x.shape[:-1], 2, 2))
        J[..., 0, 0] = 1.0
        J[..., 0, 1] = self.dt
        J[..., 1, 0] = -self.dt * 9.81 * np.cos(x[..., 0])
        J[..., 1, 1] = 1.0 - 0.3 * self.dt
        return J


@pytest.mark.parametrize("make", [detc_model, two_output_model])
def test_kf_equals_filterpy_step_by_step(make) -> None:
    filterpy = pytest.importorskip("filterpy.kalman")
    model = make()
    z, u = data(model, 3, 60)
    P0 = 20 * model.Q
    out = KalmanFilter(model).run(
        z, u, x0=np.zeros(model.n_states), P0=P0, store=["x_post", "S", "loglik", "P_post"]
    )
    for r in range(3):
        ref = filterpy.KalmanFilter(dim_x=model.n_states, dim_z=model.n_outputs, dim_u=model.n_inputs)
        ref.F, ref.B, ref.H = model.A.copy(), model.B.copy(), model.C.copy()
        ref.Q, ref.R, ref.P, ref.x = model.Q.copy(), model.R.copy(), P0.copy(), np.zeros((model.n_states, 1))
        for k in range(z.shape[1]):
            ref.predict(u=u[k][:, None])
            ref.update(z[r, k][:, None])
            # filterpy uses the same Joseph form; only the order of floating-point sums differs,
            # so agreement is to rounding relative to the magnitudes (states up to ~1e3 here).
            np.testing.assert_allclose(out.x_post[r, k], ref.x[:, 0], rtol=1e-10, atol=1e-10)
            np.testing.assert_allclose(out.P_post[r, k], ref.P, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(out.S[r, k], ref.S, rtol=1e-12)
            np.testing.assert_allclose(out.loglik[r, k], ref.log_likelihood, rtol=1e-10)


def test_loglik_is_the_gaussian_log_density() -> None:
    model = two_output_model()
    z, u = data(model, 2, 10)
    out = KalmanFilter(model).run(z, u, x0=np.zeros(3), P0=model.Q * 5)
    for k in (0, 4, 9):
        want = multivariate_normal(np.zeros(2), out.S[0, k]).logpdf(out.innovation[:, k])
        np.testing.assert_allclose(out.loglik[:, k], want, rtol=1e-12)


@pytest.mark.parametrize("make", [detc_model, two_output_model])
def test_ekf_on_linear_model_equals_kf(make) -> None:
    model = make()
    z, u = data(model, 4, 80, seed=3)
    P0 = 20 * model.Q
    store = ["x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_post"]
    kf = KalmanFilter(model).run(z, u, x0=np.zeros(model.n_states), P0=P0, store=store)
    ekf = ExtendedKalmanFilter(model).run(z, u, x0=np.zeros(model.n_states), P0=P0, store=store)
    # Same equations; the shared path uses LAPACK and the per-run path a hand-written Cholesky,
    # so they agree to rounding: relative 1e-9 on states that reach ~1e3 with P entries ~1e5.
    for f in ("x_prior", "x_post", "innovation", "e_post", "loglik"):
        np.testing.assert_allclose(getattr(ekf, f), getattr(kf, f), rtol=1e-9, atol=1e-9, err_msg=f)
    # one output shape rule: (runs, K, ...) on the shared and the per-run path alike
    assert kf.S.shape == ekf.S.shape and kf.P_post.shape == ekf.P_post.shape
    np.testing.assert_allclose(ekf.S, kf.S, rtol=1e-10)
    np.testing.assert_allclose(ekf.P_post, kf.P_post, rtol=1e-8, atol=1e-8)


def test_shared_covariance_is_computed_once() -> None:
    model = detc_model()
    z, u = data(model, 5, 20)
    kf = KalmanFilter(model)
    state = kf.initialize(np.zeros(3), 20 * model.Q, runs=5)
    assert state.shared_covariance and state.P.shape == (3, 3)
    new, out = kf.update(state, z, u, store=["S", "P_post", "x_post"])
    # the state keeps one (n, n) matrix; the outputs have the runs axis as views of one sequence
    assert new.P.shape == (3, 3) and out.S.shape == (5, 20, 1, 1) and out.P_post.shape == (5, 20, 3, 3)
    assert out.P_post.base is not None and not out.P_post.flags.writeable  # a view, not 5 copies
    gains, Ppost = kf.gain_sequence(20 * model.Q, 20)
    np.testing.assert_array_equal(Ppost, out.P_post[3])
    assert gains.shape == (20, 3, 1)


def test_per_run_covariance_from_a_bank_matches_shared() -> None:
    """A bank may replace the shared P by a per-run one (mixing); the numbers must not change."""
    model = two_output_model()
    z, u = data(model, 3, 30)
    kf = KalmanFilter(model)
    s0 = kf.initialize(np.zeros(3), 4 * model.Q, runs=3)
    s_run = s0.replace(P=np.broadcast_to(s0.P, (3, 3, 3)).copy())
    a, out_a = kf.update(s0, z, u)
    b, out_b = kf.update(s_run, z, u)
    assert b.P.shape == (3, 3, 3)
    np.testing.assert_allclose(out_b.x_post, out_a.x_post, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(b.P, np.broadcast_to(a.P, b.P.shape), rtol=1e-10, atol=1e-14)


def ekf_reference(
    model: Pendulum, z: np.ndarray, u: np.ndarray, x0: np.ndarray, P0: np.ndarray
) -> np.ndarray:
    """Textbook single-run EKF (Joseph form), written independently of the package."""
    x, P, out = x0.copy(), P0.copy(), []
    for k in range(z.shape[0]):
        F = model.jacobian(x, u[k])
        x = model.transition(x, u[k])
        P = F @ P @ F.T + model.Q
        S = model.C @ P @ model.C.T + model.R
        K = P @ model.C.T @ np.linalg.inv(S)
        x = x + K @ (z[k] - model.C @ x)
        IKC = np.eye(2) - K @ model.C
        P = IKC @ P @ IKC.T + K @ model.R @ K.T
        out.append(x)
    return np.array(out)


def test_ekf_on_a_pendulum_equals_a_textbook_ekf() -> None:
    model = Pendulum()
    rng = np.random.default_rng(7)
    T, runs = 200, 3
    u = 0.5 * np.sin(np.arange(T) * 0.05)[:, None]
    x = np.zeros((runs, 2))
    x[:, 0] = [0.3, -0.5, 1.0]
    zs = []
    for k in range(T):
        x = model.transition(x, u[k]) + rng.normal(size=(runs, 2)) * np.sqrt(np.diag(model.Q))
        zs.append(x[:, :1] + rng.normal(size=(runs, 1)) * np.sqrt(model.R[0, 0]))
    z = np.stack(zs, axis=1)
    P0 = np.diag([0.1, 0.1])
    out = ExtendedKalmanFilter(model).run(z, u, x0=np.zeros(2), P0=P0)
    for r in range(runs):
        ref = ekf_reference(model, z[r], u, np.zeros(2), P0)
        # same arithmetic, different summation order: rounding only (states are O(1))
        np.testing.assert_allclose(out.x_post[r], ref, rtol=1e-9, atol=1e-11)
    assert np.sqrt(np.mean((out.x_post[:, 50:, 0] - z[:, 50:, 0]) ** 2)) < 0.05  # it tracks


@pytest.mark.parametrize("which", ["kf-shared", "kf-per-run", "ekf"])
def test_chunked_equals_batch_bit_for_bit(which: str) -> None:
    model = two_output_model()
    z, u = data(model, 3, 41)
    filt = ExtendedKalmanFilter(model) if which == "ekf" else KalmanFilter(model)
    P0 = 3 * model.Q if which == "kf-shared" else np.broadcast_to(3 * model.Q, (3, 3, 3))
    store = ["x_prior", "x_post", "innovation", "loglik", "e_post"]
    batch = filt.run(z, u, x0=np.zeros(3), P0=P0, store=store)
    state = filt.initialize(np.zeros(3), P0, runs=3)
    parts = []
    for a, b in ((0, 1), (1, 8), (8, 9), (9, 30), (30, 41)):
        state, out = filt.update(state, z[:, a:b], u[a:b], store=store)
        parts.append(out)
    for f in store:
        np.testing.assert_array_equal(
            np.concatenate([getattr(p, f) for p in parts], axis=1), getattr(batch, f)
        )
    assert state.k == 41


@pytest.mark.parametrize("which", ["kf-shared", "kf-per-run", "ekf"])
def test_compiled_and_numpy_paths_agree(which: str, monkeypatch: pytest.MonkeyPatch) -> None:
    if not _jit.enabled():
        pytest.skip("numba not available: only the numpy path exists")
    model = detc_model()
    z, u = data(model, 3, 100)
    filt = ExtendedKalmanFilter(model) if which == "ekf" else KalmanFilter(model)
    P0 = 20 * model.Q if which == "kf-shared" else np.broadcast_to(20 * model.Q, (3, 3, 3))
    store = ["x_prior", "x_post", "innovation", "loglik", "e_post"]
    fast = filt.run(z, u, x0=np.zeros(3), P0=P0, store=store)
    monkeypatch.setattr(_jit, "enabled", lambda: False)
    slow = filt.run(z, u, x0=np.zeros(3), P0=P0, store=store)
    # Same operations in a different summation order (BLAS/LAPACK vs scalar loops): rounding only,
    # relative 1e-10 of states reaching ~1e3.
    for f in store:
        np.testing.assert_allclose(getattr(fast, f), getattr(slow, f), rtol=1e-10, atol=1e-9, err_msg=f)


def test_bad_input_is_named() -> None:
    model = detc_model()
    kf = KalmanFilter(model)
    z, u = data(model, 2, 5)
    with pytest.raises(ParameterError, match="P0 must be symmetric"):
        kf.initialize(np.zeros(3), np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]))
    with pytest.raises(ParameterError, match="P0 must be positive definite"):
        kf.initialize(np.zeros(3), np.diag([1.0, 0.0, 1.0]))
    with pytest.raises(ShapeError, match="P0 must have shape"):
        kf.initialize(np.zeros(3), np.eye(2))
    with pytest.raises(ShapeError, match="x0 must have 3 entries"):
        kf.initialize(np.zeros(2), np.eye(3))
    state = kf.initialize(np.zeros(3), np.eye(3), runs=2)
    with pytest.raises(ShapeError, match=r"z must have shape \(2, K, 1\)"):
        kf.update(state, z[:1], u)
    with pytest.raises(ShapeError, match="u must have shape"):
        kf.update(state, z, u[:3])
    bad = z.copy()
    bad[1, 2, 0] = np.nan
    with pytest.raises(NonFiniteError, match="z contains 1 NaN"):
        kf.update(state, bad, u)
    with pytest.raises(ParameterError, match="store may name only"):
        kf.update(state, z, u, store=["x_post", "gain"])
    with pytest.raises(TypeError, match="unexpected keyword"):
        kf.run(z, u, x0=np.zeros(3), P0=np.eye(3), x_0=1)
    with pytest.raises(TypeError, match="unexpected keyword"):
        KalmanFilter(model, psi=1.0)
    with pytest.raises(TypeError, match="ExtendedKalmanFilter"):
        KalmanFilter(Pendulum())
    with pytest.raises(TypeError, match="lacks"):
        ExtendedKalmanFilter(object())
    with pytest.raises(ShapeError, match="P must have shape"):
        state.replace(P=np.eye(2))


@pytest.mark.parametrize("jit", [True, False])
def test_a_covariance_that_is_not_positive_definite_is_named(
    jit: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    from chatterspec.errors import SingularMatrixError

    if not jit:
        monkeypatch.setattr(_jit, "enabled", lambda: False)
    duck = Pendulum()
    duck.R = np.array([[-1.0]])
    with pytest.raises(ParameterError, match=r"model.R must be positive semi-definite"):
        ExtendedKalmanFilter(duck)
    duck.R = np.array([[1e-3]])
    duck.Q = np.array([[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(ParameterError, match=r"model.Q must be symmetric"):
        ExtendedKalmanFilter(duck)
    model = detc_model()
    kf = KalmanFilter(model)
    state = kf.initialize(np.zeros(3), np.eye(3), runs=2)
    broken = state.replace(P=-np.broadcast_to(np.eye(3) * 10, (2, 3, 3)))  # e.g. a bad mixing step
    with pytest.raises(SingularMatrixError, match="not positive definite in run 0"):
        kf.update(broken, np.zeros((2, 3, 1)), np.zeros((3, 1)))
