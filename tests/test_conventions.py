"""The conventions shared by every filter (docs/filters.md, "Conventions"), each against the pre-round code:
a nonlinear measurement h(x) in the EKF, optional input, one storage option with one name, one output
shape rule, per-mode starts of the IMM."""

from __future__ import annotations

import numpy as np
import pytest

import chatterspec as cs

DT = 0.01
A = np.array([[1.0, DT], [-4.0 * DT, 1.0 - 0.02]])
Q = np.diag([1e-6, 1e-4])
R = np.array([[1e-3]])


def f(x, u):
    return x @ A.T


def F(x, u):
    return np.broadcast_to(A, (*np.shape(x)[:-1], 2, 2))


def h(x):  # a range-like measurement: the distance to a point one unit off the axis
    return np.hypot(x[..., :1], 1.0)


def H(x):
    d = np.hypot(x[..., 0], 1.0)
    return np.stack([x[..., 0] / d, np.zeros_like(d)], axis=-1)[..., None, :]


def model_h() -> cs.NonlinearModel:
    return cs.NonlinearModel(f, F, None, Q, R, DT, h=h, h_jac=H)


def measurements(T: int = 300, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x, zs = np.array([1.0, 0.0]), []
    for _ in range(T):
        x = A @ x + rng.multivariate_normal(np.zeros(2), Q)
        zs.append(h(x) + rng.normal(0.0, np.sqrt(R[0, 0]), 1))
    return np.array(zs)


def test_ekf_with_h_equals_filterpy() -> None:
    fp = pytest.importorskip("filterpy.kalman")
    z = measurements()
    out = cs.ExtendedKalmanFilter(model_h()).run(
        z, x0=np.array([0.8, 0.0]), P0=0.1 * np.eye(2), store={"x_post"}
    )
    ref = fp.ExtendedKalmanFilter(2, 1)
    ref.x, ref.P, ref.F, ref.Q, ref.R = np.array([[0.8], [0.0]]), 0.1 * np.eye(2), A, Q, R
    xs = []
    for zk in z:
        ref.predict()
        ref.update(zk[:, None], lambda x: H(x[:, 0]), lambda x: h(x[:, 0])[:, None])
        xs.append(ref.x[:, 0].copy())
    # the same Joseph-form equations; only summation order may differ: agreement to rounding
    np.testing.assert_allclose(out.x_post[0], np.array(xs), rtol=1e-10, atol=1e-12)


def test_ekf_with_h_equal_to_C_is_the_linear_ekf() -> None:
    C = np.array([[1.0, 0.0]])
    lin = cs.NonlinearModel(f, F, C, Q, R, DT)
    as_h = cs.NonlinearModel(
        f,
        F,
        None,
        Q,
        R,
        DT,
        h=lambda x: x[..., :1],
        h_jac=lambda x: np.broadcast_to(C, (*x.shape[:-1], 1, 2)),
    )
    z = measurements(100)[None].repeat(3, axis=0)
    kw = dict(x0=np.zeros(2), P0=0.1 * np.eye(2), store={"x_post", "loglik", "P_post"})
    a = cs.ExtendedKalmanFilter(lin).run(z, **kw)
    b = cs.ExtendedKalmanFilter(as_h).run(z, **kw)
    for name in ("x_post", "loglik", "P_post"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-9, atol=1e-14, err_msg=name)


def test_simulation_measures_through_h_and_svsf_refuses_it() -> None:
    m = model_h()
    sc = cs.Scenario(name="own", nominal=m, input=cs.Constant(0.0), duration=1.0)
    sim = cs.simulate(sc, runs=2, seed=1)
    # z - h(x) is the measurement noise: its variance is R (200 samples x 2 runs; chi-squared 99.9 %
    # bounds of the sample variance with 401 degrees of freedom are within +-25 %)
    noise = sim.z - h(sim.x)
    assert 0.75 < noise.var() / R[0, 0] < 1.25
    with pytest.raises(cs.ModelKindError, match="linear measurement"):
        cs.SVSFCov(m, psi=0.1)


def test_no_input_needed() -> None:
    lin = cs.LinearModel(A, None, np.array([[1.0, 0.0]]), Q, R, DT)  # B=None: no input
    z = measurements(50)
    kf = cs.KalmanFilter(lin)
    a = kf.run(z, x0=np.zeros(2), P0=np.eye(2))
    b = kf.run(z, np.zeros((50, 1)), x0=np.zeros(2), P0=np.eye(2))
    np.testing.assert_array_equal(a.x_post, b.x_post)
    imm = cs.IMM([kf, cs.ExtendedKalmanFilter(lin)], np.array([[0.99, 0.01], [0.01, 0.99]]))
    assert imm.run(z, x0=np.zeros(2), P0=np.eye(2)).x_post.shape == (1, 50, 2)


def test_one_output_shape_rule() -> None:
    lin = cs.LinearModel(A, None, np.array([[1.0, 0.0]]), Q, R, DT)
    z = np.stack([measurements(40, s) for s in range(3)])
    # (with the log-likelihood: the compiled loops of the other 2-state, 1-output Kalman tests; without
    # it each filter compiled a loop of its own for this test)
    store = {"S", "P_post", "P_prior", "x_post", "loglik"}
    shared = cs.KalmanFilter(lin).run(z, x0=np.zeros(2), P0=np.eye(2), store=store)  # shared P path
    per_run = cs.ExtendedKalmanFilter(lin).run(z, x0=np.zeros(2), P0=np.eye(2), store=store)
    for name in ("S", "P_post", "P_prior"):
        assert (
            getattr(shared, name).shape
            == getattr(per_run, name).shape
            == (3, 40, *getattr(per_run, name).shape[2:])
        )
    one = cs.KalmanFilter(lin).run(z[0], x0=np.zeros(2), P0=np.eye(2), store=store)  # single stream
    assert one.S.shape == (1, 40, 1, 1) and one.P_post.shape == (1, 40, 2, 2)


def test_banks_take_store() -> None:
    lin = cs.LinearModel(A, None, np.array([[1.0, 0.0]]), Q, R, DT)
    z = measurements(30)
    imm = cs.IMM([cs.KalmanFilter(lin), cs.ExtendedKalmanFilter(lin)], np.array([[0.9, 0.1], [0.1, 0.9]]))
    new = imm.run(z, x0=np.zeros(2), P0=np.eye(2), store={"P_post", "mode_x_post"})
    assert new.P_post.shape == (1, 30, 2, 2) and new.mode_x_post.shape == (1, 30, 2, 2)
    with pytest.raises(cs.ParameterError, match="unknown"):
        imm.run(z, x0=np.zeros(2), P0=np.eye(2), store={"covariance"})
    for f in (imm, cs.KalmanFilter(lin)):  # a bare string is not read letter by letter
        with pytest.raises(cs.ParameterError, match="collection of names"):
            f.run(z, x0=np.zeros(2), P0=np.eye(2), store="P_post")


def test_imm_per_mode_start() -> None:
    lin = cs.LinearModel(A, None, np.array([[1.0, 0.0]]), Q, R, DT)
    imm = cs.IMM([cs.KalmanFilter(lin), cs.ExtendedKalmanFilter(lin)], np.array([[0.9, 0.1], [0.1, 0.9]]))
    xs = np.array([[0.0, 0.0], [1.0, 0.5]])
    Ps = np.stack([np.eye(2), 2.0 * np.eye(2)])
    state = imm.initialize(np.zeros(2), np.eye(2), mode_x0=xs, mode_P0=Ps)
    for j in range(2):
        np.testing.assert_array_equal(state.mode_states[j].x[0], xs[j])
        np.testing.assert_array_equal(np.broadcast_to(state.mode_states[j].P, (1, 2, 2))[0], Ps[j])
    # the combined start is the mu0-weighted mixture (eq 31-33): mean 0.5 xs, spread added to P
    np.testing.assert_allclose(state.x[0], [0.5, 0.25])
    d = xs - state.x[0]
    np.testing.assert_allclose(
        state.P[0], 0.5 * (Ps[0] + Ps[1]) + 0.5 * (np.outer(d[0], d[0]) + np.outer(d[1], d[1]))
    )
    with pytest.raises(cs.ShapeError, match="mode_x0"):
        imm.initialize(np.zeros(2), np.eye(2), mode_x0=np.zeros((3, 2)))


def test_chattering_needs_no_input_either() -> None:
    lin = cs.LinearModel(A, None, np.eye(2), Q, np.diag([1e-6, 1e-4]), DT)
    sc = cs.Scenario(name="free", nominal=lin, input=cs.Constant(0.0), duration=1.0, x0=np.array([0.01, 0.0]))
    sim = cs.simulate(sc, runs=2, seed=5)
    zero = np.zeros((sim.z.shape[1], 1))
    np.testing.assert_array_equal(cs.chattering(lin, sim.z), cs.chattering(lin, sim.z, zero))
    a, b = cs.chattering_record(lin, sim.z), cs.chattering_record(lin, sim.z, zero)
    np.testing.assert_array_equal(a.values, b.values)


def test_imm_of_ekfs_with_h() -> None:
    # two identical modes: mixing changes nothing, so the IMM's estimate is the single EKF's
    m = model_h()
    z = measurements(120)
    kw = dict(x0=np.array([0.8, 0.0]), P0=0.1 * np.eye(2))
    single = cs.ExtendedKalmanFilter(m).run(z, **kw, store={"x_post"})
    imm = cs.IMM([cs.ExtendedKalmanFilter(m), cs.ExtendedKalmanFilter(m)], np.array([[0.9, 0.1], [0.2, 0.8]]))
    out = imm.run(z, **kw)
    np.testing.assert_allclose(out.x_post, single.x_post, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(out.mu.sum(axis=-1), 1.0, rtol=1e-12)


def test_svsf_takes_store() -> None:
    lin = cs.LinearModel(A, None, np.eye(2), Q, np.diag([1e-6, 1e-4]), DT)
    z = np.stack([measurements(60, s) for s in range(2)]).repeat(2, axis=-1)
    f = cs.SVSF(lin, psi=0.05)
    new = f.run(z, store={"x_post", "e_post"})
    assert new.x_post.shape == (2, 60, 2) and new.e_post.shape == (2, 60, 2) and new.e_lower is None
    with pytest.raises(cs.ParameterError, match="unknown"):
        f.run(z, store={"P_post"})  # the SVSF carries no covariance
