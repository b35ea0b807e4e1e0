"""Dynamic second-order SVSF: every property listed in ``docs/design.md`` §7.3 as an
exact (deterministic) test, plus the covariance gain, parametrization and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.errors import ParameterError, ShapeError, SingularMatrixError
from chatterspec.filters import SecondOrderSVSF
from chatterspec.plants.models import LinearModel

STORE = ["x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_prior", "P_post"]
SQUARE_C = np.array([[1.0, 0.2, 0.0], [0.0, 1.0, -0.3], [0.4, 0.0, 1.0]])


def model_with(C: np.ndarray) -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, -0.1, 0.95]])
    B = np.array([[0.0], [0.01], [0.05]])
    m = C.shape[0]
    return LinearModel(A, B, C, np.diag([1e-3, 2e-3, 1e-3]), 0.01 * np.eye(m) + 0.002, 0.01)


def detc_model() -> LinearModel:
    A = np.array([[1.0, 0.001, 0.0], [0.0, 1.0, 0.001], [-557.02, -28.616, 0.9418]])
    B = np.array([[0.0], [0.0], [557.02]])
    C = np.array([[1.0, 0.0, 0.0]])
    return LinearModel(A, B, C, np.diag([1.0, 10.0, 100.0]), np.array([[0.1]]), 1e-3)


def data(model: LinearModel, runs: int = 3, T: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(scale=0.5, size=(runs, T, model.n_outputs)), rng.uniform(-1, 1, size=(T, 1))


GAMMA = np.array([0.3, 0.6, 0.1])
LAM = np.array([0.5, 0.2, 0.8])
E0 = np.array([[1.0, -2.0, 0.5]])
EM1 = np.array([[0.2, 1.0, -1.5]])


def run_with_initial_residuals(z: np.ndarray, u: np.ndarray, **kw: object):
    model = model_with(SQUARE_C)
    filt = SecondOrderSVSF(model, **kw)
    runs = z.shape[0]
    state = filt.initialize(np.zeros(3), np.eye(3), runs=runs, e0=E0, e_prev0=EM1)
    return filt, filt.update(state, z, u, store=STORE)[1]


def residual_sequence(out) -> np.ndarray:
    """e(k|k) for k = -1, 0, 1, ..., T."""
    runs = out.e_post.shape[0]
    return np.concatenate(
        [np.broadcast_to(EM1, (runs, 3))[:, None], np.broadcast_to(E0, (runs, 3))[:, None], out.e_post],
        axis=1,
    )


def test_posterior_residual_recursion_eq_21() -> None:
    """e(k+1|k+1) = (gamma + Lambda) e(k|k) - gamma Lambda e(k-1|k-1), for any data (square H)."""
    z, u = data(model_with(SQUARE_C))
    _, out = run_with_initial_residuals(z, u, gamma=GAMMA, lam=LAM)
    s = residual_sequence(out)
    want = (GAMMA + LAM) * s[:, 1:-1] - GAMMA * LAM * s[:, :-2]
    # e(k+1|k+1) = z - H x(k+1|k+1) cancels O(1) numbers: rounding ~1e-15 times cond(H) ~ 2
    np.testing.assert_allclose(s[:, 2:], want, atol=1e-13)


def test_residual_roots_are_gamma_and_lambda() -> None:
    """The closed-form solution a gamma^k + b lambda^k per channel (distinct roots)."""
    z, u = data(model_with(SQUARE_C), T=40)
    _, out = run_with_initial_residuals(z, u, gamma=GAMMA, lam=LAM)
    s = residual_sequence(out)  # s[:, j] = e(j-1|j-1)
    # e_{-1} = a/g + b/l, e_0 = a + b
    a = (E0 - LAM * EM1) / (1 - LAM / GAMMA)
    b = E0 - a
    k = np.arange(-1, 41)[:, None]
    closed = a * GAMMA**k + b * LAM**k
    np.testing.assert_allclose(s[0], closed, atol=1e-13)
    assert np.all(np.abs(s[:, -1]) < 1e-3)  # it decays: both roots inside the unit circle


def test_sliding_manifold_ratio_is_gamma() -> None:
    """sigma_k = (1 + c) e(k|k) - e(k-1|k-1) obeys sigma_{k+1} = gamma sigma_k (eq 24 with (1 + c))."""
    z, u = data(model_with(SQUARE_C), T=30)
    filt, out = run_with_initial_residuals(z, u, gamma=GAMMA, cutoff=[1.0, 4.0, 0.25])
    np.testing.assert_allclose(filt.lam, [0.5, 0.2, 0.8])
    s = residual_sequence(out)
    sigma = (1 + filt.cutoff) * s[:, 1:] - s[:, :-1]
    np.testing.assert_allclose(sigma[:, 1:], GAMMA * sigma[:, :-1], atol=1e-13)
    # the printed eq (24) with (1 + lambda) would not give a constant ratio
    wrong = (1 + filt.lam) * s[:, 1:] - s[:, :-1]
    assert np.max(np.abs(wrong[:, 1:] - GAMMA * wrong[:, :-1])) > 1e-2


@pytest.mark.parametrize("which", ["square-full", "detc-cov", "detc-pinv"])
def test_zero_initial_residuals_freeze_the_measured_states(which: str) -> None:
    """e(0|0) = e(-1|-1) = 0 => e(k|k) = 0: the measured states equal H^-1 z and gamma, Lambda do nothing."""
    model = model_with(SQUARE_C) if which == "square-full" else detc_model()
    mapping = {"square-full": "full", "detc-cov": "cov", "detc-pinv": "pinv"}[which]
    z, u = data(model, T=200)
    P0 = np.eye(3) if which == "square-full" else 20 * model.Q
    outs = [
        SecondOrderSVSF(model, gamma=g, lam=lam, mapping=mapping).run(
            z, u, x0=np.zeros(3), P0=P0, store=STORE
        )
        for g, lam in ((0.5, 0.5), (0.1, 0.9))
    ]
    for out in outs:
        if which == "square-full":
            np.testing.assert_allclose(out.x_post, z @ np.linalg.inv(SQUARE_C).T, atol=1e-12)
        else:
            # H = [1 0 0]: H M = 1 up to rounding of P C^T (C P C^T)^-1; z ~ 1
            np.testing.assert_allclose(out.x_post[..., 0], z[..., 0], atol=1e-12)
        assert np.max(np.abs(out.e_post)) < 1e-12
    # gamma and Lambda have no effect on the estimates (only rounding-level residuals feed back)
    np.testing.assert_allclose(outs[0].x_post, outs[1].x_post, rtol=1e-9, atol=1e-9)


def test_covariance_uses_the_clipped_ratio_gain() -> None:
    z, u = data(model_with(SQUARE_C))
    filt, out = run_with_initial_residuals(z, u, gamma=GAMMA, lam=LAM)
    s = residual_sequence(out)
    Minv = np.linalg.inv(SQUARE_C)
    dz = out.innovation - (GAMMA + LAM) * s[:, 1:-1] + GAMMA * LAM * s[:, :-2]
    ratio = dz / out.innovation
    assert np.any(ratio > 2) or np.any(ratio < 0)  # the clip is exercised
    model = filt.model
    for r in range(z.shape[0]):
        for k in range(z.shape[1]):
            np.testing.assert_allclose(
                out.x_post[r, k] - out.x_prior[r, k], Minv @ dz[r, k], rtol=1e-10, atol=1e-13
            )
            K = Minv @ np.diag(np.clip(ratio[r, k], 0.0, 2.0))  # [IMM] eq (12) with the clip of design.md I7
            IKC = np.eye(3) - K @ SQUARE_C
            joseph = IKC @ out.P_prior[r, k] @ IKC.T + K @ model.R @ K.T  # eq (14)
            np.testing.assert_allclose(out.P_post[r, k], joseph, rtol=1e-9, atol=1e-14)


def test_zero_residual_gain_is_the_mapping() -> None:
    """With e(k|k) = 0 the ratio is 1, K = H^-1 and P(k|k) = H^-1 R H^-T exactly (full mapping)."""
    model = model_with(SQUARE_C)
    z, u = data(model)
    out = SecondOrderSVSF(model).run(z, u, x0=np.zeros(3), P0=np.eye(3), store=["P_post"])
    Minv = np.linalg.inv(SQUARE_C)
    np.testing.assert_allclose(out.P_post[0, -1], Minv @ model.R @ Minv.T, rtol=1e-8, atol=1e-15)


def test_chunked_equals_batch_bit_for_bit() -> None:
    model = detc_model()
    z, u = data(model, T=33)
    filt = SecondOrderSVSF(model, gamma=0.5, lam=0.5)
    assert filt.mapping == "cov"
    e0 = np.array([[0.3]])
    batch_state = filt.initialize(np.zeros(3), 20 * model.Q, runs=3, e0=e0)
    _, batch = filt.update(batch_state, z, u, store=STORE)
    state, parts = batch_state, []
    for a, b in ((0, 1), (1, 2), (2, 3), (3, 33)):
        state, out = filt.update(state, z[:, a:b], u[a:b], store=STORE)
        parts.append(out)
    for f in STORE:
        np.testing.assert_array_equal(
            np.concatenate([getattr(p, f) for p in parts], axis=1), getattr(batch, f)
        )


@pytest.mark.parametrize("square", [True, False])
def test_runs_in_lanes_equal_one_run_at_a_time_bit_for_bit(square: bool) -> None:
    """Without the log-likelihood the compiled loop advances 8 runs at once (vector lanes); with it, one
    run at a time. 19 runs: two blocks of 8 and 3 left over, one at a time. Every field the same bits."""
    model = model_with(SQUARE_C) if square else detc_model()
    z, u = data(model, runs=19, T=40)
    filt = SecondOrderSVSF(model, gamma=0.3, lam=0.5)
    lanes = [f for f in STORE if f != "loglik"]
    P0 = np.eye(3) if square else 20 * model.Q
    a = filt.run(z, u, x0=np.zeros(3), P0=P0, store=lanes)
    b = filt.run(z, u, x0=np.zeros(3), P0=P0, store=STORE)
    for f in lanes:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def test_compiled_and_numpy_paths_agree(monkeypatch: pytest.MonkeyPatch) -> None:
    if not _jit.enabled():
        pytest.skip("numba not available: only the numpy path exists")
    z, u = data(model_with(SQUARE_C), T=100)
    _, fast = run_with_initial_residuals(z, u, gamma=GAMMA, lam=LAM)
    monkeypatch.setattr(_jit, "enabled", lambda: False)
    _, slow = run_with_initial_residuals(z, u, gamma=GAMMA, lam=LAM)
    for f in STORE:  # scalar loops vs BLAS/LAPACK: summation order only
        np.testing.assert_allclose(getattr(fast, f), getattr(slow, f), rtol=1e-10, atol=1e-13, err_msg=f)


def test_parameters_out_of_range_are_named() -> None:
    model = detc_model()
    for g in (0.0, 1.0, 2.0):
        with pytest.raises(ParameterError, match=r"gamma must lie in the open interval \(0, 1\)"):
            SecondOrderSVSF(model, gamma=g)
    for lam in (1.0, 1.5):
        with pytest.raises(ParameterError, match=r"unit circle.*never decays"):
            SecondOrderSVSF(model, lam=lam)
    with pytest.raises(ParameterError, match="unit circle"):
        SecondOrderSVSF(model, cutoff=0.0)
    with pytest.raises(ParameterError, match=r"lam .* must be > 0"):
        SecondOrderSVSF(model, lam=0.0)
    with pytest.raises(ParameterError, match="not both"):
        SecondOrderSVSF(model, lam=0.5, cutoff=1.0)
    with pytest.raises(ShapeError, match="gamma must be a scalar or have 1 entries"):
        SecondOrderSVSF(model, gamma=[0.5, 0.5])
    with pytest.raises(SingularMatrixError, match="mapping='full'"):
        SecondOrderSVSF(model, mapping="full")
    with pytest.raises(ParameterError, match="ratio_clip"):
        SecondOrderSVSF(model, ratio_clip=(2.0, 0.0))
    with pytest.raises(TypeError, match="unexpected keyword"):
        SecondOrderSVSF(model, Lambda=0.5)
    default = SecondOrderSVSF(model)
    np.testing.assert_array_equal(default.lam, [0.5])
    np.testing.assert_array_equal(default.cutoff, [1.0])
