"""Mode outputs (studies/estimation.py) on constructed probabilities with known answers, and the figures."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.errors import ParameterError, ShapeError
from chatterspec.studies.estimation import (
    argmax_accuracy,
    confusion_matrix,
    mode_report,
    rmse_table,
    switch_delays,
)

T = 30
TRUE = np.array([0] * 10 + [1] * 10 + [2] * 10)
t = np.arange(T) * 1e-3


def ramp_mu(runs: int = 2) -> np.ndarray:
    """Probabilities that follow the true mode after a known lag: linear ramp 0 -> 1 over 4 samples."""
    mu = np.zeros((runs, T, 3))
    mu[:, :10, 0] = 1.0
    for seg, (k0, new, old) in enumerate(((10, 1, 0), (20, 2, 1))):
        ramp = np.clip((np.arange(10) + 1) / 4.0, 0, 1)  # 0.25, 0.5, 0.75, 1, 1, ...
        mu[:, k0 : k0 + 10, new] = ramp
        mu[:, k0 : k0 + 10, old] = 1 - ramp
        del seg
    return mu


def test_confusion_columns_sum_to_100_and_match_hand_computation() -> None:
    mu = ramp_mu()
    c = confusion_matrix(mu, TRUE)
    np.testing.assert_allclose(c.sum(axis=0), 100.0, rtol=1e-12)
    # actual mode 1: ramp mean over 10 samples = (0.25 + 0.5 + 0.75 + 7) / 10 = 0.85
    assert c[1, 1] == pytest.approx(85.0)
    assert c[0, 1] == pytest.approx(15.0)
    assert c[0, 0] == pytest.approx(100.0)


def test_argmax_accuracy_counts_ties_to_the_lower_index() -> None:
    acc = argmax_accuracy(ramp_mu(), TRUE)
    # samples with new weight 0.25 lose, 0.5 ties (argmax picks the old, lower index), then 8 wins
    assert acc.tolist() == pytest.approx([1.0, 0.8, 0.8])


def test_switch_delays_are_exact_on_a_known_ramp() -> None:
    d = switch_delays(ramp_mu(), TRUE, t, levels=(0.5, 0.8))
    assert d.onsets.tolist() == pytest.approx([0.010, 0.020])
    assert d.new_modes.tolist() == [1, 2]
    # 0.5 is reached at the 2nd sample of the segment (1 ms), 0.8 at the 4th (3 ms)
    np.testing.assert_allclose(d.of_mean, [[1e-3, 3e-3], [1e-3, 3e-3]], atol=1e-15)
    np.testing.assert_allclose(d.per_run[0], d.of_mean, atol=1e-15)
    rep = mode_report(ramp_mu(), TRUE, t, ("a", "b", "c")).describe()
    assert rep["switch_to"] == ["b", "c"] and rep["confusion_percent"][0][0] == pytest.approx(100.0)


def test_rmse_table_and_bad_input() -> None:
    truth = np.zeros((2, 5, 2))
    est = np.ones((2, 5, 2)) * np.array([1.0, 2.0])
    assert rmse_table({"f": est}, truth, ("p", "v")) == {"f": {"p": 1.0, "v": 2.0}}
    with pytest.raises(ShapeError):
        confusion_matrix(ramp_mu(), TRUE[:-1])
    with pytest.raises(ParameterError, match=r"-1 \.\. 2"):
        confusion_matrix(ramp_mu(), TRUE + 1)
    with pytest.raises(ParameterError, match="levels"):
        switch_delays(ramp_mu(), TRUE, t, levels=(1.5,))


def test_mode_figures_render(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from chatterspec.figures.plot_diagnosis import confusion_figure, mode_weights_figure
    from chatterspec.figures.plot_studies import save

    mu = ramp_mu()
    p1 = save(mode_weights_figure(t, mu, ("a", "b", "c"), TRUE), tmp_path / "w.png")
    p2 = save(confusion_figure(confusion_matrix(mu, TRUE), ("a", "b", "c"), "test"), tmp_path / "c.png")
    assert p1.stat().st_size > 1000 and p2.stat().st_size > 1000
    with pytest.raises(ShapeError):
        confusion_figure(np.zeros((2, 2)), ("a", "b", "c"))


def test_mode_diagnosis_of_smm_on_the_leak_timeline() -> None:
    import chatterspec as cs
    from chatterspec.studies.diagnosis import diagnose_modes

    sim = cs.simulate(cs.scenario("eha4-leak-timeline"), runs=2, seed=3)
    (res,) = diagnose_modes(sim, ("smm",))
    assert res.onsets == pytest.approx((3.0, 6.0))
    np.testing.assert_allclose(res.confusion.sum(axis=0), 100.0, rtol=1e-12)
    # the SMM targets seen as diagnosis: isolation within 5 ms of each onset, none missed, and the
    # healthy samples in alarm at most 1 % (argmax = true mode in >= 99 % of the normal segment)
    assert res.missed == (0, 0)
    assert max(res.isolation_p90) <= 0.005
    assert res.healthy_alarm_fraction <= 0.01
    lo, hi = res.false_alarm_ci
    assert lo <= res.false_alarm_rate <= hi
    assert res.describe()["method"] == "smm" and res.steps_per_second > 0
    # the IMM route on the same plant (chatterspec's transition matrix: 0.999 per 1 ms step): an EKF bank
    # isolates both onsets within 5 ms and puts >= 95 % mean probability on the true mode in every segment
    (imm,) = diagnose_modes(sim, ("imm",))
    assert imm.missed == (0, 0) and max(imm.isolation_p90) <= 0.005
    assert np.all(np.diag(imm.confusion) >= 95.0), np.diag(imm.confusion)
    import dataclasses

    sc = sim.scenario
    bare = dataclasses.replace(
        sc, filter_settings=dataclasses.replace(sc.filter_settings, transition_matrix=None)
    )
    with pytest.raises(ParameterError, match="transition_matrix"):
        diagnose_modes(dataclasses.replace(sim, scenario=bare), ("imm",))
    with pytest.raises(ParameterError, match="method must be"):
        diagnose_modes(sim, ("chattering",))


def test_diagnose_command_json_and_errors(capsys) -> None:  # type: ignore[no-untyped-def]
    import json

    from chatterspec.cli import main

    args = [
        "diagnose",
        "eha4-leak-timeline",
        "--methods",
        "smm",
        "--runs",
        "1",
        "--seed",
        "2",
        "--json",
        "--per-record",
    ]
    assert main(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["scenario"] == "eha4-leak-timeline" and [m["method"] for m in doc["methods"]] == ["smm"]
    assert doc["methods"][0]["onsets_s"] == pytest.approx([3.0, 6.0])
    assert main(["diagnose", "eha4-imm-analogue", "--methods", "chattering"]) == 2
    assert "does not support --methods chattering" in capsys.readouterr().err
    assert main(["diagnose", "eha-healthy"]) == 2
    assert "no fault onset to diagnose" in capsys.readouterr().err
