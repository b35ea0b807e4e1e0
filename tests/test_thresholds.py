"""Chi-squared thresholds and their false-alarm rates (chatterspec.detection.thresholds).

False-alarm rates are tested against exact binomial (Clopper-Pearson) intervals. Realizations are
independent; the DFT bins of one healthy record are *nearly* independent (the MA(1) chattering has a
smooth spectrum and the record is unwindowed), so pooling bins x runs gives a count that is
binomial to a very good approximation.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from chatterspec.detection.pipeline import scenario_chattering
from chatterspec.detection.spectral import STFTConfig, expected_spectrum, periodogram, spectrogram
from chatterspec.detection.thresholds import (
    exact_threshold,
    frame_threshold,
    paper_gamma_matrix,
    paper_threshold,
    per_test_alpha,
    threshold,
)
from chatterspec.detection.verdicts import detect_spectrum
from chatterspec.errors import ParameterError, ShapeError
from chatterspec.plants.scenarios import scenario

HEALTHY = ("so-healthy-low", "so-healthy-high", "eha-healthy")
RUNS = 1000


def clopper_pearson(k: int, n: int, level: float = 0.99) -> tuple[float, float]:
    ci = scipy.stats.binomtest(k, n).proportion_ci(confidence_level=level, method="exact")
    return ci.low, ci.high


@pytest.fixture(scope="module")
def healthy():
    """1000 healthy 4 s records of each full-measurement healthy scenario and their periodograms."""
    out = {}
    for i, name in enumerate(HEALTHY):
        rec = scenario_chattering(scenario(name), RUNS, seed=777 + i)
        out[name] = (rec, periodogram(rec.values, rec.dt))
    return out


# -- construction ---------------------------------------------------------------------
def test_exact_threshold_values_dof_and_tested_bins():
    model = scenario("so-healthy-low").nominal
    N = 4000
    f = np.fft.rfftfreq(N, model.dt)
    th = exact_threshold(model, f, N, alpha=1e-3, law="chi2")
    E = expected_spectrum(model, f, N)
    n_tested = N // 2 - 1  # bins 1 .. N/2 - 1: DC and Nyquist excluded
    assert th.n_tested == n_tested and not th.tested[0] and not th.tested[-1]
    a = 1e-3 / n_tested
    assert th.per_test_alpha == pytest.approx(a)
    np.testing.assert_allclose(th.values[1:-1], E[1:-1] * scipy.stats.chi2.ppf(1 - a, 2) / 2, rtol=1e-9)
    np.testing.assert_allclose(th.values[0], E[0] * scipy.stats.chi2.ppf(1 - a, 1), rtol=1e-9)  # DC: 1 dof
    assert th.dof[0] == 1 and th.dof[1] == 2 and th.dof[-1] == 1
    assert th.law == "chi2" and th.eigenvalues is None and np.all(th.effective_dof == th.dof[:, None])
    # default exact law: at DC (l2 = 0) it is the chi2(1) quantile of l1 = E; elsewhere between
    # E chi2(2)/2 (l1 = l2) and E chi2(1) (l2 = 0); effective dof in [1, 2]
    ex = exact_threshold(model, f, N, alpha=1e-3)
    assert ex.law == "exact" and ex.eigenvalues.shape == (f.size, 2, 2)
    np.testing.assert_allclose(ex.values[0], th.values[0], rtol=1e-12)
    np.testing.assert_allclose(ex.eigenvalues.sum(axis=-1), E, rtol=1e-9)
    assert np.all(ex.values[1:-1] >= th.values[1:-1] * (1 - 1e-9))
    assert np.all(ex.values[1:-1] <= E[1:-1] * scipy.stats.chi2.isf(a, 1))
    assert np.all((ex.effective_dof >= 1 - 1e-12) & (ex.effective_dof <= 2 + 1e-12))
    assert ex.effective_dof[0, 0] == pytest.approx(1.0) and ex.effective_dof[1000, 0] == pytest.approx(
        2.0, abs=1e-3
    )
    with pytest.raises(ParameterError, match="law"):
        exact_threshold(model, f, N, law="gauss")
    assert (th.kind, th.alpha_meaning, th.correction, th.averaged) == (
        "exact",
        "family-wise",
        "bonferroni",
        1,
    )
    assert "probability at most 0.001" in th.describe() and "one record" in th.describe()
    # odd N: no Nyquist bin, the last bin is tested
    f_odd = np.fft.rfftfreq(N + 1, model.dt)
    assert exact_threshold(model, f_odd, N + 1).tested[-1]
    # averaged K spectra: E chi2(2K)/(2K), DC chi2(K)/K
    thk = exact_threshold(model, f, N, alpha=1e-3, averaged=10, law="chi2")
    np.testing.assert_allclose(thk.values[5], E[5] * scipy.stats.chi2.ppf(1 - a, 20) / 20, rtol=1e-9)
    np.testing.assert_allclose(thk.values[0], E[0] * scipy.stats.chi2.ppf(1 - a, 10) / 10, rtol=1e-9)
    # exact law, K = 10: Welch-Satterthwaite (c / K) chi2(nu_eff); chi2(K)/K at DC (l2 = 0)
    exk = exact_threshold(model, f, N, alpha=1e-3, averaged=10)
    np.testing.assert_allclose(exk.values[0], thk.values[0], rtol=1e-9)
    l1, l2 = exk.eigenvalues[5, :, 0], exk.eigenvalues[5, :, 1]
    nu = 10 * (l1 + l2) ** 2 / (l1**2 + l2**2)
    np.testing.assert_allclose(exk.effective_dof[5], nu, rtol=1e-12)
    c = (l1**2 + l2**2) / (l1 + l2)
    np.testing.assert_allclose(exk.values[5], c * scipy.stats.chi2.isf(a, nu) / 10, rtol=1e-9)


def test_corrections():
    assert per_test_alpha(0.01, 100, "none") == 0.01
    assert per_test_alpha(0.01, 100, "bonferroni") == pytest.approx(1e-4)
    assert per_test_alpha(0.01, 100, "sidak") == pytest.approx(1 - 0.99 ** (1 / 100), rel=1e-12)
    # Sidak is slightly less conservative than Bonferroni
    assert per_test_alpha(0.01, 100, "sidak") > per_test_alpha(0.01, 100, "bonferroni")
    model = scenario("so-healthy-low").nominal
    f = np.fft.rfftfreq(400, model.dt)
    per_bin = exact_threshold(model, f, 400, 0.01, correction="none")
    assert per_bin.alpha_meaning == "per-bin" and "no family-wise guarantee" in per_bin.describe()
    with pytest.raises(ParameterError, match="correction"):
        exact_threshold(model, f, 400, 0.01, correction="holm")


def test_paper_threshold_eq58_62():
    """Sigma_Gamma built here from the paper's eq 58 text, without the package's helper."""
    model = scenario("so-healthy-high").nominal
    f = np.fft.rfftfreq(4000, model.dt)
    th = paper_threshold(model, f, alpha=1e-3)
    C, A, Q, R = model.C, model.A, model.Q, model.R
    M = -C @ A @ np.linalg.inv(C)
    m = M.shape[0]
    # eq 58: lambda_ij = m_ij off the diagonal, m_ii + 1 (m_ii >= 0) or m_ii - 1 (m_ii < 0) on it
    lam = [
        [M[i, j] if i != j else (M[i, i] + 1 if M[i, i] >= 0 else M[i, i] - 1) for j in range(m)]
        for i in range(m)
    ]
    sigma = [
        sum(C[i, j] * Q[j, k] * C[i, k] for j in range(m) for k in range(m))
        + sum(lam[i][j] * R[j, k] * lam[i][k] for j in range(m) for k in range(m))
        for i in range(m)
    ]
    chi = scipy.stats.chi2.ppf(1 - 1e-3, 2) / 2
    np.testing.assert_allclose(th.values, np.tile(np.array(sigma) * chi, (f.size, 1)), rtol=1e-12)
    np.testing.assert_allclose(paper_gamma_matrix(model), np.array(lam), rtol=1e-15)
    assert (th.kind, th.alpha_meaning, th.correction) == ("paper", "per-bin", "none")
    # eq 59: with diagonal R, Sigma_Gamma bounds the chattering's spectral density
    # diag(C Q C' + G(w) R G(w)^H), G(w) = e^{iw} I + M, at every frequency
    assert np.count_nonzero(R - np.diag(np.diag(R))) == 0
    w = np.linspace(0.0, np.pi, 4001)
    G = np.exp(1j * w)[:, None, None] * np.eye(m) + M
    psd = np.real(np.einsum("wij,jk,wik->wi", G, R, G.conj())) + np.diag(C @ Q @ C.T)
    assert np.all(psd <= np.array(sigma) * (1 + 1e-12))


def test_paper_threshold_scalar_closed_form():
    """One channel, x_k = v_k + w_{k+1} - a w_k: the bound is attained, Sigma = q + r (1 + |a|)^2,
    the density's maximum over frequency (at Nyquist for a > 0, at DC for a < 0)."""
    from chatterspec.plants.models import LinearModel

    for a in (0.9, -0.5):
        q, r = 2e-4, 3.0
        model = LinearModel(
            np.array([[a]]), np.zeros((1, 1)), np.eye(1), np.array([[q]]), np.array([[r]]), 1e-3
        )
        th = paper_threshold(model, np.fft.rfftfreq(100, 1e-3), alpha=0.01)
        expected = (q + r * (1 + abs(a)) ** 2) * scipy.stats.chi2.ppf(0.99, 2) / 2
        np.testing.assert_allclose(th.values, expected, rtol=1e-12)


