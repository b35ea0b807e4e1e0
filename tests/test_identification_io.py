"""Fault identification at the edges: model files, the CLI (detect, monitor, diagnose), the recording."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main
from chatterspec.errors import ModelFileError
from chatterspec.plants.modelfile import load_data, load_model, write_model_toml
from chatterspec.plants.models import eha_linear, second_order

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

SO = """
name = "so"
dt = 0.001
[channels]
outputs = ["x", "v"]
inputs = ["u"]
[matrices]
form = "continuous"
A = [[0.0, 1.0], [-3947.8417604357433, -12.566370614359172]]
B = [[0.0], [100.0]]
C = [[1.0, 0.0], [0.0, 1.0]]
Q_diag = [1e-8, 1e-6]
R_diag = [1e-8, 1e-6]
[svsf]
psi = [1e-3, 1e-2]
[parameters]
f0 = { value = 10.0, unit = "Hz" }
zeta = { value = 0.1 }
[entries]
"A[2,1]" = "-(2*pi*f0)**2"
"A[2,2]" = "-2*zeta*2*pi*f0"
[hypotheses]
frequency = ["f0"]
both = ["f0", "zeta"]
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "m.toml"
    p.write_text(text)
    return p


def test_example_model_file_declares_the_catalogue_map() -> None:
    spec = load_model(EXAMPLES / "eha_model.toml")
    pm = spec.model.parameter_map
    assert pm.parameter_names == ("leakage", "friction", "bulk_modulus")
    assert [h.name for h in pm.hypotheses][-1] == "leakage+friction"
    assert np.allclose(pm.evaluate(spec.model.dt), eha_linear().parameter_map.evaluate(1e-3), rtol=1e-15)


def test_continuous_entries_are_discretized_and_round_trip(tmp_path: Path) -> None:
    spec = load_model(_write(tmp_path, SO))
    ref = second_order(10.0, 0.1)
    assert np.allclose(spec.model.A, ref.A, rtol=1e-12)
    out = write_model_toml(tmp_path / "again.toml", spec.model, spec.psi)
    again = load_model(out).model.parameter_map
    assert [h.name for h in again.hypotheses] == ["frequency", "both"]
    assert np.array_equal(
        again.evaluate(1e-3, {"f0": 12.0}), spec.model.parameter_map.evaluate(1e-3, {"f0": 12.0})
    )


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (('both = ["f0", "zeta"]', 'both = ["f0", "viscosity"]'), "viscosity.*its parameters: f0, zeta"),
        (('"A[2,2]" = "-2*zeta*2*pi*f0"', '"A[2,2]" = "-3*zeta*2*pi*f0"'), r"A\[2,2\].*does not describe"),
        (('"A[2,1]" = "-(2*pi*f0)**2"', '"A[2,1]" = "-(2*pi*f0)**2 + mass"'), "mass"),
        (('"A[2,1]"', '"A[2;1]"'), "entry key"),
        (('"A[2,1]" = "-(2*pi*f0)**2"', '"A[2,1]" = "__import__(1)"'), "only one-argument calls"),
        (("zeta = { value = 0.1 }", 'zeta = { value = "x" }'), "numeric value"),
    ],
)
def test_bad_parameter_tables_name_file_and_field(
    tmp_path: Path, edit: tuple[str, str], message: str
) -> None:
    text = SO.replace(*edit)
    assert text != SO
    with pytest.raises(ModelFileError, match=message) as err:
        load_model(_write(tmp_path, text))
    assert "m.toml" in str(err.value)


def test_detect_json_identification(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["detect", "eha-friction-minor", "--json", "--no-progress"]) == 0
    doc = json.loads(capsys.readouterr().out)
    ident = doc["identification"]
    assert ident["selected"] == "friction" and ident["true"]["parameters"] == {"friction": 4000.0}
    row = next(h for h in ident["hypotheses"] if h["hypothesis"] == "friction")
    assert row["parameter"] == "friction" and row["unit"] == "N s/m"
    assert row["ci_low"] < 4000.0 < row["ci_high"]
    assert main(["detect", "so-timeline-constant", "--json", "--no-progress"]) == 0
    doc = json.loads(capsys.readouterr().out)
    sel = [iv["selected"] for iv in doc["identification_intervals"]]
    assert sel == ["natural_frequency", "damping"]


def test_detect_pooled_runs_and_no_identify(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["detect", "eha-bulk-25up", "--runs", "40", "--json", "--no-progress"]) == 0
    ident = json.loads(capsys.readouterr().out)["identification"]
    assert ident["records"] == 40 and ident["scope"] == "pooled over runs"
    assert ident["selection_rate"]["bulk_modulus"] == 1.0
    assert main(["detect", "eha-bulk-25up", "--no-identify", "--json", "--no-progress"]) == 0
    assert "skipped" in json.loads(capsys.readouterr().out)["identification"]["reason"]


