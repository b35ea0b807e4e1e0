"""The chattering frame score -log p (chatterspec.detection.verdicts)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import scipy.integrate
import scipy.stats

from chatterspec import _jit
from chatterspec.detection import verdicts
from chatterspec.detection.spectral import STFTConfig, frame_columns
from chatterspec.detection.thresholds import frame_threshold, weighted_chi2_sf
from chatterspec.detection.verdicts import FrameScore, frame_scores, frame_verdicts
from chatterspec.errors import ParameterError
from chatterspec.plants.models import eha_linear
from chatterspec.plants.simulate import covariance_sqrt

CFG = STFTConfig()


@pytest.fixture(scope="module")
def eha():
    m = eha_linear()
    th = frame_threshold(m, CFG.freqs_hz(m.dt), CFG, m.dt, alpha=1e-3)
    return m, th


def _healthy_frames(model, n_samples: int, seed: int) -> np.ndarray:
    """Frame spectra of healthy chattering, the MA(1) e = C w(k) + v(k+1) - C A C^-1 v(k)."""
    rng = np.random.default_rng(seed)
    C = model.C
    M = C @ model.A @ np.linalg.inv(C)
    w = rng.standard_normal((n_samples, model.n_states)) @ (C @ covariance_sqrt(model.Q)).T
    v = rng.standard_normal((n_samples + 1, model.n_outputs)) @ covariance_sqrt(model.R).T
    e = w + v[1:] - v[:-1] @ M.T
    return frame_columns(e, model.dt, CFG)[1]


def _polar_log_sf(t: float, l1: float, l2: float) -> float:
    """-log P(l1 Z1^2 + l2 Z2^2 > t) by adaptive quadrature of the polar form (reference)."""
    a, b = max(l1, l2), min(l1, l2)
    u = t / (2 * a)
    f = lambda p: math.exp(-(t / (2 * (a * math.cos(p) ** 2 + b * math.sin(p) ** 2)) - u))  # noqa: E731
    val = scipy.integrate.quad(f, 0, math.pi / 2, epsabs=0, epsrel=1e-13, limit=500)[0]
    return u - math.log(2 * val / math.pi)


@pytest.mark.parametrize("r", [1.0, 0.99998, 0.999, 0.9, 0.44, 0.1])
@pytest.mark.parametrize("u", [0.3, 3.0, 12.0, 40.0, 150.0])
def test_bin_law_matches_quadrature(r, u):
    off, cnt, cv, wv = verdicts._node_tables(np.array([r]))
    ex = getattr(verdicts._exact_log_sf, "py_func", verdicts._exact_log_sf)
    got = ex(u, int(off[0]), int(cnt[0]), cv, wv)
    assert got == pytest.approx(_polar_log_sf(2 * u, 1.0, r), rel=1e-11)
    if u <= 40:  # the Gauss-Legendre form of the thresholds module agrees there
        assert got == pytest.approx(-math.log(weighted_chi2_sf(2 * u, 1.0, r)), rel=1e-11)


def test_score_is_the_per_frame_rule(eha):
    """score >= -log(alpha) exactly where the per-frame Bonferroni verdict at alpha flags."""
    m, th = eha
    P = _healthy_frames(m, 60_000, 1)
    P[40:60] *= 3.0  # some flagged frames
    s = FrameScore(th)(P)
    flags, _, _ = frame_verdicts(P, th)
    assert flags.any() and not flags.all()
    assert np.array_equal(flags, s >= -math.log(1e-3))
    # at the threshold itself: -log p = -log alpha (the threshold's quantile has rtol 1e-10)
    assert FrameScore(th)(th.values[None]) == pytest.approx(-math.log(1e-3), rel=1e-8)


def test_score_is_max_bin_bonferroni(eha):
    m, th = eha
    P = _healthy_frames(m, 12_000, 2)[:10]
    s = FrameScore(th)
    ev = th.eigenvalues
    idx = np.flatnonzero(th.tested)
    ref = -np.log(weighted_chi2_sf(P[:, idx], ev[idx, :, 0], ev[idx, :, 1]))
    want = np.maximum(ref.max(axis=1) - math.log(idx.size), 0.0)
    np.testing.assert_allclose(s(P), want, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s.bin_scores(P), ref, rtol=1e-12)


def test_paths_agree(eha, monkeypatch):
    m, th = eha
    P = _healthy_frames(m, 40_000, 3)
    P[100:110, :, 0] *= 2.5  # large low bins on the position channel: the second pass runs
    compiled = FrameScore(th, compiled=True)(P)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    numpy = FrameScore(th)(P)
    np.testing.assert_allclose(numpy, compiled, rtol=1e-13, atol=0)
    kern = getattr(verdicts._score_kernel, "py_func", verdicts._score_kernel)
    s = FrameScore(th)
    out = np.empty((4, 3))
    kern(P[98:102], *s._kernel_args, out)
    np.testing.assert_allclose(out, numpy[98:102], rtol=1e-13)


def test_healthy_score_is_a_valid_p_value(eha):
    """P(score >= h) <= exp(-h) on healthy frames.

    Non-overlapping frames (every 5th; frames of 1 s, hop 0.2 s) are independent trials, so the
    exceedance count is at most Binomial(n, exp(-h)) (Bonferroni: the bound holds whatever the
    dependence between bins): it must not exceed the binomial 0.999 quantile.
    """
    m, th = eha
    s = FrameScore(th)(_healthy_frames(m, 600_000, 4)[::5])
    n = s.size
    for h in (1.0, 2.0, 4.0):
        k = int(np.count_nonzero(s >= h))
        assert k <= scipy.stats.binom.ppf(0.999, n, math.exp(-h)), (h, k, n * math.exp(-h))


def test_exponential_law_and_band(eha):
    m, th = eha
    P = _healthy_frames(m, 6_000, 5)
    no_law = replace(th, eigenvalues=None)
    s = FrameScore(no_law)
    assert s.law == "exponential"
    idx = np.flatnonzero(th.tested)
    want = np.maximum((P[:, idx] / th.expected[idx]).max(axis=1) - math.log(idx.size), 0)
    np.testing.assert_allclose(s(P), want, rtol=1e-14)
    banded = FrameScore(th.restricted((10.0, 60.0)))
    assert banded.n_tested == int(np.count_nonzero(th.restricted((10.0, 60.0)).tested)) < s.n_tested
    np.testing.assert_allclose(frame_scores(P, th), FrameScore(th)(P))
    with pytest.raises(ParameterError, match="healthy law"):
        FrameScore(replace(th, eigenvalues=None, expected=None))
    with pytest.raises(ParameterError, match="power must have shape"):
        s(P[:, :10])


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
def test_compiled_flag(eha):
    m, th = eha
    P = _healthy_frames(m, 3_000, 6)
    assert np.array_equal(FrameScore(th, compiled=True)(P), FrameScore(th, compiled=False)(P))