def test_dispatcher_and_bad_input():
    model = scenario("so-healthy-low").nominal
    f = np.fft.rfftfreq(400, model.dt)
    assert threshold("exact", model, f, n_samples=400).kind == "exact"
    assert threshold("paper", model, f).kind == "paper"
    assert threshold("frame", model, np.fft.rfftfreq(1000, model.dt)).alpha_meaning == "per-frame"
    with pytest.raises(ParameterError, match="unknown threshold kind"):
        threshold("bogus", model, f, n_samples=400)
    with pytest.raises(ParameterError, match="n_samples"):
        threshold("exact", model, f)
    for bad in (0.0, 1.0, -0.1, 1.5, float("nan")):
        with pytest.raises(ParameterError, match=r"\(0, 1\)|finite"):
            exact_threshold(model, f, 400, alpha=bad)
        with pytest.raises(ParameterError):
            paper_threshold(model, f, alpha=bad)
    th = exact_threshold(model, f, 400)
    with pytest.raises(ShapeError, match="does not match the threshold"):
        th.check_spectrum(np.zeros((5, 200, 2)))
    with pytest.raises(ShapeError):
        detect_spectrum(np.zeros((5, 201, 3)), th)


# -- false-alarm rates ------------------------------------------------------------------
@pytest.mark.parametrize("alpha", [1e-2, 1e-3])
@pytest.mark.parametrize("name", HEALTHY)
def test_per_bin_false_alarm_rate_of_exact_threshold(healthy, name, alpha):
    """Per-bin rate, pooled over tested bins x runs x channels, inside the 99 % Clopper-Pearson interval.

    n = 1999 bins x 1000 runs x m channels (4-6 million tests): the interval is about +-4 % of alpha at
    1 % and +-13 % at 0.1 %, tight enough to catch a wrong dof (chi2(1) vs chi2(2)), a missing factor
    2, or the asymptotic instead of the exact expectation on the EHA position channel.
    """
    rec, pg = healthy[name]
    th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples, alpha, correction="none")
    exceed = pg.power[:, th.tested] > th.values[th.tested]
    k, n = int(exceed.sum()), exceed.size
    lo, hi = clopper_pearson(k, n)
    assert lo <= alpha <= hi, f"{name}: rate {k / n:.5f} (99% CI [{lo:.5f}, {hi:.5f}]) vs alpha {alpha}"


