"""Output paths and small CLI defects.

Every writing command checks its path before computing (the computation is
replaced by a function that fails the test if it is reached), fails with one
line and exit 2, and a write that still fails at the end prints the result
first. No ``OSError`` reaches the user as a traceback.
"""

from __future__ import annotations

import errno
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main
from chatterspec.errors import ParameterError
from chatterspec.viewer.sinks import viewer_url

HAS_PROC = Path("/proc").is_dir()  # the reproductions use /proc (not writable, even for root)


def _forbid(*_a, **_k):
    raise AssertionError("the computation started although the output path is unusable")


def _one_line_error(err: str, *words: str) -> None:
    # notes (e.g. the in-call alarm calibration's, on its first run) may come before the error
    lines = [ln for ln in err.strip().splitlines() if ln and ": note: " not in ln]
    assert len(lines) == 1, err
    assert "Traceback" not in err and "error:" in lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])


@pytest.fixture
def not_a_folder(tmp_path: Path) -> Path:
    """A regular file: any path below it cannot be created (portable stand-in for /proc)."""
    f = tmp_path / "plain-file"
    f.write_text("x")
    return f


@pytest.fixture
def no_compute(monkeypatch):
    import chatterspec.figures.paper_figures as pf
    import chatterspec.plants.simulate as sim
    import chatterspec.studies.calibration.thresholds as cal_cli
    import chatterspec.studies.detection_rates as far_cli
    import chatterspec.studies.detection_rates as power_cli

    monkeypatch.setattr(sim, "simulate", _forbid)
    monkeypatch.setattr(power_cli, "power_study", _forbid)
    monkeypatch.setattr(cal_cli, "calibrate", _forbid)
    monkeypatch.setattr(far_cli, "false_alarm_study", _forbid)
    monkeypatch.setattr(pf, "scenario_spectrum", _forbid)
    monkeypatch.setattr(pf, "render", _forbid)


@pytest.mark.skipif(not HAS_PROC, reason="needs /proc")
@pytest.mark.parametrize(
    "argv, option",
    [
        (["detect", "eha-healthy", "--record", "/proc/x.rrd"], "--record"),
        (["power", "f0", "--runs", "64", "--plot", "/proc/p.png"], "--plot"),
        (["spectrum", "eha-healthy", "--plot", "/proc/nope/x.png"], "--plot"),
        (["calibrate", "eha-healthy", "--runs", "64", "--out", "/proc/c.json"], "--out"),
        (["figures", "--figures-dir", "/proc/nope"], "--figures-dir"),
        (["demo", "--recordings-dir", "/proc/nope"], "--recordings-dir"),
        (["demo", "--no-record", "--figures-dir", "/proc/nope"], "--figures-dir"),
        (["far", "eha-healthy", "--runs", "64", "--plot", "/proc/f.png"], "--plot"),
    ],
)
def test_issue_reproductions_fail_before_computing(argv, option, no_compute, capsys) -> None:
    assert main(argv) == 2
    _one_line_error(capsys.readouterr().err, option, "cannot be written")


def test_existing_folder_as_record_file(tmp_path: Path, no_compute, capsys) -> None:
    d = tmp_path / "d.rrd"
    d.mkdir()
    assert main(["detect", "eha-healthy", "--record", str(d)]) == 2
    _one_line_error(capsys.readouterr().err, "--record", "existing folder")


@pytest.mark.parametrize(
    "make_argv",
    [
        lambda f: ["detect", "eha-healthy", "--record", str(f / "x.rrd")],
        lambda f: ["power", "f0", "--plot", str(f / "sub" / "p.png")],
        lambda f: ["spectrum", "eha-healthy", "--plot", str(f / "x.png")],
        lambda f: ["calibrate", "eha-healthy", "--out", str(f / "c.json")],
        lambda f: ["calibrate", "eha-healthy", "--plot", str(f / "c.png")],
        lambda f: ["far", "eha-healthy", "--plot", str(f / "f.png")],
        lambda f: ["figures", "--figures-dir", str(f)],  # an existing file where a folder is meant
        lambda f: ["demo", "--recordings-dir", str(f / "r")],
    ],
)
def test_unwritable_parent_fails_before_computing(make_argv, not_a_folder, no_compute, capsys) -> None:
    assert main(make_argv(not_a_folder)) == 2
    _one_line_error(capsys.readouterr().err)


def test_unknown_figure_suffix_rejected_before_computing(tmp_path: Path, no_compute, capsys) -> None:
    assert main(["power", "f0", "--plot", str(tmp_path / "p.xyz")]) == 2
    _one_line_error(capsys.readouterr().err, "--plot", ".png")


