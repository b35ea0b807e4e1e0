"""What a new user meets first: a catalogue name is enough to simulate, results print short, a
detection report is a table, and ``--json`` carries no binary rounding noise. Each test failed
before the public-API work (a name raised AttributeError, reprs printed whole arrays, there was no
``table()``, JSON floats had 16-17 significant digits)."""

from __future__ import annotations

import json

import numpy as np

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.jsonout import DIGITS, dumps, rounded


def test_simulate_takes_a_catalogue_name() -> None:
    by_name = cs.simulate("eha-healthy", runs=1, seed=4)
    by_object = cs.simulate(cs.scenario("eha-healthy"), runs=1, seed=4)
    np.testing.assert_array_equal(by_name.z, by_object.z)
    first = next(cs.iter_simulations("so-healthy-low", 2, seed=1))
    assert first.z.shape[0] == 2
    # a model file too (the scenario of its [simulation] table, named after the file)
    from pathlib import Path

    toml = Path(__file__).resolve().parents[1] / "examples" / "eha_model.toml"
    assert cs.simulate(str(toml), runs=1, seed=1).scenario.name == "eha_model"


def test_simulate_refuses_what_is_not_a_scenario() -> None:
    import pytest

    with pytest.raises(cs.ParameterError, match="a Scenario, a LinearModel, a model file"):
        cs.simulate(3)
    with pytest.raises(cs.UnknownScenarioError, match="valid names"):
        cs.simulate("no-such-scenario")


def _no_long_array(text: str) -> None:
    # a whole array prints as "[[ 0.00000000e+00, ..." or with numpy's "..." elision
    assert "[[" not in text and "e+00" not in text and "e-0" not in text and "..., " not in text, text
    assert "\n" not in text


def test_reprs_show_shapes_not_arrays() -> None:
    sim = cs.simulate("eha-leak-major", runs=2, seed=1)
    text = repr(sim)
    _no_long_array(text)
    assert "runs=2" in text and "z=array(2, 4001, 3)" in text and "'eha-leak-major'" in text
    assert len(text) < 250

    report = cs.detect_scenario(cs.scenario("eha-leak-major"), runs=2, seed=1)
    text = repr(report)
    _no_long_array(text)
    assert text.startswith("DetectionReport(detected=True")
    assert len(text) < 300

    kf = cs.KalmanFilter(sim.scenario.nominal)
    out = kf.run(sim.z[:, 1:], sim.u[:-1], x0=np.zeros(3), P0=1e-6 * np.eye(3))
    text = repr(out)
    _no_long_array(text)
    assert "x_post=array(2, 4000, 3)" in text and "P_post" not in text  # not stored: not shown


def test_detection_report_table() -> None:
    report = cs.detect_scenario(cs.scenario("eha-leak-major"), runs=1, seed=1)
    table = report.table()
    lines = table.splitlines()
    header = next(i for i, ln in enumerate(lines) if ln.startswith("channel"))
    rows = lines[header + 1 : header + 1 + len(report.channels)]
    assert [r.split()[0] for r in rows] == list(report.channels)
    for row, verdict in zip(rows, report.verdicts, strict=True):
        assert row.split()[1] == ("YES" if verdict.detected else "no")
        assert float(row.split()[4]) == round(verdict.peak_ratio, 3)
    assert lines[header + 1 + len(report.channels)] == "fault detected: YES"


def test_rounded_keeps_integers_and_removes_noise() -> None:
    noisy = 0.1 + 0.1 + 0.1 - 0.1
    assert noisy != 0.2  # the binary noise the JSON used to carry
    doc = rounded({"a": noisy, "n": np.int64(2**53 + 1), "b": np.bool_(True), "v": np.array([noisy])})
    assert doc == {"a": 0.2, "n": 2**53 + 1, "b": True, "v": [0.2]}
    assert dumps({"a": noisy}) == '{"a": 0.2}'
    # enough digits for a threshold: the relative error of 12 significant digits is below 5e-12
    th = 12.345678901234567
    assert abs(rounded(th) - th) <= 5e-12 * th


def _floats(doc: object) -> list[float]:
    if isinstance(doc, dict):
        return [f for v in doc.values() for f in _floats(v)]
    if isinstance(doc, list):
        return [f for v in doc for f in _floats(v)]
    return [doc] if isinstance(doc, float) else []


def test_cli_json_floats_have_meaningful_digits(capsys) -> None:
    argv = ["detect", "so-timeline-step", "--runs", "2", "--seed", "3", "--json", "--no-progress"]
    assert main(argv) == 0
    text = capsys.readouterr().out
    doc = json.loads(text)
    floats = _floats(doc)
    assert floats
    # significant digits of the shortest repr (what json writes): 0.7220719703918376 has 16
    digits = [len(repr(abs(f)).split("e")[0].replace(".", "").strip("0")) for f in floats]
    assert max(digits) <= DIGITS, [f for f, d in zip(floats, digits, strict=True) if d > DIGITS][:5]
    assert doc["runs"] == 2 and isinstance(doc["runs"], int)
    assert doc["threshold"]["alpha"] == 1e-3
