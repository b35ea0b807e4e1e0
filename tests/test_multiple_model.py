"""Multiple-model filters: exact identities (one-mode IMM = its filter, identical-KF IMM = the KF,
SMM of identical modes = the SVSF, the printed IMM spread = 2x the standard one), bad input, and the
diagnosis targets of SMM-SVSF on ``eha4-leak-timeline`` and IMM-EKF on ``eha4-imm-analogue``."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

import chatterspec as cs
from chatterspec.errors import ParameterError, ShapeError
from chatterspec.filters import ExtendedKalmanFilter, KalmanFilter, SecondOrderSVSF, SVSFCov
from chatterspec.filters.bank import combine, log_gaussian, normalize_log_weights
from chatterspec.filters.imm import IMM, pairwise_spread
from chatterspec.filters.smm_svsf import SMMSVSF
from chatterspec.plants.models import LinearModel
from chatterspec.studies.estimation import confusion_matrix, rmse_table, switch_delays


def model(b3: float = 0.05, C: np.ndarray | None = None) -> LinearModel:
    A = np.array([[1.0, 0.01, 0.0], [-0.4, 0.98, 0.01], [0.0, -0.1, 0.95]])
    B = np.array([[0.0], [0.01], [b3]])
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]) if C is None else C
    return LinearModel(A, B, C, np.diag([1e-3, 2e-3, 1e-3]), 0.01 * np.eye(C.shape[0]), 0.01)


def oscillator() -> LinearModel:
    """A 2-state, 1-output model: the sizes of the hand-formula IMM of ``tests/test_hand_formulas.py``,
    whose compiled loops (one per correction kind and size) the one-mode banks here share."""
    A = np.array([[1.0, 0.01], [-0.4, 0.98]])
    B, C = np.array([[0.0], [0.01]]), np.array([[1.0, 0.0]])
    return LinearModel(A, B, C, np.diag([1e-3, 2e-3]), [[0.01]], 0.01)


def data(m: LinearModel, runs: int = 3, T: int = 80, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    n = m.n_states
    x = np.zeros((runs, n))
    u = rng.uniform(-1, 1, size=(T, 1))
    zs = []
    for k in range(T):
        x = m.transition(x, u[k]) + rng.normal(size=(runs, n)) * np.sqrt(np.diag(m.Q))
        zs.append(x @ m.C.T + rng.normal(size=(runs, m.n_outputs)) * 0.1)
    return np.stack(zs, axis=1), u


P0 = 0.1 * np.eye(3)
PI2 = np.array([[0.95, 0.05], [0.1, 0.9]])


# ------------------------------------------------------------------------------- exact identities
@pytest.mark.parametrize(
    "make",
    [
        lambda m: KalmanFilter(m),
        lambda m: ExtendedKalmanFilter(m),
        lambda m: SVSFCov(m, psi=0.3, gamma=0.3),
        lambda m: SecondOrderSVSF(m, gamma=0.3, cutoff=1.0),
    ],
    ids=["kf", "ekf", "svsf-cov", "svsf2"],
)
def test_one_mode_imm_equals_its_filter(make) -> None:  # type: ignore[no-untyped-def]
    m = oscillator()
    z, u = data(m)
    f = make(m)
    x0, P0_ = np.zeros(2), np.diag([0.1, 0.2])
    # (storing the log-likelihood also keeps the reference on the one-run compiled loop, a third of the
    # lane loop's compile time: the lane loop's own bits are the lane tests' subject)
    ref = f.run(z, u, x0=x0, P0=P0_, store=["x_post", "P_post", "loglik"])
    out = IMM([f], np.ones((1, 1))).run(z, u, x0=x0, P0=P0_, store={"P_post"})
    # mixing with one mode is the identity and e(k|k) of the mixed estimate is the filter's own residual
    np.testing.assert_allclose(out.x_post, ref.x_post, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(
        out.P_post, np.broadcast_to(ref.P_post, out.P_post.shape), rtol=1e-9, atol=1e-13
    )
    assert np.all(out.mu == 1.0)
    # the mode's likelihood (29) is the filter's own: the same Gaussian of the same innovation. Measured
    # |gap| <= 1.3e-15 (|loglik| 1e-3 .. 7.3, a few ulps of its terms); the tolerance is ~1000x that
    np.testing.assert_allclose(out.loglik[..., 0], ref.loglik, rtol=1e-10, atol=1e-12)


def test_imm_of_identical_kalman_filters_equals_the_kalman_filter() -> None:
    m = model()
    z, u = data(m, seed=4)
    ref = KalmanFilter(m).run(z, u, x0=np.zeros(3), P0=P0, store=["x_post", "P_post"])
    imm = IMM([KalmanFilter(m), ExtendedKalmanFilter(m)], PI2, mu0=np.array([0.3, 0.7]))
    out = imm.run(z, u, x0=np.zeros(3), P0=P0, store={"P_post", "mode_x_post"})
    np.testing.assert_allclose(out.x_post, ref.x_post, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(
        out.P_post, np.broadcast_to(ref.P_post, out.P_post.shape), rtol=1e-8, atol=1e-13
    )
    # equal likelihoods: the probabilities follow the Markov chain alone, mu(k) = mu(k-1) Pi
    mu = np.array([0.3, 0.7])
    for _ in range(z.shape[1]):
        mu = mu @ PI2
    np.testing.assert_allclose(out.mu[:, -1], np.broadcast_to(mu, (3, 2)), rtol=1e-9)


def test_printed_imm_spread_is_exactly_twice_the_standard_one() -> None:
    rng = np.random.default_rng(1)
    mu = rng.dirichlet(np.ones(4), size=5)
    xs = rng.normal(size=(5, 4, 3))
    Ps = np.zeros((5, 4, 3, 3))
    x, P = combine(mu, xs, Ps)  # with P_j = 0, P is the spread of eq (33)
    d = xs - x[:, None]
    standard = np.einsum("rj,rja,rjb->rab", mu, d, d)
    np.testing.assert_allclose(P, standard, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(pairwise_spread(mu, xs), 2.0 * standard, rtol=1e-12, atol=1e-14)


def test_smm_of_identical_modes_equals_the_svsf() -> None:
    m = model()  # 3 states, 2 outputs: the compiled SMM loop of the other SMM tests (test_one_sample.py)
    z, u = data(m, seed=2)
    ref = SVSFCov(m, psi=0.3, gamma=0.3).run(z, u, x0=np.zeros(3), P0=P0, store=["x_post", "P_post"])
    for reading in ("table1", "bank"):
        smm = SMMSVSF([m, m, m], psi=0.3, gamma=0.3, reading=reading)
        out = smm.run(z, u, x0=np.zeros(3), P0=P0, store={"P_post"})
        np.testing.assert_allclose(out.x_post, ref.x_post, rtol=1e-9, atol=1e-12, err_msg=reading)
        np.testing.assert_allclose(out.P_post, ref.P_post, rtol=1e-8, atol=1e-13, err_msg=reading)
        np.testing.assert_allclose(out.mu, 1.0 / 3.0, rtol=1e-12)


def test_chunked_updates_equal_one_run() -> None:
    m0, m1 = model(0.05), model(0.5)
    z, u = data(m1, seed=5)
    # the IMM of Kalman-type modes shares its compiled loop with the other 3-state, 2-output Kalman banks
    # of the tests (chunking of a bank mixing every correction kind: tests/test_imm_kernel.py)
    for filt in (IMM([KalmanFilter(m0), ExtendedKalmanFilter(m1)], PI2), SMMSVSF([m0, m1], psi=0.3)):
        whole = filt.run(z, u, x0=np.zeros(3), P0=P0)
        state = filt.initialize(np.zeros(3), P0, runs=3)
        parts = []
        for a, b in ((0, 1), (1, 30), (30, 80)):
            state, o = filt.update(state, z[:, a:b], u[a:b])
            parts.append(o.mu)
        np.testing.assert_allclose(np.concatenate(parts, axis=1), whole.mu, rtol=1e-12, atol=1e-15)


def test_log_gaussian_matches_scipy_and_survives_20_decades() -> None:
    rng = np.random.default_rng(0)
    Lm = rng.normal(size=(3, 3))
    S = Lm @ Lm.T + 0.5 * np.eye(3)
    e = rng.normal(size=(6, 3))
    want = stats.multivariate_normal(np.zeros(3), S).logpdf(e)
    np.testing.assert_allclose(log_gaussian(e, np.broadcast_to(S, (6, 3, 3))), want, rtol=1e-12)
    # position variance 1e-14 m^2 beside pressure 4e4 Pa^2 (the IMM analogue): scaling keeps it exact
    S2 = np.diag([1e-14, 4e4])
    e2 = np.array([1e-7, 200.0])
    # (scipy's multivariate_normal rejects this S as singular; the diagonal density is a sum of 1-D ones)
    want2 = stats.norm.logpdf(e2, scale=np.sqrt(np.diag(S2))).sum()
    np.testing.assert_allclose(log_gaussian(e2, S2), want2, rtol=1e-12)


def test_weights_in_the_log_domain_and_the_floor() -> None:
    logw = np.array([[0.0, -1e5, -2e5], [-3.0, -1.0, -2.0]])  # exp underflows for the first row
    mu = normalize_log_weights(logw, 1e-3)
    np.testing.assert_allclose(mu.sum(axis=1), 1.0, rtol=1e-15)
    assert np.all(mu >= 1e-3 / (1 + 2e-3))  # floored, then renormalized
    assert np.all(mu[0, 1:] > 0)  # the floored modes can come back
    np.testing.assert_allclose(
        normalize_log_weights(logw[1:], 0.0), stats.norm.pdf([0]) * 0 + _softmax(logw[1:])
    )


def _softmax(a: np.ndarray) -> np.ndarray:
    e = np.exp(a - a.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


# ------------------------------------------------------------------------------------ bad input
def test_bad_input_gets_specific_errors() -> None:
    m = model()
    kf = KalmanFilter(m)
    with pytest.raises(ParameterError, match="row"):
        IMM([kf, kf], np.array([[0.9, 0.2], [0.1, 0.9]]))
    with pytest.raises(ParameterError, match="non-negative"):
        IMM([kf, kf], np.array([[1.1, -0.1], [0.1, 0.9]]))
    with pytest.raises(ParameterError, match="non-negative"):
        IMM([kf, kf], PI2, mu0=np.array([1.2, -0.2]))
    with pytest.raises(ParameterError, match="sum to 1"):
        IMM([kf, kf], PI2, mu0=np.array([0.5, 0.6]))
    three = model(C=np.eye(3))
    with pytest.raises(ShapeError, match="same numbers of states, measurements"):
        IMM([kf, KalmanFilter(three)], PI2)
    with pytest.raises(ShapeError, match="same numbers of states, measurements"):
        SMMSVSF([m, three], psi=0.3)
    for floor in (-0.1, 0.5, 0.7):
        with pytest.raises(ParameterError, match=r"weight_floor"):
            SMMSVSF([m, m], psi=0.3, weight_floor=floor)
        with pytest.raises(ParameterError, match=r"weight_floor"):
            IMM([kf, kf], PI2, weight_floor=floor)
    SMMSVSF([m, m], psi=0.3, weight_floor=0.0)  # the lower end is allowed
    with pytest.raises(ShapeError, match="transition_matrix"):
        IMM([kf, kf], np.eye(3))
    with pytest.raises(ParameterError, match="reading"):
        SMMSVSF([m, m], psi=0.3, reading="posterior")
    with pytest.raises(TypeError):
        SMMSVSF([m, m], psi=0.3, floor=0.1)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="protocol"):
        IMM([kf, object()], PI2)


# --------------------------------------------------------------------------- the diagnosis targets
def _smm_case(runs: int, seed: int) -> dict[str, object]:
    sc = cs.scenario("eha4-leak-timeline")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=runs, seed=seed)
    z, u, truth = sim.z[:, 1:], sim.u[:-1], sim.x[:, 1:]
    smm = SMMSVSF(fs.mode_models, psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping, modes=fs.modes)
    out = smm.run(z, u, x0=fs.x0, P0=fs.P0)
    plain = SVSFCov(fs.mode_models[0], psi=np.array(fs.psi), gamma=fs.gamma, mapping=fs.mapping)
    ref = plain.run(z, u, x0=fs.x0, P0=fs.P0, store=["x_post"])
    table = rmse_table({"svsf": ref.x_post, "smm": out.x_post}, truth, sc.nominal.state_names)
    return {"out": out, "true": fs.mode_index(sc)[1:], "t": sim.t[1:], "table": table, "R": fs.R}


def _check_smm_targets(case: dict[str, object], n_samples: int) -> None:
    out, true, table = case["out"], case["true"], case["table"]
    am = out.argmax_mode  # type: ignore[attr-defined]
    for j in range(3):  # target: argmax = true mode in >= 99 % of every segment's samples
        assert np.mean(am[:, true == j] == j) >= 0.99, j  # type: ignore[operator]
    d = switch_delays(out.mu, true, case["t"], levels=(0.8,))  # type: ignore[arg-type, attr-defined]
    assert d.onsets.tolist() == pytest.approx([3.0, 6.0])
    assert np.all(d.of_mean[:, 0] <= 0.005), d.of_mean  # the mean weight passes 0.8 within 5 ms
    vel = table["smm"]["velocity"] / table["svsf"]["velocity"]  # type: ignore[index]
    assert vel <= 0.1, vel
    # pressure RMSE = sqrt(R) within 2 %: the relative standard error of an RMSE of N Gaussian errors
    # is 1/sqrt(2N) (0.53 % for N = 18 000), so 2 % is >= 3.7 standard errors for every N used here
    assert 0.02 >= 3.7 / np.sqrt(2 * n_samples)
    sigma = np.sqrt(case["R"][3, 3])  # type: ignore[index]
    for name in ("svsf", "smm"):
        assert table[name]["pressure"] == pytest.approx(sigma, rel=0.02), name  # type: ignore[index]


def test_smm_svsf_targets_on_the_leak_timeline() -> None:
    case = _smm_case(runs=2, seed=11)
    _check_smm_targets(case, n_samples=2 * 9000)


@pytest.mark.slow
def test_smm_svsf_targets_on_the_leak_timeline_many_runs() -> None:
    case = _smm_case(runs=20, seed=12)
    _check_smm_targets(case, n_samples=20 * 9000)


@pytest.mark.parametrize("bank", ["ekf", "svsf-cov"])
def test_imm_confusion_on_the_imm_analogue(bank: str) -> None:
    """Target for IMM-EKF (every diagonal > 80 %, columns sum to 100 %); the SVSF-cov bank meets it too.

    Not marked slow since the compiled IMM step (2 x 60 000 samples: about 0.4 s of CPU for the
    filter; the numpy path, CHATTERSPEC_JIT=0, takes about 40 s, so it is not in the numpy CI list).

    Measured (seed 2, 2 runs): EKF 89.9 / 89.7 / 100.0, SVSF-cov 90.0 / 89.7 / 100.0. The 2nd-order SVSF
    and the ``luen`` mapping lose the friction mode (50 % and 6 %, docs/paper-notes.md), so they are
    reported, not asserted. A diagonal is a mean over 2 x 20 000 strongly correlated samples; the margin
    of 80 % against ~90 % is the target's own threshold, not a fitted tolerance.
    """
    sc = cs.scenario("eha4-imm-analogue")
    fs = sc.filter_settings
    sim = cs.simulate(sc, runs=2, seed=2)
    if bank == "ekf":
        filters = [ExtendedKalmanFilter(mdl) for mdl in fs.mode_models]
    else:
        filters = [
            SVSFCov(mdl, psi=np.array(fs.psi), gamma=fs.gamma, mapping="cov") for mdl in fs.mode_models
        ]
    imm = IMM(filters, fs.transition_matrix, mu0=np.array(fs.mu0))
    out = imm.run(sim.z[:, 1:], sim.u[:-1], x0=fs.x0, P0=fs.P0)
    conf = confusion_matrix(out.mu, fs.mode_index(sc)[1:])
    np.testing.assert_allclose(conf.sum(axis=0), 100.0, rtol=1e-12)
    assert np.all(np.diag(conf) > 80.0), conf
