"""What the commands print and write is accurate: no "nan" as a figure, file headers about the file."""

from __future__ import annotations

import re
from pathlib import Path

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.plants.modelfile import load_model


def test_diagnose_a_scenario_faulty_from_the_start_prints_no_nan(capsys) -> None:
    argv = ["diagnose", "eha-leak-minor", "--runs", "2", "--calibration-runs", "40", "--no-progress"]
    assert main([*argv, "--per-record"]) == 0
    out = capsys.readouterr().out
    assert not re.search(r"\bnan\b", out, flags=re.IGNORECASE), out
    assert "n/a (no healthy part)" in out and "no healthy frames" in out
    assert main(argv) == 0  # at a budget: no healthy time to measure the realized rate on
    out = capsys.readouterr().out
    assert not re.search(r"\bnan\b", out, flags=re.IGNORECASE), out
    assert "n/a (no healthy part; --onset S gives one)" in out


def test_model_toml_header_describes_the_nominal_model_in_the_file(tmp_path: Path, capsys) -> None:
    path = tmp_path / "leak.toml"
    assert main(["scenarios", "eha-leak-major", "--model-toml", str(path)]) == 0
    header = [s for s in path.read_text().splitlines() if s.startswith("#")]
    nominal = cs.scenario("eha-leak-major").nominal
    assert load_model(path).model.name == nominal.name
    first = header[0]
    assert first.startswith("# Nominal (healthy) model") and nominal.name in first
    assert f"{nominal.natural_frequency_hz:.4g} Hz" in first  # 39.07 Hz: the healthy EHA of Table 1
    assert "leakage = 9e-11" not in first  # the faulty true plant is not what the file holds
    assert any("true plant differs" in s and "leakage = 9e-11" in s for s in header[1:])
