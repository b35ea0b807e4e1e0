"""SVSF with covariance ([SMM] eq 2.1-2.10): the division-free gain equals eq (2.5) wherever
e != 0, the Joseph covariance uses that gain, the state path equals the existing SVSF, and the
usual batch/online, compiled/numpy and bad-input checks."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.errors import NonFiniteError, ParameterError, ShapeError, SingularMatrixError
from chatterspec.filters import SVSF, SVSFCov
from chatterspec.plants.models import LinearModel

STORE = ["x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_prior", "P_post"]


def model_with(C: np.ndarray) -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, -0.1, 0.95]])
    B = np.array([[0.0], [0.01], [0.05]])
    m = C.shape[0]
    return LinearModel(A, B, C, np.diag([1e-3, 2e-3, 1e-3]), 0.01 * np.eye(m) + 0.002, 0.01)


SQUARE_C = np.array([[1.0, 0.2, 0.0], [0.0, 1.0, -0.3], [0.4, 0.0, 1.0]])
THIN_C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


class Duck:
    """A LinearModel seen only through the duck-typed interface (forces the per-sample model path)."""

    def __init__(self, model: LinearModel) -> None:
        self._m = model
        for a in ("C", "Q", "R", "dt", "n_states", "n_outputs", "n_inputs"):
            setattr(self, a, getattr(model, a))

    def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self._m.transition(x, u)

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self._m.jacobian(x, u)


def data(model: LinearModel, runs: int = 3, T: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(scale=0.5, size=(runs, T, model.n_outputs)), rng.uniform(-1, 1, size=(T, 1))


def previous(out_e_post: np.ndarray, e0: np.ndarray) -> np.ndarray:
    """e(k|k) for every sample: the initial residual, then the stored posteriors shifted by one."""
    return np.concatenate([e0[:, None], out_e_post[:, :-1]], axis=1)


@pytest.mark.parametrize(
    ("C", "mapping"), [(SQUARE_C, "full"), (THIN_C, "pinv"), (THIN_C, "cov"), (SQUARE_C, "cov")]
)
def test_division_free_gain_equals_eq_2_5(C: np.ndarray, mapping: str) -> None:
    model = model_with(C)
    z, u = data(model)
    psi, gamma = np.array([0.3, 0.6, 0.2])[: model.n_outputs], 0.4
    filt = SVSFCov(model, psi=psi, gamma=gamma, mapping=mapping)
    e0 = np.full((3, model.n_outputs), 0.1)
    state = filt.initialize(np.zeros(3), np.eye(3) * 0.5, runs=3, e0=e0)
    _, out = filt.update(state, z, u, store=STORE)
    e, ebar = out.innovation, previous(out.e_post, e0)
    inside = np.abs(e) < psi
    assert 0.2 < inside.mean() < 0.8  # both regimes of sat() are exercised
    assert np.all(e != 0)
    for r in range(3):
        for k in range(z.shape[1]):
            Pp = out.P_prior[r, k]
            if mapping == "full":
                M = np.linalg.inv(C)
            elif mapping == "pinv":
                M = np.linalg.pinv(C)
            else:
                M = Pp @ C.T @ np.linalg.inv(C @ Pp @ C.T)
            sat = np.clip(e[r, k] / psi, -1, 1)
            # eq (2.5) literally: C+ diag[(|e| + gamma |e(k|k)|) o sat(e / psi)] diag(e)^-1
            K = (
                M
                @ np.diag((np.abs(e[r, k]) + gamma * np.abs(ebar[r, k])) * sat)
                @ np.linalg.inv(np.diag(e[r, k]))
            )
            # rounding only: the filter divides by max(|e|, psi) instead of multiplying by sat/e
            np.testing.assert_allclose(
                out.x_post[r, k] - out.x_prior[r, k], K @ e[r, k], rtol=1e-10, atol=1e-13
            )
            IKC = np.eye(3) - K @ C
            joseph = IKC @ Pp @ IKC.T + K @ model.R @ K.T  # eq (2.9)
            np.testing.assert_allclose(out.P_post[r, k], joseph, rtol=1e-9, atol=1e-14)
            np.testing.assert_allclose(out.S[r, k], C @ Pp @ C.T + model.R, rtol=1e-12)


def test_outside_the_layer_the_residual_shrinks_by_gamma() -> None:
    model = model_with(SQUARE_C)
    z, u = data(model)
    psi, gamma = np.array([0.3, 0.6, 0.2]), 0.4
    filt = SVSFCov(model, psi=psi, gamma=gamma)
    out = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3))
    ebar = previous(out.e_post, np.zeros((3, 3)))
    outside = np.abs(out.innovation) > psi
    assert outside.mean() > 0.2
    # |e(k+1|k+1)| = gamma |e(k|k)| outside the layer (design.md §7.2); C C^-1 = I up to rounding of O(1)
    np.testing.assert_allclose(np.abs(out.e_post)[outside], gamma * np.abs(ebar)[outside], atol=1e-13)


def test_state_path_equals_the_existing_svsf() -> None:
    """Full measurement: the covariance is bookkeeping; the estimates are those of eq (8)."""
    model = model_with(SQUARE_C)
    z, u = data(model, T=80)
    psi = [0.2, 0.5, 1.0]
    ref = SVSF(model, psi=psi, gamma=0.3).run(z, u, x0=np.zeros(3), store={"x_post"})
    filt = SVSFCov(model, psi=psi, gamma=0.3)
    state = filt.initialize(np.zeros(3), np.eye(3), runs=3, e0=z[:, 0])
    _, out = filt.update(state, z[:, 1:], u[:-1])
    # identical equations, SVSF works in C-aligned coordinates: rounding relative to |x| ~ 30
    np.testing.assert_allclose(out.x_post, ref.x_post[:, 1:], rtol=1e-12, atol=1e-12)


def test_zero_innovation_is_not_a_singularity() -> None:
    model = model_with(SQUARE_C)
    out = SVSFCov(model, psi=0.1).run(np.zeros((2, 5, 3)), np.zeros((5, 1)), x0=np.zeros(3), P0=np.eye(3))
    assert np.all(out.innovation == 0) and np.all(out.x_post == 0) and np.all(np.isfinite(out.loglik))


def test_nonlinear_path_equals_linear_path() -> None:
    model = model_with(THIN_C)
    z, u = data(model)
    a = SVSFCov(model, psi=0.3, gamma=0.2).run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    b = SVSFCov(Duck(model), psi=0.3, gamma=0.2).run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    for f in STORE:  # same kernel; the prediction comes from model.transition (numpy) instead: rounding
        np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=1e-10, atol=1e-13, err_msg=f)


@pytest.mark.parametrize("mapping", ["pinv", "cov"])
def test_chunked_equals_batch_bit_for_bit(mapping: str) -> None:
    model = model_with(THIN_C)
    z, u = data(model, T=37)
    filt = SVSFCov(model, psi=[0.3, 0.2], gamma=0.5, mapping=mapping)
    batch = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    state = filt.initialize(np.zeros(3), np.eye(3), runs=3)
    parts = []
    for a, b in ((0, 1), (1, 2), (2, 20), (20, 37)):
        state, out = filt.update(state, z[:, a:b], u[a:b], store=STORE)
        parts.append(out)
    for f in STORE:
        np.testing.assert_array_equal(
            np.concatenate([getattr(p, f) for p in parts], axis=1), getattr(batch, f)
        )


@pytest.mark.parametrize(("C", "mapping"), [(SQUARE_C, "full"), (THIN_C, "cov")])
def test_runs_in_lanes_equal_one_run_at_a_time_bit_for_bit(C: np.ndarray, mapping: str) -> None:
    """Without the log-likelihood the compiled loop advances 8 runs at once (vector lanes); with it, one
    run at a time. 19 runs: two blocks of 8 and 3 left over, one at a time. Every field the same bits."""
    model = model_with(C)
    z, u = data(model, runs=19, T=40)
    filt = SVSFCov(model, psi=0.3, gamma=0.4, mapping=mapping)
    lanes = [f for f in STORE if f != "loglik"]
    a = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3), store=lanes)
    b = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    for f in lanes:
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


@pytest.mark.parametrize("mapping", ["full", "cov"])
def test_compiled_and_numpy_paths_agree(mapping: str, monkeypatch: pytest.MonkeyPatch) -> None:
    if not _jit.enabled():
        pytest.skip("numba not available: only the numpy path exists")
    model = model_with(SQUARE_C)
    z, u = data(model, T=100)
    filt = SVSFCov(model, psi=[0.3, 0.6, 0.2], gamma=0.4, mapping=mapping)
    fast = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    monkeypatch.setattr(_jit, "enabled", lambda: False)
    slow = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    for f in STORE:  # scalar loops vs BLAS/LAPACK: summation order only
        np.testing.assert_allclose(getattr(fast, f), getattr(slow, f), rtol=1e-10, atol=1e-13, err_msg=f)


def test_bad_input_is_named() -> None:
    thin = model_with(THIN_C)
    with pytest.raises(SingularMatrixError, match="mapping='full' needs a square invertible C"):
        SVSFCov(thin, psi=0.1, mapping="full")
    with pytest.raises(ParameterError, match="psi must be > 0"):
        SVSFCov(thin, psi=[0.1, 0.0])
    with pytest.raises(ShapeError, match="psi must be a scalar or have 2 entries"):
        SVSFCov(thin, psi=[0.1, 0.2, 0.3])
    with pytest.raises(NonFiniteError, match="psi contains"):
        SVSFCov(thin, psi=np.nan)
    for g in (0.0, 1.0, -0.5, 1.5):
        with pytest.raises(ParameterError, match="gamma must lie in the open interval"):
            SVSFCov(thin, psi=0.1, gamma=g)
    with pytest.raises(ParameterError, match="mapping must be"):
        SVSFCov(thin, psi=0.1, mapping="bogus")
    with pytest.raises(SingularMatrixError, match="mapping='luen' needs n = 2m"):
        SVSFCov(thin, psi=0.1, mapping="luen")
    with pytest.raises(TypeError, match="unexpected keyword"):
        SVSFCov(thin, psi=0.1, boundary=1.0)
    filt = SVSFCov(thin, psi=0.1)
    assert filt.mapping == "cov"
    with pytest.raises(ParameterError, match="P0 must be positive definite"):
        filt.initialize(np.zeros(3), -np.eye(3))
    state = filt.initialize(np.zeros(3), np.eye(3), runs=2)
    with pytest.raises(ShapeError, match=r"z must have shape \(2, K, 2\)"):
        filt.update(state, np.zeros((2, 4, 3)), np.zeros((4, 1)))


def test_vbl_equals_the_kalman_filter_inside_the_layer() -> None:
    """A layer so wide that psi_vbl <= psi always: the VBL-SVSF is the Kalman filter."""
    from chatterspec.filters import KalmanFilter

    model = model_with(THIN_C)
    z, u = data(model)
    vbl = SVSFCov(model, psi=1e6, gamma=0.3, vbl=True).run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    P0 = np.broadcast_to(np.eye(3), (3, 3, 3))  # per-run P: the KF takes the same kernel
    kf = KalmanFilter(model).run(z, u, x0=np.zeros(3), P0=P0, store=STORE)
    for f in STORE:  # same kernel, same Kalman-gain branch: identical arithmetic
        np.testing.assert_array_equal(getattr(vbl, f), getattr(kf, f), err_msg=f)
    # and a layer so narrow that psi_vbl > psi always: the fixed-psi SVSF
    narrow = SVSFCov(model, psi=1e-9, gamma=0.3, vbl=True).run(z, u, x0=np.zeros(3), P0=np.eye(3))
    fixed = SVSFCov(model, psi=1e-9, gamma=0.3).run(z, u, x0=np.zeros(3), P0=np.eye(3))
    np.testing.assert_array_equal(narrow.x_post, fixed.x_post)


@pytest.mark.parametrize("jit", [True, False])
def test_vbl_switches_per_sample_by_its_criterion(jit: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    if not jit:
        monkeypatch.setattr(_jit, "enabled", lambda: False)
    model = model_with(SQUARE_C)
    z, u = data(model)
    psi, gamma = np.array([3.2, 6.4, 2.4]), 0.3  # wide enough that both gains occur
    filt = SVSFCov(model, psi=psi, gamma=gamma, vbl=True)
    out = filt.run(z, u, x0=np.zeros(3), P0=np.eye(3), store=STORE)
    ebar = previous(out.e_post, np.zeros((3, 3)))
    M = np.linalg.inv(SQUARE_C)
    used = []
    for r in range(3):
        for k in range(z.shape[1]):
            e = out.innovation[r, k]
            Kkf = out.P_prior[r, k] @ SQUARE_C.T @ np.linalg.inv(out.S[r, k])
            need = np.abs(e) + gamma * np.abs(ebar[r, k])
            kf = bool(np.all(need / np.diag(SQUARE_C @ Kkf) <= psi))
            K = Kkf if kf else M @ np.diag(need / np.maximum(np.abs(e), psi))
            used.append(kf)
            np.testing.assert_allclose(out.x_post[r, k] - out.x_prior[r, k], K @ e, rtol=1e-9, atol=1e-13)
    assert 0.1 < np.mean(used) < 0.9  # both branches are exercised


def four_state_model() -> LinearModel:
    """n = 4, m = 2 (x1 and x4 measured, like the EHA): the Luenberger form applies."""
    A = np.array(
        [[1.0, 0.01, 0.0, 0.0], [0.0, 1.0, 0.01, 0.0], [-0.5, -0.3, 0.97, 0.01], [0.0, 0.4, 0.2, 0.9]]
    )
    B = np.array([[0.0], [0.0], [0.05], [0.01]])
    C = np.array([[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])
    return LinearModel(A, B, C, np.diag([1e-4, 1e-3, 1e-2, 1e-3]), np.diag([1e-3, 2e-3]), 0.01)


def test_luen_mapping_equals_the_existing_reduced_order_svsf() -> None:
    model = four_state_model()
    z, u = data(model, T=80)
    psi = np.array([0.2, 0.3, 0.5, 0.8])
    ref = SVSF(model, psi=psi, gamma=0.3).run(z, u, x0=np.zeros(4), store={"x_post"})
    filt = SVSFCov(model, psi=psi, gamma=0.3, mapping="luen")
    state = filt.initialize(np.zeros(4), np.eye(4), runs=3, e0=z[:, 0])
    _, out = filt.update(state, z[:, 1:], u[:-1], store=STORE)
    # same eq 9-11 in the same coordinates; matrices formed in a different order: rounding only
    np.testing.assert_allclose(out.x_post, ref.x_post[:, 1:], rtol=1e-10, atol=1e-12)
    assert np.all(np.linalg.eigvalsh(out.P_post) > 0)  # the Joseph form keeps P positive definite
    with pytest.raises(ParameterError, match=r"correct\(\) is not available with mapping='luen'"):
        filt.correct(state, np.zeros((3, 4)), np.eye(4), z[:, 1])
    with pytest.raises(ShapeError, match="psi must be a scalar or have 4 entries"):
        SVSFCov(model, psi=[0.1, 0.2], mapping="luen")


def test_second_order_luen_residual_recursion_and_freeze() -> None:
    from chatterspec.filters import SecondOrderSVSF

    model = four_state_model()
    z, u = data(model, T=60)
    g, lam = np.array([0.3, 0.6]), np.array([0.5, 0.2])
    filt = SecondOrderSVSF(model, gamma=g, lam=lam, mapping="luen")
    e0, em1 = np.array([[1.0, -0.5]]), np.array([[0.3, 0.2]])
    state = filt.initialize(np.zeros(4), np.eye(4), runs=3, e0=e0, e_prev0=em1)
    _, out = filt.update(state, z, u, store=STORE)
    s = np.concatenate(
        [np.broadcast_to(em1, (3, 2))[:, None], np.broadcast_to(e0, (3, 2))[:, None], out.e_post], 1
    )
    # d_u = e - r makes the measured residual e(k+1|k+1) = r = (g + L) e(k|k) - g L e(k-1|k-1) (eq 21)
    np.testing.assert_allclose(s[:, 2:], (g + lam) * s[:, 1:-1] - g * lam * s[:, :-2], atol=1e-13)
    frozen = SecondOrderSVSF(model, gamma=g, lam=lam, mapping="luen").run(z, u, x0=np.zeros(4), P0=np.eye(4))
    np.testing.assert_allclose(frozen.x_post[..., [0, 3]], z, atol=1e-13)


def test_luen_with_a_per_run_jacobian_equals_the_linear_path() -> None:
    model = four_state_model()
    z, u = data(model, T=40)
    psi = np.array([0.2, 0.3, 0.5, 0.8])
    a = SVSFCov(model, psi=psi, mapping="luen").run(z, u, x0=np.zeros(4), P0=np.eye(4), store=STORE)
    b = SVSFCov(Duck(model), psi=psi, mapping="luen").run(z, u, x0=np.zeros(4), P0=np.eye(4), store=STORE)
    for f in STORE:  # model.transition (numpy) vs A x + B u in the engine: rounding only
        np.testing.assert_allclose(getattr(b, f), getattr(a, f), rtol=1e-10, atol=1e-13, err_msg=f)
