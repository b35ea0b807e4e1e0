"""Thresholds from recorded healthy data (``calibrate --data``), against the simulated calibration.

The plant is a second-order system sampled at 100 Hz (two channels, 1 s / 0.2 s frames: the frame
count of the EHA per hour at a tenth of its samples), so hours of healthy data cost about a second.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main
from chatterspec.detection.alarms.calibration import BATCHES, MAX_RATE_PER_STEP, MIN_COUNT, starts_on_grid
from chatterspec.errors import ParameterError
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.online.recorded_calibration import calibrate_recorded
from chatterspec.online.simulated_stream import csv_header, csv_lines, simulate_blocks
from chatterspec.plants.modelfile import write_model_toml
from chatterspec.plants.models import second_order
from chatterspec.plants.simulate import model_scenario
from chatterspec.studies.alarm_budget import calibrate_alarm, frames_per_hour
from chatterspec.studies.calibration.recorded import HealthyRecording, array_chunks, min_hours
from chatterspec.studies.calibration.result import load_calibration
from chatterspec.studies.calibration.thresholds import calibrate

DT = 0.01
#: Hours of healthy data: above min_hours for two channels (3.45 h at one per day).
HOURS = 4.0
CONF = 0.99


def _model():
    return second_order(2.0, 0.1, dt=DT, Q=np.diag([1e-8, 1e-6]), R=np.diag([1e-6, 1e-4]))


def _healthy(model, hours: float, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    sc = model_scenario(model, duration=4.0)
    parts = list(simulate_blocks(sc, seed, hours * 3600.0, block_s=600.0))
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]


@pytest.fixture(scope="module")
def recorded():
    """The model, 4 h of its healthy data and their calibration (cusum at one per day, 99 % intervals)."""
    model = _model()
    t, z, u = _healthy(model, HOURS, seed=11)
    cal = calibrate_recorded(
        model,
        array_chunks(z, u, 6000),
        z.shape[0],
        rule="cusum",
        false_alarms_per_hour=1 / 24,
        alarm_confidence=CONF,
        recording=HealthyRecording("four-hours.npz", "0" * 64),
    )
    return model, t, z, u, cal


def _overlap(a: tuple[float, float], b: tuple[float, float]) -> bool:
    return a[0] <= b[1] and b[0] <= a[1]


def test_min_hours_is_the_fit_regime_or_a_count() -> None:
    # the extrapolating fit: e * MIN_COUNT starts at MAX_RATE_PER_STEP per channel frame in 7 of 8 batches
    keep = (BATCHES - 1) / BATCHES
    fit = math.e * MIN_COUNT / (keep * MAX_RATE_PER_STEP * 3 * 18000.0)
    assert min_hours(3, 18000.0, 1 / 24) == pytest.approx(fit)
    assert 2.2 < fit < 2.4  # the EHA: 3 channels, 5 frames per second
    # a budget frequent enough to count: MIN_COUNT starts in 7 of 8 batches
    assert min_hours(3, 18000.0, 100.0) == pytest.approx(MIN_COUNT / (keep * 100.0))


def test_thresholds_agree_with_the_simulated_calibration(recorded) -> None:
    model, _, _, _, cal = recorded
    sim = calibrate(model, alpha=cal.alpha, runs=1000, seed=3, confidence=CONF)
    # Two independent estimates of the same quantile, each interval covering it with probability >= 0.99:
    # the intervals overlap with probability >= 0.98 per channel (fixed seeds: deterministic here).
    for rec_q, sim_q in zip(cal.frame_family_wise, sim.frame_family_wise, strict=True):
        assert _overlap((rec_q.ci_low, rec_q.ci_high), (sim_q.ci_low, sim_q.ci_high)), (rec_q, sim_q)
    for rec_q, sim_q in zip(cal.family_wise, sim.family_wise, strict=True):
        assert _overlap((rec_q.ci_low, rec_q.ci_high), (sim_q.ci_low, sim_q.ci_high)), (rec_q, sim_q)
    assert cal.agreement()["per_bin_agrees"]  # the per-bin quantiles against the exact law (binomial bound)
    # the alarm threshold against the simulated one for the same score, both 99 % jackknife intervals
    settings = MonitorSettings(threshold=sim.threshold("frame-family-wise"))
    rc = calibrate_alarm(model, settings, "cusum", 1 / 24, hours=HOURS, seed=5, confidence=CONF)
    assert cal.alarm is not None and cal.alarm.method == rc.method == "extrapolated"
    assert _overlap(cal.alarm.threshold_interval, rc.threshold_interval), (cal.alarm, rc)
    assert cal.alarm.steps_per_hour == frames_per_hour(settings, DT)


def test_the_scores_are_the_monitors(recorded) -> None:
    # the monitor with the file's threshold computes the scores the alarm threshold was counted on:
    # starts on the calibration's grid of thresholds are identical
    model, _, z, u, cal = recorded
    mon = ChatteringMonitor(model, MonitorSettings(threshold=cal.threshold("frame-family-wise")))
    scores = np.concatenate(
        [mon.push(z[a : a + 7000], u[a : a + 7000]).frames.score for a in range(0, len(z), 7000)]
    )
    grid = np.asarray(cal.alarm.fit["h"])
    starts = starts_on_grid(cal.alarm.rule, scores[None], grid).reshape(grid.size, -1).sum(axis=1)
    assert starts.tolist() == list(cal.alarm.fit["starts"])


def test_provenance(recorded) -> None:
    _, t, z, _, cal = recorded
    s = cal.source
    assert s["data"] == "four-hours.npz" and s["sha256"] == "0" * 64
    assert s["samples"] == z.shape[0] and s["span_s"] == pytest.approx([t[0], t[-1]])
    assert (
        s["frames"] == (z.shape[0] - 1 - 100) // 20 + 1
        and cal.runs == s["records"] == (z.shape[0] - 1) // 400
    )
    assert cal.seed is None and cal.scenario == "recorded four-hours.npz"


def test_data_normalization_estimates_the_healthy_spectrum() -> None:
    model = _model()
    _, z, u = _healthy(model, 0.5, seed=2)
    cal = calibrate_recorded(model, array_chunks(z, u, 6000), z.shape[0], normalization="data")
    exact = calibrate_recorded(model, array_chunks(z, u, 6000), z.shape[0])
    ratio = (cal.frame_expected / exact.frame_expected)[cal.frame_tested]
    # each bin: the mean over 8996 frames of a chi2(2)/2-distributed power, at least as good as the mean
    # of its 1800 non-overlapping frames: relative standard error <= 1 / sqrt(1800) = 2.4 %;
    # 5 standard errors over 100 bins and channels
    assert np.all(np.abs(ratio - 1) < 5 / math.sqrt(1800)), (ratio.min(), ratio.max())
    assert cal.normalization == "empirical" and cal.normalization_info["frames"] == cal.source["frames"]


def test_a_budget_the_recording_cannot_support_is_refused_with_the_length() -> None:
    model = _model()
    _, z, u = _healthy(model, 0.5, seed=2)
    need = min_hours(2, 18000.0, 1 / 24)
    with pytest.raises(
        ParameterError,
        match=rf"needs at least {need:.3g} h of healthy data at the cusum rule.*you gave 0\.5 h",
    ):
        calibrate_recorded(model, array_chunks(z, u, 6000), z.shape[0], rule="cusum")
    with pytest.raises(ParameterError, match=r"needs at least 999 non-overlapping frames \(16\.6 min"):
        calibrate_recorded(model, array_chunks(z[:30000], u[:30000], 6000), 30000, alpha=1e-3)
    with pytest.raises(ParameterError, match=r"shorter than one record of 4 s; record at least 4\.01 s"):
        calibrate_recorded(model, array_chunks(z[:300], u[:300], 6000), 300)


def _write_npz(path: Path, model, t, z, u) -> None:
    cols = {"time": t, **{n: z[:, i] for i, n in enumerate(model.output_names)}}
    cols |= {n: u[:, i] for i, n in enumerate(model.input_names)}
    np.savez(path, **cols)


def test_calibration_file_round_trip_into_monitor_and_detect(recorded, tmp_path: Path, capsys) -> None:
    model, t, z, u, _ = recorded
    toml = write_model_toml(tmp_path / "so.toml", model, [0.01, 0.1])
    data = tmp_path / "healthy.npz"
    _write_npz(data, model, t, z, u)
    out = tmp_path / "cal.npz"
    argv = [
        "calibrate",
        str(toml),
        "--data",
        str(data),
        "--rule",
        "cusum",
        "--false-alarms-per-hour",
        "0.0417",
    ]
    assert main([*argv, "--out", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    cal = load_calibration(out, model)
    assert cal.source["sha256"] == hashlib.sha256(data.read_bytes()).hexdigest() == doc["source"]["sha256"]
    assert cal.source["data"] == "healthy.npz" and cal.alarm is not None
    # the monitor takes the file (its rule and threshold) on new data
    t2, z2, u2 = _healthy(model, 0.05, seed=99)
    fresh = tmp_path / "fresh.npz"
    _write_npz(fresh, model, t2, z2, u2)
    assert main(["monitor", str(toml), "--data", str(fresh), "--calibration", str(out), "--json"]) == 0
    mon = json.loads(capsys.readouterr().out)
    assert mon["alarm"]["rule"]["threshold"] == pytest.approx(cal.alarm.threshold)
    # detect --record takes it as a simulated file (record thresholds, the recording's alarm rule)
    rrd = tmp_path / "x.rrd"
    assert main(["detect", str(toml), "--calibration", str(out), "--record", str(rrd), "--json"]) == 0
    det = json.loads(capsys.readouterr().out)
    assert det["alarm"]["rule"]["threshold"] == pytest.approx(cal.alarm.threshold) and rrd.exists()


def test_standard_input(tmp_path: Path, capsys, monkeypatch) -> None:
    model = _model()
    toml = write_model_toml(tmp_path / "so.toml", model, [0.01, 0.1])
    t, z, u = _healthy(model, 180.0 / 3600.0, seed=4)
    text = (csv_header(model) + "\n" + csv_lines(t, z, u)).encode()
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(text)))
    assert main(["calibrate", str(toml), "--data", "-", "--json"]) == 0
    src = json.loads(capsys.readouterr().out)["source"]
    assert src["data"] == "standard input" and src["sha256"] == hashlib.sha256(text).hexdigest()
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(b"time,position\n0,1\n0.01,2\n")))
    assert main(["calibrate", str(toml), "--data", "-"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "standard input: missing column(s) ['velocity', 'u']" in err, err


@pytest.mark.parametrize(
    ("extra", "named"),
    [
        (["--runs", "10"], "--runs cannot be used with --data"),
        (["--alarm-hours", "3"], "--alarm-hours cannot be used with --data"),
        (["--rule", "cusum"], "needs at least 3.45 h of healthy data at the cusum rule"),
    ],
)
def test_cli_refusals(extra: list[str], named: str, tmp_path: Path, capsys) -> None:
    model = _model()
    toml = write_model_toml(tmp_path / "so.toml", model, [0.01, 0.1])
    t, z, u = _healthy(model, 180.0 / 3600.0, seed=4)
    data = tmp_path / "h.npz"
    _write_npz(data, model, t, z, u)
    assert main(["calibrate", str(toml), "--data", str(data), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and named in err, err
    assert main(["calibrate", str(toml), "--normalization", "data"]) == 2
    assert "--normalization applies to --data" in capsys.readouterr().err