def test_calibrate_prints_result_when_the_final_write_fails(tmp_path: Path, monkeypatch, capsys) -> None:
    """The check passes, then the disk fills up: the table is printed, then one error line, exit 2."""
    from chatterspec.studies.calibration.result import Calibration

    def full(self, path):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(Calibration, "save", full)
    out = tmp_path / "c.json"
    rc = main(
        ["calibrate", "eha-healthy", "--runs", "8", "--alpha", "0.2", "--no-progress", "--out", str(out)]
    )
    cap = capsys.readouterr()
    assert rc == 2
    assert "calibration of eha-healthy" in cap.out and "per-bin agreement" in cap.out
    _one_line_error(cap.err, "--out", "No space left on device", "computed but not saved")
    assert not out.exists()


def test_detect_json_printed_when_the_recording_fails(tmp_path: Path, monkeypatch, capsys) -> None:
    from chatterspec.viewer import recordings

    def sink_fails(*_a, **_k):  # what rerun raises when its file sink cannot be created
        raise RuntimeError("Failed to create file: No space left on device (os error 28), path: x.rrd")

    monkeypatch.setattr(recordings, "record_detection", sink_fails)
    rc = main(["detect", "eha-healthy", "--json", "--record", str(tmp_path / "x.rrd")])
    cap = capsys.readouterr()
    assert rc == 2
    doc = json.loads(cap.out)
    assert doc["scenario"] == "eha-healthy" and "recording" not in doc
    _one_line_error(cap.err, "--record", "No space left on device")


def test_no_traceback_for_any_oserror(monkeypatch, capsys) -> None:
    import chatterspec.cli.scenarios as sc_cli

    def denied(args):
        raise PermissionError(errno.EACCES, "Permission denied", "/somewhere/file")

    monkeypatch.setattr(sc_cli, "run", denied)
    assert main(["scenarios"]) == 2
    _one_line_error(capsys.readouterr().err, "Permission denied", "/somewhere/file")


# ------------------------------------------------------------------------------ hints and small defects
def test_detect_record_hint_names_the_real_file(tmp_path: Path, capsys) -> None:
    rrd = tmp_path / "rec.rrd"
    assert main(["detect", "eha-healthy", "--record", str(rrd)]) == 0
    out = capsys.readouterr().out
    assert f"chatterspec replay {rrd}" in out and "FILE.rrd" not in out
    assert rrd.stat().st_size > 0


def test_spectrum_default_output_goes_under_figures(tmp_path: Path, monkeypatch, capsys) -> None:
    import matplotlib.pyplot as plt

    import chatterspec.figures.paper_figures as pf

    class Fake:
        figure = plt.figure(figsize=(1, 1))
        notes = ()

    monkeypatch.setattr(pf, "scenario_spectrum", lambda *a, **k: Fake())
    monkeypatch.chdir(tmp_path)
    assert main(["spectrum", "eha-healthy"]) == 0
    assert (tmp_path / "figures" / "eha-healthy-spectrum.png").is_file()
    assert not (tmp_path / "eha-healthy-spectrum.png").exists()


@pytest.mark.parametrize("bad", ["foo", "localhost", "host:port", "http://127.0.0.1:9876", "1.2.3.4:99999"])
def test_live_rejects_what_is_not_a_viewer_address(bad: str, capsys) -> None:
    with pytest.raises(ParameterError):
        viewer_url(bad)
    with pytest.raises(SystemExit) as exc:
        main(["detect", "eha-healthy", "--live", bad])
    assert exc.value.code == 2
    assert "--live" in capsys.readouterr().err


@pytest.mark.parametrize(
    "good, url",
    [
        ("9876", "rerun+http://127.0.0.1:9876/proxy"),
        ("example.org:9877", "rerun+http://example.org:9877/proxy"),
        ("rerun+http://127.0.0.1:9876/proxy", "rerun+http://127.0.0.1:9876/proxy"),
    ],
)
def test_live_accepts_urls_ports_and_host_port(good: str, url: str) -> None:
    assert viewer_url(good) == url


def test_unreachable_viewer_is_one_clean_line(tmp_path: Path) -> None:
    """In a real process (pytest would capture a raw ``warnings`` line): one clean line, no source path."""
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = ["detect", "eha-healthy", "--record", str(tmp_path / "u.rrd"), "--live", f"127.0.0.1:{port}"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "PYTHONWARNINGS": "default"}
    proc = subprocess.run(
        [sys.executable, "-m", "chatterspec", *argv], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if "unreachable" in ln]
    assert len(lines) == 1, proc.stderr
    assert "Warning" not in proc.stderr and ".py:" not in proc.stderr  # no raw `warnings` line


