"""The alarm layer inside the online monitor, its budgets, the CLI options and calibration files."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main as cli_main
from chatterspec.detection.alarms.calibration import RuleCalibration, poisson_count_interval
from chatterspec.detection.alarms.rules import CusumRule, FrameRule, PersistenceRule
from chatterspec.detection.alarms.streams import run_rule
from chatterspec.detection.pipeline import chattering_record
from chatterspec.detection.spectral import chattering_autocovariance, frame_columns
from chatterspec.detection.verdicts import FrameScore
from chatterspec.errors import CalibrationMismatchError, ParameterError
from chatterspec.jsonout import rounded
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.online.simulated_stream import simulate_blocks
from chatterspec.plants.scenarios import scenario
from chatterspec.plants.simulate import simulate
from chatterspec.studies.alarm_budget import alarm_settings, calibrate_alarm, healthy_chattering

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MODEL = EXAMPLES / "eha_model.toml"
DATA = EXAMPLES / "eha_data.csv"


@pytest.fixture(scope="module")
def onset():
    """eha4-like onset on the linear EHA: 3 s healthy, then the major leakage (one realization)."""
    from chatterspec.studies.alarm_budget import onset_scenarios

    sc = onset_scenarios("eha-leak-medium", healthy_s=3.0, fault_s=3.0, phases=(1.0,))[0]
    return simulate(sc, runs=1, seed=3)


def _events(mon: ChatteringMonitor, sim, sizes) -> list[tuple]:
    out = []
    lo = 0
    for k in sizes:
        for e in mon.push(sim.z[0, lo : lo + k], sim.u[lo : lo + k]).events:
            out.append((e.kind, e.channel, e.frame, e.rule, round(e.score, 9), e.statistic))
        lo += k
    assert lo >= sim.z.shape[1]
    return out


def test_monitor_alarms_equal_the_layer_on_batch_scores_in_any_chunking(onset):
    sim = onset
    model = sim.scenario.nominal
    rule = CusumRule(8.0, drift=3.0)
    settings = MonitorSettings(rule=rule)
    rec = chattering_record(model, sim.z, sim.u)
    _, P = frame_columns(rec.values[0], model.dt, settings.stft)
    mon = ChatteringMonitor(model, settings)
    scores = FrameScore(mon.threshold)(P)
    blk = run_rule(rule, scores)
    want = [
        (
            "fault-start" if e.kind == "alarm-start" else "fault-end",
            model.output_names[e.channel],
            e.step,
            "cusum",
            round(float(scores[e.step, e.channel]), 9),
            float(blk.statistic[e.step, e.channel]),
        )
        for e in blk.events()
    ]
    assert want and want[0][0] == "fault-start" and want[0][1] == "pressure"
    T = sim.z.shape[1]
    for sizes in ([T], [1000] * (T // 1000 + 1), [1, 7, 199, 3000, T]):
        assert _events(ChatteringMonitor(model, settings), sim, sizes) == want
    upd = ChatteringMonitor(model, settings).push(sim.z[0], sim.u)
    np.testing.assert_array_equal(upd.frames.score, scores)
    np.testing.assert_array_equal(upd.frames.alarm, blk.active)
    np.testing.assert_array_equal(upd.frames.alarm_statistic, blk.statistic)


def test_frame_rule_at_minus_log_alpha_is_the_per_frame_rule(onset):
    model = onset.scenario.nominal
    legacy = _events(ChatteringMonitor(model, MonitorSettings(alpha=1e-3)), onset, [onset.z.shape[1]])
    rule = FrameRule(-math.log(1e-3))
    new = _events(ChatteringMonitor(model, MonitorSettings(rule=rule)), onset, [onset.z.shape[1]])
    assert [e[:3] for e in legacy] == [e[:3] for e in new] and legacy


def test_alpha_only_events_report_the_per_frame_threshold(onset):
    """Without a rule (the API default) the events come from the per-frame verdict at ``alpha``; they and
    the monitor report its threshold on the score ``-ln p`` (nats): ``h = -ln(alpha)``, the level at
    which the flags are exactly the frames with ``score >= h`` (frame_score; up to 1e-10 relative)."""
    model = onset.scenario.nominal
    alpha = 1e-3
    mon = ChatteringMonitor(model, MonitorSettings(alpha=alpha))
    upd = mon.push(onset.z[0], onset.u)
    h = -math.log(alpha)
    assert mon.rule.threshold == pytest.approx(h, rel=1e-15)
    assert upd.events and all(e.threshold == mon.rule.threshold for e in upd.events)
    score, flags = upd.frames.score, upd.frames.flags
    clear = ~np.isclose(score, h, rtol=1e-10, atol=0.0)
    np.testing.assert_array_equal(flags[clear], score[clear] >= h)
    # frames between -log10(alpha) and -ln(alpha) are there and unflagged: the threshold is in nats
    between = (score > -math.log10(alpha)) & (score < h)
    assert between.any() and not flags[between].any()


def test_paths_give_the_same_alarms(onset, monkeypatch):
    model = onset.scenario.nominal
    settings = MonitorSettings(rule=PersistenceRule(5.0, k=2, n=4), psi=(4.2e-3, 4.8e-3, 4.3e3))
    T = onset.z.shape[1]
    a = _events(ChatteringMonitor(model, settings), onset, [700] * (T // 700 + 1))
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    b = _events(ChatteringMonitor(model, settings), onset, [700] * (T // 700 + 1))
    assert [e[:4] for e in a] == [e[:4] for e in b] and a
    np.testing.assert_allclose([e[4] for e in a], [e[4] for e in b], rtol=1e-12)


def test_events_carry_rule_and_budget(onset):
    model = onset.scenario.nominal
    cal = calibrate_alarm(model, MonitorSettings(), "frame", 2.0)
    s = alarm_settings(model, MonitorSettings(), calibration=cal)
    assert s.alpha == pytest.approx(math.exp(-cal.threshold))  # the drawn verdict is the rule's
    ev = ChatteringMonitor(model, s).push(onset.z[0], onset.u).events[0]
    d = ev.to_dict()
    assert d["rule"] == "frame" and d["false_alarms_per_hour"] == 2.0 and d["threshold"] == cal.threshold
    assert d["score"] >= cal.threshold and "[frame rule, 2 false alarms per hour]" in ev.describe()
    with pytest.raises(ParameterError, match="budget was calibrated for"):
        MonitorSettings(rule=CusumRule(3.0), budget=cal)
    # the API refuses a calibration for another rule or budget, as the CLI does (CalibrationMismatchError)
    with pytest.raises(CalibrationMismatchError, match="calibrated for the frame rule; got --rule cusum"):
        alarm_settings(model, MonitorSettings(), "cusum", calibration=cal)
    with pytest.raises(CalibrationMismatchError, match="calibrated for 2 false alarms per hour"):
        alarm_settings(model, MonitorSettings(), false_alarms_per_hour=1.0, calibration=cal)


def test_healthy_chattering_has_the_ma1_law():
    """Lag-0 and lag-1 covariances of the generated chattering, across a block boundary.

    Tolerance: 5 standard errors of the sample (co)variance of an MA(1) Gaussian series
    (var of the lag-0 mean ~ 2 (g0^2 + 2 g1^2) / n, lag-1 ~ (g0^2 + 3 g1^2) / n, n effective).
    """
    model = scenario("eha-healthy").nominal
    n = 1_250_000  # 2 blocks + a part: 600 000 samples per block
    e = np.concatenate(list(healthy_chattering(model, n, 4)))
    assert e.shape == (n, 3)
    g0, g1 = chattering_autocovariance(model)
    c0 = np.mean(e * e, axis=0)
    c1 = np.mean(e[1:] * e[:-1], axis=0)
    se0 = np.sqrt(2 * (g0**2 + 2 * g1**2) / n)
    se1 = np.sqrt((g0**2 + 3 * g1**2) / n)
    assert np.all(np.abs(c0 - g0) < 5 * se0), (c0, g0)
    assert np.all(np.abs(c1 - g1) < 5 * se1), (c1, g1)
    # the boundary sample continues the noise: lag-1 products there behave like any other
    assert np.array_equal(np.concatenate(list(healthy_chattering(model, n, 4))), e)


def test_budget_through_the_monitor_one_hour():
    """One hour of healthy linear-EHA data (1 kHz, 3 channels) through one monitor per rule at a
    budget of 60 false alarms per hour (the 7-day, 1-per-day version: benchmarks/bench_alarms.py).

    Tolerances: the frame rule's law threshold is an upper bound (starts <= exceedances, P(score >= h)
    <= e^-h), so its count must not exceed the 99 % Poisson quantile of the budget; the simulated
    rules must lie in the two-sided 99 % Poisson interval of a mean anywhere inside the calibration's
    95 % rate interval (the threshold's own uncertainty from its 4 h of other healthy streams).
    """
    sc = scenario("eha-healthy")
    model = sc.nominal
    X = 60.0
    mons = {}
    cals = {}
    for r in ("frame", "persistence", "cusum"):
        cals[r] = calibrate_alarm(model, MonitorSettings(), r, X, hours=4.0, seed=99)
        mons[r] = ChatteringMonitor(model, alarm_settings(model, MonitorSettings(), calibration=cals[r]))
    starts = dict.fromkeys(mons, 0)
    for _, z, u in simulate_blocks(sc, 2024, 3600.0, block_s=300.0):
        for r, mon in mons.items():
            starts[r] += sum(e.kind == "fault-start" for e in mon.push(z, u).events)
    assert cals["frame"].method == "law"
    assert starts["frame"] <= poisson_count_interval(X, 0.99)[1], starts
    for r in ("persistence", "cusum"):
        lo = poisson_count_interval(cals[r].rate_interval[0], 0.99)[0]
        hi = poisson_count_interval(cals[r].rate_interval[1], 0.99)[1]
        assert lo <= starts[r] <= hi, (r, starts[r], cals[r].rate_interval)


def test_alarm_settings_cache_and_methods():
    model = scenario("eha-healthy").nominal
    a = calibrate_alarm(model, MonitorSettings(), "cusum", 1.0)
    assert calibrate_alarm(model, MonitorSettings(), "cusum", 1.0, hours=4.0) is a  # cached; 12 / 3 channels
    assert calibrate_alarm(model, MonitorSettings(), "cusum", 1.0, seed=np.int64(0)) is a  # same seed, cached
    assert a.method in ("counted", "extrapolated") and a.hours == pytest.approx(4.0, rel=1e-3)
    s = alarm_settings(model, MonitorSettings(), "cusum", 1.0)
    assert s.rule == a.rule and s.budget is a and s.alpha == 1e-3
    assert RuleCalibration.from_dict(json.loads(json.dumps(a.to_dict()))) == a


def test_healthy_scores_take_the_numpy_frames_without_the_compiled_path(monkeypatch):
    """Without numba (or with CHATTERSPEC_JIT=0) the frames are cut by the numpy form, never by the
    compiled loops run as Python (20x the CPU of the whole in-call calibration); same bits."""
    from chatterspec import _jit
    from chatterspec.detection import spectral
    from chatterspec.studies.alarm_budget import healthy_frame_scores

    model = scenario("eha-healthy").nominal
    compiled = healthy_frame_scores(model, MonitorSettings(), 0.02) if _jit.enabled() else None

    def forbid(*_a):
        raise AssertionError("a compiled frame loop ran on the numpy path")

    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    monkeypatch.setattr(spectral, "_taper_kernel", forbid)
    monkeypatch.setattr(spectral, "_power_kernel", forbid)
    numpy_scores = healthy_frame_scores(model, MonitorSettings(), 0.02)
    assert numpy_scores.shape == (1, 356, 3)  # 72 s at a 0.2 s hop, 1 s window: (72 - 1) / 0.2 + 1
    if compiled is not None:
        assert np.array_equal(compiled, numpy_scores)


# --------------------------------------------------------------------------- CLI
def _run(capsys, *argv: str) -> tuple[int, str, str]:
    rc = cli_main(list(argv))
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--rule", "cusum", "--alpha", "0.001"], "--alpha sets the per-frame level"),
        (["--alpha", "0.001", "--false-alarms-per-hour", "1"], "give one of them"),
        (["--false-alarms-per-hour", "0"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "inf"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "nan"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "-2"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "lots"], "--false-alarms-per-hour must be a number"),
        (
            ["--rule", "persistence", "--persistence-k", "6", "--persistence-n", "5"],
            "--persistence-k, --persistence-n: persistence k must be <= n",
        ),
        (["--rule", "persistence", "--persistence-k", "0"], "--persistence-k must be an integer >= 1"),
        (["--persistence-k", "2"], "apply to --rule persistence"),
        (["--rule", "frame", "--cusum-drift", "2"], "--cusum-drift applies to --rule cusum"),
        (["--cusum-drift", "0"], "--cusum-drift must be positive"),
        (["--alarm-hours", "0"], "--alarm-hours must be positive"),
    ],
)
def test_cli_bad_alarm_options(capsys, extra, needle):
    rc, out, err = _run(capsys, "monitor", str(MODEL), "--data", str(DATA), *extra)
    assert rc == 2 and needle in err, err
    assert len(err.strip().splitlines()) == 1 and out == ""


def test_cli_monitor_reports_rule_and_budget(capsys):
    rc, out, err = _run(capsys, "monitor", str(MODEL), "--data", str(DATA), "--json")
    assert rc == 0
    doc = json.loads(out)
    assert doc["alarm"]["rule"]["rule"] == "cusum" and doc["alarm"]["false_alarms_per_hour"] == pytest.approx(
        1 / 24
    )
    assert doc["alarm"]["calibration"]["method"] == "extrapolated"
    assert doc["events"] and all(e["rule"] == "cusum" for e in doc["events"])
    assert "alarms: cusum rule" in err
    rc, out, err = _run(capsys, "monitor", str(MODEL), "--data", str(DATA), "--events", "jsonl")
    first = json.loads(out.splitlines()[0])
    assert first["rule"] == "cusum" and first["false_alarms_per_hour"] == pytest.approx(1 / 24)
    assert "[cusum rule, 1 false alarm per 24 h]" in err
    rc, out, err = _run(capsys, "monitor", str(MODEL), "--data", str(DATA), "--alpha", "0.001")
    assert rc == 0 and "fault start(s) [frame rule, per-frame alpha 0.001]" in out


def test_calibration_file_records_the_rule_and_is_refused_for_another(tmp_path: Path, capsys):
    cal = tmp_path / "cal.npz"
    rc, out, err = _run(
        capsys, "calibrate", str(MODEL), "--runs", "99", "--no-progress", "--rule", "persistence",
        "--persistence-k", "2", "--persistence-n", "4", "--false-alarms-per-hour", "60", "--alarm-hours", "1",
        "--out", str(cal),
    )  # fmt: skip
    assert rc == 0, err
    assert "alarm rule for the monitor: persistence rule" in out
    from chatterspec.studies.calibration.result import load_calibration

    c = load_calibration(cal)
    assert c.alarm.rule == PersistenceRule(c.alarm.threshold, k=2, n=4)
    assert c.alarm.false_alarms_per_hour == 60.0 and c.alarm.steps_per_hour == pytest.approx(18000.0)
    assert c.alarm.method == "counted"
    base = ["monitor", str(MODEL), "--data", str(DATA), "--calibration", str(cal)]
    for extra, needle in (
        (["--rule", "cusum"], "was calibrated for the persistence rule; got --rule cusum"),
        (["--false-alarms-per-hour", "1"], "was calibrated for 60 false alarms per hour"),
        (["--persistence-n", "5"], "with n = 4; got 5"),
    ):
        rc, out, err = _run(capsys, *base, *extra)
        assert rc == 2 and needle in err and len(err.strip().splitlines()) <= 2, err
    rc, out, err = _run(capsys, *base, "--json")
    assert rc == 0
    doc = json.loads(out)
    # --json rounds floats to 12 significant digits (chatterspec.jsonout): the threshold as printed
    assert doc["alarm"]["rule"] == rounded(c.alarm.rule.to_dict())
    assert doc["alarm"]["calibration"]["hours"] == pytest.approx(1.0, rel=1e-3)


def test_detect_record_computes_the_frame_threshold_once(tmp_path: Path, capsys, monkeypatch):
    """``detect --record`` with a CUSUM budget computes the monitor's per-frame threshold once: the alarm
    calibration (its healthy frame scores) and the recorded monitor share it (an empty calibration cache,
    so the healthy scores are simulated; the batch verdict's per-bin threshold is another function)."""
    import chatterspec.detection.thresholds as thresholds
    import chatterspec.studies.alarm_budget as alarm_budget

    monkeypatch.setenv("CHATTERSPEC_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(alarm_budget, "_CACHE", {})
    calls = []
    frame_threshold = thresholds.frame_threshold

    def counted(*args, **kwargs):
        calls.append(args[4:6])  # (alpha, correction)
        return frame_threshold(*args, **kwargs)

    monkeypatch.setattr(thresholds, "frame_threshold", counted)
    rrd = str(tmp_path / "d.rrd")
    rc, out, err = _run(
        capsys, "detect", "eha-healthy", "--record", rrd, "--json", "--rule", "cusum",
        "--false-alarms-per-hour", "200", "--alarm-hours", "0.25",
    )  # fmt: skip
    assert rc == 0, err
    assert "calibrating the cusum alarm threshold" in err  # not read back from a cache
    assert json.loads(out)["alarm"]["rule"]["rule"] == "cusum"
    assert calls == [(1e-3, "bonferroni")]


def test_detect_record_takes_the_alarm_options(tmp_path: Path, capsys):
    rrd = tmp_path / "d.rrd"
    rc, out, err = _run(
        capsys, "detect", "eha-leak-major", "--record", str(rrd), "--json", "--rule", "frame",
        "--false-alarms-per-hour", "1",
    )  # fmt: skip
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["alarm"]["method"] == "law" and doc["alarm"]["rule"]["rule"] == "frame"
    ev = doc["recording"]["events"]
    assert ev and ev[0]["rule"] == "frame" and ev[0]["false_alarms_per_hour"] == 1.0
    with pytest.raises(SystemExit) as exc:  # argparse's choices: usage and the valid names, exit 2
        cli_main(["detect", "eha-leak-major", "--record", str(rrd), "--rule", "banana"])
    assert exc.value.code == 2 and "choose from 'frame', 'persistence', 'cusum'" in capsys.readouterr().err


def test_onset_scenarios_and_delays():
    """Onset scenarios start healthy; the CUSUM at its one-per-day EHA threshold (about 21 nats)
    raises the major leakage within 0.5 s of the onset (the target; benchmarks/bench_alarms.py
    measures it on 200 runs), the per-frame rule at 0.1 % alarms in the healthy stretch."""
    from chatterspec.studies.alarm_budget import alarm_delays, onset_scenarios

    scs = onset_scenarios("eha-leak-major", healthy_s=4.0, fault_s=2.0, phases=(0.0, 3.0))
    assert [sc.fault_intervals for sc in scs] == [((4.0, 6.0),)] * 2
    assert scs[1].input.sample([4.0])[0] == pytest.approx(scenario("eha-leak-major").input.sample([3.0])[0])
    tl = onset_scenarios("so-timeline-step", healthy_s=3.0)
    assert [sc.fault_intervals for sc in tl] == [((3.0, 5.0),), ((3.0, 5.0),)]
    base = scenario("so-timeline-step").input  # each window keeps its own input, shifted to the onset
    for sc, start in zip(tl, (0.0, 4.0), strict=True):
        x = np.array([0.0, 0.5, 1.9])
        np.testing.assert_array_equal(sc.input.sample(3.0 + x), base.sample(start + x))
    res = alarm_delays(scs, {"cusum": CusumRule(21.0), "frame 0.1%": FrameRule(-math.log(1e-3))}, 4, seed=1)
    c = res["cusum"]
    assert c.detected == 1.0 and c.quantile(1.0) <= 0.5 and c.on_fault_channel.all()
    assert c.false_starts == 0 and c.healthy_hours == pytest.approx(8 * 3.0 / 3600, rel=0.05)
    d = c.to_dict()
    assert d["runs"] == 8 and d["median_s"] <= 0.5
