"""Detection verdicts, severity and STFT intervals (chatterspec.detection.detect)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.stats

from chatterspec.detection.detect import (
    ChannelVerdict,
    detect_frames,
    detect_record,
    detect_spectrum,
    frame_intervals,
    stft_detect,
)
from chatterspec.detection.pipeline import ChatteringRecord, scenario_chattering
from chatterspec.detection.spectral import STFTConfig, expected_spectrum, periodogram, spectrogram
from chatterspec.detection.thresholds import exact_threshold, frame_threshold, paper_threshold
from chatterspec.errors import ParameterError, ShapeError
from chatterspec.plants.scenarios import scenario

RUNS = 4  # a handful of realizations per fault scenario keeps the file fast


def _report(name: str, runs: int = RUNS, seed: int = 1, **kw):
    return detect_record(scenario_chattering(scenario(name), runs, seed=seed), **kw)


def _channel(rep, name: str) -> int:
    return rep.channels.index(name)


FAULTS = [
    "so-f9-low", "so-f11-low", "so-f12-low", "so-f15-low",
    "so-f9-high", "so-f11-high", "so-f12-high", "so-f15-high",
    "eha-leak-minor", "eha-leak-medium", "eha-leak-major",
    "eha-friction-minor", "eha-friction-major",
    "eha-bulk-50down", "eha-bulk-25down", "eha-bulk-25up", "eha-bulk-50up",
]  # fmt: skip


@pytest.mark.parametrize("name", FAULTS)
def test_default_detector_finds_every_fault_on_its_channel(name):
    """Exact + Bonferroni at family-wise 0.1 %: every one of 4 runs flagged on the fault's channel.

    Observed (seeds 1..4): detection rate 4/4 for every scenario; the weakest are so-f11-high and
    eha-leak-minor, whose smallest single-run peak ratios over 20 runs were 2.9 and 2.6.
    """
    rep = _report(name)
    sc = scenario(name)
    i = _channel(rep, sc.fault_channel)
    assert rep.per_run.detected[:, i].all(), rep.per_run.peak_ratio[:, i]
    assert rep.detected and rep.averaged is not None and rep.averaged.detected[i]
    if name.startswith("so-f"):
        # the most significant bin sits near the true natural frequency (0.25 Hz grid, one or two
        # bins), and so does the averaged spectrum's largest excess power
        f_true = float(name.split("-")[1][1:])
        assert np.all(np.abs(rep.per_run.most_significant_hz[:, i] - f_true) <= 1.0)
        assert abs(rep.averaged.peak_hz[i] - f_true) <= 1.0
        # position chattering does not see a change of f0 (paper, after eq 63)
        assert not rep.per_run.detected[:, _channel(rep, "position")].any()


@pytest.mark.parametrize("name", ["so-healthy-low", "so-healthy-high", "eha-healthy"])
def test_default_detector_quiet_on_healthy_records(name):
    """200 healthy runs: number of flagged (run, channel) pairs consistent with <= alpha per channel.

    One-sided binomial test of H0: p <= 1e-3 over 200 x m families (fails only with prob. < 1 %).
    """
    rep = _report(name, runs=200, seed=99)
    k, n = int(rep.per_run.detected.sum()), rep.per_run.detected.size
    assert scipy.stats.binomtest(k, n, 1e-3, alternative="greater").pvalue > 0.01
    assert not rep.averaged.detected.any()  # the averaged spectrum (K = 200) is not flagged either
    assert np.all(np.abs(rep.per_run.excess_power) < 0.2)  # ~ N(0, 1/sqrt(1999)) per record


def _mean_severity(name: str, channel: str, runs: int = RUNS) -> tuple[float, float]:
    rep = _report(name, runs=runs, seed=5)
    i = _channel(rep, channel)
    return float(rep.per_run.peak_ratio[:, i].mean()), float(rep.per_run.excess_power[:, i].mean())


@pytest.mark.parametrize(
    ("family", "channel"),
    [
        (["eha-leak-minor", "eha-leak-medium", "eha-leak-major"], "pressure"),
        (["eha-friction-minor", "eha-friction-major"], "velocity"),
        (["eha-bulk-25down", "eha-bulk-50down"], "pressure"),
        (["eha-bulk-25up", "eha-bulk-50up"], "pressure"),
        (["so-f11-low", "so-f12-low", "so-f15-low"], "velocity"),
        (["so-f11-high", "so-f12-high", "so-f15-high"], "velocity"),
    ],
)
def test_severity_grows_with_fault_size(family, channel):
    """Mean (over 4 runs) peak_ratio and excess_power increase with the fault size within a family."""
    scores = np.array([_mean_severity(name, channel) for name in family])
    assert np.all(np.diff(scores[:, 0]) > 0), f"peak ratio {scores[:, 0]}"
    assert np.all(np.diff(scores[:, 1]) > 0), f"excess power {scores[:, 1]}"


def test_paper_threshold_misses_f11_at_high_noise_while_default_detects():
    """Fig 5b: at high noise the 11 Hz peak stays below the paper's flat threshold.

    The default detector (exact + Bonferroni) finds it in every run.
    """
    rec = scenario_chattering(scenario("so-f11-high"), 6, seed=3)
    pg = periodogram(rec.values, rec.dt)
    paper = paper_threshold(rec.model, pg.freqs_hz, 1e-3)
    band = (pg.freqs_hz >= 10.0) & (pg.freqs_hz <= 12.0)
    v = 1  # velocity
    assert np.all(pg.power[:, band, v].max(axis=1) < paper.values[band, v].min())
    default = detect_record(rec)
    assert default.per_run.detected[:, v].all()
    assert np.all(np.abs(default.per_run.most_significant_hz[:, v] - 11.0) <= 1.0)


def test_detect_spectrum_vectorized_and_verdicts():
    rec = scenario_chattering(scenario("so-f12-low"), 3, seed=2)
    pg = periodogram(rec.values, rec.dt)
    th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples)
    det = detect_spectrum(pg.power, th, channels=rec.channels)
    assert det.detected.shape == det.peak_ratio.shape == (3, 2)
    # each run equals its own single-spectrum call
    single = detect_spectrum(pg.power[1], th, channels=rec.channels)
    np.testing.assert_allclose(single.peak_ratio, det.peak_ratio[1])
    v = det.verdicts(1)
    assert all(isinstance(c, ChannelVerdict) for c in v)
    assert v[1].channel == "velocity" and v[1].detected and v[1].alpha_meaning == "family-wise"
    assert v[1].dc_ratio > 1  # a step input puts a large DC term into any mismatch; not used for the verdict
    np.testing.assert_allclose(det.detection_rate, [0.0, 1.0])
    # paper threshold has no expectation: excess_power needs it explicitly
    paper = paper_threshold(rec.model, pg.freqs_hz, 1e-3)
    with pytest.raises(ParameterError, match="expected"):
        detect_spectrum(pg.power, paper)
    E = expected_spectrum(rec.model, pg.freqs_hz, pg.n_samples)
    assert detect_spectrum(pg.power, paper, E).detected.shape == (3, 2)


def test_report_to_dict_is_json_ready():
    rep = _report("so-f15-high", runs=1, seed=4)
    d = json.loads(json.dumps(rep.to_dict()))
    assert d["detected"] is True and d["runs"] == 1 and d["averaged"] is False
    assert [c["channel"] for c in d["channels"]] == ["position", "velocity"]
    assert set(d["channels"][1]) >= {"channel", "detected", "peak_hz", "peak_ratio", "excess_power"}
    assert "intervals" not in d  # single-segment scenario
    multi = json.loads(json.dumps(_report("eha-leak-major", runs=3).to_dict()))
    assert multi["averaged"] is True and multi["channels"][2]["detection_rate"] == 1.0
    paper = _report("so-healthy-low", runs=1, threshold="paper").to_dict()
    assert paper["threshold"]["kind"] == "paper" and paper["threshold"]["alpha_meaning"] == "per-bin"


# -- STFT --------------------------------------------------------------------------------
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_timeline_constant_gives_two_intervals(seed):
    """so-timeline-constant: intervals near [0, 2] s and [4, 6] s on the velocity channel.

    Allowed error: one hop plus half a window (0.7 s), the resolution of 1 s frames at 0.2 s hops.
    Observed: (0.001, 2.40) and (3.60, 6.20) s (strong faults flag every frame that overlaps them).
    """
    rep = _report("so-timeline-constant", runs=1, seed=seed)
    ivs = rep.frames.intervals["velocity"]
    assert len(ivs) == 2
    for (on, off), (t_on, t_off) in zip(ivs, [(0.0, 2.0), (4.0, 6.0)], strict=True):
        assert abs(on - t_on) <= 0.7 and abs(off - t_off) <= 0.7
    assert rep.frames.intervals["position"] == []
    d = rep.to_dict()
    assert {"channel": "velocity", "onset_s": ivs[1][0], "offset_s": ivs[1][1]} in d["intervals"]


def test_timeline_step_damping_mismatch_visible_after_step():
    """so-timeline-step: the step at 5 s excites the damping mismatch (zeta 0.1 on [4, 6)): frames flagged."""
    rec = scenario_chattering(scenario("so-timeline-step"), 3, seed=8)
    fd = stft_detect(rec.values, rec.model, t0=float(rec.t[0]))
    times = fd.spectrogram.times_s
    after = (times > 5.0) & (times < 6.0)
    assert fd.flags[:, after, 1].all()
    # and the mismatch is gone once the true plant is nominal again (frames entirely after 6 s)
    assert not fd.flags[:, times - 0.5 > 6.2, 1].any()


def test_detect_frames_matches_manual_comparison():
    rec = scenario_chattering(scenario("so-healthy-high"), 2, seed=1)
    cfg = STFTConfig()
    sg = spectrogram(rec.values, rec.dt, cfg)
    th = frame_threshold(rec.model, sg.freqs_hz, cfg, rec.dt, 0.5)
    flags = detect_frames(sg, th)
    manual = (sg.power[..., 1:-1, :] > th.values[1:-1]).any(axis=-2)
    np.testing.assert_array_equal(flags, manual)


def test_frame_intervals_estimator():
    cfg = STFTConfig()
    dt = 1e-3
    times = (np.arange(10) * 200 + 499.5) * dt
    flags = np.array([0, 0, 1, 1, 1, 0, 0, 1, 1, 1], dtype=bool)
    ivs = frame_intervals(flags, times, cfg, dt)
    # interior run: half a hop before the first / after the last flagged centre
    assert ivs[0] == pytest.approx((times[2] - 0.1, times[4] + 0.1))
    # run touching the end of the record: offset at the end of the last frame's window
    assert ivs[1] == pytest.approx((times[7] - 0.1, 1.8 + 1.0))
    assert frame_intervals(np.zeros(10, bool), times, cfg, dt) == []
    # run touching the start: onset at the first frame's first sample
    assert frame_intervals(np.ones(3, bool), times[:3], cfg, dt)[0][0] == pytest.approx(0.0)
    with pytest.raises(ShapeError):
        frame_intervals(np.ones((2, 10), bool), times, cfg, dt)


def test_bad_input_errors():
    rec = scenario_chattering(scenario("so-healthy-low"), 1, seed=0)
    short = ChatteringRecord(t=rec.t[:500], values=rec.values[:, :500], model=rec.model)
    with pytest.raises(ShapeError, match="shorter than one STFT window"):
        detect_record(short, stft=True)
    with pytest.raises(ShapeError, match="shorter than one STFT window"):
        stft_detect(short.values, rec.model)
    for bad in (0.0, 1.0, 2.0, -1e-3):
        with pytest.raises(ParameterError, match=r"\(0, 1\)"):
            detect_record(rec, alpha=bad)
    with pytest.raises(ParameterError, match="unknown threshold kind"):
        detect_record(rec, threshold="median")
    pg = periodogram(rec.values, rec.dt)
    th = exact_threshold(rec.model, pg.freqs_hz, pg.n_samples)
    with pytest.raises(ShapeError):
        detect_spectrum(pg.power[:, :-1], th)
    with pytest.raises(ShapeError):
        detect_spectrum(pg.power, th, expected=np.ones((3, 2)))
    with pytest.raises(ShapeError, match="channels"):
        detect_spectrum(pg.power, th, channels=["a"])
