"""The excitation study (power vs richness and dither in closed loop) and the footprint study."""

from __future__ import annotations

import json

import numpy as np
import pytest

from chatterspec.errors import ParameterError
from chatterspec.plants.scenarios import scenario
from chatterspec.studies.closed_loop import (
    EXCITATION_REFERENCES,
    dither_signal,
    excitation_points,
    excitation_scenario,
    excitation_study,
    footprint,
    replayed_open_loop,
)


def test_hold_needs_the_dither_and_six_rad_s_per_tone_detects_the_medium_leak() -> None:
    """The hard case and its remedy, at the default detector's family-wise alpha = 0.1 %.

    Measured with 2000 runs (seed 20, ``power leakage --closed-loop --dither 0 ... 10``): held
    still without dither the medium leak is flagged in 0.10 % of runs [0.005 %, 0.46 %] (99 %
    Clopper-Pearson), the healthy loop in 0.15 %; with the 20/30/40 Hz multisine at 6 rad/s per
    tone in 99.25 % [98.6 %, 99.65 %]. Here 300 runs (seed 3): with a detection rate of at least
    98.6 %, fewer than 285 detections (95 %) has probability < 1e-6 (binomial); without dither,
    an upper 99 % bound above 5 % would need >= 8 detections, probability < 1e-4 at a rate of 0.46 %.
    """
    res = excitation_study(points=(("hold", 0.0), ("hold", 6.0)), runs=300, seed=3, progress=False)
    without, with_dither = res.detection(0, 0), res.detection(0, 1)
    assert without.ci_high < 0.05, without
    assert with_dither.count >= 285, with_dither
    assert res.smallest_dither(0, "hold") == 1
    # the price: a few hundredths of a millimetre of tracking error (measured 0.0082 -> 0.0239 mm)
    cost = res.tracking_cost_mm(0, 1)
    assert 0.005 < cost < 0.05
    assert res.false_alarm(0, 0).ci_high < 0.05 and res.false_alarm(0, 1).ci_high < 0.05


def test_richness_and_the_noisy_sensor() -> None:
    """A move excites the leak without dither; a 1 mm position sensor makes the loop its own dither.

    Deterministic facts of the design, with large margins: the catalogue's four 10-20 mm moves
    give pressure swings of 100 kPa (the leak's chattering term ~1 kPa at 0.5-2.5 Hz, where the
    healthy spectrum is ~9e4 Pa^2: detected in every run of 64); with eq 66's 1 mm sensor the PI
    loop feeds ~100 rad/s rms of noise into the pump, which excites the held actuator as much.
    """
    res = excitation_study(
        points=(("hold", 0.0), ("4-moves", 0.0)), position_noise=(1e-5, 1e-3), runs=64, seed=1, progress=False
    )
    assert res.detection(0, 0).count <= 2  # precise sensor, held still: blind
    assert res.detection(0, 1).count == 64  # moving
    assert res.detection(1, 0).count == 64  # noisy sensor: the loop excites itself
    assert res.u_rms[1, 0, 0] > 60.0 and res.u_rms[0, 0, 0] < 5.0  # pump speed RMS, rad/s
    doc = res.to_dict()
    assert doc["smallest_dither_for_95_percent"][0]["dither_tried"] is False
    json.dumps(doc)


def test_a_reference_dither_is_priced_against_the_undithered_reference() -> None:
    """0.15 mm of multisine on the reference ~ kp b 0.15 mm = 7.7 rad/s per tone on the pump: detected.

    (128 runs measured 100 %, [95.9, 100] %; the tracking error is taken against the task's reference,
    so the dither the position follows counts as a cost: +0.022 mm.)
    """
    res = excitation_study(
        points=(("hold", 0.0), ("hold", 0.15)), dither_at="reference", runs=32, seed=1, progress=False
    )
    assert res.detection(0, 1).count >= 30 and res.detection(0, 0).count == 0
    assert "mm on the reference" in res.dither_description
    assert 0.01 < res.tracking_cost_mm(0, 1) < 0.05


def test_design_points_and_bad_input() -> None:
    pts = excitation_points()
    assert pts[0] == ("hold", 0.0) and ("hold", 6.0) in pts and ("4-steps", 0.0) in pts
    assert {r for r, d in pts if d > 0} == {"hold"}
    assert excitation_points(["hold", "1-move"], [0, 2]) == (
        ("hold", 0.0),
        ("hold", 2.0),
        ("1-move", 0.0),
        ("1-move", 2.0),
    )
    with pytest.raises(ParameterError, match=r"must lie in \[0, 300\) rad/s"):
        excitation_scenario("leakage", 6e-11, "hold", dither_signal("multisine", 120.0))
    with pytest.raises(ParameterError, match="unknown reference"):
        excitation_scenario("leakage", 6e-11, "wiggle")
    with pytest.raises(ParameterError, match="closed-loop study covers"):
        excitation_study("f0", runs=1)
    with pytest.raises(ParameterError, match="dither level must be"):
        dither_signal("multisine", -1.0)
    assert dither_signal("prbs", 2.0).peak == 2.0 and dither_signal("multisine", 0.0) is None
    assert len(EXCITATION_REFERENCES) == 8


def test_power_cli_closed_loop(capsys: pytest.CaptureFixture[str], tmp_path) -> None:  # type: ignore[no-untyped-def]
    from chatterspec.cli import main

    out = tmp_path / "exc.png"
    code = main(
        ["power", "leakage", "--closed-loop", "--dither", "0", "6", "--runs", "8", "--plot", str(out)]
    )
    assert code == 0 and out.exists()
    text = capsys.readouterr().out
    assert "smallest dither with >= 95 % detection" in text or "no dither level tried" in text
    assert main(["power", "friction", "--closed-loop", "--references", "hold", "--runs", "4", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["channel"] == "velocity" and doc["points"][0]["reference"] == "hold"
    assert main(["power", "leakage", "--dither", "1"]) == 2  # one line on stderr, exit 2
    assert "--dither needs --closed-loop" in capsys.readouterr().err


def test_integral_action_hides_the_leak_in_the_position_not_in_the_chattering() -> None:
    """Fault minus healthy on the same noise: the loop holds the position and moves the fault into u.

    Measured at 100 runs: position change 0.019 mm RMS under the loop, 0.375 mm when the healthy
    loop's command is replayed open loop (no correction); pump speed change 3.8 rad/s RMS. The
    pressure chattering flags the leak in every run in both cases (the filter is given the
    measured u). Margins of 5x on deterministic-size effects, 20 runs.
    """
    sc = scenario("eha-cl-leak-medium")
    closed = footprint(sc, runs=20, seed=0)
    replay = footprint(replayed_open_loop(sc), runs=20, seed=0)
    p = closed.channels.index("pressure")
    assert closed.detection[p] == 1.0 and replay.detection[p] == 1.0
    assert replay.delta_rms[0] > 5 * closed.delta_rms[0]
    assert closed.delta_u_rms > 1.0 and replay.delta_u_rms == 0.0
    assert closed.peak_hz[p] < 5.0  # the moves' band, not the open-loop chirp's 10-100 Hz
    assert np.argmax(closed.band_excess[:, p]) == 0
    held = footprint("eha-cl-hold-leak-medium", runs=20, seed=0)
    assert held.detection[p] <= 0.05
    with pytest.raises(ParameterError, match="faulty scenario"):
        footprint("eha-cl-healthy", runs=2)
