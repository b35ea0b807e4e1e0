"""Options the command would silently ignore or misuse are refused with a message that says what to fix."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_MODEL = ROOT / "examples" / "eha_model.toml"
EXAMPLE_DATA = ROOT / "examples" / "eha_data.csv"
MONITOR = ["monitor", str(EXAMPLE_MODEL), "--data", str(EXAMPLE_DATA)]


def _error(capsys, argv: list[str]) -> str:
    assert main(argv) == 2, argv
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err


@pytest.mark.parametrize(
    ("argv", "named"),
    [
        (["detect", "eha-healthy", "--alpha", "0.01"], "--alpha"),
        (["detect", "eha-healthy", "--threshold", "paper"], "--threshold"),
        (["detect", "eha-healthy", "--correction", "sidak", "--alpha", "0.01"], "--alpha and --correction"),
        (["diagnose", "eha4-leak-onset", "--alpha", "0.01"], "--alpha"),
        # (at a budget --calibration-runs also sets every route's healthy streams: allowed there)
        (["diagnose", "eha4-leak-onset", "--per-record", "--calibration-runs", "50"], "--calibration-runs"),
        (
            ["monitor", str(EXAMPLE_MODEL), "--data", str(EXAMPLE_DATA), "--alpha", "0.01"],
            "--alpha",
        ),
    ],
)
def test_options_a_calibration_overrides_are_refused(argv: list[str], named: str, capsys) -> None:
    # refused before the file is even read (it does not exist here): nothing is computed
    err = _error(capsys, [*argv, "--calibration", "no-such-calibration.npz"])
    assert f"{named} cannot be used with --calibration" in err


def test_a_file_that_is_not_a_calibration_is_named_as_such(tmp_path: Path, capsys) -> None:
    data = tmp_path / "data.npz"
    np.savez(data, time=np.arange(3.0), position=np.zeros(3))
    err = _error(capsys, ["detect", "eha-healthy", "--calibration", str(data)])
    assert "not a chatterspec calibration file" in err and "[position, time]" in err
    assert "has no the entry" not in err
    err = _error(capsys, ["detect", "eha-healthy", "--calibration", str(EXAMPLE_MODEL)])
    assert "not a chatterspec calibration file" in err and "JSONDecodeError" not in err


@pytest.mark.parametrize(
    ("key", "line", "message"),
    [
        (
            "R_diag",
            "R_diag = [-1e-06, 1e-06, 1000000]",
            "[matrices] R_diag holds variances, which must be >= 0",
        ),
        ("Q_diag", "Q_diag = [-1e-12, 1e-06, 1]", "[matrices] Q_diag holds variances, which must be >= 0"),
        ("R_diag", "R = [[1e-06, 0, 0], [0, -1e-06, 0], [0, 0, 1e6]]", "[matrices] R must be positive"),
    ],
)
def test_negative_variances_name_the_file_and_field(
    key: str, line: str, message: str, tmp_path: Path, capsys
) -> None:
    text = "\n".join(line if s.startswith(f"{key} =") else s for s in EXAMPLE_MODEL.read_text().splitlines())
    bad = tmp_path / "bad.toml"
    bad.write_text(text + "\n")
    err = _error(capsys, ["monitor", str(bad), "--data", str(EXAMPLE_DATA)])
    assert f"model file {str(bad)!r}" in err and message in err


def test_record_every_below_the_minimum_is_refused(capsys) -> None:
    argv = ["monitor", str(EXAMPLE_MODEL), "--data", "-", "--record", "x.rrd"]
    err = _error(capsys, [*argv, "--record-every", "0.0001"])
    assert "--record-every must be >= 0.05 minutes" in err


# Each case once hung, wrote a traceback or was accepted silently; now one line and exit 2, before
# any simulation (the hours and budget bounds are checked from the model and STFT alone).
@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([*MONITOR, "--alarm-hours", "1e9"], "give at most 621.4 h for this model (--alarm-hours)"),
        (
            ["calibrate", str(EXAMPLE_MODEL), "--rule", "cusum", "--alarm-hours", "1e12"],
            "more than the alarm calibration can hold",
        ),
        (
            ["calibrate", str(EXAMPLE_MODEL), "--rule", "frame", "--alarm-hours", "0.0001"],
            "give 0 STFT frame(s) of 1 s (hop 0.2 s); the alarm calibration needs at least 2",
        ),
        (
            [*MONITOR, "--rule", "frame", "--false-alarms-per-hour", "1e9"],
            "raise at most 27000 alarm starts per hour (one per two steps per channel)",
        ),
        (
            ["power", "leakage", "--closed-loop", "--dither", "5", "--dither-hz", "600", "--runs", "2"],
            "multisine tones must lie below the Nyquist frequency 500 Hz",
        ),
        (
            ["power", "leakage", "--closed-loop", "--dither-signal", "prbs", "--dither-hz", "20"],
            "--dither-signal prbs has none",
        ),
        (  # the parent folders were created
            [*MONITOR, "--record", "/nonexistent/dir/x.rrd"],
            "the folder '/nonexistent/dir' does not exist (create it first)",
        ),
        (  # silently ignored: the identification events are JSON lines
            [*MONITOR, "--identification-events", "changes"],
            "--identification-events writes JSON lines: it needs --events jsonl",
        ),
        (  # said "'/etc/passwd' File exists"
            ["scenarios", "eha-leak-major", "--model-toml", "/etc/passwd/x.toml"],
            "--model-toml '/etc/passwd/x.toml' cannot be written: '/etc/passwd' is not a folder",
        ),
    ],
)
def test_the_boundary_closes(argv: list[str], message: str, capsys, monkeypatch) -> None:
    from chatterspec.studies import alarm_budget, closed_loop
    from chatterspec.studies.calibration import thresholds

    def forbid(*_a, **_k):
        raise AssertionError("simulated before refusing")

    monkeypatch.setattr(alarm_budget, "healthy_chattering", forbid)
    monkeypatch.setattr(thresholds, "calibrate", forbid)
    monkeypatch.setattr(closed_loop, "_ExcitationChunks", forbid)
    assert message in _error(capsys, argv)


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        # exited 1 (where every other data error exits 2), after the alarm threshold was simulated
        (300, "300 rows give 299 chattering samples (0.299 s), fewer than one STFT window of 1000 samples"),
        # reported only after the alarm simulation
        (-1, "line 1003: 'oops' is not a number"),
    ],
)
def test_data_files_are_checked_before_any_simulation(
    rows: int, message: str, tmp_path: Path, capsys, monkeypatch
):
    from chatterspec.studies import alarm_budget

    def forbid(*_a, **_k):
        raise AssertionError("simulated before the data file was read")

    monkeypatch.setattr(alarm_budget, "healthy_chattering", forbid)
    lines = EXAMPLE_DATA.read_text().splitlines()
    head, body = lines[:2], lines[2:]
    body = body[:rows] if rows > 0 else [*body[:1000], "1.0,2.0,oops,4.0,5.0", *body[1000:]]
    data = tmp_path / "d.csv"
    data.write_text("\n".join([*head, *body]) + "\n")
    assert message in _error(capsys, ["monitor", str(EXAMPLE_MODEL), "--data", str(data)])
    if rows < 0:  # a followed file: its header is read before the simulation too
        data.write_text("time,position,velocity\n")
        argv = ["monitor", str(EXAMPLE_MODEL), "--data", str(data), "--follow", "--idle-timeout", "1"]
        assert "the header lacks column(s) ['pressure', 'pump_speed']" in _error(capsys, argv)
