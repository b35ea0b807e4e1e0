"""``detect`` and ``diagnose`` take --workers (and --scheduler) like the other Monte Carlo commands, with the
same numbers. Two worker processes start per test (a few seconds each): the runs are kept small."""

from __future__ import annotations

import json

import pytest

from chatterspec.cli import main


def _json(capsys, argv: list[str]) -> dict:
    assert main(argv) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def test_detect_with_workers_gives_the_serial_report(capsys) -> None:
    # 300 runs: chunks [0, 256) and [256, 300) (the serial path's chunks), one per worker
    argv = ["detect", "so-timeline-step", "--runs", "300", "--seed", "3", "--json", "--no-progress"]
    serial = _json(capsys, argv)
    parallel = _json(capsys, [*argv, "--workers", "2"])
    assert parallel == serial
    assert serial["runs"] == 300 and "intervals" in serial  # the averaged verdict and run 0's STFT too


def _without_timings(doc: dict) -> dict:
    doc.pop("simulation_s")
    for m in doc["methods"]:
        m.pop("steps_per_second")  # the filters' own time: not a result
        m["calibration"].pop("seconds", None)
    return doc


def test_diagnose_with_workers_gives_the_serial_figures(capsys) -> None:
    # 70 runs: chunks of 64 and 6 realizations on two workers, folded in chunk order
    argv = [
        "diagnose",
        "so-timeline-step",
        "--runs",
        "70",
        "--calibration-runs",
        "30",
        "--json",
        "--no-progress",
        "--per-record",  # the former table (the budget comparison's workers test: test_budget_diagnosis.py)
    ]
    serial = _without_timings(_json(capsys, argv))
    parallel = _without_timings(_json(capsys, [*argv, "--workers", "2"]))
    assert parallel == serial
    (m,) = serial["methods"]
    assert m["runs"] == 70 and m["onsets_s"]


@pytest.mark.parametrize("command", ["detect", "diagnose"])
def test_workers_must_be_positive(command: str, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main([command, "so-timeline-step", "--workers", "0"])
    assert exc.value.code == 2 and "expected an integer >= 1" in capsys.readouterr().err