def _short_data(tmp_path: Path, samples: int) -> Path:
    src = Path(__file__).resolve().parents[1] / "examples" / "eha_data.csv"
    lines = src.read_text().splitlines()
    head = [ln for ln in lines[:5] if ln.startswith("#") or ln.startswith("time")]
    body = [ln for ln in lines if ln and ln[0].isdigit()][:samples]
    out = tmp_path / "short.csv"
    out.write_text("\n".join(head + body) + "\n")
    return out


def test_monitor_on_data_shorter_than_one_window(tmp_path: Path, monkeypatch, capsys) -> None:
    """A data error like the others: one line, exit 2, before the alarm threshold is simulated."""
    from chatterspec.studies import alarm_budget

    monkeypatch.setattr(alarm_budget, "healthy_chattering", _forbid)
    model = Path(__file__).resolve().parents[1] / "examples" / "eha_model.toml"
    data = _short_data(tmp_path, 300)  # 0.3 s at dt = 1 ms; the STFT window is 1 s
    argv = ["monitor", str(model), "--data", str(data)]
    for extra in ([], ["--json"]):
        assert main([*argv, *extra]) == 2
        out, err = capsys.readouterr()
        assert out == ""
        _one_line_error(err, "300 rows give 299 chattering samples", "fewer than one STFT window of 1000")


def test_monitor_ctrl_c_names_the_partial_recording(tmp_path: Path, monkeypatch, capsys) -> None:
    from chatterspec.viewer import recordings

    real = recordings.run_monitor

    def interrupted(monitor, sinks, **kw):
        kw["on_event"] = None
        kw["z"], kw["u"] = kw["z"][:1500], kw["u"][:1500]
        real(monitor, sinks, **kw)  # closes the sinks (footer written), then the user hits Ctrl-C
        raise KeyboardInterrupt

    monkeypatch.setattr(recordings, "run_monitor", interrupted)
    model = Path(__file__).resolve().parents[1] / "examples" / "eha_model.toml"
    data = _short_data(tmp_path, 2000)
    rrd = tmp_path / "part.rrd"
    rc = main(["monitor", str(model), "--data", str(data), "--record", str(rrd)])
    err = capsys.readouterr().err
    assert rc == 130
    assert f"partial recording: {rrd}" in err and rrd.stat().st_size > 0


def test_chunk_runs_not_a_multiple_of_64_is_rounded_with_a_note(monkeypatch, capsys) -> None:
    import chatterspec.studies.calibration.thresholds as cal_cli

    seen = {}

    def fake(name, **kw):
        seen.update(kw)
        raise ParameterError("stop here")

    monkeypatch.setattr(cal_cli, "calibrate", fake)
    assert main(["calibrate", "eha-healthy", "--chunk-runs", "10"]) == 2
    assert seen["chunk_runs"] == 64
    assert "--chunk-runs 10 rounded up to 64" in capsys.readouterr().err


def test_estimate_rounds_chunk_runs_as_its_help_says(monkeypatch, capsys) -> None:
    import chatterspec.studies.estimation as est

    seen = {}

    def fake(name, filters, **kw):
        seen.update(kw)
        raise ParameterError("stop here")

    monkeypatch.setattr(est, "estimation_study", fake)
    assert main(["estimate", "detc-uncertain", "--chunk-runs", "100"]) == 2  # was taken as 100
    assert seen["chunk_runs"] == 128
    assert "--chunk-runs 100 rounded up to 128" in capsys.readouterr().err


def test_replay_rejects_a_file_that_is_not_a_recording(tmp_path: Path, capsys) -> None:
    for name, payload in (("x.txt", b"hello"), ("fake.rrd", b"not a recording")):
        f = tmp_path / name
        f.write_bytes(payload)
        assert main(["replay", str(f)]) == 2
        _one_line_error(capsys.readouterr().err, "not a Rerun recording")


def test_replay_accepts_a_real_recording_header(tmp_path: Path) -> None:
    from chatterspec.cli.replay import RRD_MAGIC, _is_rrd

    f = tmp_path / "ok.rrd"
    f.write_bytes(RRD_MAGIC + np.zeros(8, np.uint8).tobytes())
    assert _is_rrd(f)
