"""One sample per call (``filter.online(...).step(z, u)``): the batch path's numbers, its errors, its state.

Every estimate is compared with ``run`` / ``update`` on the same data **bit for bit**: on the compiled
path both go through the same compiled steps (one sample per call there, a loop over the record here);
on the numpy path (``CHATTERSPEC_JIT=0``) a step is ``update`` on one sample, and ``update`` gives the
same bits for any chunking. The one exception is stated where it is tested: the numpy path's shared
Kalman covariance (BLAS products) against the per-run recursion, equal to rounding.
"""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.errors import DivergenceError, NonFiniteError, ShapeError
from chatterspec.filters import IMM, SMMSVSF, ExtendedKalmanFilter, KalmanFilter, SecondOrderSVSF, SVSFCov
from chatterspec.filters.one_sample import OnlineBank, OnlineFilter, OnlineSVSF
from chatterspec.filters.svsf import SVSF
from chatterspec.plants.models import LinearModel
from chatterspec.plants.nonlinear import NonlinearModel

DT = 0.01


def model3(a22: float = 0.98) -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, a22, 0.01], [0.0, 0.0, 0.95]])
    B = np.array([[0.0], [0.01], [0.05]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    Q = np.diag([1e-4, 1e-3, 1e-3])
    R = np.array([[0.01, 0.002], [0.002, 0.02]])
    return LinearModel(A, B, C, Q, R, DT)


def data(runs: int, T: int, m: int = 2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.normal(scale=0.3, size=(runs, T, m)), rng.uniform(-1.0, 1.0, size=(T, 1))


def steps(f: object, z: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.array([f.step(z[k], u[k]) for k in range(z.shape[0])])  # type: ignore[attr-defined]


X0, P0 = np.array([0.1, 0.0, -0.1]), np.diag([1.0, 2.0, 0.5])
STORE = ("x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_prior", "P_post")


# one-sample functions of a 2-state oscillator measured through a range-like h(x) (module level:
# the compiled loops inline them, and workers pickle them)
def osc_f(x, u, out):  # type: ignore[no-untyped-def]
    out[0] = x[0] + DT * x[1]
    out[1] = x[1] + DT * (-4.0 * np.sin(x[0]) - 0.2 * x[1] + u[0])


def osc_jac(x, u, out):  # type: ignore[no-untyped-def]
    out[0, 0] = 1.0
    out[0, 1] = DT
    out[1, 0] = -4.0 * DT * np.cos(x[0])
    out[1, 1] = 1.0 - 0.2 * DT


def osc_h(x, out):  # type: ignore[no-untyped-def]
    out[0] = np.sqrt(x[0] * x[0] + 1.0)


def osc_h_jac(x, out):  # type: ignore[no-untyped-def]
    out[0, 0] = x[0] / np.sqrt(x[0] * x[0] + 1.0)
    out[0, 1] = 0.0


def oscillator() -> NonlinearModel:
    Q, R = np.diag([1e-6, 1e-4]), np.eye(1) * 1e-4
    return NonlinearModel.from_steps(osc_f, osc_jac, Q, R, DT, h=osc_h, h_jac=osc_h_jac)


@pytest.mark.parametrize(
    "make",
    [
        lambda m: KalmanFilter(m),
        lambda m: ExtendedKalmanFilter(m),
        lambda m: SVSFCov(m, psi=[0.5, 0.4], gamma=0.2),
        lambda m: SecondOrderSVSF(m, gamma=0.2, lam=0.5),
        lambda m: SVSFCov(m, psi=[0.5, 0.4], gamma=0.2, vbl=True),
    ],
    ids=["kf", "ekf", "svsf-cov", "svsf2", "svsf-cov-vbl"],
)
def test_online_filter_equals_the_batch_path(make):  # type: ignore[no-untyped-def]
    model = model3()
    f = make(model)
    z, u = data(1, 300)
    ref = f.run(z, u, x0=X0, P0=P0, store=STORE)
    on = f.online(X0, P0)
    assert isinstance(on, OnlineFilter)
    xs = steps(on, z[0], u)
    np.testing.assert_array_equal(xs, ref.x_post[0])
    for name in ("x_prior", "innovation", "S", "P_prior"):
        np.testing.assert_array_equal(getattr(on, name), getattr(ref, name)[0, -1], err_msg=name)
    assert on.loglik == ref.loglik[0, -1]
    np.testing.assert_array_equal(on.P, ref.P_post[0, -1])
    assert on.k == 300
    # the state carries on in the batch interface: the rest of a record equals the whole record
    z2, u2 = data(1, 100, seed=1)
    whole = f.run(np.concatenate([z, z2], axis=1), np.concatenate([u, u2]), x0=X0, P0=P0).x_post
    _, out = f.update(on.state, z2, u2)
    np.testing.assert_array_equal(out.x_post[0], whole[0, 300:])


def test_compiled_path_is_one_compiled_call_per_sample():
    on = KalmanFilter(model3()).online(X0, P0)
    assert on.compiled == _jit.enabled()


def test_shared_p0_takes_the_per_run_recursion_bit_for_bit():
    # compiled: the shared covariance sequence is the per-run step's covariance half (same steps, same
    # order): P0 shared or given per run, any number of runs, the same bits
    model = model3()
    z, u = data(3, 200)
    kf = KalmanFilter(model)
    shared = kf.run(z, u, x0=X0, P0=P0, store=STORE)
    per_run = kf.run(z, u, x0=X0, P0=np.broadcast_to(P0, (3, 3, 3)), store=STORE)
    for name in STORE:
        a, b = getattr(shared, name), getattr(per_run, name)
        if _jit.enabled():
            np.testing.assert_array_equal(a, b, err_msg=name)
        else:
            # numpy path: BLAS products and S^-1 against the per-run Cholesky, a few ulps per step on
            # O(1) quantities over 200 steps of a stable filter
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12, err_msg=name)


def test_ekf_with_compiled_h_equals_its_batch_path_and_numpy():
    model = oscillator()
    rng = np.random.default_rng(2)
    T = 400
    z = 1.0 + 0.01 * rng.standard_normal((2, T, 1))
    u = np.sin(0.05 * np.arange(T))[:, None]
    ekf = ExtendedKalmanFilter(model)
    x0, P0_ = np.array([0.2, 0.0]), np.eye(2) * 0.1
    ref = ekf.run(z, u, x0=x0, P0=P0_, store=STORE)
    on = ekf.online(x0, P0_)
    assert on.compiled == _jit.enabled()
    np.testing.assert_array_equal(steps(on, z[0], u), ref.x_post[0])
    with _jit.numpy_path():
        num = ekf.run(z, u, x0=x0, P0=P0_, store=STORE)
    for name in STORE:
        # LLVM's and numpy's sin/cos/sqrt and the summation orders differ by an ulp or so per step
        np.testing.assert_allclose(
            getattr(ref, name), getattr(num, name), rtol=1e-9, atol=1e-12, err_msg=name
        )


def test_sample_function_model_evaluates_rows_like_the_python_model():
    model = oscillator()
    x = np.array([[0.3, -0.2], [0.1, 0.5], [-1.0, 0.0]])
    u = np.array([0.5])
    want = np.stack(
        [x[:, 0] + DT * x[:, 1], x[:, 1] + DT * (-4.0 * np.sin(x[:, 0]) - 0.2 * x[:, 1] + 0.5)], 1
    )
    np.testing.assert_allclose(model.transition(x, u), want, rtol=1e-15)
    np.testing.assert_allclose(model.measure(x)[:, 0], np.sqrt(x[:, 0] ** 2 + 1.0), rtol=1e-15)
    assert model.jacobian(x, u).shape == (3, 2, 2)
    assert model.measurement_jacobian(x).shape == (3, 1, 2)


def bank_models() -> tuple[LinearModel, LinearModel]:
    return model3(), model3(a22=0.9)


def test_online_imm_and_smm_equal_their_batch_paths():
    m0, m1 = bank_models()
    z, u = data(1, 250, seed=3)
    pi = np.array([[0.98, 0.02], [0.03, 0.97]])
    imm = IMM((KalmanFilter(m0), KalmanFilter(m1)), pi)
    smm = SMMSVSF((m0, m1), psi=[0.5, 0.4], gamma=0.2)
    for bank in (imm, smm):
        ref = bank.run(z, u, x0=X0, P0=P0, store={"P_post"})
        on = bank.online(X0, P0)
        assert isinstance(on, OnlineBank)
        np.testing.assert_array_equal(steps(on, z[0], u), ref.x_post[0])
        np.testing.assert_array_equal(on.mu, ref.mu[0, -1])
        np.testing.assert_array_equal(on.P, ref.P_post[0, -1])
        np.testing.assert_array_equal(on.loglik, ref.loglik[0, -1])
        z2, u2 = data(1, 50, seed=4)
        whole = bank.run(np.concatenate([z, z2], 1), np.concatenate([u, u2]), x0=X0, P0=P0).x_post
        np.testing.assert_array_equal(bank.update(on.state, z2, u2)[1].x_post[0], whole[0, 250:])


@pytest.mark.parametrize("switching", ["sat", "sgn"])
@pytest.mark.parametrize("start", ["measured", "given"])
def test_online_chattering_svsf_equals_run(switching, start):  # type: ignore[no-untyped-def]
    model = LinearModel(
        np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, 0.0, 0.95]]),
        np.array([[0.0], [0.01], [0.05]]),
        np.eye(3),
        np.eye(3) * 1e-4,
        np.eye(3) * 1e-4,
        DT,
    )
    f = SVSF(model, psi=0.05 if switching == "sat" else None, switching=switching)
    z, u = data(1, 400, m=3, seed=5)
    x0 = None if start == "measured" else np.array([0.01, -0.02, 0.0])
    ref = f.run(z[0], u, x0=x0, store={"x_post"})
    on = f.online(z[0, 0], x0)
    assert isinstance(on, OnlineSVSF)
    xs, es = [], []
    for k in range(1, 400):
        xs.append(on.step(z[0, k], u[k - 1]))
        es.append(on.e_prior)
    np.testing.assert_array_equal(np.array(xs), ref.x_post[1:])
    np.testing.assert_array_equal(np.array(es), ref.e_prior[1:])


