"""The on-disk cache of the in-call alarm calibration (``chatterspec._cache``, ``calibrate_alarm``).

The healthy frame scores are computed once (a quarter of an hour of the EHA) and then stand in for
the simulation, so each case costs only the rule's calibration; a recomputation is seen by the
stand-in being called.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest

from chatterspec import _cache
from chatterspec.detection.spectral import STFTConfig
from chatterspec.online.monitor import MonitorSettings
from chatterspec.plants.scenarios import scenario
from chatterspec.studies import alarm_budget
from chatterspec.studies.alarm_budget import CACHE_KIND, calibrate_alarm

HOURS = 0.25


@pytest.fixture(scope="module")
def model():
    return scenario("eha-healthy").nominal


@pytest.fixture(scope="module")
def scores(model):
    return alarm_budget.healthy_frame_scores(model, MonitorSettings(), HOURS, seed=0, progress=False)


@pytest.fixture
def cache(tmp_path: Path, monkeypatch, scores):
    """A fresh cache folder, an empty in-process cache, and the simulation replaced by ``scores``
    (``calls`` counts the simulations)."""
    monkeypatch.setenv(_cache.CACHE_DIR_ENV, str(tmp_path / "cache"))
    monkeypatch.delenv(_cache.NO_CACHE_ENV, raising=False)
    monkeypatch.setattr(alarm_budget, "_CACHE", {})
    calls: list[float] = []

    def simulated(model, settings, hours, seed=0, *, scenario=None, progress=None, threshold=None):
        calls.append(hours)
        return scores

    monkeypatch.setattr(alarm_budget, "healthy_frame_scores", simulated)
    return tmp_path / "cache" / CACHE_KIND, calls


def _calibrate(model, settings=None, rule="cusum", budget=200.0, **kw):
    alarm_budget._CACHE.clear()  # a new process: only the disk remains
    return calibrate_alarm(model, settings or MonitorSettings(), rule, budget, hours=HOURS, **kw)


def test_a_cache_hit_returns_the_identical_calibration(model, cache) -> None:
    folder, calls = cache
    notes: list[str] = []
    first = _calibrate(model, note=notes.append)
    assert calls == [HOURS] and len(notes) == 1
    assert "calibrating the cusum alarm threshold" in notes[0] and str(folder) in notes[0]
    assert len(list(folder.glob("*.json"))) == 1
    again = _calibrate(model, note=notes.append)
    assert calls == [HOURS] and len(notes) == 1  # read back: no simulation, no note
    assert again == first and again.threshold == first.threshold  # bit for bit, intervals and fit too


@pytest.mark.parametrize(
    "change",
    [
        {"seed": 1},
        {"budget": 150.0},
        {"rule": "persistence"},
        {"confidence": 0.99},
        {"settings": MonitorSettings(stft=STFTConfig(hop_s=0.25))},
        {"settings": MonitorSettings(band=(20.0, 200.0))},
        {"settings": MonitorSettings(alpha=0.01)},
    ],
    ids=lambda c: next(iter(c)),
)
def test_a_changed_setting_misses(model, cache, change) -> None:
    folder, calls = cache
    base = _calibrate(model)
    other = _calibrate(model, **change)
    assert len(calls) == 2 and len(list(folder.glob("*.json"))) == 2
    if "seed" not in change and "confidence" not in change and "settings" not in change:
        assert other != base


def test_a_changed_model_misses(model, cache) -> None:
    _, calls = cache
    _calibrate(model)
    _calibrate(replace(model, R=model.R * 1.01))
    assert len(calls) == 2


def test_corrupt_or_foreign_entries_are_computed_again(model, cache) -> None:
    folder, calls = cache
    good = _calibrate(model)
    (entry,) = folder.glob("*.json")
    original = entry.read_text()
    doc = json.loads(original)
    foreign = dict(doc, key={**doc["key"], "seed": 99})  # another key's entry under this name
    wrong_value = dict(doc, value={**doc["value"], "rule": {"rule": "frame", "threshold": 1.0}})
    bad = ("", "{not json", original[: len(original) // 2], json.dumps(foreign), json.dumps(wrong_value))
    for text in bad:
        entry.write_text(text)
        assert _calibrate(model) == good
    assert len(calls) == 6  # every bad entry was recomputed ...
    assert json.loads(entry.read_text()) == doc  # ... and rewritten whole


def test_the_cache_can_be_turned_off_and_an_unwritable_one_is_only_noted(model, cache, monkeypatch, tmp_path):
    folder, calls = cache
    notes: list[str] = []
    monkeypatch.setenv(_cache.NO_CACHE_ENV, "1")
    _calibrate(model, note=notes.append)
    _calibrate(model, note=notes.append)
    assert len(calls) == 2 and not folder.exists()
    assert f"not cached: {_cache.NO_CACHE_ENV} is set" in notes[0]
    monkeypatch.delenv(_cache.NO_CACHE_ENV)
    blocker = tmp_path / "a-file"
    blocker.write_text("x")
    monkeypatch.setenv(_cache.CACHE_DIR_ENV, str(blocker / "cache"))  # below a file: cannot be created
    notes.clear()
    cal = _calibrate(model, note=notes.append)
    assert cal.method in ("counted", "extrapolated") and len(calls) == 3
    assert len(notes) == 2 and notes[1].startswith("the alarm calibration was not cached: cannot write")


def test_the_cache_folder_follows_the_environment(monkeypatch, tmp_path) -> None:
    monkeypatch.delenv(_cache.NO_CACHE_ENV, raising=False)
    monkeypatch.setenv(_cache.CACHE_DIR_ENV, str(tmp_path / "mine"))
    assert _cache.cache_dir() == tmp_path / "mine"
    monkeypatch.delenv(_cache.CACHE_DIR_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert _cache.cache_dir() == tmp_path / "xdg" / "chatterspec"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/path")  # not absolute: ignored, as the XDG spec says
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert _cache.cache_dir() == tmp_path / "home" / ".cache" / "chatterspec"
    monkeypatch.setenv(_cache.NO_CACHE_ENV, "0")  # 0: not turned off
    assert _cache.cache_dir() is not None


def test_a_second_monitor_run_reads_the_threshold_back(tmp_path: Path, monkeypatch, capsys) -> None:
    from chatterspec.cli import main

    examples = Path(__file__).resolve().parents[1] / "examples"
    monkeypatch.setenv(_cache.CACHE_DIR_ENV, str(tmp_path))
    monkeypatch.setattr(alarm_budget, "_CACHE", {})
    argv = ["monitor", str(examples / "eha_model.toml"), "--data", str(examples / "eha_data.csv")]
    argv += ["--alarm-hours", "0.25", "--false-alarms-per-hour", "200", "--no-identify"]
    assert main(argv) == 0
    first = capsys.readouterr()
    assert "calibrating the cusum alarm threshold of 'linear EHA (Table 1)' on 0.25 h" in first.err
    assert f"cached in {tmp_path / CACHE_KIND}" in first.err
    alarm_budget._CACHE.clear()
    assert main(argv) == 0
    second = capsys.readouterr()
    assert "calibrating" not in second.err
    strip = [ln for ln in first.out.splitlines() if " s wall" not in ln]  # the wall time differs
    assert strip == [ln for ln in second.out.splitlines() if " s wall" not in ln]
