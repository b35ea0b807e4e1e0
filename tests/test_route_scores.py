"""The routes' per-sample scores: mode log odds, NIS (chi-square under a matched Kalman filter) and the
covariance-inflation likelihood ratio of the innovation CUSUM."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

import chatterspec as cs
from chatterspec.detection.route_scores import (
    inflation_drift,
    inflation_score,
    innovation_channel,
    isolated_fault_mode,
    mode_log_odds,
    nis_cap,
    normalized_innovation_squared,
)
from chatterspec.errors import ParameterError, ShapeError
from chatterspec.studies.intervals import clopper_pearson


def test_mode_log_odds_is_bounded_by_the_floor() -> None:
    mu = np.array(
        [[1 / 3, 1 / 3, 1 / 3], [1.0, 0.0, 0.0], [0.0, 0.2, 0.8], [0.5, 0.25, 0.25], [0.9, 0.06, 0.04]]
    )
    lo = mode_log_odds(mu, floor=1e-3)
    assert lo[0] == pytest.approx(math.log(2.0))
    assert lo[1] == pytest.approx(math.log(1e-3))  # no fault probability: the floor
    assert lo[2] == pytest.approx(-math.log(1e-3))  # no normal probability: the floor
    assert lo[3] == pytest.approx(0.0)
    assert lo[4] == pytest.approx(math.log(0.1 / 0.9))
    rng = np.random.default_rng(1)
    many = rng.dirichlet([0.05, 0.05, 0.05], size=(50, 40))
    v = mode_log_odds(many, floor=1e-3)
    assert v.shape == (50, 40) and v.min() >= math.log(1e-3) - 1e-12 and v.max() <= -math.log(1e-3) + 1e-12
    assert (isolated_fault_mode(mu) == np.array([1, 1, 2, 1, 1])).all()
    with pytest.raises(ShapeError):
        mode_log_odds(np.ones((3, 1)))
    with pytest.raises(ParameterError):
        mode_log_odds(mu, floor=0.0)


@pytest.mark.parametrize("name", ["eha4-leak-timeline", "eha4-imm-analogue"])
@pytest.mark.parametrize("method", ["smm", "imm"])
def test_mode_routes_floor_the_weights_at_1e_3(name: str, method: str) -> None:
    """``diagnose``'s mode routes as documented (README, ``docs/design.md`` S4/S6): the SMM-SVSF floors
    its weights at 1e-3 (the scenario's setting, or the default where the scenario sets none) and both
    mode routes raise every probability to 1e-3 first, so their scores lie in [-6.9, 6.9]."""
    from chatterspec.studies.budget_diagnosis import ModeRoute

    route = ModeRoute(cs.scenario(name), method)
    assert route.floor == 1e-3
    assert route.score_max == pytest.approx(-math.log(1e-3))
    if method == "smm":
        assert route.filter.weight_floor == 1e-3


def test_nis_equals_the_quadratic_form_shared_or_per_run() -> None:
    rng = np.random.default_rng(0)
    A = rng.normal(size=(3, 7, 4, 4))
    S = A @ np.swapaxes(A, -1, -2) + np.eye(4)
    e = rng.normal(size=(3, 7, 4))
    want = np.einsum("rki,rkij,rkj->rk", e, np.linalg.inv(S), e)
    np.testing.assert_allclose(normalized_innovation_squared(e, S), want, rtol=1e-12)
    want0 = np.einsum("rki,kij,rkj->rk", e, np.linalg.inv(S[0]), e)
    np.testing.assert_allclose(normalized_innovation_squared(e, S[0]), want0, rtol=1e-12)
    d = np.diagonal(S, axis1=-2, axis2=-1)
    assert (innovation_channel(e, S) == np.argmax(e**2 / d, axis=-1)).all()
    with pytest.raises(ParameterError, match="positive definite"):
        normalized_innovation_squared(e, -S)
    with pytest.raises(ShapeError):
        normalized_innovation_squared(e, S[..., :3, :3])


def test_inflation_score_minus_drift_is_the_log_likelihood_ratio() -> None:
    # (1 - 1/L) NIS / 2 - (m/2) log L = log N(e; 0, L S) - log N(e; 0, S), exactly
    rng = np.random.default_rng(2)
    A = rng.normal(size=(3, 3))
    S = A @ A.T + np.eye(3)
    e = rng.normal(size=(20, 3)) * 2.0
    nis = normalized_innovation_squared(e, np.broadcast_to(S, (20, 3, 3)))
    for L in (1.5, 2.0, 10.0):
        mvn = scipy.stats.multivariate_normal
        llr = mvn(cov=L * S).logpdf(e) - mvn(cov=S).logpdf(e)
        got = inflation_score(nis, L) - inflation_drift(3, L)
        np.testing.assert_allclose(got, llr, rtol=1e-10, atol=1e-12)
        # the drift exceeds the healthy mean of the score (E NIS = m): a CUSUM returns to 0 when healthy
        assert inflation_drift(3, L) > (1 - 1 / L) * 3 / 2
    cap = nis_cap(3)
    assert scipy.stats.chi2.sf(cap, 3) == pytest.approx(1e-9, rel=1e-6)
    assert inflation_score(np.array([1e9]), 2.0, cap)[0] == pytest.approx(0.25 * cap)
    with pytest.raises(ParameterError, match="inflation"):
        inflation_score(nis, 1.0)
    with pytest.raises(ParameterError):
        inflation_drift(0, 2.0)


def test_nis_of_the_matched_kalman_filter_is_chi_square() -> None:
    # eha-healthy: the nominal model is the plant, Q and R are the simulation's, so the KF's NIS is
    # chi-square with m = 3 degrees of freedom and independent from sample to sample (Mehra and Peschon).
    # 16 runs x 3900 samples after 0.1 s: the fraction above the chi2 median and above its 99 % point are
    # binomial; each must contain its nominal value in its 99.9 % Clopper-Pearson interval.
    from chatterspec.studies.budget_diagnosis import InnovationRoute

    sc = cs.scenario("eha-healthy")
    sim = cs.simulate(sc, runs=16, seed=11)
    nis, chan = InnovationRoute(sc).nis(sim)
    x = nis[:, sim.t[1:] >= 0.1].ravel()
    for q in (0.5, 0.01):
        k = int(np.count_nonzero(x > scipy.stats.chi2.isf(q, 3)))
        lo, hi = clopper_pearson(k, x.size, 0.999)
        assert lo <= q <= hi, (q, k, x.size)
    assert chan.shape == nis.shape and set(np.unique(chan)) <= {0, 1, 2}
