"""Estimation metrics (DETC2015 eq 28-30) and NEES/NIS consistency against independent oracles."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from chatterspec.errors import NonFiniteError, ShapeError
from chatterspec.studies.estimation import MonteCarloMean, consistency, nees, nis, state_error_metrics


def test_rmse_bias_std_by_hand() -> None:
    rng = np.random.default_rng(1)
    x = rng.normal(size=(3, 50, 2))
    xh = x - rng.normal(0.3, 2.0, size=x.shape)
    m = state_error_metrics(x, xh)
    e = x - xh
    for r in range(3):
        for i in range(2):
            ei = e[r, :, i]
            assert m.rmse[r, i] == pytest.approx(np.sqrt(np.sum(ei**2) / ei.size), rel=1e-13)
            assert m.bias[r, i] == pytest.approx(np.sum(ei) / ei.size, rel=1e-13)
            assert m.std[r, i] == pytest.approx(np.std(ei), rel=1e-13)
    np.testing.assert_allclose(m.rmse**2, m.bias**2 + m.std**2, rtol=1e-12)


def test_skip_and_single_record() -> None:
    x = np.zeros((10, 1))
    xh = np.r_[np.full(5, 100.0), np.ones(5)][:, None]
    m = state_error_metrics(x, xh, skip=5)
    assert m.rmse.shape == (1, 1) and m.rmse[0, 0] == 1.0 and m.bias[0, 0] == -1.0 and m.std[0, 0] == 0.0


def test_monte_carlo_standard_error() -> None:
    per_run = np.arange(10.0)[:, None]
    s = MonteCarloMean.of(per_run)
    assert s.mean[0] == 4.5 and s.stderr[0] == pytest.approx(np.std(np.arange(10.0), ddof=1) / np.sqrt(10))
    assert np.isnan(MonteCarloMean.of(per_run[:1]).stderr[0])


def test_nees_nis_match_explicit_inverse() -> None:
    rng = np.random.default_rng(2)
    L = rng.normal(size=(4, 3, 3))
    P = L @ np.swapaxes(L, -1, -2) + 3 * np.eye(3)  # (T, n, n) shared by runs
    e = rng.normal(size=(5, 4, 3))
    got = nees(e, P)
    want = np.array([[e[r, k] @ np.linalg.inv(P[k]) @ e[r, k] for k in range(4)] for r in range(5)])
    np.testing.assert_allclose(got, want, rtol=1e-10)
    S = P[0]
    got = nis(e, S)
    want = np.array([[e[r, k] @ np.linalg.inv(S) @ e[r, k] for k in range(4)] for r in range(5)])
    np.testing.assert_allclose(got, want, rtol=1e-10)


def test_consistency_of_true_gaussian_errors() -> None:
    # Errors drawn from N(0, P) are consistent by construction. With a fixed seed the
    # test's own false-rejection probability is alpha = 1 %; the per-step coverage over
    # 400 steps must lie in the 99.9 % Clopper-Pearson band of Binomial(400, 0.99).
    rng = np.random.default_rng(3)
    P = np.array([[2.0, 0.5], [0.5, 1.0]])
    e = rng.multivariate_normal(np.zeros(2), P, size=(50, 400))
    t = consistency(nees(e, P), 2, alpha=0.01, kind="NEES")
    assert t.consistent and t.dof == 50 * 400 * 2
    lo = scipy.stats.beta.ppf(0.0005, 0.99 * 400, 0.01 * 400 + 1)
    assert t.fraction_inside >= lo
    # Errors twice too large (covariance 4x) must be rejected: the mean NEES is 8 vs bounds near 2.
    bad = consistency(nees(2 * e, P), 2, alpha=0.01, kind="NEES")
    assert not bad.consistent and bad.statistic > bad.upper


def test_bad_input() -> None:
    with pytest.raises(ShapeError, match="must match"):
        state_error_metrics(np.zeros((2, 3, 1)), np.zeros((2, 3, 2)))
    with pytest.raises(NonFiniteError, match="x_est"):
        state_error_metrics(np.zeros((2, 3)), np.full((2, 3), np.nan))
    with pytest.raises(ShapeError, match=r"end in \(2, 2\)"):
        nis(np.zeros((1, 3, 2)), np.eye(3))
    with pytest.raises(ShapeError, match="kind"):
        consistency(np.ones((2, 3)), 1, kind="nees")
