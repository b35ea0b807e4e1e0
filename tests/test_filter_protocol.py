"""The one filter protocol: every covariance-carrying filter has the same state, output and
``initialize / update / run`` contract, and a multiple-model bank can drive it through that
interface alone (read and replace x and P between steps)."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.filters import (
    ExtendedKalmanFilter,
    Filter,
    FilterOutput,
    FilterState,
    KalmanFilter,
    SecondOrderSVSF,
    SVSFCov,
)
from chatterspec.plants.models import LinearModel

ALL = ["x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_prior", "P_post"]


def model(b3: float = 0.05) -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, -0.1, 0.95]])
    B = np.array([[0.0], [0.01], [b3]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    return LinearModel(A, B, C, np.diag([1e-3, 2e-3, 1e-3]), 0.01 * np.eye(2), 0.01)


def filters(m: LinearModel) -> dict[str, Filter]:
    return {
        "kf": KalmanFilter(m),
        "ekf": ExtendedKalmanFilter(m),
        "svsf-cov": SVSFCov(m, psi=0.3, gamma=0.3),
        "svsf2": SecondOrderSVSF(m, gamma=0.3, cutoff=1.0),
    }


NAMES = list(filters(model()))


def data(runs: int = 4, T: int = 25) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(11)
    return rng.normal(scale=0.2, size=(runs, T, 2)), rng.uniform(-1, 1, size=(runs, T, 1))


@pytest.mark.parametrize("name", NAMES)
def test_every_filter_has_the_protocol_and_output_shapes(name: str) -> None:
    filt = filters(model())[name]
    assert isinstance(filt, Filter)
    z, u = data()
    state = filt.initialize(np.zeros(3), np.eye(3) * 0.1, runs=4)
    assert isinstance(state, FilterState) and state.x.shape == (4, 3) and state.k == 0
    new, out = filt.update(state, z, u, store=ALL)
    assert isinstance(out, FilterOutput) and new.k == 25
    assert out.x_prior.shape == out.x_post.shape == (4, 25, 3)
    assert out.innovation.shape == out.e_post.shape == (4, 25, 2)
    assert out.loglik.shape == (4, 25)
    shared = name == "kf"
    # one output shape rule: a leading runs axis on every path (the shared KF's are broadcast views)
    assert out.S.shape == (4, 25, 2, 2)
    assert out.P_post.shape == (4, 25, 3, 3)
    assert new.P.shape == ((3, 3) if shared else (4, 3, 3))
    # the state is the last sample of the output
    np.testing.assert_array_equal(new.x, out.x_post[:, -1])
    np.testing.assert_array_equal(new.e_post, out.e_post[:, -1])
    np.testing.assert_array_equal(new.e_prev, out.e_post[:, -2])
    # the innovation and posterior residual follow their definitions (C x(k+1|k), C x(k+1|k+1))
    C = filt.model.C
    np.testing.assert_allclose(out.innovation, z - out.x_prior @ C.T, atol=1e-15)
    np.testing.assert_allclose(out.e_post, z - out.x_post @ C.T, atol=1e-15)
    # run() is initialize() + update()
    np.testing.assert_array_equal(filt.run(z, u, x0=np.zeros(3), P0=np.eye(3) * 0.1).x_post, out.x_post)
    # store selects fields; the rest are None
    _, few = filt.update(state, z, u, store=["loglik"])
    assert few.loglik is not None and few.x_post is None and few.S is None
    # an empty chunk changes nothing
    same, _ = filt.update(state, z[:, :0], u[:, :0])
    assert same.k == 0


@pytest.mark.parametrize("name", NAMES)
def test_replacing_the_state_with_itself_changes_nothing(name: str) -> None:
    """A bank that writes back unchanged values (and per-run P for shared P) gets the same numbers."""
    filt = filters(model())[name]
    z, u = data()
    state = filt.initialize(np.zeros(3), np.eye(3) * 0.1, runs=4)
    _, whole = filt.update(state, z, u)
    outs = []
    for k in range(z.shape[1]):
        P = state.P if state.P.ndim == 3 else np.broadcast_to(state.P, (4, 3, 3))
        state = state.replace(x=state.x.copy(), P=P.copy())
        state, out = filt.update(state, z[:, k : k + 1], u[:, k : k + 1])
        outs.append(out.x_post)
    # per-run and shared covariance paths agree to rounding (different but equivalent arithmetic)
    np.testing.assert_allclose(np.concatenate(outs, axis=1), whole.x_post, rtol=1e-10, atol=1e-13)


def test_a_two_mode_bank_through_the_interface_alone() -> None:
    """A minimal IMM-style loop ([IMM] eq 18-21, 29-31) using only initialize/update/replace/loglik.

    The data come from mode 1; the mode probability of mode 1 must dominate.
    """
    m0, m1 = model(0.05), model(0.5)  # the input gain of the measured x3 differs
    rng = np.random.default_rng(3)
    runs, T = 20, 300
    x = np.zeros((runs, 3))
    zs = []
    us = rng.uniform(-1, 1, size=(T, 1))
    for k in range(T):
        x = m1.transition(x, us[k]) + rng.normal(size=(runs, 3)) * np.sqrt(np.diag(m1.Q))
        zs.append(x @ m1.C.T + rng.normal(size=(runs, 2)) * 0.1)  # R = 0.01 I
    z = np.stack(zs, axis=1)
    bank = [KalmanFilter(m0), KalmanFilter(m1)]  # shared P, per-run after the first mixing
    states = [f.initialize(np.zeros(3), np.eye(3) * 0.1, runs=runs) for f in bank]
    mu = np.full((runs, 2), 0.5)
    history = []
    Pi = np.array([[0.99, 0.01], [0.01, 0.99]])
    for k in range(T):
        c = mu @ Pi  # (19)
        w = mu[:, :, None] * Pi[None] / c[:, None, :]  # (18) mu_{i|j}
        xs = np.stack([s.x for s in states], axis=1)  # (runs, i, n)
        Ps = np.stack([np.broadcast_to(s.P, (runs, 3, 3)) for s in states], axis=1)  # shared or per run
        mixed = []
        for j, (f, s) in enumerate(zip(bank, states, strict=True)):
            x0 = np.einsum("ri,rin->rn", w[:, :, j], xs)  # (20)
            d = xs - x0[:, None]
            P0 = np.einsum("ri,rinm->rnm", w[:, :, j], Ps + d[..., :, None] * d[..., None, :])  # (21)
            s, out = f.update(s.replace(x=x0, P=P0), z[:, k : k + 1], us[k : k + 1], store=["loglik"])
            mixed.append((s, out.loglik[:, 0]))
        states = [s for s, _ in mixed]
        ll = np.stack([lk for _, lk in mixed], axis=1)
        logw = np.log(c) + ll  # (30), in the log domain
        mu = np.exp(logw - logw.max(axis=1, keepdims=True))
        mu /= mu.sum(axis=1, keepdims=True)
        history.append(mu[:, 1])
    assert np.all(np.isfinite(mu))
    assert np.mean(history[100:]) > 0.9


def test_replace_rejects_unknown_fields_and_wrong_shapes() -> None:
    state = KalmanFilter(model()).initialize(np.zeros(3), np.eye(3), runs=2)
    with pytest.raises(TypeError, match="unexpected keyword"):
        state.replace(mu=1)
    with pytest.raises(ValueError, match="x must have shape"):
        state.replace(x=np.zeros((3, 3)))


@pytest.mark.parametrize("name", NAMES)
def test_correct_from_the_filters_own_prior_reproduces_update(name: str) -> None:
    """correct() (measurement update from a supplied prior, [SMM] Table 1) = update()'s second half."""
    filt = filters(model())[name]
    z, u = data()
    state = filt.initialize(np.zeros(3), np.eye(3) * 0.1, runs=4)
    for k in range(5):
        new, out = filt.update(state, z[:, k : k + 1], u[:, k : k + 1], store=ALL)
        Pp = out.P_prior[:, 0] if out.P_prior.ndim == 4 else out.P_prior[0]
        fixed, cout = filt.correct(state, out.x_prior[:, 0], Pp, z[:, k], store=ALL)
        if name == "kf":  # the shared-covariance path computes the gain with LAPACK: rounding only
            np.testing.assert_allclose(cout.x_post, out.x_post, rtol=1e-12, atol=1e-15)
        else:  # same kernel after the prediction: bit for bit
            np.testing.assert_array_equal(cout.x_post, out.x_post)
            np.testing.assert_array_equal(cout.loglik, out.loglik)
            np.testing.assert_array_equal(fixed.P, new.P)
        np.testing.assert_array_equal(fixed.e_prev, new.e_prev)
        assert fixed.k == new.k
        state = new
    with pytest.raises(ValueError, match="x_prior must have shape"):
        filt.correct(state, np.zeros((2, 3)), np.eye(3), z[:, 0])
