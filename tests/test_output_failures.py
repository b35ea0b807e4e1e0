"""A recording that cannot be written (disk full): the result is printed first, then one line, exit 2.

``/dev/full`` accepts the open and fails every write with ENOSPC, as a full disk does, so the
path check before the computation passes and the failure comes from the write itself.
"""

from __future__ import annotations

import gc
import json
import os
import sys
from pathlib import Path

import pytest

from chatterspec.cli import main

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_MODEL = ROOT / "examples" / "eha_model.toml"
EXAMPLE_DATA = ROOT / "examples" / "eha_data.csv"

pytestmark = pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full (Linux)")


@pytest.fixture
def full(tmp_path: Path) -> Path:
    link = tmp_path / "full.rrd"
    link.symlink_to("/dev/full")
    return link


def _one_error_line(err: str) -> None:
    # the monitor states its alarm rule on stderr before it starts, and a first run for a model notes that
    # it computes (and caches) the alarm threshold: information lines, not errors
    lines = [
        s
        for s in err.splitlines()
        if s.strip() and not s.startswith("chatterspec monitor: alarms: ") and ": note: " not in s
    ]
    assert len(lines) == 1 and "No space left on device" in lines[0] and "Traceback" not in err, err
    assert lines[0].startswith("chatterspec ") and ": error: --record " in lines[0]


def _quiet_start(capsys) -> None:
    # Objects left by earlier tests (e.g. a notebook kernel's sockets) may print a ResourceWarning on
    # stderr when they are collected; collect them now and drop that text, so the assertions below read
    # only what the command wrote.
    gc.collect()
    capsys.readouterr()


@pytest.mark.parametrize(
    ("argv", "result"),
    [
        (["detect", "eha-leak-major"], "fault detected: YES"),
        (
            ["monitor", str(EXAMPLE_MODEL), "--data", str(EXAMPLE_DATA)],
            "8.00 s of data, 36 frames",
        ),
        (["estimate", "detc-normal", "--runs", "2", "--filters", "kf", "--no-progress"], "NEES"),
        (["diagnose", "eha4-leak-timeline", "--methods", "smm", "--runs", "1", "--no-progress"], "smm"),
    ],
)
def test_result_first_then_one_line_exit_2(argv: list[str], result: str, full: Path, capsys) -> None:
    _quiet_start(capsys)
    assert main([*argv, "--record", str(full)]) == 2
    out, err = capsys.readouterr()
    assert result in out
    _one_error_line(err)


def test_json_stays_one_document(full: Path, capsys) -> None:
    _quiet_start(capsys)
    assert main(["detect", "eha-leak-major", "--json", "--record", str(full)]) == 2
    out, err = capsys.readouterr()
    assert json.loads(out)["detected"] is True
    _one_error_line(err)


def test_stream_stops_before_reading_when_the_recording_cannot_open(
    full: Path, tmp_path: Path, capsys, monkeypatch
) -> None:
    _quiet_start(capsys)
    with EXAMPLE_DATA.open() as fh:
        monkeypatch.setattr(sys, "stdin", fh)
        rc = main(["monitor", str(EXAMPLE_MODEL), "--data", "-", "--record", str(full)])
    out, err = capsys.readouterr()
    assert rc == 2 and out == ""
    _one_error_line(err)
    assert "nothing was monitored" in err
