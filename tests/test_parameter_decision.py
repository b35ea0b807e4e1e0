"""Decisions on the identified parameters: the score's law, the alarm at a budget, plants inside and
outside their tolerances, joint faults, windows across a change, excitation, the CLI.

Statistical checks use fixed seeds and binomial / Poisson tolerances at a two-sided level of 1e-3 (each
says why); the long runs (24 h per plant, 500 onsets) are ``scripts/tolerance_study.py``.
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from chatterspec.cli import main
from chatterspec.detection.alarms.calibration import calibrate_rule, poisson_count_interval
from chatterspec.detection.alarms.rules import make_rule
from chatterspec.detection.alarms.streams import count_starts
from chatterspec.detection.identification import OnlineIdentifier, identification_setup, identify
from chatterspec.detection.parameter_decision import (
    ParameterBands,
    ParameterDecision,
    band_scores,
    calibrate_parameter_rule,
    detectable_change,
    joint_hypothesis,
    monitor_parameters,
    parameter_null_scores,
)
from chatterspec.errors import IdentifiabilityError
from chatterspec.plants.models import eha_linear
from chatterspec.plants.scenarios import _eha
from chatterspec.plants.simulate import simulate
from chatterspec.studies.intervals import clopper_pearson
from chatterspec.studies.tolerance_study import (
    chirp_scenario,
    eha_with_tolerances,
    onset_study,
    study_settings,
)

LEVEL = 1e-3  # two-sided level of every statistical check below
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
BE, A, L = 2.07e8, 2144.0, 4.8e-12


def _binomial_ok(k: int, n: int, p: float, inflation: float = 1.0) -> bool:
    """``k`` of ``n`` consistent with probability ``p`` (normal approximation at LEVEL; the variance times
    ``inflation`` for dependent indicators)."""
    z = stats.norm.isf(LEVEL / 2)
    return abs(k - n * p) <= z * np.sqrt(inflation * n * p * (1 - p))


@pytest.mark.parametrize("width_se", [0.0, 10.0])
def test_score_is_a_p_value_on_the_band_edge_and_conservative_inside(width_se: float) -> None:
    rng = np.random.default_rng(1)
    n, se = 20000, 1.0
    low, high = np.array([0.0]), np.array([width_se])
    theta = rng.standard_normal((n, 1)) * se + high  # on the upper edge
    p = np.exp(-band_scores(theta, np.full((n, 1), se), low, high))[:, 0]
    for a in (0.01, 0.05, 0.5):  # uniform on the edge: P(p <= a) = a (independent draws: binomial)
        assert _binomial_ok(int(np.sum(p <= a)), n, a), (a, np.mean(p <= a))
    if width_se:  # in the middle of the band the test almost never rejects
        mid = rng.standard_normal((n, 1)) * se + width_se / 2
        assert np.mean(np.exp(-band_scores(mid, np.full((n, 1), se), low, high)) <= 0.05) < 1e-3
    nan = band_scores(np.array([[np.nan]]), np.array([[np.nan]]), low, high)
    assert nan[0, 0] == 0.0  # no estimate: no evidence


def test_worst_case_streams_are_uniform_p_values_with_the_window_overlap() -> None:
    n_hops, steps = 5, 100_000
    s = parameter_null_scores(2, n_hops, steps, seed=3, two_sided=[False, True])[0]
    p = np.exp(-s)
    # indicators of windows sharing hops are (n-1)-dependent: variance at most (2n - 1) x the binomial
    for c in range(2):
        assert _binomial_ok(int(np.sum(p[:, c] <= 0.05)), steps, 0.05, inflation=2 * n_hops - 1)
    z = stats.norm.isf(p[:, 0])  # the one-sided stream's normals: lag-1 correlation (n - 1) / n
    r = np.corrcoef(z[:-1], z[1:])[0, 1]
    assert abs(r - 0.8) < 0.01  # its standard error is about (1 - r^2) / sqrt(N / n) = 0.003


def test_the_rule_on_worst_case_streams_holds_its_budget() -> None:
    bands = ParameterBands.from_map(eha_with_tolerances().parameter_map)
    F = 18000.0  # windows per hour at a 0.2 s hop
    cal = calibrate_parameter_rule("cusum", bands, 5, F, 2.0, hours=6.0, seed=1)
    assert cal.method in ("counted", "extrapolated") and cal.channels == 3
    assert calibrate_parameter_rule("cusum", bands, 5, F, 2.0, hours=6.0, seed=1) is cal  # cached
    frame = calibrate_parameter_rule("frame", bands, 5, F, 2.0)
    assert frame.method == "law" and frame.threshold == pytest.approx(np.log(F * 3 / 2.0))
    # fresh worst-case streams (another seed): the starts at the threshold against the budget; the
    # threshold's own uncertainty is its 99.9 % jackknife interval, so the count is checked against the
    # Poisson interval of the rates at the two ends of that interval (each at 99.9 %)
    sharp = calibrate_rule(
        make_rule("cusum"), parameter_null_scores(3, 5, 6 * 18000, 1), F, 2.0, confidence=0.999
    )
    hours = 12.0
    fresh = parameter_null_scores(3, 5, int(hours * F), seed=77)
    starts = int(count_starts(sharp.rule, fresh).sum())
    lo = poisson_count_interval(sharp.rate_interval[0] * hours, 0.999)[0]
    hi = poisson_count_interval(sharp.rate_interval[1] * hours, 0.999)[1]
    assert lo <= starts <= hi, (starts, lo, hi, sharp.rate_interval)


def test_detectable_change() -> None:
    se = np.array([1.0, np.nan, 0.0])
    d = detectable_change(se, 1e-5, 0.95)
    assert d[0] == pytest.approx(stats.norm.isf(1e-5) + stats.norm.ppf(0.95)) and np.all(np.isinf(d[1:]))


def test_plant_inside_its_tolerances_raises_no_alarm_and_changes_beyond_them_do() -> None:
    model = eha_with_tolerances()
    settings = study_settings(model)
    inside = simulate(chirp_scenario("in", 8.0, {"bulk_modulus": 0.9 * BE, "friction": 1.2 * A}), 32, 4)
    rec = monitor_parameters(model, inside.z, inside.u, settings)
    assert not rec.alarm.any()
    b = settings.bands
    for p in ("bulk_modulus", "friction"):  # reported inside: every interval within the band
        i = b.names.index(p)
        assert np.all((rec.ci_low[:, :, i] >= b.low[i]) & (rec.ci_high[:, :, i] <= b.high[i]))
    assert np.median(rec.estimate[:, :, 2]) == pytest.approx(0.9 * BE, rel=1e-3)
    for fault, name in (({"bulk_modulus": 0.75 * BE}, "bulk_modulus"), ({"leakage": 3e-11}, "leakage")):
        sim = simulate(chirp_scenario("out", 4.0, fault), 16, 5)
        rec = monitor_parameters(model, sim.z, sim.u, settings)
        i = b.names.index(name)
        assert rec.alarm[:, -1, i].all() and not np.delete(rec.alarm, i, axis=2).any()


def test_change_mid_record_is_decided_on_windows_after_it() -> None:
    # windows across the change mix two plants: their joint fit is rejected and gives no evidence, so the
    # bulk modulus (not the leakage, which absorbs the misfit there) is named, one window after the onset
    r = onset_study(
        eha_with_tolerances(), {"bulk_modulus": 0.75 * BE}, 16, onset_s=6.0, record_s=10.0, seed=6
    )
    assert (
        r["detected"] == 16 and r["first_parameter"]["bulk_modulus"] == 16 and r["alarms_before_onset"] == 0
    )
    assert r["named"] == {"leakage": 0, "friction": 0, "bulk_modulus": 16}
    assert r["delay_median_s"] <= 1.5


def test_online_decisions_equal_the_whole_record_ones_in_any_chunking() -> None:
    model = eha_with_tolerances()
    sim = simulate(chirp_scenario("on", 8.0, fault={"bulk_modulus": 0.75 * BE}, onset_s=4.0), 1, 8)
    settings = study_settings(model)
    batch = monitor_parameters(model, sim.z, sim.u, settings)
    setup = identification_setup(model)
    online = OnlineIdentifier(setup, hop_samples=200, window_hops=5)
    dec = ParameterDecision(setup, settings)
    rng = np.random.default_rng(0)
    cuts = np.cumsum(rng.integers(1, 900, size=40))
    blocks = []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, sim.z.shape[1]], strict=True):
        if lo < hi <= sim.z.shape[1]:
            blocks.append(dec.update(online.push(sim.z[0, lo:hi], sim.u[lo:hi])))
    alarm = np.concatenate([b.alarm for b in blocks])
    score = np.concatenate([b.score for b in blocks])
    assert np.array_equal(alarm, batch.alarm[0])
    # the sums agree to rounding (vectorized reductions over other batch layouts) and each window's fit
    # iterates on its own to a relative step of 1e-10: the scores agree far below any threshold's scale
    np.testing.assert_allclose(score, batch.score[0], rtol=1e-5, atol=1e-9)
    events = [e for b in blocks for e in b.events]
    assert [(e.kind, e.parameter) for e in events] == [("fault-start", "bulk_modulus")]
    assert "outside its +-15 %" in events[0].describe()


def test_leak_and_friction_together_are_named_with_intervals() -> None:
    # every combination of the declared parameters is a hypothesis: no declaration needed
    truth = {"leakage": 3e-11, "friction": 1.4 * A}
    sc = _eha("lf", "leakage+friction", "", None, **truth)
    runs = 200
    sim = simulate(sc, runs, 9)
    idn = identify(sc.nominal, sim.z, sim.u)
    k = round(idn.selection_rate()["leakage+friction"] * runs)
    assert clopper_pearson(k, runs, 1 - LEVEL)[1] >= 0.95  # consistent with naming both in >= 95 %
    assert k >= 0.95 * runs
    for p, v in truth.items():  # the 95 % intervals cover at their level (binomial, two-sided LEVEL)
        lo, hi = idn.interval("leakage+friction", p)
        c = int(np.sum((lo <= v) & (v <= hi)))
        assert _binomial_ok(c, runs, 0.95), (p, c)


def test_joint_hypothesis_is_required() -> None:
    setup = identification_setup(eha_linear(), ["leakage"])
    with pytest.raises(IdentifiabilityError, match="every declared parameter"):
        joint_hypothesis(setup)


def test_held_actuator_is_not_excited_and_dither_lowers_the_detectable_leakage() -> None:
    from chatterspec.studies.tolerance_study import CYCLE_MOVES, excitation_cycle

    no, yes = excitation_cycle(None, 4, seed=2), excitation_cycle(6.0, 4, seed=2)
    held = (no.times_s > 6.0) & (no.times_s < CYCLE_MOVES[0] - 0.5)
    assert np.all(no.state[:, held, 0] == 2)  # leakage: not excited while held (by a factor ~30)
    moving = (no.times_s > CYCLE_MOVES[-1]) & (no.times_s < CYCLE_MOVES[-1] + 1.5)
    assert np.all(no.state[:, moving, 0] == 0)  # excited once the moves fill the horizon
    ratio = np.median(no.detectable[:, held, 0]) / np.median(yes.detectable[:, held, 0])
    assert ratio > 4.0  # the study's multisine: 6.4 x (scripts/tolerance_study.py)
    assert not no.alarm.any() and not yes.alarm.any()


def test_detect_and_diagnose_decide_on_the_parameters(capsys: pytest.CaptureFixture[str]) -> None:
    tol = ["--tolerance", "bulk_modulus=15%", "--tolerance", "friction=30%", "--tolerance", "leakage=100%"]
    assert main(["detect", "eha-bulk-25down", "--runs", "8", "--json", "--no-progress", *tol]) == 0
    t = json.loads(capsys.readouterr().out)["tolerance"]
    assert t["fault"] and t["detected_records"] == 8
    rows = {r["parameter"]: r for r in t["parameters"]}
    assert rows["bulk_modulus"]["position"] == "outside" and rows["bulk_modulus"]["outside_records"] == 8
    assert rows["friction"]["outside_records"] == 0 and rows["leakage"]["outside_records"] == 0
    assert main(["detect", "eha-bulk-25down", "--no-identify", *tol]) == 2  # nothing to decide on
    assert "identified parameters" in capsys.readouterr().err
    argv = [
        "diagnose",
        "eha-bulk-25down",
        "--onset",
        "2",
        "--runs",
        "8",
        "--calibration-runs",
        "64",
        "--json",
    ]
    assert main([*argv, "--methods", "parameters", "--no-progress", *tol]) == 0
    doc = json.loads(capsys.readouterr().out)
    m = doc["methods"][0]
    assert m["method"] == "parameters" and m["onsets"][0]["isolated"] == {"bulk_modulus": 8}
    assert main([*argv, "--methods", "parameters", "--no-progress"]) == 2  # no tolerance: not supported
    assert "tolerances" in capsys.readouterr().err


def test_monitor_with_tolerances_decides_on_the_parameters(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # the example's plant leaks (9e-11 from 4 s): outside +-100 %; the spectral events are mismatch only
    model = tmp_path / "m.toml"
    text = (EXAMPLES / "eha_model.toml").read_text()
    model.write_text(text.replace('unit = "m^3/(s Pa)",', 'unit = "m^3/(s Pa)", tolerance = "100%",'))
    argv = ["monitor", str(model), "--data", str(EXAMPLES / "eha_data.csv")]
    assert main([*argv, "--events", "jsonl", "--identification-events", "changes", "--json"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    faults = [e for e in lines if e["event"] == "fault-start"]
    assert [e["parameter"] for e in faults] == ["leakage"] and faults[0]["sample_time_s"] > 4.0
    summary = lines[-1]
    assert summary["decision"] == "parameters (tolerances)"
    assert [e["parameter"] for e in summary["events"] if e["event"] == "fault-start"] == ["leakage"]
    spectral = summary["spectral_events"]  # the chattering saw it too: the detector's own events
    assert any(e["kind"] == "fault-start" and e["channel"] == "pressure" and "peak_hz" in e for e in spectral)
    assert all("parameter" not in e for e in spectral)
    named = [e["fault"] for e in lines if e["event"] == "identification" and e["fault"]]
    assert named and set(named) == {"leakage"}


def test_horizon_sums_do_not_depend_on_how_the_stream_is_cut() -> None:
    # each window's information is the sum of the last K windows' added oldest first: the same bits in one
    # call, in calls of any size, and from a plain loop over the terms
    from chatterspec.detection.parameter_decision import _Horizon

    rng = np.random.default_rng(5)
    info = rng.lognormal(0.0, 3.0, size=(2, 40, 3))  # (streams, windows, parameters)
    K = 7
    whole = _Horizon(K).sums(info)
    h = _Horizon(K)
    cuts = [0, 1, 2, 9, 10, 23, 40]
    pieces = np.concatenate([h.sums(info[:, a:b]) for a, b in itertools.pairwise(cuts)], axis=1)
    assert np.array_equal(whole, pieces)
    ref = np.zeros_like(info)
    for j in range(info.shape[1]):
        for i in range(max(0, j - K + 1), j + 1):
            ref[:, j] += info[:, i]
    assert np.array_equal(whole, ref)
