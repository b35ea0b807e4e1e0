"""False-alarm rates, calibration and power studies (fixed seeds, exact binomial tolerances).

Power statement for the per-bin tests. A study pools ``n = runs * tested bins
* channels`` bin trials. For ``RUNS_PER_BIN = 128``, ``n >= 128 * 1999 * 2 =
511744``. The smallest expected count is at alpha = 0.1 %: ``n alpha ~ 512``.
The test fails when alpha lies outside the 99 % Clopper-Pearson interval; a
rate 30 % off (1.3 alpha or 0.7 alpha) is then detected with probability
>= 0.99 (computed exactly in :func:`test_per_bin_design_has_power` with the
trials divided by a design effect of 1.5: the intervals are computed from
run-level counts, since bins and channels of one record are not independent
trials; the measured design effect is <= 1.2). The false-failure probability of each interval
check is <= 1 %, six checks -> <= 6 % in the worst case before fixing the seed;
with the fixed seeds used here the outcome is deterministic.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import scipy.stats

from chatterspec.detection.spectral import STFTConfig
from chatterspec.errors import CalibrationMismatchError, ParameterError, ShapeError
from chatterspec.plants.models import eha_linear
from chatterspec.studies.calibration.result import load_calibration
from chatterspec.studies.calibration.thresholds import calibrate
from chatterspec.studies.detection_rates import false_alarm_study, power_study
from chatterspec.studies.intervals import (
    RateEstimate,
    clopper_pearson,
    cluster_clopper_pearson,
    quantile_ci_ranks,
)

RUNS_PER_BIN = 128
CONF = 0.99


def _power_30pc(n: float, alpha: float, conf: float = CONF) -> float:
    """P(alpha outside the package's CP interval) when the true rate is 1.3 or 0.7 alpha (min of the two).

    ``n`` may be an effective number of independent trials (design effect > 1).
    """
    out = []
    for p in (1.3 * alpha, 0.7 * alpha):
        mu, sd = n * p, math.sqrt(n * p)
        k = np.arange(max(int(mu - 8 * sd), 0), int(mu + 8 * sd))  # all but < 1e-12 of the binomial mass
        nn = round(n)
        reject = np.array(
            [not (lo <= alpha <= hi) for lo, hi in (clopper_pearson(int(x), nn, conf) for x in k)]
        )
        out.append(float(np.sum(scipy.stats.binom.pmf(k, nn, p) * reject)))
    return min(out)


@pytest.mark.parametrize("n, conf", [(40, 0.9), (200, 0.99)])
def test_clopper_pearson_exact_coverage(n, conf):
    """Oracle: the definition of a confidence interval, by exact enumeration of the binomial law.

    Clopper-Pearson is conservative: for every true p the probability that
    the interval covers p is >= conf (checked on a grid of p, exactly).
    """
    k = np.arange(n + 1)
    bounds = np.array([clopper_pearson(int(x), n, conf) for x in k])
    for p in np.linspace(0.005, 0.995, 67):
        cover = (bounds[:, 0] <= p) & (p <= bounds[:, 1])
        assert float(np.sum(scipy.stats.binom.pmf(k, n, p) * cover)) >= conf - 1e-12, p


def test_per_bin_design_has_power():
    """The per-bin tests below detect a 30 % error in the rate with probability >= 0.99.

    Computed with the package's interval at the smallest study's size, after
    dividing the trials by a design effect of 1.5 (the bins and channels of one
    record are not independent trials; the measured design effect of the
    pooled per-bin count is <= 1.2 on these scenarios, see test_far_design_effect).
    """
    n = RUNS_PER_BIN * 1999 * 2 / 1.5  # smallest study: two channels
    assert _power_30pc(n, 1e-3) >= 0.99
    assert _power_30pc(n, 1e-2) >= 0.99


@pytest.fixture(scope="module", params=["so-healthy-low", "so-healthy-high", "eha-healthy"])
def far(request):
    return false_alarm_study(
        request.param, alpha=(1e-2, 1e-3), runs=RUNS_PER_BIN, seed=2024, frames=False, progress=False
    )


@pytest.mark.parametrize("alpha", [1e-2, 1e-3])
def test_exact_per_bin_rate_matches_alpha(far, alpha):
    r = far.get("exact", alpha)
    assert r.per_bin.trials >= RUNS_PER_BIN * 1999 * 2
    assert r.per_bin.ci_low <= alpha <= r.per_bin.ci_high, r.per_bin
    assert r.verdict == "consistent"


def test_default_detector_family_wise_rate_within_alpha():
    """Family-wise (Bonferroni) rate <= alpha within its interval.

    alpha = 5 % so that ``runs * alpha`` is large enough to see an excess: with
    600 runs a channel whose true family-wise rate were 2 alpha (10 %) would
    have its 99 % CP lower end above alpha with probability 0.98 (exact binomial).
    """
    res = false_alarm_study("eha-healthy", alpha=0.05, runs=600, seed=7, frames=False, progress=False)
    r = res.get("exact-bonferroni")
    assert r.alpha_meaning == "family-wise"
    for est in r.family_wise:
        assert est.ci_low <= 0.05, est
    assert r.verdict == "within"


def test_stft_detector_per_frame_rate_within_alpha():
    """Per-frame rate of the STFT detector (Bonferroni over bins) <= alpha within its interval.

    200 runs x 16 frames = 3200 frames per channel at alpha = 5 %. Were the
    frames independent, a per-frame rate of 1.5 alpha would put the 99 % CP
    lower end above alpha with probability 0.999; adjacent frames share 80 %
    of their samples, and with the pessimistic 5x fewer (640) independent
    frames a rate of 2 alpha is still flagged with probability 0.99.
    """
    res = false_alarm_study("so-healthy-high", alpha=0.05, runs=200, seed=8, progress=False)
    r = res.get("frame-bonferroni")
    assert r.alpha_meaning == "per-frame"
    assert res.n_frames == 16
    for est in r.per_frame:
        assert est.ci_low <= 0.05, est
        assert est.rate > 0.01  # the detector is not vacuous
    assert r.verdict == "within"


@pytest.fixture(scope="module")
def cal():
    return calibrate("so-healthy-low", alpha=0.02, runs=400, seed=5, progress=False)


def test_empirical_agrees_with_exact(cal):
    """Analytic exact thresholds lie inside the empirical order-statistic intervals.

    Each per-bin interval has coverage >= 99 %, so over ~4000 bin/channel
    intervals the number of misses is binomial with p <= 1 %; we allow its
    99.9 % quantile. The family-wise quantile (max normalized bin) must cover
    the Sidak factor on every channel (each a 99 % interval).
    """
    ag = cal.agreement()
    assert ag["per_bin_agrees"], ag
    assert all(ag["family_wise_agrees"]), cal.family_wise
    assert 0.9 < ag["per_frame_median_ratio"] < 1.1


def test_calibration_roundtrip_and_threshold(cal, tmp_path):
    for name in ("cal.json", "cal.npz"):
        path = cal.save(tmp_path / name)
        back = load_calibration(path, cal_model(), n_samples=4000, config=STFTConfig())
        np.testing.assert_array_equal(back.per_bin, cal.per_bin)
        thr = back.threshold("family-wise")
        assert thr.kind == "empirical" and thr.alpha_meaning == "family-wise"
        assert thr.values.shape == cal.expected.shape
        assert back.frame_family_wise == cal.frame_family_wise
        fthr = back.threshold("frame-family-wise")
        assert fthr.kind == "empirical" and fthr.alpha_meaning == "per-frame"
        assert fthr.values.shape == cal.frame_expected.shape


def test_frame_family_wise_quantile_agrees_with_analytic(cal):
    """The empirical per-frame family-wise factor (max normalized bin of a frame) covers the analytic one.

    Each channel's order-statistic interval has >= 99 % coverage (pooled ranks over the
    non-overlapping frames, a conservative count for the overlapping ones); the analytic
    Bonferroni frame threshold over the tested bins is flat in S/E up to the exact-law
    correction at the lowest bins, so its median factor is the one to compare.
    """
    ft = cal.frame_tested
    analytic = float(np.median(cal.frame_analytic["frame-bonferroni"][ft] / cal.frame_expected[ft]))
    for q in cal.frame_family_wise:
        assert q.ci_low <= analytic <= q.ci_high, (q, analytic)


def test_monitor_uses_calibrated_frame_threshold(cal):
    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
    from chatterspec.plants.simulate import simulate

    thr = cal.threshold("frame-family-wise")
    mon = ChatteringMonitor(cal_model(), MonitorSettings(threshold=thr))
    assert mon.threshold is thr
    sim = simulate(__import__("chatterspec").scenario("so-healthy-low"), runs=1, seed=3)
    upd = mon.push(sim.z[0], sim.u)
    assert upd.frames.n_frames == 16
    with pytest.raises(ShapeError, match="STFT window"):
        ChatteringMonitor(cal_model(), MonitorSettings(stft=STFTConfig(window_s=0.5), threshold=thr))


def cal_model():
    from chatterspec.plants.scenarios import scenario

    return scenario("so-healthy-low").nominal


def test_calibration_from_other_model_refused(cal, tmp_path):
    path = cal.save(tmp_path / "cal.json")
    with pytest.raises(CalibrationMismatchError, match="fingerprint"):
        load_calibration(path, eha_linear())
    with pytest.raises(CalibrationMismatchError, match="N = 4000"):
        load_calibration(path, cal_model(), n_samples=2000)
    with pytest.raises(CalibrationMismatchError, match="STFT"):
        load_calibration(path, cal_model(), config=STFTConfig(window_s=0.5))


def test_far_uses_calibration(cal):
    res = false_alarm_study("so-healthy-low", alpha=0.02, runs=64, seed=99, calibration=cal, progress=False)
    assert "empirical-per-bin" in res.kinds and "empirical-per-frame" in res.kinds
    with pytest.raises(CalibrationMismatchError):
        false_alarm_study("eha-healthy", runs=1, calibration=cal, progress=False)


@pytest.mark.parametrize("alpha", [0.0, 1.0, -0.1, 1.5, float("nan")])
def test_bad_alpha(alpha):
    with pytest.raises(ParameterError, match="alpha"):
        false_alarm_study("so-healthy-low", alpha=alpha, runs=1)
    with pytest.raises(ParameterError, match="alpha"):
        calibrate("so-healthy-low", alpha=alpha, runs=1)


def test_bad_runs_and_unhealthy():
    with pytest.raises(ParameterError, match="runs"):
        calibrate("so-healthy-low", runs=0)
    with pytest.raises(ParameterError, match="healthy"):
        false_alarm_study("eha-leak-major", runs=1)


def test_clopper_pearson_and_quantile_ranks():
    lo, hi = clopper_pearson(0, 100, 0.95)
    assert lo == 0.0 and hi == pytest.approx(1 - 0.025 ** (1 / 100))
    point, lo, hi = quantile_ci_ranks(1000, 0.99, 0.99)
    assert point == 990 and lo < 990 < hi <= 1000


def test_power_grows_with_fault_size():
    res = power_study("leakage", sizes=[3e-11, 9e-11], noise=[10.0], runs=64, seed=3, progress=False)
    det = res.detection("exact-bonferroni")[0]
    assert det[0] <= 0.05  # healthy: false alarms only
    assert det[-1] >= det[1] and det[-1] > 0.9
    d = res.to_dict()
    assert d["points"][0]["healthy"] and "roc" in d


def test_power_counts_match_the_detector_run_directly():
    """Oracle for the power/ROC counts: the detector itself (detect_record) on the same realizations.

    Every ROC point is the fraction of records the single-record detector flags
    on the fault channel; recomputing it through chatterspec.detection.detect
    (another code path than the study's chunk function) must give the same
    count exactly, at two alphas of the ROC grid and at both fault sizes.
    """
    from chatterspec.detection.detect import detect_record
    from chatterspec.detection.pipeline import scenario_chattering
    from chatterspec.studies.detection_rates import power_scenario

    alphas = (1e-3, 0.05)
    res = power_study("leakage", sizes=[9e-11], noise=[10.0], runs=32, seed=3, alphas=alphas, progress=False)
    for j, size in enumerate(res.sizes):
        rec = scenario_chattering(power_scenario("leakage", size, 10.0), 32, 3)
        for a in alphas:
            rep = detect_record(rec, a, "exact", "bonferroni", stft=False)
            assert rep.detection_rate[res.channel] == res.detection("exact-bonferroni", a)[0, j], (size, a)
    far, dr = res.roc(0, 1)
    assert dr[-1] > far[-1]  # the fault is seen more often than the healthy record at alpha = 5 %


# ------------------------------------------------------------------------- false-alarm verdict intervals
def _ma_exceedances(
    datasets: int, records: int, bins: int, width: int, alpha: float, seed: int
) -> np.ndarray:
    """Bin exceedances with a known marginal rate ``alpha`` and correlated neighbours.

    x_b = (e_b + ... + e_{b+width-1}) / sqrt(width) is standard normal at every
    bin, so P(x_b > z_{1-alpha}) = alpha exactly; neighbouring bins share
    samples, like neighbouring periodogram bins of a finite record.
    """
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((datasets, records, bins + width - 1))
    c = np.cumsum(np.concatenate([np.zeros((datasets, records, 1)), e], axis=-1), axis=-1)
    x = (c[..., width:] - c[..., :-width]) / math.sqrt(width)
    return x > scipy.stats.norm.ppf(1 - alpha)


def test_cluster_interval_holds_its_level_on_correlated_bins():
    """A healthy detector (true rate = alpha) is called "above" at most (1 - conf) / 2 of the time.

    400 independent studies of 100 records x 200 correlated bins (true rate
    exactly 5 %). "above" means the 90 % interval's lower end exceeds alpha,
    which a valid interval does with probability <= 5 %; we allow the 99.9 %
    binomial quantile of 400 such trials (32). The bins-as-independent-trials
    Clopper-Pearson interval (the old one) fails this test: with a design
    effect of ~5 it calls "above" ~20 % of the time.
    """
    alpha, conf, datasets = 0.05, 0.9, 400
    exc = _ma_exceedances(datasets, 100, 200, 10, alpha, seed=11)
    per_record = exc.sum(axis=-1)  # (datasets, records)
    count, count_sq = per_record.sum(axis=-1), (per_record**2).sum(axis=-1)
    trials = 100 * 200
    allowed = scipy.stats.binom.ppf(0.999, datasets, (1 - conf) / 2)
    new = [RateEstimate(int(k), trials, conf, 100, float(q)) for k, q in zip(count, count_sq, strict=True)]
    old = [RateEstimate(int(k), trials, conf) for k in count]
    above_new = sum(r.ci_low > alpha for r in new)
    above_old = sum(r.ci_low > alpha for r in old)
    assert above_new <= allowed, above_new
    assert above_old > allowed, above_old  # the test is sensitive to the defect it guards against
    below_new = sum(r.ci_high < alpha for r in new)
    assert below_new <= allowed, below_new
    assert 3 < np.median([r.trials / r.effective_trials for r in new]) < 10  # the design effect is seen


def test_cluster_interval_reduces_to_clopper_pearson():
    # independent Bernoulli trials: the per-record counts have exactly the binomial variance
    rng = np.random.default_rng(5)
    per = rng.binomial(500, 0.02, size=400)
    lo, hi, n_eff = cluster_clopper_pearson(int(per.sum()), 400 * 500, 400, float((per**2).sum()), 0.99)
    lo0, hi0 = clopper_pearson(int(per.sum()), 400 * 500, 0.99)
    assert n_eff == pytest.approx(400 * 500, rel=0.2)  # sampling noise of s^2 over 400 records
    assert lo == pytest.approx(lo0, rel=0.02) and hi == pytest.approx(hi0, rel=0.02)
    assert cluster_clopper_pearson(0, 1000, 10, 0.0, 0.99)[:2] == clopper_pearson(0, 1000, 0.99)
    lo1, hi1, n1 = cluster_clopper_pearson(20, 1000, 1, 400.0, 0.99)  # one record: no variance estimate
    assert n1 == 1.0 and lo1 < 0.001 and hi1 > 0.5
    with pytest.raises(ParameterError):
        RateEstimate(3, 100, 0.9, clusters=10)


def test_healthy_far_verdict_not_above_too_often():
    """End to end over seeds: the exact per-bin detector of a healthy record is not called "above".

    40 seeds x 48 records of 0.5 s (a cheap second-order model, 249 tested bins
    x 2 channels); at confidence 0.9 a valid interval says "above" with
    probability <= 5 %; allowed: the 99.9 % binomial quantile of 40 trials (7).
    """
    from chatterspec.plants.scenarios import scenario
    from chatterspec.plants.simulate import model_scenario

    sc = model_scenario(scenario("so-healthy-low").nominal, duration=0.5)
    verdicts = [
        false_alarm_study(sc, alpha=0.05, runs=48, seed=s, frames=False, confidence=0.9, progress=False)
        .get("exact")
        .verdict
        for s in range(40)
    ]
    assert verdicts.count("above") <= scipy.stats.binom.ppf(0.999, 40, 0.05), verdicts
    assert verdicts.count("consistent") >= 30, verdicts


def test_far_design_effect():
    """The study reports run-level intervals: effective trials <= trials, and frames (80 % overlap)
    are worth clearly fewer independent trials than bins."""
    res = false_alarm_study("so-healthy-high", alpha=0.05, runs=64, seed=8, progress=False)
    pb = res.get("exact").per_bin
    fr = res.get("frame").per_bin
    assert pb.trials / pb.effective_trials < 1.3
    assert fr.trials / fr.effective_trials > 1.5
    assert res.get("exact").to_dict()["per_bin"]["effective_trials"] == pb.effective_trials


def test_incomplete_calibration_file_names_the_missing_entry(cal, tmp_path):
    import json

    from chatterspec.errors import DataFileError

    good = json.loads(cal.save(tmp_path / "c.json").read_text())
    for key, words in (("arrays", "threshold arrays"), ("scenario", "scenario name")):
        doc = {k: v for k, v in good.items() if k != key}
        path = tmp_path / f"no-{key}.json"
        path.write_text(json.dumps(doc))
        with pytest.raises(DataFileError, match=f"no {words}") as exc:
            load_calibration(path)
        assert "KeyError" not in str(exc.value)
    (tmp_path / "other.json").write_text('{"alpha": 0.01}')
    with pytest.raises(DataFileError, match="not a chatterspec calibration file"):
        load_calibration(tmp_path / "other.json")
    (tmp_path / "g.npz").write_bytes(b"garbage")
    with pytest.raises(DataFileError, match="cannot read calibration file"):
        load_calibration(tmp_path / "g.npz")


def test_roc_tick_labels_do_not_overlap():
    """A narrow false-alarm range (0.125-0.25, as 8 runs give) used to label the log axis's minor
    ticks, which overlapped; the drawn labels' boxes must be disjoint."""
    from chatterspec.figures.plot_studies import power_figure
    from chatterspec.studies.detection_rates import PowerResult

    alphas = np.array([1e-3, 1e-2, 0.1])
    counts = np.zeros((1, 3, 3, 3, 3), dtype=int)
    counts[0, 0, :, :, 2] = [1, 1, 2]  # healthy: 1/8 .. 2/8 false alarms
    counts[0, 1, :, :, 2] = [2, 4, 6]
    counts[0, 2, :, :, 2] = [6, 8, 8]
    res = PowerResult(
        family="leakage",
        sizes=(4.8e-12, 2e-11, 6e-11),
        noise=(1.0,),
        kinds=("paper", "exact", "exact-bonferroni"),
        alphas=alphas,
        alpha=1e-3,
        runs=8,
        seed=0,
        confidence=0.99,
        channel="pressure",
        channels=("position", "velocity", "pressure"),
        counts=counts,
        counts_any=counts.max(axis=-1),
    )
    fig = power_figure(res)
    fig.canvas.draw()
    ax = fig.axes[1]
    renderer = fig.canvas.get_renderer()
    lo, hi = ax.get_xlim()
    labels = [
        t
        for t in ax.get_xticklabels(minor=False) + ax.get_xticklabels(minor=True)
        if t.get_text() and t.get_visible() and lo <= t.get_position()[0] <= hi
    ]
    assert len(labels) >= 2
    boxes = sorted((t.get_window_extent(renderer) for t in labels), key=lambda b: b.x0)
    for a, b in itertools.pairwise(boxes):
        assert a.x1 <= b.x0, "ROC tick labels overlap"
    import matplotlib.pyplot as plt

    plt.close(fig)


@pytest.mark.slow
def test_far_eha_healthy_verdict_rate_over_seeds():
    """The reported case, `far eha-healthy --alpha 0.01`, over 20 seeds of 500 runs (~1 min).

    At confidence 0.9 a valid interval calls the exact per-bin detector
    "above" (or "below") with probability <= 5 % each; allowed: the 99.9 %
    binomial quantile of 20 trials (4). Same for the STFT per-bin kind
    ("frame"), whose overlapping frames have a design effect of ~2.
    """
    verdicts: dict[str, list[str]] = {"exact": [], "frame": []}
    for s in range(20):
        res = false_alarm_study(
            "eha-healthy", alpha=0.01, runs=500, seed=1000 + s, confidence=0.9, progress=False
        )
        for k in verdicts:
            verdicts[k].append(res.get(k).verdict)
    allowed = scipy.stats.binom.ppf(0.999, 20, 0.05)
    for k, v in verdicts.items():
        assert v.count("above") <= allowed and v.count("below") <= allowed, (k, v)