def test_dc_bin_has_one_degree_of_freedom(healthy):
    """DC false-alarm rate at per-bin 5 %, pooled over scenarios, runs and channels (7000 tests)."""
    k = n = 0
    for rec, pg in healthy.values():
        th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples, 0.05, correction="none")
        exceed = pg.power[:, 0] > th.values[0]
        k, n = k + int(exceed.sum()), n + exceed.size
    lo, hi = clopper_pearson(k, n)
    # with 2 dof at DC the rate would be ~ P(chi2_1 > chi2_2 quantile) ~ 0.023, outside [lo, hi]
    assert lo <= 0.05 <= hi


def test_family_wise_rate_of_default_detector(healthy):
    """Default detector (exact, Bonferroni, 0.1 % family-wise): healthy record-channel flag rate <= alpha.

    Each (record, channel) is one family of 1999 tested bins; 1000 runs x 7 channels = 7000 families.
    Bonferroni guarantees rate <= alpha, so we use a one-sided binomial test of H0: p <= 1e-3 (reject at
    p-value < 1 %) and check the 99 % Clopper-Pearson interval reaches down to alpha or below.
    """
    k = n = 0
    for rec, pg in healthy.values():
        th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples)
        flagged = (pg.power[:, th.tested] > th.values[th.tested]).any(axis=1)
        k, n = k + int(flagged.sum()), n + flagged.size
    assert scipy.stats.binomtest(k, n, 1e-3, alternative="greater").pvalue > 0.01, f"{k}/{n} flagged"
    assert clopper_pearson(k, n)[0] <= 1e-3