def test_monitor_identifies_the_example_per_hop_and_records_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rec = tmp_path / "m.rrd"
    argv = ["monitor", "--model", str(EXAMPLES / "eha_model.toml"), "--data", str(EXAMPLES / "eha_data.csv")]
    assert main([*argv, "--json", "--record", str(rec)]) == 0
    doc = json.loads(capsys.readouterr().out)
    ident = doc["identification"]
    assert ident["windows"] == 35 and ident["window_s"] == pytest.approx(1.0)
    assert ident["changes"][0]["selected"] == "no fault"
    assert ident["last"]["selected"] == "leakage"  # the example's leakage of 9e-11 from 4 s on
    row = next(h for h in ident["last"]["hypotheses"] if h["hypothesis"] == "leakage")
    assert row["ci_low"] < 9e-11 < row["ci_high"]
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rec))
    chunks = reader.stream().filter(content="/identification/leakage", is_static=False).to_chunks()
    rows = [v for c in chunks for v in c.to_record_batch().column("Scalars:scalars").to_pylist()]
    # estimate, interval ends and nominal, drawn in 1e-12 m^3/(s Pa) (the nominal 4.8e-12's engineering
    # exponent: the viewer's axis then reads 4.8 and 90, not 0.000 000 000 09)
    assert len(rows) == 35 and all(len(r) == 4 for r in rows)
    est = np.array([r[0] for r in rows], dtype=float)
    assert np.all(np.isnan(est[:15])) and np.nanmedian(est[-10:]) == pytest.approx(90.0, rel=0.05)
    assert all(r[3] == pytest.approx(4.8) for r in rows)
    data = load_data(EXAMPLES / "eha_data.csv", load_model(EXAMPLES / "eha_model.toml").model)
    assert data.n_samples == 8001
    assert main([*argv, "--events", "jsonl", "--identification-events", "changes"]) == 0
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    kinds = [e["event"] for e in events]
    assert kinds.count("identification") == 3 and kinds.count("fault-start") == 1


def test_streamed_monitor_records_its_identification(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # the example's rows through standard input (a streamed file): the same per-hop identification as
    # from the file, drawn in the recording with the nominal value (1e-12 m^3/(s Pa): 4.8)
    import sys

    rec = tmp_path / "s.rrd"
    with (EXAMPLES / "eha_data.csv").open() as fh:
        monkeypatch.setattr(sys, "stdin", fh)
        assert (
            main(
                ["monitor", "--model", str(EXAMPLES / "eha_model.toml"), "--data", "-", "--record", str(rec)]
            )
            == 0
        )
    capsys.readouterr()
    from rerun.chunk import RrdReader

    chunks = (
        RrdReader(str(rec)).stream().filter(content="/identification/leakage", is_static=False).to_chunks()
    )
    rows = [v for c in chunks for v in c.to_record_batch().column("Scalars:scalars").to_pylist()]
    assert len(rows) == 35 and all(len(r) == 4 and r[3] == pytest.approx(4.8) for r in rows)
    assert np.nanmedian([r[0] for r in rows[-10:]]) == pytest.approx(90.0, rel=0.05)  # the 9e-11 leak


def test_monitor_identification_lines_follow_the_alarm() -> None:
    # The per-hop identification tests at the per-frame alpha; its human lines must follow the alarm
    # rule: nothing said on healthy data without an alarm, a fault said once the alarm is active
    # (even if it was selected earlier), "no fault" only after a fault was said. JSON keeps every change.
    from types import SimpleNamespace

    from chatterspec.cli._identify import MonitorIdentification

    class Out:
        def __init__(self, selected: str) -> None:
            self.n_windows, self.times_s = 1, np.array([1.0])
            self.selected = selected

        def report(self, i: int) -> object:
            d = {"selected": self.selected, "hypotheses": [], "window_s": [0.0, 1.0]}
            return SimpleNamespace(selected=self.selected, window_s=(0.0, 1.0), to_dict=lambda: dict(d))

    said: list[str] = []
    ident = MonitorIdentification.__new__(MonitorIdentification)
    ident.emit, ident.say, ident.every_hop = None, said.append, False
    ident.selected = ident.said = ident.last = None
    ident.changes, ident.windows = [], 0
    alarm = [False]
    ident.alarm_active = lambda: alarm[0]
    for sel, active in [
        ("no fault", False),
        ("unexplained", False),  # a per-frame rejection with no alarm: not said
        ("no fault", False),
        ("leakage", False),  # selected before the alarm ...
        ("leakage", True),  # ... said when the alarm starts
        ("leakage", True),
        ("no fault", False),  # said: a fault was said before
    ]:
        alarm[0] = active
        ident.handle(Out(sel))
    assert [s.split(": ", 1)[1].split(":")[0] for s in said] == ["leakage", "no fault"]
    changes = [c["selected"] for c in ident.changes]
    assert changes == ["no fault", "unexplained", "no fault", "leakage", "no fault"]
