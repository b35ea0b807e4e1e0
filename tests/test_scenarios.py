"""The scenario catalogue of docs/design.md §5."""

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
    "eha4-healthy",
    "eha4-leak-minor",
    "eha4-leak-major",
    "eha4-leak-onset",
    # closed loop (the EHA under its position controller)
    "eha-cl-healthy",
    "eha-cl-leak-minor",
    "eha-cl-leak-medium",
    "eha-cl-leak-major",
    "eha-cl-friction-major",
    "eha-cl-bulk-25down",
    "eha-cl-hold-healthy",
    "eha-cl-hold-leak-medium",
    "eha4-cl-healthy",
    "eha4-cl-leak-timeline",
)


def test_catalogue_names_are_the_cli_contract() -> None:
    assert set(scenario_names()) == set(NAMES)
    assert len(scenario_names()) == 41
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


# ------------------------------------------------------------------ estimator-paper scenarios
def test_plant_kinds_and_json_listing() -> None:
    import json

    from chatterspec.plants.nonlinear import NonlinearModel

    kinds = {name: sc.plant_kind for name, sc in catalogue().items()}
    assert {n for n, k in kinds.items() if k == "nonlinear"} == {
        "eha4-leak-timeline",
        "eha4-imm-analogue",
        "eha4-healthy",
        "eha4-leak-minor",
        "eha4-leak-major",
        "eha4-leak-onset",
        "eha4-cl-healthy",
        "eha4-cl-leak-timeline",
    }
    d = scenario("eha4-leak-timeline").describe()
    json.dumps(d)
    assert d["plant_kind"] == "nonlinear" and d["nominal"]["linearized"] is True
    # nonlinear segments report the linearization at rest: 39.08 Hz / 0.594 for the normal EHA4
    assert round(d["nominal"]["natural_frequency_hz"], 2) == 39.08
    assert [s["label"] for s in d["segments"]] == ["nominal plant", "leak-minor", "leak-major"]
    assert [s["matches_nominal"] for s in d["segments"]] == [True, False, False]
    assert d["segments"][2]["natural_frequency_hz"] > d["segments"][0]["natural_frequency_hz"]
    assert d["filter_settings"]["modes"] == ["normal", "leak-minor", "leak-major"]
    lin = scenario("eha-healthy").describe()
    assert lin["plant_kind"] == "linear" and lin["nominal"]["linearized"] is False
    assert lin["filter_settings"] is None
    assert isinstance(scenario("eha4-imm-analogue").nominal, NonlinearModel)


def test_detc_scenarios_as_printed() -> None:
    """DETC2015 eq (25)-(27) and docs/design.md D1 (eigenvalue moduli, DC gains)."""
    normal, uncertain = scenario("detc-normal"), scenario("detc-uncertain")
    F = np.array([[1, 0.001, 0], [0, 1, 0.001], [-557.02, -28.616, 0.9418]])
    F2 = np.array([[1, 0.001, 0], [0, 1, 0.001], [-240, -28, 0.9418]])
    for sc in (normal, uncertain):
        np.testing.assert_array_equal(sc.nominal.A, F)
        np.testing.assert_array_equal(sc.nominal.B, [[0], [0], [557.02]])
        np.testing.assert_array_equal(sc.nominal.C, [[1, 0, 0]])
        assert sc.plant_kind == "linear" and sc.duration == 1.0 and sc.n_samples == 1001
        # the filter's printed Q, R on the nominal model; the printed noise on the true plant
        np.testing.assert_array_equal(sc.nominal.Q, np.diag([1.0, 10.0, 100.0]))
        np.testing.assert_array_equal(sc.nominal.R, [[0.1]])
        np.testing.assert_allclose(np.sqrt(np.diag(sc.segments[0].model.Q)), [0.05, 0.1, 0.1], rtol=1e-15)
        np.testing.assert_allclose(np.sqrt(sc.segments[0].model.R), [[0.05]], rtol=1e-15)
        fs = sc.filter_settings
        np.testing.assert_array_equal(fs.P0, 20 * np.diag([1.0, 10.0, 100.0]))
        assert (fs.gamma, fs.psi, fs.cutoff_lambda, fs.mapping) == (0.5, (0.25,), (0.5,), "cov")
    assert normal.is_healthy and normal.fault_intervals == ()
    assert uncertain.fault_intervals == ((0.5, 1.0),)
    np.testing.assert_array_equal(uncertain.segments[1].model.A, F2)
    idx = uncertain.segment_index()
    assert idx[499] == 0 and idx[500] == 1
    np.testing.assert_allclose(np.sort(np.abs(np.linalg.eigvals(F))), [0.980, 0.9948, 0.9948], atol=5e-4)
    dc = lambda A: (np.array([[1, 0, 0]]) @ np.linalg.solve(np.eye(3) - A, [[0], [0], [557.02]]))[0, 0]  # noqa: E731
    assert dc(F) == pytest.approx(1.0, rel=1e-12) and dc(F2) == pytest.approx(557.02 / 240, rel=1e-12)
    # the listed mode is the complex pole pair of (F - I)/dt: -19.1 +- 165.8j (26.6 Hz, zeta 0.114)
    assert normal.nominal.natural_frequency_hz == pytest.approx(26.6, abs=0.05)
    assert normal.nominal.damping_ratio == pytest.approx(0.114, abs=0.0005)


