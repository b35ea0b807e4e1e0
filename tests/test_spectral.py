"""Periodogram, expected healthy spectrum and STFT (chatterspec.detection.spectral)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from chatterspec.detection.pipeline import scenario_chattering
from chatterspec.detection.spectral import (
    STFTConfig,
    chattering_autocovariance,
    expected_frame_spectrum,
    expected_spectrum,
    frame_columns,
    mean_periodogram,
    periodogram,
    spectrogram,
    window_overlap_ratio,
)
from chatterspec.errors import NonFiniteError, ParameterError, ShapeError, SingularMatrixError
from chatterspec.plants.models import LinearModel, second_order
from chatterspec.plants.scenarios import scenario

DT = 1e-3
RUNS_MC = 1000


@pytest.fixture(scope="module")
def healthy_records():
    """1000 healthy 4 s records (N = 4000) of each scenario with full measurement (~3.5 s in total)."""
    return {
        name: scenario_chattering(scenario(name), RUNS_MC, seed=20230 + i)
        for i, name in enumerate(("so-healthy-low", "so-healthy-high", "eha-healthy"))
    }


# -- periodogram --------------------------------------------------------------
def test_periodogram_definition_and_shapes():
    rng = np.random.default_rng(0)
    x = rng.standard_normal((3, 10, 2))
    p = periodogram(x, DT)
    assert p.power.shape == (3, 6, 2)
    np.testing.assert_allclose(p.freqs_hz, np.arange(6) / (10 * DT))
    # eq 49 written out with k = 0..N-1 (the k = 1..N of the paper only changes the phase)
    k = np.arange(10)
    n = 3
    direct = np.abs((x[1, :, 0] * np.exp(-2j * np.pi * n * k / 10)).sum()) ** 2 / 10
    assert p.power[1, n, 0] == pytest.approx(direct, rel=1e-12)
    # a single record may drop the realization axis
    np.testing.assert_allclose(periodogram(x[0], DT).power, p.power[0])
    np.testing.assert_allclose(mean_periodogram(x, DT).power, p.power.mean(axis=0))


def test_periodogram_rejects_bad_input():
    with pytest.raises(ShapeError, match="axis -2"):
        periodogram(np.zeros(10), DT)
    with pytest.raises(NonFiniteError):
        periodogram(np.array([[0.0], [np.nan]]), DT)
    with pytest.raises(ParameterError):
        periodogram(np.zeros((4, 1)), -1.0)


# -- expected spectrum -----------------------------------------------------------
def test_asymptotic_form_is_eq56_read_index_wise():
    model = scenario("eha-healthy").nominal
    f = np.linspace(0.0, 500.0, 37)
    w = 2 * np.pi * f * DT
    C, Q, R = model.C, np.diag(model.Q), np.diag(model.R)
    M = -C @ model.A @ model.C_inv
    eq56 = np.zeros((f.size, 3))
    for i in range(3):
        eq56[:, i] = (C[i] ** 2 * Q).sum() + sum(
            np.abs(np.exp(1j * w) * (i == j) + M[i, j]) ** 2 * R[j] for j in range(3)
        )
    np.testing.assert_allclose(expected_spectrum(model, f, form="asymptotic"), eq56, rtol=1e-10)


def test_exact_form_equals_quadratic_form_of_ma1_covariance():
    """E[S(f_n)] = f^H Sigma f / N with the Toeplitz covariance of the MA(1) chattering."""
    model = second_order(10.0, 0.1, 100.0, DT, Q=np.diag([1e-8, 1e-6]), R=np.diag([1e-6, 1e-4]))
    N = 16
    g0, g1 = chattering_autocovariance(model)
    f = np.arange(N // 2 + 1) / (N * DT)
    k = np.arange(N)
    E = expected_spectrum(model, f, N)
    for i in range(2):
        Sigma = np.diag(np.full(N, g0[i])) + g1[i] * (np.eye(N, k=1) + np.eye(N, k=-1))
        for n in range(N // 2 + 1):
            v = np.exp(-2j * np.pi * n * k / N)
            assert E[n, i] == pytest.approx((v.conj() @ Sigma @ v).real / N, rel=1e-10)


def test_expected_spectrum_needs_full_measurement_and_valid_form():
    partial = second_order(2.0, 0.0, 100.0, DT, measure="position")
    with pytest.raises(SingularMatrixError, match="full-measurement"):
        expected_spectrum(partial, [0.0, 1.0], 10)
    full = scenario("so-healthy-low").nominal
    with pytest.raises(ParameterError, match="n_samples"):
        expected_spectrum(full, [0.0, 1.0])
    with pytest.raises(ParameterError, match="form"):
        expected_spectrum(full, [0.0], 10, form="paper")


@pytest.mark.parametrize("name", ["so-healthy-low", "so-healthy-high", "eha-healthy"])
def test_mean_healthy_periodogram_matches_exact_expectation(healthy_records, name):
    """Monte Carlo mean of 1000 healthy periodograms vs the exact finite-N expectation, at every bin.

    Tolerance: a bin with nu degrees of freedom has S = E chi2(nu)/nu, so Var(S) = 2 E^2 / nu and the
    mean of R runs has relative standard error sqrt(2 / nu) / sqrt(R) (1/sqrt(1000) = 3.2 % at the
    chi2(2) bins, sqrt(2) times that at DC/Nyquist). The bins are nearly independent, so we allow the
    two-sided normal quantile of a Bonferroni family of all bins x channels at family level 1e-3
    (z ~ 5.1): a correct implementation fails with probability < 0.1 %, while a wrong expectation
    (e.g. eq 56 with the opposite sign of M, or the asymptotic form on the EHA position channel
    at low frequency) misses by far more than 5 SE at many bins. (The mean of 1000 exponentials
    is only slightly skewed, 2/sqrt(1000) = 0.06, so the normal quantile is adequate.)
    """
    rec = healthy_records[name]
    pg = periodogram(rec.values, rec.dt)
    E = expected_spectrum(rec.model, pg.freqs_hz, pg.n_samples)
    mean = pg.power.mean(axis=0)
    dof = np.full(pg.n_bins, 2.0)
    dof[0] = 1.0
    if pg.n_samples % 2 == 0:
        dof[-1] = 1.0
    se = np.sqrt(2.0 / dof)[:, None] / np.sqrt(rec.runs)
    z = (mean / E - 1.0) / se
    n_tests = z.size
    z_crit = scipy.stats.norm.isf(1e-3 / (2 * n_tests))
    assert np.abs(z).max() < z_crit, f"worst bin z = {np.abs(z).max():.2f} > {z_crit:.2f}"
    # the fit is not vacuous: the z-scores look standard normal overall
    assert abs(z.mean()) < 0.1 and 0.9 < z.std() < 1.1


# -- STFT ----------------------------------------------------------------------------
def test_stft_config_validation():
    cfg = STFTConfig()
    assert (cfg.n_window(DT), cfg.n_hop(DT)) == (1000, 200)
    with pytest.raises(ParameterError, match="hop_s"):
        STFTConfig(window_s=0.5, hop_s=0.6)
    with pytest.raises(ParameterError, match="window"):
        STFTConfig(window="no-such-window")
    with pytest.raises(ParameterError):
        STFTConfig(window_s=-1.0)
    with pytest.raises(ParameterError):
        STFTConfig(hop_s=0.0)


def test_spectrogram_frames_times_and_scaling():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((2, 4321, 3))
    cfg = STFTConfig(window_s=0.5, hop_s=0.1)
    W, H = 500, 100
    sg = spectrogram(x, DT, cfg, t0=0.25)
    n_frames = (4321 - W) // H + 1  # complete frames only
    assert sg.power.shape == (2, n_frames, W // 2 + 1, 3)
    np.testing.assert_allclose(sg.times_s, 0.25 + (np.arange(n_frames) * H + (W - 1) / 2) * DT)
    np.testing.assert_array_equal(sg.frame_starts, np.arange(n_frames) * H)
    # frame j covers samples [jH, jH + W): |sum w x e^{-iwk}|^2 / sum w^2
    w = cfg.taper(DT)
    j = 7
    direct = np.abs(np.fft.rfft(w * x[1, j * H : j * H + W, 2])) ** 2 / np.dot(w, w)
    np.testing.assert_allclose(sg.power[1, j, :, 2], direct, rtol=1e-10, atol=1e-12)


def test_frame_columns_identical_on_any_buffer_containing_the_frame():
    """The online monitor computes columns from a ring buffer: they must equal the batch columns exactly."""
    rng = np.random.default_rng(2)
    x = rng.standard_normal((3, 6000, 2))
    cfg = STFTConfig()
    batch = spectrogram(x, DT, cfg)
    for start, stop in [(0, 6000), (1234, 5678), (200, 1200), (199, 1400), (4999, 6000), (3333, 4444)]:
        j, cols = frame_columns(x[:, start:stop], DT, cfg, first_sample=start)
        if j.size:
            assert j[0] * 200 >= start and j[-1] * 200 + 1000 <= stop
        np.testing.assert_array_equal(cols, batch.power[:, j])
        # one realization alone (the online monitor's usual case) gives the same bits
        j1, cols1 = frame_columns(x[1, start:stop], DT, cfg, first_sample=start)
        np.testing.assert_array_equal(cols1, batch.power[1, j1])
    j, cols = frame_columns(x[:, 10:900], DT, cfg, first_sample=10)
    assert j.size == 0 and cols.shape == (3, 0, 501, 2)


def test_spectrogram_rejects_record_shorter_than_one_window():
    with pytest.raises(ShapeError, match="shorter than one STFT window"):
        spectrogram(np.zeros((999, 2)), DT, STFTConfig())


@pytest.mark.parametrize("window_s", [1.0, 0.25])
def test_window_overlap_ratio_hamming(window_s):
    """Closed form for the periodic Hamming window w_k = a - b cos(theta k), theta = 2 pi / W.

    Over a full period sum w_k^2 = W (a^2 + b^2 / 2) and the circular lag-1 sum is
    W (a^2 + b^2 cos(theta) / 2); the linear lag-1 sum drops the wrap-around term w_{W-1} w_0.
    """
    cfg = STFTConfig(window_s=window_s)
    W = round(window_s / DT)
    a, b, theta = 0.54, 0.46, 2 * np.pi / W
    w0, w_last = a - b, a - b * np.cos(theta * (W - 1))
    expected = (W * (a**2 + b**2 * np.cos(theta) / 2) - w_last * w0) / (W * (a**2 + b**2 / 2))
    assert window_overlap_ratio(cfg, DT) == pytest.approx(expected, rel=1e-12)
    assert 0.99 < window_overlap_ratio(STFTConfig(), DT) < 1.0


def test_window_overlap_ratio_is_the_frame_lag1_weight():
    """Monte Carlo oracle of what rho_w means: for x_k = e_k + c e_{k-1} (gamma0 = 1 + c^2,
    gamma1 = c), the mean frame power at bin frequency w is gamma0 + 2 gamma1 rho_w cos(w).
    20000 independent frames; away from DC/Nyquist the frame power is ~ E chi2(2)/2, relative
    SE 1/sqrt(20000); 5 SE (Bonferroni over the 7 bins checked at ~1e-6 each)."""
    cfg = STFTConfig(window_s=0.02, hop_s=0.02)  # W = 20, non-overlapping frames
    rng = np.random.default_rng(31)
    c = 0.8
    e = rng.standard_normal((200, 100 * 20 + 1))
    x = (e[:, 1:] + c * e[:, :-1])[..., None]
    sg = spectrogram(x, DT, cfg)
    mean = sg.power[..., 0].mean(axis=(0, 1))
    omega = 2 * np.pi * sg.freqs_hz * DT
    rho = window_overlap_ratio(cfg, DT)
    expected = 1 + c**2 + 2 * c * rho * np.cos(omega)
    n = sg.power.shape[0] * sg.power.shape[1]
    inner = slice(2, -2)
    assert np.all(np.abs(mean[inner] / expected[inner] - 1) < 5 / np.sqrt(n))
    # rho_w = 1 (the unwindowed lag weight) is rejected: > 6 SE off at the highest bins
    wrong = 1 + c**2 + 2 * c * np.cos(omega)
    assert np.max(np.abs(mean[inner] / wrong[inner] - 1)) > 6 / np.sqrt(n)


@pytest.mark.parametrize("name", ["so-healthy-high", "eha-healthy"])
def test_mean_healthy_frame_spectrum_matches_expected_frame_spectrum(healthy_records, name):
    """Mean of non-overlapping healthy frames vs gamma0 + 2 gamma1 rho_w cos(w).

    We use frames 0, 5, 10, 15 (starts 1 s apart, so they share no sample and are independent for the
    MA(1) chattering up to one boundary sample): 4 x 1000 = 4000 frames per bin. A windowed bin is
    E chi2(2)/2 to a good approximation, so the relative SE of the mean is 1/sqrt(4000) (sqrt(2) times
    that at DC/Nyquist); tolerance as in the periodogram test (Bonferroni over bins x channels, 1e-3).
    """
    rec = healthy_records[name]
    cfg = STFTConfig()
    sg = spectrogram(rec.values, rec.dt, cfg)
    E = expected_frame_spectrum(rec.model, sg.freqs_hz, cfg, rec.dt)
    frames = sg.power[:, ::5]
    n = frames.shape[0] * frames.shape[1]
    mean = frames.mean(axis=(0, 1))
    dof = np.full(sg.freqs_hz.size, 2.0)
    dof[[0, -1]] = 1.0
    z = (mean / E - 1.0) / (np.sqrt(2.0 / dof)[:, None] / np.sqrt(n))
    z_crit = scipy.stats.norm.isf(1e-3 / (2 * z.size))
    assert np.abs(z).max() < z_crit


def test_expected_spectrum_of_custom_model_with_correlated_noise():
    """Non-diagonal Q and R: gamma0 = diag(CQC' + R + MRM'), gamma1 = diag(MR) (vector MA(1))."""
    A = np.array([[0.9, 0.1], [-0.2, 0.8]])
    C = np.array([[1.0, 0.5], [0.0, 2.0]])
    Q = np.array([[1.0, 0.3], [0.3, 2.0]])
    R = np.array([[0.5, 0.1], [0.1, 0.4]])
    model = LinearModel(A, np.zeros((2, 1)), C, Q, R, DT)
    g0, g1 = chattering_autocovariance(model)
    # Monte Carlo oracle: simulate the plant and the auxiliary SVSF (the package's simulation and
    # filter, not the formula) and measure the chattering's lag-0/lag-1 autocovariances. Runs are
    # independent: the per-run estimates give the SE; 5 SE (Bonferroni over 4 checks, ~2e-6 each).
    from chatterspec.detection.pipeline import scenario_chattering
    from chatterspec.plants.simulate import model_scenario

    x = scenario_chattering(model_scenario(model, duration=2.0), 64, seed=17).values  # (64, N, 2)
    c0 = np.mean(x**2, axis=1)  # (runs, m)
    c1 = np.mean(x[:, 1:] * x[:, :-1], axis=1)
    for est, ref in ((c0, g0), (c1, g1)):
        se = est.std(axis=0, ddof=1) / np.sqrt(est.shape[0])
        assert np.all(np.abs(est.mean(axis=0) - ref) < 5 * se), (est.mean(axis=0), ref, se)
    assert np.all(np.abs(g1) > 10 * c1.std(axis=0, ddof=1) / 8)  # the lag-1 term is resolved, not ~0


# -- exact finite-N law of a bin: l1 Z1^2 + l2 Z2^2 ------------------------------------------
def _scalar_ma1(a: float = 0.9, q: float = 1e-4, r: float = 1.0) -> LinearModel:
    """One-channel model whose chattering is x_k = v_k + w_{k+1} - a w_k (gamma1 = -a r)."""
    return LinearModel(
        A=np.array([[a]]), B=np.zeros((1, 1)), C=np.eye(1), Q=np.array([[q]]), R=np.array([[r]]), dt=DT
    )


def _simulate_ma1(model: LinearModel, draws: int, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    a, q, r = model.A[0, 0], model.Q[0, 0], model.R[0, 0]
    w = rng.standard_normal((draws, n + 1)) * np.sqrt(r)
    v = rng.standard_normal((draws, n)) * np.sqrt(q)
    return (v + w[:, 1:] - a * w[:, :-1])[..., None]


def test_periodogram_eigenvalues_closed_form_and_monte_carlo():
    """(l1, l2) = gamma0/2 + (1 - 1/N) gamma1 cos w +- |gamma1|/N; l2 = 0 at DC/Nyquist; MC of (Re, Im)."""
    from chatterspec.detection.spectral import periodogram_eigenvalues

    model = _scalar_ma1()
    N = 64
    f = np.fft.rfftfreq(N, DT)
    l1, l2 = periodogram_eigenvalues(model, f, N)
    g0, g1 = chattering_autocovariance(model)
    c = g0 / 2 + (1 - 1 / N) * g1 * np.cos(2 * np.pi * f * DT)[:, None]
    np.testing.assert_allclose(l1[1:-1], (c + abs(g1) / N)[1:-1], rtol=1e-10)
    np.testing.assert_allclose(l2[1:-1], (c - abs(g1) / N)[1:-1], rtol=1e-9)
    np.testing.assert_allclose(l1 + l2, expected_spectrum(model, f, N), rtol=1e-10)
    assert l2[0, 0] == 0.0 and l2[-1, 0] == 0.0
    # Monte Carlo: eigenvalues of the empirical covariance of (Re X, Im X) / sqrt(N)
    x = _simulate_ma1(model, 100_000, N, seed=5)[..., 0]
    X = np.fft.rfft(x, axis=1) / np.sqrt(N)
    for b in (1, 2, 5, 20):
        lam = np.linalg.eigvalsh(np.cov(np.vstack([X[:, b].real, X[:, b].imag])))[::-1]
        np.testing.assert_allclose(lam, [l1[b, 0], l2[b, 0]], rtol=0.03)
    # arbitrary (off-grid) frequencies go through direct sums: l1 + l2 is still the exact mean
    fo = np.array([3.3, 117.0, 401.7])
    k = np.arange(N)
    m1, m2 = periodogram_eigenvalues(model, fo, N)
    for i, fi in enumerate(fo):
        e = np.exp(-2j * np.pi * fi * DT * k)
        cov = g0[0] * np.eye(N) + g1[0] * (np.eye(N, k=1) + np.eye(N, k=-1))
        M = np.vstack([e.real, e.imag]) / np.sqrt(N)
        np.testing.assert_allclose([m1[i, 0], m2[i, 0]], np.linalg.eigvalsh(M @ cov @ M.T)[::-1], rtol=1e-9)


def test_frame_eigenvalues_match_frame_columns_monte_carlo():
    """Hamming frames of W = 32 samples via frame_columns: mean l1 + l2, variance 2 (l1^2 + l2^2)."""
    from chatterspec.detection.spectral import frame_eigenvalues

    model = _scalar_ma1()
    cfg = STFTConfig(window_s=32 * DT, hop_s=32 * DT)
    f = cfg.freqs_hz(DT)
    l1, l2 = frame_eigenvalues(model, f, cfg)
    np.testing.assert_allclose(l1 + l2, expected_frame_spectrum(model, f, cfg), rtol=1e-10)
    assert l2[0, 0] == 0.0 and l2[-1, 0] == 0.0 and np.all(l2 <= l1)
    _, power = frame_columns(_simulate_ma1(model, 100_000, 32, seed=6), DT, cfg)
    power = power[:, 0, :, 0]  # (draws, bins)
    for b in (0, 1, 2, 3, 8):
        assert power[:, b].mean() == pytest.approx(l1[b, 0] + l2[b, 0], rel=0.02)
        assert power[:, b].var() == pytest.approx(2 * (l1[b, 0] ** 2 + l2[b, 0] ** 2), rel=0.05)


@pytest.mark.parametrize(
    ("window", "window_s", "hop_s", "shape"),
    [
        ("hamming", 1.0, 0.2, (2, 4000, 3)),
        ("hann", 0.101, 0.033, (5001, 2)),
        ("boxcar", 0.064, 0.064, (3, 1000, 1)),
        ("hamming", 1.0, 0.2, (60, 3000, 3)),  # two frame blocks (bounded windowed copy)
    ],
)
def test_frame_columns_bit_identical_to_short_time_fft(window, window_s, hop_s, shape):
    """frame_columns vectorizes ShortTimeFFT.stft over frames: same products, same rfft, same bits."""
    from chatterspec.detection.spectral import STFTConfig, _stft_engine

    cfg = STFTConfig(window_s=window_s, hop_s=hop_s, window=window)
    x = np.random.default_rng(11).standard_normal(shape)
    W, H = cfg.n_window(DT), cfg.n_hop(DT)
    j, power = frame_columns(x, DT, cfg, first_sample=7)
    sft = _stft_engine(cfg.window, W, H, DT)
    off = j[0] * H - 7
    seg = np.moveaxis(x[..., off : off + (j.size - 1) * H + W, :], -2, -1)
    Y = sft.stft(seg, p0=0, p1=j.size, k_offset=W // 2, axis=-1)  # the former implementation
    ref = np.swapaxes((Y.real**2 + Y.imag**2) / float(np.dot(sft.win, sft.win)), -3, -1)
    np.testing.assert_array_equal(power, ref)


@pytest.mark.parametrize(
    ("window", "window_s", "hop_s", "shape", "first"),
    [
        ("hamming", 1.0, 0.2, (1800, 3), 0),  # the online monitor's push: one run, 5 frames
        ("hamming", 1.0, 0.2, (2, 4000, 3), 7),
        ("hann", 0.101, 0.033, (5001, 2), 3),
        ("hamming", 1.0, 0.2, (60, 3000, 3), 0),  # frame blocks of one frame (bounded windowed copy)
    ],
)
def test_frame_engine_compiled_loops_give_the_numpy_bits(window, window_s, hop_s, shape, first):
    """The monitor's compiled taper / power loops: the same products, sums and divisions, so the same bits.

    (numba without fastmath does not contract ``re * re + im * im`` into an FMA, which would change
    the last bit of some bins; the Python form of each kernel is checked too.)
    """
    from chatterspec import _jit
    from chatterspec.detection import spectral

    cfg = STFTConfig(window_s=window_s, hop_s=hop_s, window=window)
    x = np.random.default_rng(12).standard_normal(shape) * 3e-3
    j_ref, ref = spectral.FrameEngine(cfg, DT)(x, first)
    np.testing.assert_array_equal(ref, frame_columns(x, DT, cfg, first_sample=first)[1])
    engine = spectral.FrameEngine(cfg, DT, compiled=True)
    for _ in range(2):  # the second call reuses the scratch buffers
        j, power = engine(x, first)
        np.testing.assert_array_equal(j, j_ref)
        np.testing.assert_array_equal(power, ref)
    if _jit.HAVE_NUMBA:  # the kernels' Python form on a small input
        W, H = cfg.n_window(DT), cfg.n_hop(DT)
        F = 3
        x3 = x.reshape(-1, *x.shape[-2:])[:1, : W + 2 * H]
        taps = [np.full((1, x.shape[-1], F, W), np.nan) for _ in range(2)]  # NaN: unwritten
        spectral._taper_kernel(x3, 0, H, engine.win, taps[0])
        spectral._taper_kernel.py_func(x3, 0, H, engine.win, taps[1])
        assert np.isfinite(taps[0]).all() and np.isfinite(taps[1]).all()
        np.testing.assert_array_equal(taps[0], taps[1])
        Y = np.fft.rfft(taps[0], axis=-1)
        pows = [np.full((1, F, W // 2 + 1, x.shape[-1]), np.nan) for _ in range(2)]
        spectral._power_kernel(Y, engine.scale, pows[0])
        spectral._power_kernel.py_func(Y, engine.scale, pows[1])
        np.testing.assert_array_equal(pows[0], pows[1])
        np.testing.assert_array_equal(
            pows[0][0], np.moveaxis((Y.real**2 + Y.imag**2) / engine.scale, -3, -1)[0]
        )
