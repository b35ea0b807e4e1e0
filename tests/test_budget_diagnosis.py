"""``chatterspec diagnose`` at one false-alarm budget: onset variants, where the healthy steps and the onsets
fall, the threshold sweep, the same numbers whatever the workers and chunks, the realized false-alarm rate
against the calibration, and the command's bad input (one line, exit 2)."""

from __future__ import annotations

import json

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.detection.alarms.calibration import poisson_count_interval
from chatterspec.detection.alarms.rules import CusumRule
from chatterspec.detection.alarms.streams import run_rule
from chatterspec.errors import ParameterError
from chatterspec.studies.budget_diagnosis import (
    BudgetSettings,
    InnovationRoute,
    ModeRoute,
    RouteScores,
    diagnose_at_budget,
    onsets_of,
    route_geometry,
    sweep_chunk,
)
from chatterspec.studies.diagnosis import with_onset


def test_onset_variant_of_a_scenario_faulty_from_the_start() -> None:
    sc = cs.scenario("eha-leak-minor")
    assert onsets_of(sc) == ((0.0, 4.0, 0),)
    v = with_onset(sc, 2.0)
    assert v.name == "eha-leak-minor-onset2s" and v.n_samples == sc.n_samples and v.input == sc.input
    first, second = v.segments
    assert first.model is sc.nominal and (first.start, first.stop) == (0.0, 2.0) and not v.deviates(first)
    assert second.model is sc.plant and (second.start, second.stop) == (2.0, 4.0)
    assert onsets_of(v) == ((2.0, 4.0, 1),)
    # a fault window from 0 s is cut as well
    w = with_onset(cs.scenario("eha4-leak-minor"), 1.5)
    assert [(s.start, s.stop, w.deviates(s)) for s in w.segments] == [(0.0, 1.5, False), (1.5, 4.0, True)]
    with pytest.raises(ParameterError, match="healthy at t = 0"):
        with_onset(cs.scenario("eha4-leak-timeline"), 1.0)
    with pytest.raises(ParameterError, match="record length"):
        with_onset(sc, 4.0)
    with pytest.raises(ParameterError):
        with_onset(sc, 0.0)


def test_geometry_of_sample_and_frame_routes() -> None:
    sc = cs.scenario("eha4-leak-timeline")
    route = ModeRoute(sc, "imm")
    g = route_geometry(sc, route.step_times(), route.step_s, 0.1, route.labels)
    assert g.onsets == (3.0, 6.0) and g.true_labels == ("leak-minor", "leak-major")
    # samples t = 0.1 .. 3.0 s are healthy (z(3.0) comes from the healthy plant), 2901 of them
    assert g.times[0] == pytest.approx(0.1) and g.healthy_steps == 2901
    assert g.times[g.lo[0]] == pytest.approx(3.001) and g.times[g.hi[0] - 1] == pytest.approx(6.0)
    assert g.hi[1] == g.times.size and g.times[-1] == pytest.approx(9.0)
    # frames (1 s window, 0.2 s hop) end at 1.0, 1.2, ...: those ending before 3 s are healthy
    from chatterspec.detection.spectral import STFTConfig
    from chatterspec.detection.thresholds import frame_threshold

    lin = with_onset(cs.scenario("eha-leak-minor"), 2.0)
    m, cfg = lin.nominal, STFTConfig()
    from chatterspec.studies.budget_diagnosis import ChatteringRoute

    ch = ChatteringRoute(lin, frame_threshold(m, cfg.freqs_hz(m.dt), cfg, m.dt, 1e-3))
    gc = route_geometry(lin, ch.step_times(), ch.step_s, 0.1)
    assert gc.times[0] == pytest.approx(1.0) and gc.healthy_steps == 6  # 1.0, 1.2, ..., 2.0
    assert gc.times[gc.lo[0]] == pytest.approx(2.2) and ch.step_s == pytest.approx(0.2)
    sim = cs.simulate(lin, runs=2, seed=0)
    np.testing.assert_array_equal(ch.scores(sim).times, ch.step_times())