def test_detc_input_is_seeded_uniform_plus_step() -> None:
    """U(-1, 1) per 1 ms sample (the same for every realization) plus a unit step at 0.5 s.

    The sequence comes from a fixed seed, so the distribution checks are deterministic; they
    guard the transcription: 500 U(-1,1) samples have mean sd 0.026 and the K-S test at 1e-3."""
    import scipy.stats

    sc = scenario("detc-uncertain")
    t = sc.time
    u = sc.input.sample(t)
    assert np.all(np.abs(u[:500]) <= 1) and np.all((u[500:] >= 0) & (u[500:] <= 2))
    np.testing.assert_array_equal(sc.input.sample(t[:300]), u[:300])  # a function of t alone
    np.testing.assert_array_equal(scenario("detc-normal").input.sample(t), u)
    assert len(np.unique(u)) == len(u)  # a new value every sample
    assert scipy.stats.kstest(u[:500], scipy.stats.uniform(-1, 2).cdf).pvalue > 1e-3
    assert scipy.stats.kstest(u[500:] - 1, scipy.stats.uniform(-1, 2).cdf).pvalue > 1e-3


def test_eha4_leak_timeline_as_the_smm_paper() -> None:
    sc = scenario("eha4-leak-timeline")
    assert sc.duration == 9.0 and sc.dt == 1e-3 and sc.n_samples == 9001
    assert sc.fault_intervals == ((3.0, 6.0), (6.0, 9.0))
    np.testing.assert_array_equal(sc.nominal.C, np.eye(4))
    np.testing.assert_array_equal(sc.nominal.Q, 1e-9 * np.eye(4))
    np.testing.assert_array_equal(sc.nominal.R, 1e-6 * np.eye(4))
    fs = sc.filter_settings
    np.testing.assert_array_equal(fs.P0, 1e-8 * np.eye(4))
    assert fs.weight_floor == 1e-3 and fs.gamma == 0.1 and fs.mapping == "full"
    assert [m.parameters["leakage"] for m in fs.mode_models] == [4.78e-12, 2.52e-11, 6.01e-11]
    modes = fs.mode_index(sc)
    assert modes[2999] == 0 and modes[3000] == 1 and modes[5999] == 1 and modes[6000] == 2 and modes[-1] == 2
    u = sc.input.sample(sc.time)
    assert np.max(np.abs(u)) == pytest.approx(94.25, rel=1e-6)


def test_eha4_imm_analogue() -> None:
    sc = scenario("eha4-imm-analogue")
    assert "ANALOGUE" in sc.description
    assert sc.dt == 1e-4 and sc.n_samples == 60001 and sc.fault_intervals == ((2.0, 4.0), (4.0, 6.0))
    np.testing.assert_array_equal(sc.nominal.C, [[1, 0, 0, 0], [0, 0, 0, 1]])
    np.testing.assert_allclose(np.sqrt(np.diag(sc.nominal.R)), [1e-7, 200.0], rtol=1e-15)
    fs = sc.filter_settings
    assert fs.modes == ("normal", "leak-minor", "friction-imm-major")
    assert fs.mu0 == (0.90, 0.05, 0.05)
    np.testing.assert_allclose(fs.transition_matrix.sum(axis=1), 1.0, rtol=0, atol=1e-15)
    assert fs.transition_matrix[0, 0] == 0.90 and fs.transition_matrix[0, 1] == 0.05
    modes = fs.mode_index(sc)
    assert modes[19999] == 0 and modes[20000] == 1 and modes[40000] == 2


