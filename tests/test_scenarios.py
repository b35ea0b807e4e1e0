"""The scenario catalogue of DESIGN.md section 4."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import Scenario, Segment, UnknownScenarioError, catalogue, scenario, scenario_names
from chatterspec.plants.models import second_order
from chatterspec.plants.signals import Chirp, Step

NAMES = (
    "so-healthy-low",
    "so-healthy-high",
    *(f"so-f{f}-{n}" for n in ("low", "high") for f in (9, 11, 12, 15)),
    "so-timeline-constant",
    "so-timeline-step",
    "so-boundary-layer",
    "eha-healthy",
    "eha-leak-minor",
    "eha-leak-medium",
    "eha-leak-major",
    "eha-friction-minor",
    "eha-friction-major",
    "eha-bulk-50down",
    "eha-bulk-25down",
    "eha-bulk-25up",
    "eha-bulk-50up",
    "detc-normal",
    "detc-uncertain",
    "eha4-leak-timeline",
    "eha4-imm-analogue",
)


def test_catalogue_names_are_the_cli_contract() -> None:
    assert set(scenario_names()) == set(NAMES)
    assert len(scenario_names()) == 27
    cat = catalogue()
    assert tuple(cat) == scenario_names()
    for name, sc in cat.items():
        assert sc.name == name
        assert sc.dt == (1e-4 if name == "eha4-imm-analogue" else 1e-3)


def test_unknown_name_lists_valid_names() -> None:
    with pytest.raises(UnknownScenarioError) as info:
        scenario("so-healthy-medium")
    msg = str(info.value)
    assert "so-healthy-medium" in msg
    assert all(n in msg for n in NAMES)
    assert isinstance(info.value, KeyError)


@pytest.mark.parametrize("name", ["so-healthy-low", "so-healthy-high", "eha-healthy"])
def test_healthy_entries(name: str) -> None:
    sc = scenario(name)
    assert sc.is_healthy
    assert sc.fault_intervals == ()
    assert sc.n_samples == 4001
    assert sc.time[-1] == pytest.approx(4.0)


@pytest.mark.parametrize(("noise", "r"), [("low", (1e-8, 1e-6)), ("high", (1e-6, 1e-4))])
@pytest.mark.parametrize("f", [9, 11, 12, 15])
def test_second_order_mismatch_entries(noise: str, r: tuple, f: int) -> None:
    sc = scenario(f"so-f{f}-{noise}")
    assert sc.nominal.natural_frequency_hz == pytest.approx(10.0)
    assert sc.plant.natural_frequency_hz == pytest.approx(float(f))
    assert sc.plant.damping_ratio == pytest.approx(0.1)
    np.testing.assert_array_equal(np.diag(sc.nominal.R), r)
    np.testing.assert_array_equal(np.diag(sc.nominal.Q), (1e-8, 1e-6))
    assert sc.fault_intervals == ((0.0, 4.0),)
    assert sc.fault_channel == "velocity"
    assert isinstance(sc.input, Step) and sc.input.time == 0.0


def test_boundary_layer_entry() -> None:
    sc = scenario("so-boundary-layer")
    assert sc.nominal.n_outputs == 1 and sc.nominal.n_states == 2
    np.testing.assert_array_equal(sc.nominal.C, [[1.0, 0.0]])
    assert sc.nominal.natural_frequency_hz == pytest.approx(2.0)
    assert sc.nominal.damping_ratio == 0.0
    np.testing.assert_array_equal(np.diag(sc.nominal.Q), (1e-10, 1e-8))
    np.testing.assert_array_equal(sc.nominal.R, [[1e-8]])
    assert sc.fault_intervals == ((1.0, 2.0), (3.0, 4.0))
    modes = [(s.start, s.stop, s.model.natural_frequency_hz, s.model.damping_ratio) for s in sc.segments]
    assert modes == [
        (0.0, 1.0, pytest.approx(2.0), 0.0),
        (1.0, 2.0, pytest.approx(3.0), 0.0),
        (2.0, 3.0, pytest.approx(2.0), 0.0),
        (3.0, 4.0, pytest.approx(2.0), pytest.approx(0.1)),
        (4.0, 5.0, pytest.approx(2.0), 0.0),
    ]
    assert sc.n_samples == 5001


@pytest.mark.parametrize("name", ["so-timeline-constant", "so-timeline-step"])
def test_timeline_entries(name: str) -> None:
    sc = scenario(name)
    assert sc.duration == 8.0
    assert sc.nominal.natural_frequency_hz == pytest.approx(5.0) and sc.nominal.damping_ratio == 0.0
    assert sc.fault_intervals == ((0.0, 2.0), (4.0, 6.0))
    u = sc.input.sample(sc.time)
    if name.endswith("step"):
        k5 = 5000
        assert u[k5 - 1] == 0.0 and u[k5] == 1.0
    else:
        assert np.all(u == 1.0)


def test_eha_entries_use_chirp() -> None:
    sc = scenario("eha-leak-major")
    assert isinstance(sc.input, Chirp)
    assert (sc.input.f_start_hz, sc.input.f_stop_hz, sc.input.amplitude) == (10.0, 100.0, 300.0)
    assert sc.fault_channel == "pressure"
    assert scenario("eha-friction-major").fault_channel == "velocity"
    assert scenario("eha-bulk-50up").fault_channel == "pressure"


def test_segment_index_switches_on_the_right_sample() -> None:
    sc = scenario("so-boundary-layer")
    idx = sc.segment_index()
    assert idx[999] == 0 and idx[1000] == 1 and idx[1999] == 1 and idx[2000] == 2
    assert idx[2999] == 2 and idx[3000] == 3 and idx[3999] == 3 and idx[4000] == 4


def test_describe_is_json_ready() -> None:
    import json

    d = scenario("so-timeline-step").describe()
    json.dumps(d)
    assert [s["matches_nominal"] for s in d["segments"]] == [False, True, False, True]
    assert d["segments"][0]["natural_frequency_hz"] == pytest.approx(8.0)


def test_scenario_validation() -> None:
    from chatterspec.errors import ParameterError

    m = second_order(5.0, 0.1)
    with pytest.raises(ParameterError, match="overlap"):
        Scenario("x", m, Step(), 4.0, windows=(Segment(0.0, 2.0, m), Segment(1.0, 3.0, m)))
    with pytest.raises(ParameterError, match="dimensions"):
        Scenario("x", m, Step(), 4.0, plant=second_order(5.0, 0.1, measure="position"))
    with pytest.raises(ParameterError, match="start < stop"):
        Segment(2.0, 1.0, m)