def test_sweep_agrees_with_the_rule_run_by_hand() -> None:
    # a synthetic stream on eha-leak-minor's onset variant: healthy noise, a shift from the onset on
    sc = with_onset(cs.scenario("eha-leak-minor"), 2.0)
    route = InnovationRoute(sc)
    times = route.step_times()
    g = route_geometry(sc, times, route.step_s, 0.1)
    rng = np.random.default_rng(4)
    runs = 5
    s = rng.exponential(1.0, size=(runs, times.size, 1))
    s[:, times >= 2.0] += 2.5
    rs = RouteScores("innovation", times, s, np.zeros((runs, times.size), dtype=np.int8), 0.0)
    hs = np.array([3.0, 8.0, 20.0])
    out = sweep_chunk(rs, g, CusumRule(drift=1.5), hs, route.labels)
    fed = s[:, g.first :]
    for j, h in enumerate(hs):
        blk = run_rule(CusumRule(threshold=h, drift=1.5), fed)
        assert out["healthy_starts"][j] == blk.starts[:, g.healthy].sum()
        act = blk.active[..., 0]
        for r in range(runs):
            win = np.flatnonzero(act[r, g.lo[0] : g.hi[0]])
            assert out["first"][0][j, r] == (win[0] if win.size else -1)
            assert out["before"][0][j, r] == act[r, g.lo[0] - 1]


def _strip(doc: dict) -> dict:
    doc = json.loads(json.dumps(doc))
    doc.pop("steps_per_second")
    doc.pop("timings_s")
    return doc


def test_same_numbers_whatever_the_workers_and_the_chunks() -> None:
    # 130 runs = 3 blocks of 64: chunks of 64, one chunk of 192, and 2 worker processes must give the
    # same results (exact equality: each realization's scores depend only on it, counts are integers)
    # (the chattering route goes to the worker processes too: its frame score must pickle)
    from chatterspec.detection.spectral import STFTConfig
    from chatterspec.detection.thresholds import frame_threshold
    from chatterspec.studies.budget_diagnosis import ChatteringRoute

    sc = with_onset(cs.scenario("eha-leak-minor"), 2.0)
    m, cfg = sc.nominal, STFTConfig()
    law = frame_threshold(m, cfg.freqs_hz(m.dt), cfg, m.dt, 1e-3)
    routes = {"chattering": ChatteringRoute(sc, law), "innovation": InnovationRoute(sc)}
    settings = BudgetSettings(60.0, "cusum", calibration_runs=70)
    docs = []
    for kw in ({"chunk_runs": 64}, {"chunk_runs": 192}, {"chunk_runs": 64, "workers": 2}):
        res = diagnose_at_budget(sc, routes, 130, 3, settings, progress=False, **kw)
        docs.append([_strip(r.describe()) for r in res])
    assert docs[1] == docs[0] and docs[2] == docs[0]
    assert [d["runs"] for d in docs[0]] == [130, 130] and docs[0][1]["onsets"][0]["onset_s"] == 2.0