def test_imm_analogue_moves_the_piston_where_the_printed_input_cannot() -> None:
    """docs/design.md I10: with +-60 rad/s the piston moves in every mode (|v| ~ 2 cm/s, a few
    direction changes per 2 s); with the printed +-5 rad/s it creeps at < 1 mm/s in the normal and
    leakage modes with hundreds of velocity sign flips (the evidence for the analogue)."""
    from chatterspec import simulate
    from chatterspec.plants.signals import SquareWave

    sc = scenario("eha4-imm-analogue")
    v = simulate(sc, runs=2, seed=0).x[0, :, 1]
    for a in (0, 20000, 40000):
        seg = v[a : a + 20000]
        assert np.max(np.abs(seg)) > 0.01
        assert np.count_nonzero(np.diff(np.sign(seg))) < 20
    literal = Scenario("literal", sc.nominal, SquareWave(1.0, 5.0), 6.0, windows=sc.windows)
    v = simulate(literal, runs=2, seed=0).x[0, :, 1]
    for a in (0, 20000):
        seg = v[a : a + 20000]
        assert np.max(np.abs(seg)) < 2e-3
        assert np.count_nonzero(np.diff(np.sign(seg))) > 200


def test_filter_settings_validation() -> None:
    from chatterspec.errors import ParameterError, ShapeError
    from chatterspec.plants.eha4 import eha4
    from chatterspec.plants.scenarios import FilterSettings

    two = {"modes": ("a", "b"), "mode_models": (eha4(), eha4("leak-minor"))}
    with pytest.raises(ParameterError, match="rows summing to 1"):
        FilterSettings(**two, transition_matrix=[[0.9, 0.2], [0.1, 0.9]])
    with pytest.raises(ParameterError, match="non-negative"):
        FilterSettings(**two, transition_matrix=[[1.1, -0.1], [0.1, 0.9]])
    with pytest.raises(ShapeError, match="transition_matrix"):
        FilterSettings(**two, transition_matrix=np.eye(3))
    with pytest.raises(ParameterError, match="sum to 1"):
        FilterSettings(**two, mu0=(0.5, 0.6))
    with pytest.raises(ParameterError, match=r"weight_floor must lie in \[0, 1/2\)"):
        FilterSettings(**two, weight_floor=0.5)
    with pytest.raises(ParameterError, match="unit circle"):
        FilterSettings(cutoff_lambda=(1.0,))
    with pytest.raises(ParameterError, match="gamma"):
        FilterSettings(gamma=1.0)
    with pytest.raises(ParameterError, match="mapping"):
        FilterSettings(mapping="inverse")
    with pytest.raises(ParameterError, match="positive semi-definite"):
        FilterSettings(P0=-np.eye(2))
    with pytest.raises(ShapeError, match="mode_models"):
        FilterSettings(modes=("a",), mode_models=())
    with pytest.raises(ShapeError, match=r"filter_settings.Q must have shape \(2, 2\)"):
        Scenario("x", second_order(5.0, 0.1), Step(), 1.0, filter_settings=FilterSettings(Q=np.eye(3)))
    with pytest.raises(TypeError, match="unexpected keyword"):
        FilterSettings(lam=0.5)


def test_cli_lists_plant_kinds(capsys: pytest.CaptureFixture[str]) -> None:
    import json

    from chatterspec.cli import main

    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    line = next(ln for ln in out.splitlines() if ln.startswith("eha4-leak-timeline"))
    assert "nonlinear" in line and "~39.08 Hz/0.5937" in line
    assert next(ln for ln in out.splitlines() if ln.startswith("detc-normal")).split()[1] == "linear"
    assert main(["scenarios", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    kinds = {e["name"]: e["plant_kind"] for e in doc["scenarios"]}
    assert kinds["eha4-imm-analogue"] == "nonlinear" and kinds["eha-healthy"] == "linear"
    assert len(kinds) == 41


def test_as_scenario_takes_every_source_the_studies_accept(tmp_path) -> None:
    """One resolver for a scenario source: a Scenario (itself), a catalogue name, a LinearModel (its
    healthy zero-input scenario of the given duration) and a model file; anything else is refused."""
    import dataclasses

    from chatterspec.errors import ParameterError
    from chatterspec.plants.modelfile import write_model_toml
    from chatterspec.plants.simulate import as_scenario, model_scenario

    sc = scenario("so-healthy-low")
    assert as_scenario(sc) is sc
    assert as_scenario("so-healthy-low").describe() == sc.describe()
    model = dataclasses.replace(second_order(10.0, 0.1), name="mine")
    own = as_scenario(model, 2.5)
    assert own.describe() == model_scenario(model, 2.5).describe()
    assert (own.name, own.nominal, own.duration, own.family) == ("mine", model, 2.5, "user")
    assert not np.any(own.input.sample(np.linspace(0.0, 2.5, 7)))  # healthy: zero input
    path = write_model_toml(tmp_path / "plant.toml", model, psi=(0.1, 0.1))
    from_file = as_scenario(str(path), 3.0)
    assert (from_file.name, from_file.duration) == ("plant", 3.0)
    np.testing.assert_array_equal(from_file.nominal.A, model.A)
    with pytest.raises(ParameterError, match="LinearModel"):
        as_scenario(3.0)  # type: ignore[arg-type]