def test_bad_input_raises_and_leaves_the_state():
    f = KalmanFilter(model3())
    z, u = data(1, 20)
    on = f.online(X0, P0)
    steps(on, z[0, :10], u[:10])
    bad = z[0, 10].copy()
    bad[1] = np.nan
    with pytest.raises(NonFiniteError, match="sample k = 11"):
        on.step(bad, u[10])
    with pytest.raises(NonFiniteError, match="u of sample k = 11"):
        on.step(z[0, 10], [np.inf])
    with pytest.raises(ShapeError, match=r"z must have shape \(2,\)"):
        on.step(z[0, 10, :1], u[10])
    with pytest.raises(ShapeError, match=r"u must have shape \(1,\)"):
        on.step(z[0, 10], [1.0, 2.0])
    assert on.k == 10
    np.testing.assert_array_equal(steps(on, z[0, 10:], u[10:]), f.run(z, u, x0=X0, P0=P0).x_post[0, 10:])


def test_divergence_names_the_sample_and_keeps_the_last_finite_state():
    # a finite but huge measurement at sample 7 drives the estimate past the largest float
    f = KalmanFilter(model3())
    z, u = data(1, 20)
    z[0, 6] = 1e308
    on = f.online(X0, P0)
    with pytest.raises(DivergenceError, match="sample k = ") as info:
        steps(on, z[0], u)
    k = int(str(info.value).split("sample k = ")[1].split(" ")[0])
    assert 7 <= k < 20 and on.k == k - 1
    assert np.all(np.isfinite(on.x)) and np.all(np.isfinite(on.P))


def test_scalar_measurement_and_no_input():
    model = LinearModel(np.array([[0.9]]), None, np.array([[1.0]]), np.eye(1) * 0.01, np.eye(1) * 0.1, DT)
    f = KalmanFilter(model)
    z = np.random.default_rng(6).normal(size=(1, 50, 1))
    on = f.online(np.zeros(1), np.eye(1))
    xs = np.array([on.step(float(z[0, k, 0])) for k in range(50)])
    np.testing.assert_array_equal(xs, f.run(z, x0=np.zeros(1), P0=np.eye(1)).x_post[0])