def test_averaged_threshold_per_bin_rate(healthy):
    """Averages of K = 10 independent periodograms vs E chi2(20)/20 at per-bin alpha = 1 %.

    100 groups x 1999 bins x 2 channels = 399 800 tests; 99 % Clopper-Pearson interval.
    """
    rec, pg = healthy["so-healthy-high"]
    K = 10
    avg = pg.power.reshape(RUNS // K, K, *pg.power.shape[1:]).mean(axis=1)
    th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples, 0.01, correction="none", averaged=K)
    exceed = avg[:, th.tested] > th.values[th.tested]
    lo, hi = clopper_pearson(int(exceed.sum()), exceed.size)
    assert lo <= 0.01 <= hi


def test_paper_threshold_crosses_far_above_nominal_rate_on_healthy_records(healthy):
    """How often a healthy 4 s record crosses the paper's flat threshold somewhere (alpha = 0.1 % per bin).

    The flat bound is far above E[S] at low frequency but close to it near Nyquist, where ~2000 bins are
    tested at per-bin 0.1 %: roughly a third of healthy records (per channel) cross it somewhere, which
    is what eq 64's vacuous union bound (1999 x 0.1 % ~ 2) hides. We assert the 99 % Clopper-Pearson
    interval lies far above the nominal 0.1 % and around 1/3.
    """
    rec, pg = healthy["so-healthy-low"]
    th = paper_threshold(rec.model, pg.freqs_hz, 1e-3)
    crossed = (pg.power[:, th.tested] > th.values[th.tested]).any(axis=1)
    k, n = int(crossed.sum()), crossed.size
    lo, hi = clopper_pearson(k, n)
    assert lo > 100 * 1e-3
    assert 0.2 < lo and hi < 0.5, f"paper threshold healthy crossing rate {k / n:.3f} [{lo:.3f}, {hi:.3f}]"


def test_stft_per_frame_false_alarm_rate(healthy):
    """Per-frame (family over one frame's 499 tested bins) false-alarm rate at alpha = 1 % on healthy data.

    Overlapping frames (0.8 s of 1 s shared) are strongly dependent, so counting every frame would
    understate the variance of the count. Conservative interpretation: (a) an exact Clopper-Pearson test
    on non-overlapping frames only (starts 1 s apart: independent), and (b) the rate over all frames
    (its expectation is still alpha) against an interval computed as if only 1/5 of the frames (the
    non-overlapping fraction) carried information.
    """
    alpha = 0.01
    cfg = STFTConfig()
    k_all = n_all = k_ind = n_ind = 0
    for rec, _ in healthy.values():
        sg = spectrogram(rec.values[:500], rec.dt, cfg)
        th = frame_threshold(rec.model, sg.freqs_hz, cfg, rec.dt, alpha)
        flags = (sg.power[..., th.tested, :] > th.values[th.tested]).any(axis=-2)  # (runs, frames, m)
        k_all, n_all = k_all + int(flags.sum()), n_all + flags.size
        ind = flags[:, ::5]
        k_ind, n_ind = k_ind + int(ind.sum()), n_ind + ind.size
    lo, hi = clopper_pearson(k_ind, n_ind)
    assert lo <= alpha * 1.0 and alpha * 0.8 <= hi  # Bonferroni: rate <= alpha, and close to it
    lo, hi = clopper_pearson(round(k_all / 5), n_all // 5)
    assert lo <= alpha and alpha * 0.8 <= hi, f"per-frame rate {k_all / n_all:.4f}"


def test_band_family_wise_rate_counts_only_the_band(healthy):
    """Bonferroni over a band (50-200 Hz: 601 bins): healthy family-wise rate <= alpha and near it.

    alpha = 5 %: 1000 runs x 2 channels = 2000 independent (run, channel) families; 99 % Clopper-Pearson.
    Bonferroni over nearly independent bins gives 1 - exp(-alpha) ~ 4.9 %, so the interval must reach
    0.8 alpha; a correction over all 1999 bins (alpha / 1999 per bin) would give ~1.5 % and fail that.
    """
    rec, pg = healthy["so-healthy-high"]
    th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples, 0.05, band=(50.0, 200.0))
    assert th.n_tested == 601 and th.band == (50.0, 200.0)
    crossed = (pg.power[:, th.tested] > th.values[th.tested]).any(axis=1)
    lo, hi = clopper_pearson(int(crossed.sum()), crossed.size)
    assert lo <= 0.05 and hi >= 0.8 * 0.05, (lo, hi)
    # the STFT frame and the paper's threshold take the same band
    assert threshold("paper", rec.model, pg.freqs_hz, band=(50.0, 200.0)).n_tested == 601
    with pytest.raises(ParameterError, match="band"):
        threshold("exact", rec.model, pg.freqs_hz, n_samples=pg.n_samples, band=(200.0, 50.0))
