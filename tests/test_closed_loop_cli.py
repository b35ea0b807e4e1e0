"""The closed-loop scenarios in every command that takes a scenario (small run counts)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main


def _json(capsys: pytest.CaptureFixture[str], argv: list[str]) -> dict:
    assert main(argv) == 0
    return json.loads(capsys.readouterr().out)


def test_detect_far_calibrate(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    doc = _json(capsys, ["detect", "eha-cl-bulk-25down", "--json"])
    pressure = next(c for c in doc["channels"] if c["channel"] == "pressure")
    assert pressure["detected"] and doc["fault_intervals_true"] == [[2.0, 4.0]]
    onsets = [iv["onset_s"] for iv in doc["intervals"] if iv["channel"] == "any"]
    assert onsets and min(onsets) >= 1.8  # the STFT places the fault in its window
    far = _json(capsys, ["far", "eha-cl-healthy", "--runs", "64", "--alpha", "0.01", "--json"])
    assert far["scenario"] == "eha-cl-healthy"
    cal = tmp_path / "cal.npz"
    assert (
        # 100 runs: alpha 0.01 per record needs >= 99 (fewer and detect refuses the file)
        main(["calibrate", "eha-cl-hold-healthy", "--runs", "100", "--alpha", "0.01", "--out", str(cal)]) == 0
    )
    capsys.readouterr()
    # the calibration of the held loop serves the moving one: same nominal model and record length
    doc = _json(capsys, ["detect", "eha-cl-leak-major", "--calibration", str(cal), "--json"])
    assert doc["threshold"]["kind"] == "empirical" and doc["detected"]


def test_simulate_stream_feeds_the_monitor(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    toml = tmp_path / "eha-cl.toml"
    assert main(["scenarios", "eha-cl-leak-major", "--model-toml", str(toml)]) == 0
    capsys.readouterr()
    assert main(["simulate", "eha-cl-leak-major", "--rate", "0", "--duration", "3"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    assert lines[0] == "time,position,velocity,pressure,pump_speed"
    data = np.loadtxt(lines[1:], delimiter=",")
    assert data.shape == (3001, 5) and np.abs(data[:, 4]).max() <= 300.0
    k = np.searchsorted(data[:, 0], 1.1)  # after the first S-curve move to 10 mm
    assert abs(data[k, 1] - 0.01) < 1e-3
    csv = tmp_path / "stream.csv"
    csv.write_text(text)
    assert main(["monitor", str(toml), "--data", str(csv), "--events", "jsonl"]) == 0
    events = [json.loads(ln) for ln in capsys.readouterr().out.splitlines() if ln.startswith("{")]
    assert any(e["event"] == "fault-start" and e["channel"] == "pressure" for e in events)


def test_diagnose_a_closed_loop_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    doc = _json(
        capsys,
        [
            "diagnose",
            "eha-cl-bulk-25down",
            "--runs",
            "4",
            "--calibration-runs",
            "64",
            "--json",
            "--no-progress",
        ],
    )
    text = json.dumps(doc)
    assert "chattering" in text and "eha-cl-bulk-25down" in text