def test_realized_false_alarms_agree_with_the_calibration() -> None:
    # the innovation route on the linear EHA at 120 false alarms per hour, calibrated on 1000 healthy runs
    # (1.1 h); the diagnosed runs' healthy time (1000 x 1.9 s, 0.1 s to 2 s) is out of sample. Its alarm
    # starts are Poisson given the true rate, which the calibration places in its interval (jackknife,
    # 99.9 %): the count must lie inside the 99.9 % Poisson count interval of some rate of that interval.
    sc = with_onset(cs.scenario("eha-leak-minor"), 2.0)
    settings = BudgetSettings(120.0, "cusum", calibration_runs=1000, calibration_confidence=0.999)
    (r,) = diagnose_at_budget(sc, {"innovation": InnovationRoute(sc)}, 1000, 9, settings, progress=False)
    assert r.healthy_hours == pytest.approx(1000 * 1.901 / 3600, rel=1e-9)
    lo_rate, hi_rate = r.calibration["rate_interval"]
    lo, _ = poisson_count_interval(lo_rate * r.healthy_hours, 0.999)
    _, hi = poisson_count_interval(hi_rate * r.healthy_hours, 0.999)
    assert lo <= r.false_alarms <= hi, (r.false_alarms, lo, hi, r.calibration)
    assert r.onsets[0].missed + r.onsets[0].detected + r.onsets[0].in_alarm_at_onset == 1000


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--false-alarms-per-hour", "0"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "-1"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "inf"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "nan"], "--false-alarms-per-hour must be positive and finite"),
        (["--false-alarms-per-hour", "often"], "--false-alarms-per-hour must be a number"),
        (["--methods", "smm"], "does not support --methods smm"),
        (
            ["--rule", "persistence", "--persistence-k", "3", "--persistence-n", "2"],
            "persistence k must be <= n",
        ),
        (["--persistence-k", "2"], "apply to --rule persistence"),
        (["--rule", "persistence", "--persistence-k", "0"], "--persistence-k must be an integer >= 1"),
        (["--per-record", "--methods", "innovation"], "at a false-alarm budget only"),
        (["--warmup", "-1"], "--warmup"),
        (["--calibration", "cal.npz"], "exact law"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(capsys, extra, needle) -> None:  # type: ignore[no-untyped-def]
    assert main(["diagnose", "eha-leak-minor", "--onset", "2", *extra]) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1, err


def test_methods_and_onsets_the_scenario_cannot_run(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["diagnose", "detc-uncertain", "--methods", "chattering"]) == 2
    assert "measures every state" in capsys.readouterr().err
    assert main(["diagnose", "eha4-leak-timeline", "--onset", "1"]) == 2
    assert "healthy at t = 0" in capsys.readouterr().err
    assert main(["diagnose", "eha-healthy"]) == 2
    assert "no fault onset" in capsys.readouterr().err


def test_command_json_figure_and_recording(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    rr = pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    fig, rrd = tmp_path / "amoc.png", tmp_path / "d.rrd"
    argv = [
        "diagnose",
        "eha-leak-minor",
        "--onset",
        "2",
        "--runs",
        "6",
        "--calibration-runs",
        "150",
        "--seed",
        "2",
    ]
    argv += ["--false-alarms-per-hour", "30", "--no-progress", "--plot", str(fig), "--record", str(rrd)]
    rr.set_strict_mode(True)
    try:
        assert main([*argv, "--json"]) == 0
    finally:
        rr.set_strict_mode(False)
    doc = json.loads(capsys.readouterr().out)
    assert doc["budget_per_hour"] == 30 and doc["rule"] == "cusum"
    assert [m["method"] for m in doc["methods"]] == ["chattering", "innovation"]
    for m in doc["methods"]:
        assert m["rule"]["rule"] == "cusum" and m["budget_per_hour"] == 30
        assert set(m) >= {
            "false_alarms",
            "healthy_hours",
            "false_alarm_rate_ci99",
            "onsets",
            "steps_per_second",
        }
        assert len(m["curve"]["thresholds"]) == len(m["curve"]["far_per_hour"])
    assert fig.stat().st_size > 0 and doc["figure"] == str(fig)
    # the recording holds each route's statistic and threshold; the innovation CUSUM's g is that of
    # realization 0 run alone through the rule
    summary = RrdReader(rrd).store().summary()
    assert "/routes/innovation/statistic" in summary and "/routes/chattering/threshold" in summary
    sc = with_onset(cs.scenario("eha-leak-minor"), 2.0)
    route = InnovationRoute(sc)
    sim = cs.simulate(sc, runs=1, seed=2)
    h = doc["methods"][1]["rule"]["threshold"]
    g = run_rule(CusumRule(threshold=h, drift=route.drift), route.scores(sim).score).statistic[0, :, 0]
    values, times = [], []
    for chunk in (
        RrdReader(rrd).stream().filter(content="/routes/innovation/statistic", is_static=False).to_chunks()
    ):
        rb = chunk.to_record_batch()
        times.extend(rb.column("time").cast("int64").to_pylist())
        values.extend(v[0] for v in rb.column("Scalars:scalars").to_pylist())
    # the JSON threshold has 12 significant digits (chatterspec.jsonout): each renewal of the CUSUM
    # carries its rounding (|dh| <= 5e-12 h) into g, so the recorded g agrees to a few renewals of that
    np.testing.assert_allclose(np.asarray(values)[np.argsort(times)], g, rtol=0, atol=1e-9 * h)
    # the table names the rule, the budget and every route
    assert main(argv[:-4]) == 0
    out = capsys.readouterr().out
    assert "cusum rule" in out and "30 false alarm(s) per hour" in out and "innovation" in out


def test_innovation_route_off_the_chi_square_law_is_scaled_on_healthy_runs() -> None:
    import scipy.stats

    from chatterspec.studies.diagnosis import healthy_version

    assert InnovationRoute(with_onset(cs.scenario("eha-leak-minor"), 2.0)).matched  # KF, plant Q and R
    assert not InnovationRoute(cs.scenario("eha4-leak-timeline")).matched  # EKF on the nonlinear plant
    detc = cs.scenario("detc-uncertain")
    route = InnovationRoute(detc, cap=False)  # uncapped: the score is proportional to NIS
    assert not route.matched  # filter Q = diag(1, 10, 100) against a noise of (0.05, 0.1, 0.1)^2
    sim = cs.simulate(healthy_version(detc), runs=8, seed=1)
    scaled = route.with_healthy_scale(sim)
    nis, _ = route.nis(sim)
    want = np.median(nis[:, nis.shape[1] // 10 :]) / scipy.stats.chi2.median(1)
    assert scaled.scale == pytest.approx(want, rel=1e-12) and scaled.scale < 0.05
    np.testing.assert_allclose(
        scaled.scores(sim).score[..., 0], route.scores(sim).score[..., 0] / scaled.scale
    )
