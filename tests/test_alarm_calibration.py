"""Thresholds for a false-alarm budget (chatterspec.detection.alarms.calibration)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.stats

from chatterspec import _jit
from chatterspec.detection.alarms.calibration import (
    RuleCalibration,
    calibrate_rule,
    check_budget,
    law_frame_rule,
    poisson_count_interval,
    poisson_interval,
    starts_on_grid,
)
from chatterspec.detection.alarms.rules import CusumRule, FrameRule, PersistenceRule, make_rule
from chatterspec.detection.alarms.streams import count_starts
from chatterspec.errors import ParameterError


def test_poisson_interval_is_garwood():
    assert poisson_interval(0, 0.99)[0] == 0.0
    assert poisson_interval(0, 0.99)[1] == pytest.approx(-math.log(0.005))  # P(K = 0) = 0.005 at the top
    lo, hi = poisson_interval(10, 0.95)
    # each end leaves 2.5 % on its side: P(K >= 10 | lo) = P(K <= 10 | hi) = 0.025
    assert scipy.stats.poisson.sf(9, lo) == pytest.approx(0.025, rel=1e-9)
    assert scipy.stats.poisson.cdf(10, hi) == pytest.approx(0.025, rel=1e-9)
    a, b = poisson_count_interval(7.0, 0.99)
    assert scipy.stats.poisson.cdf(a - 1, 7.0) <= 0.005 and scipy.stats.poisson.sf(b, 7.0) <= 0.005
    assert (a, b) == (1, 15)


@pytest.mark.parametrize("bad", [0, -1.0, float("inf"), float("nan"), "x"])
def test_budget_must_be_positive_and_finite(bad):
    with pytest.raises(ParameterError, match="--false-alarms-per-hour"):
        check_budget(bad, "--false-alarms-per-hour")


@pytest.mark.parametrize(
    "rule", [FrameRule(), PersistenceRule(k=2, n=3), CusumRule(drift=2.0)], ids=lambda r: r.name
)
def test_grid_counts_equal_the_layer_on_both_paths(rule, monkeypatch):
    rng = np.random.default_rng(3)
    s = rng.exponential(size=(2, 3000, 2))
    grid = np.array([1.0, 2.5, 4.0, 6.0])
    # ties: scores exactly at grid thresholds, after a step below them (s >= h counts them, s > h would not)
    s[:, 100:140:4, :] = 0.0
    s[:, 101:140:4, :] = np.resize(grid, (10, 1))
    s[:, 102:140:4, :] = 0.0
    s[:, 103:140:4, :] = np.resize(grid[::-1], (10, 1))
    want = np.stack([count_starts(rule.with_threshold(h), s) for h in grid])
    assert np.array_equal(starts_on_grid(rule, s, grid), want)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    assert np.array_equal(starts_on_grid(rule, s, grid), want)


def test_law_frame_rule():
    c = law_frame_rule(18000.0, 3, 1 / 24)
    assert c.threshold == pytest.approx(math.log(18000 * 3 * 24))
    assert c.method == "law" and c.rate_interval == (0.0, 1 / 24)
    assert RuleCalibration.from_dict(c.to_dict()) == c


def _iid_frame_threshold(F: float, m: int, X: float) -> float:
    """Exact threshold of the frame rule on iid Exp(1) scores: starts per step e^-h (1 - e^-h)."""
    q = 0.5 * (1 - math.sqrt(1 - 4 * X / (F * m)))  # e^-h from e^-h (1 - e^-h) = X / (F m)
    return -math.log(q)


def test_counted_and_extrapolated_thresholds_match_the_exact_answer():
    """iid Exp(1) scores: the frame rule's start rate is known in closed form.

    The intervals are 95 % (jackknife, normal): with this fixed seed the exact threshold must lie
    inside; the counted case also checks the realized count against the Garwood interval.
    """
    rng = np.random.default_rng(11)
    F, m = 3600.0, 2  # one step per second
    s = rng.exponential(size=(1, 200_000, m))  # 55.6 h per channel
    for X, method in ((60.0, "counted"), (0.1, "extrapolated")):
        c = calibrate_rule(FrameRule(), s, F, X, seed=11)
        assert c.method == method
        h = _iid_frame_threshold(F, m, X)
        lo, hi = c.threshold_interval
        assert lo <= h <= hi, (X, c.threshold, h, c.threshold_interval)
        assert c.rate_interval[0] < X < c.rate_interval[1]
        assert c.hours == pytest.approx(200_000 / F)
    # the counted threshold reproduces the budget on the data it was counted on
    c = calibrate_rule(FrameRule(), s, F, 60.0)
    n = int(count_starts(c.rule, s).sum())
    lo, hi = poisson_interval(n, 0.99)
    assert lo <= 60.0 * c.hours <= hi


@pytest.mark.parametrize("confidence", [0.95, 0.8])
def test_threshold_interval_is_the_two_sided_student_t_interval(confidence):
    """``threshold_interval`` is ``h +- t SE`` with Student's t at B - 1 degrees of freedom, leaving
    (1 - confidence) / 2 on each side: its half-width over the jackknife SE is that t quantile (taken
    here from scipy.stats.t; the one-sided quantile, a 90 % interval labelled 95 %, is 1.89, not 2.36)."""
    s = np.random.default_rng(11).exponential(size=(1, 50_000, 2))  # 13.9 h per channel
    B = 8
    c = calibrate_rule(FrameRule(), s, 3600.0, 60.0, confidence=confidence, batches=B)
    assert c.method == "counted" and c.confidence == confidence
    lo, hi = c.threshold_interval
    se = c.fit["jackknife_se"]
    assert 0.0 < se < math.inf
    assert (hi - lo) / 2 == pytest.approx(scipy.stats.t.ppf(0.5 + confidence / 2, B - 1) * se, rel=1e-9)
    assert (lo + hi) / 2 == pytest.approx(c.threshold, rel=1e-12)


def test_counted_threshold_is_linear_in_the_log_count():
    """Module docstring: a counted ``h`` is where log(count), linear between grid points, crosses
    log(X T), with the grid and the counts the result reports (``fit["h"]``, ``fit["starts"]``)."""
    s = np.random.default_rng(11).exponential(size=(1, 50_000, 2))
    X = 60.0
    c = calibrate_rule(FrameRule(), s, 3600.0, X)
    assert c.method == "counted"
    grid, starts = np.asarray(c.fit["h"]), np.asarray(c.fit["starts"], dtype=float)
    target = X * c.hours
    i = int(np.flatnonzero(starts >= target)[-1])  # the last grid point still at or above the target
    assert grid[i] <= c.threshold < grid[i + 1] and starts[i + 1] > 0
    frac = (c.threshold - grid[i]) / (grid[i + 1] - grid[i])
    log_frac = math.log(starts[i] / target) / math.log(starts[i] / starts[i + 1])
    assert frac == pytest.approx(log_frac, rel=1e-9)
    # the data tell the two readings apart: linear in the count itself would land elsewhere
    assert abs(log_frac - (starts[i] - target) / (starts[i] - starts[i + 1])) > 1e-4


def test_extrapolated_cusum_meets_the_budget_on_longer_streams():
    """Fit on 60 h, check on 600 other hours of the same law (one step per second): the extrapolated
    threshold's start count lies in the two-sided 99 % Poisson interval of a mean anywhere in the
    calibration's 95 % rate interval (its own uncertainty)."""
    rng = np.random.default_rng(2)
    F = 3600.0
    rule = CusumRule(drift=2.0)
    short = rng.exponential(size=(1, int(60 * F), 1))
    c = calibrate_rule(rule, short, F, 0.2)
    assert c.method == "extrapolated" and c.fit["slope"] < 0
    long = rng.exponential(size=(20, int(30 * F), 1))
    n = int(count_starts(c.rule, long).sum())
    hours = 600.0
    lo = poisson_count_interval(c.rate_interval[0] * hours, 0.99)[0]
    hi = poisson_count_interval(c.rate_interval[1] * hours, 0.99)[1]
    assert lo <= n <= hi, (n, c.rate_interval, c.threshold)


def test_too_short_streams_are_refused():
    s = np.random.default_rng(0).exponential(size=(1, 300, 1))
    with pytest.raises(ParameterError, match="too short"):
        calibrate_rule(make_rule("cusum"), s, 3600.0, 1e-3)


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
def test_calibration_does_not_depend_on_the_path(monkeypatch):
    s = np.random.default_rng(4).exponential(size=(1, 40_000, 2))
    a = calibrate_rule(PersistenceRule(k=2, n=3), s, 3600.0, 3.0)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    b = calibrate_rule(PersistenceRule(k=2, n=3), s, 3600.0, 3.0)
    assert a == b
