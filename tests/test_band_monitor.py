"""``band`` for the online monitor: MonitorSettings, ``[detector]``, ``monitor --band``, ``detect --record``.

Every threshold kind offers a frequency band; the monitor must too.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main as cli_main
from chatterspec.detection.thresholds import frame_threshold
from chatterspec.errors import ModelFileError, ParameterError
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.plants.datafile import load_data
from chatterspec.plants.modelfile import load_model, write_model_toml

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MODEL = EXAMPLES / "eha_model.toml"
DATA = EXAMPLES / "eha_data.csv"


def test_settings_band_restricts_the_per_frame_threshold() -> None:
    spec = load_model(MODEL)
    mon = ChatteringMonitor(spec.model, MonitorSettings(band=(20.0, 60.0)))
    th = mon.threshold
    f = th.freqs_hz[th.tested]
    assert f.min() >= 20.0 and f.max() <= 60.0 and th.band == (20.0, 60.0)
    # Bonferroni over the in-band bins only: the same threshold as frame_threshold(band=...)
    ref = frame_threshold(spec.model, mon.freqs_hz, mon.settings.stft, spec.model.dt, 1e-3, band=(20.0, 60.0))
    np.testing.assert_array_equal(th.tested, ref.tested)
    np.testing.assert_allclose(th.values, ref.values)
    full = ChatteringMonitor(spec.model, MonitorSettings()).threshold
    assert th.n_tested < full.n_tested and np.all(th.values[th.tested] < full.values[th.tested])
    # a given (e.g. calibrated) threshold is restricted to the band
    given = ChatteringMonitor(spec.model, MonitorSettings(threshold=full, band=(20.0, 60.0))).threshold
    np.testing.assert_array_equal(given.tested, th.tested)
    np.testing.assert_array_equal(given.values, full.values)
    for bad in ((60.0, 20.0), (-1.0, 5.0), (1.0,), "20-60"):
        with pytest.raises(ParameterError, match="band"):
            MonitorSettings(band=bad)  # type: ignore[arg-type]


def _events(band: tuple[float, float] | None) -> list:
    spec = load_model(MODEL)
    data = load_data(DATA, spec.model)
    mon = ChatteringMonitor(spec.model, MonitorSettings(band=band), t0=float(data.t[0]))
    return [e for e in mon.push(data.z, data.u).events if e.kind == "fault-start"]


def test_band_decides_what_the_monitor_sees() -> None:
    """Example data: leakage from 4 s, footprint 34-60 Hz on pressure (no fault above 200 Hz)."""
    inside = _events((20.0, 60.0))
    assert [e.channel for e in inside] == ["pressure"] and 20.0 <= inside[0].peak_hz <= 60.0
    assert _events((200.0, 400.0)) == []


def test_detector_table_band(tmp_path: Path) -> None:
    text = MODEL.read_text()
    path = tmp_path / "m.toml"
    path.write_text(text + "band = [20, 60]\n")
    assert load_model(path).detector["band"] == (20.0, 60.0)
    for bad in ("[60, 20]", "[1, 2, 3]", '"20-60"', "[-1, 5]"):
        path.write_text(text + f"band = {bad}\n")
        with pytest.raises(ModelFileError) as exc:
            load_model(path)
        assert str(path) in str(exc.value) and "[detector] band" in str(exc.value), str(exc.value)
    # write_model_toml writes it back
    spec = load_model(MODEL)
    out = write_model_toml(tmp_path / "w.toml", spec.model, spec.psi, detector={"band": (5.0, 100.0)})
    assert load_model(out).detector["band"] == (5.0, 100.0)


def _monitor_json(capsys, *extra: str, model: Path = MODEL) -> dict:
    rc = cli_main(["monitor", str(model), "--data", str(DATA), "--json", *extra])
    assert rc == 0
    return json.loads(capsys.readouterr().out)


def test_cli_monitor_band_and_model_file_band(tmp_path: Path, capsys) -> None:
    doc = _monitor_json(capsys, "--band", "200", "400")
    assert not [e for e in doc["events"] if e["kind"] == "fault-start"]
    # the [detector] band of the model file applies when --band is not given ...
    path = tmp_path / "m.toml"
    path.write_text(MODEL.read_text() + "band = [200, 400]\n")
    doc = _monitor_json(capsys, model=path)
    assert not [e for e in doc["events"] if e["kind"] == "fault-start"]
    # ... and --band overrides it
    doc = _monitor_json(capsys, "--band", "20", "60", model=path)
    starts = [e for e in doc["events"] if e["kind"] == "fault-start"]
    assert [e["channel"] for e in starts] == ["pressure"]
    rc = cli_main(["monitor", str(MODEL), "--data", str(DATA), "--band", "60", "20"])
    assert rc == 2 and "band" in capsys.readouterr().err


def test_detect_record_passes_band_to_the_monitor(tmp_path: Path, capsys, monkeypatch) -> None:
    from chatterspec.viewer import recordings

    seen = []
    real = recordings.record_detection

    def spy(sim, settings, **kw):
        seen.append(settings)
        return real(sim, settings, **kw)

    monkeypatch.setattr(recordings, "record_detection", spy)
    rrd = tmp_path / "d.rrd"
    rc = cli_main(["detect", "so-timeline-step", "--record", str(rrd), "--band", "2", "20", "--json"])
    assert rc == 0 and rrd.is_file()
    assert seen and seen[0].band == (2.0, 20.0)
    capsys.readouterr()
