"""DETC2015 ([DETC]) claims under its printed setup, 10^3 runs as in the paper.

Setup: scenarios ``detc-normal`` / ``detc-uncertain`` (eq 25-27, printed noise, Q, R, P0 = 20 Q, gamma = 0.5,
psi = 5 v_std; resolutions of ``docs/design.md`` D1-D5). All three filters run on the same realizations,
so filter comparisons use the *paired* per-run difference and its Monte Carlo standard error.

Tolerances: a one-sided ordering claim "a < b" is accepted when the paired mean difference exceeds
Z = 3.09 standard errors (one-sided 0.1 % false-pass level under the normal approximation, valid at 1000
runs). Where the paper's number is reproduced and where it is not is written up in docs/paper-notes.md.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from chatterspec.plants.scenarios import scenario
from chatterspec.plants.signals import HeldUniform, Step, Sum
from chatterspec.studies.estimation import estimate_records, estimation_study

RUNS = 1000  # as in the paper (~9 s per case on 2 busy cores)
SEED = 2015
Z = 3.09  # one-sided 0.1 %
V_STD = 0.05  # printed measurement noise std (eq 26)
VEL, ACC = 1, 2


@pytest.fixture(scope="module")
def normal():
    return estimation_study("detc-normal", "kf,svsf,svsf2", runs=RUNS, seed=SEED, progress=False)


@pytest.fixture(scope="module")
def uncertain():
    return estimation_study("detc-uncertain", "kf,svsf,svsf2", runs=RUNS, seed=SEED, progress=False)


def _greater(res, a, b, state):
    d = res.difference(a, b)
    return d.mean[state], d.stderr[state]


@pytest.mark.parametrize("state", [VEL, ACC])
def test_normal_kf_has_the_lowest_velocity_and_acceleration_rmse(normal, state):
    for other in ("svsf", "svsf2"):
        mean, se = _greater(normal, other, "kf", state)
        assert mean > Z * se, (other, mean, se)


@pytest.mark.parametrize("state", [VEL, ACC])
def test_normal_first_order_svsf_has_the_highest_velocity_and_acceleration_rmse(normal, state):
    for other in ("kf", "svsf2"):
        mean, se = _greater(normal, "svsf", other, state)
        assert mean > Z * se, (other, mean, se)


def test_second_order_svsf_position_is_the_measurement_itself():
    # e(0|0) = e(-1|-1) = 0 => e(k|k) = 0 for all k (eq 21): x1_hat = z exactly (docs/design.md §7.3)
    rec = estimate_records("detc-normal", "svsf2", runs=3, seed=SEED)
    np.testing.assert_allclose(rec.outputs["svsf2"].x_post[:, :, 0], rec.z[:, 1:, 0], rtol=0, atol=1e-12)


def test_normal_second_order_svsf_position_rmse_equals_the_measurement_noise_std(normal):
    # Per run the RMSE is sqrt(mean v^2) over N = 1000 samples: E = sigma (1 - 1/(4N)) to first order.
    # Accept within 4 Monte Carlo standard errors (two-sided ~6e-5 false-fail level).
    rmse = normal.get("svsf2").rmse
    N = normal.steps
    expected = V_STD * (1 - 1 / (4 * N))
    assert abs(rmse.mean[0] - expected) < 4 * rmse.stderr[0], (rmse.mean[0], rmse.stderr[0])


def test_uncertain_kf_velocity_bias_has_the_sign_and_size_of_the_paper(uncertain):
    # The paper's +9.63 (Table 2) comes from one unprinted realization of its U(-1, 1) input; the bias
    # depends on that realization. Estimate its spread over 8 other input realizations (64 runs each)
    # and accept when 9.63 lies within our mean +- 3 sqrt(sd_input^2 + stderr^2).
    bias = uncertain.get("kf").bias
    assert bias.mean[VEL] > 0
    sc = scenario("detc-uncertain")
    other = []
    for s in range(8):
        alt = dataclasses.replace(sc, input=Sum((HeldUniform(-1.0, 1.0, 1e-3, 7000 + s), Step(0.5))))
        other.append(estimation_study(alt, "kf", runs=64, seed=1, progress=False).get("kf").bias.mean[VEL])
    sd_input = float(np.std(other, ddof=1))
    tol = 3 * np.hypot(sd_input, bias.stderr[VEL])
    assert abs(bias.mean[VEL] - 9.63) < tol, (bias.mean[VEL], sd_input, tol)
    assert all(v > 0 for v in other)


def test_uncertain_filters_are_not_separated_as_the_paper_says(uncertain):
    # Evidence for docs/paper-notes.md: the paper's Table 1 has the 2nd-order SVSF's uncertain velocity
    # RMSE at 0.36x the KF's (12.49 vs 34.66). Under the printed setup the three filters are within 1 %:
    # the 2nd-order SVSF's measured channel is the raw measurement (e(k|k) = 0), and its 'cov' mapping
    # moves the unmeasured states with the same covariance regression as the KF. A change here means the
    # filters or the setup changed; update the paper-notes table if so.
    kf = uncertain.get("kf").rmse.mean[VEL]
    for other in ("svsf", "svsf2"):
        assert abs(uncertain.get(other).rmse.mean[VEL] / kf - 1) < 0.01
