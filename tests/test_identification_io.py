"""Fault identification at the edges: model files, the CLI (detect, monitor, diagnose), the recording."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main
from chatterspec.errors import ModelFileError
from chatterspec.plants.datafile import load_data
from chatterspec.plants.modelfile import load_model, write_model_toml
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
    argv = ["monitor", str(EXAMPLES / "eha_model.toml"), "--data", str(EXAMPLES / "eha_data.csv")]
    assert main([*argv, "--json", "--record", str(rec)]) == 0
    doc = json.loads(capsys.readouterr().out)
    ident = doc["identification"]
    assert ident["windows"] == 35 and ident["window_s"] == pytest.approx(1.0)
    # a fault is named only while the spectral alarm is active (from 3.7 s): before it, no label
    named = [c for c in ident["changes"] if c["fault"] is not None]
    assert named and named[0]["time_s"] >= 3.7 and ident["changes"][0]["fault"] is None
    last = ident["last"]
    assert last["fault"] == "leakage" and last["channels"]["pressure"] == "fault"  # 9e-11 from 4 s on
    leak = next(r for r in last["parameters"] if r["parameter"] == "leakage")
    assert leak["ci_low"] < 9e-11 < leak["ci_high"] and leak["state"] == "fault"
    from rerun.chunk import RrdReader

    reader = RrdReader(str(rec))
    chunks = reader.stream().filter(content="/identification/leakage", is_static=False).to_chunks()
    rows = [v for c in chunks for v in c.to_record_batch().column("Scalars:scalars").to_pylist()]
    # estimate, interval ends and nominal (no tolerance: no band), drawn in 1e-12 m^3/(s Pa) (the nominal
    # 4.8e-12's engineering exponent: the viewer's axis then reads 4.8 and 90, not 0.000 000 000 09)
    assert len(rows) == 35 and all(len(r) == 4 for r in rows)
    est = np.array([r[0] for r in rows], dtype=float)
    # the joint estimate of every declared parameter in every window (9e-11 from 4 s on)
    assert np.all(np.isfinite(est)) and np.median(est[-10:]) == pytest.approx(90.0, rel=0.05)
    assert all(r[3] == pytest.approx(4.8) for r in rows)
    data = load_data(EXAMPLES / "eha_data.csv", load_model(EXAMPLES / "eha_model.toml").model)
    assert data.n_samples == 8001
    assert main([*argv, "--events", "jsonl", "--identification-events", "changes"]) == 0
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    kinds = [e["event"] for e in events]
    assert kinds.count("fault-start") == 1
    idents = [e for e in events if e["event"] == "identification"]
    assert len(idents) == len(ident["changes"])  # one per change of the fault named or of a state
    assert all((e["fault"] is None) == (not e["alarm"]) for e in idents)
    assert all("selected" not in e for e in idents if not e["alarm"])  # no label between alarms


def test_monitor_names_a_fault_only_under_an_alarm() -> None:
    # The per-window tests run at the per-frame alpha; a fault is named only while the monitor's alarm
    # is active (the spectral alarm reported with note_alarm), and the states follow the decisions.
    import chatterspec as cs
    from chatterspec.detection.identification import identification_setup
    from chatterspec.detection.parameter_decision import parameter_alarm_settings
    from chatterspec.online.identification_monitor import IdentificationMonitor

    sc = cs.scenario("eha-leak-major")  # leaky from t = 0: every window selects "leakage"
    sim = cs.simulate(sc, runs=1, seed=2)
    setup = identification_setup(sc.nominal)
    settings = parameter_alarm_settings(setup, hop_s=0.2, window_hops=5)
    assert settings.calibration is None  # no tolerance: the spectral alarm decides
    mon = IdentificationMonitor(setup, settings)
    # an alarm decided at the end of the frame whose last sample is 2.6 s (frames end at 1.0 + 0.2 j s) ...
    mon.note_alarm("fault-start", "pressure", 2.6)
    mon.note_alarm("fault-end", "pressure", 3.6)  # ... cleared at the end of the one ending 3.6 s
    upd = mon.push(sim.z[0], sim.u)
    # a window is decided at its last chattering sample, and is its frame shifted by one sample: the
    # spectral alarm state of a window is the one decided at its frame's end, one sample earlier
    frame_end = dict(zip(upd.windows, mon.frame_ends(upd.found).tolist(), strict=True))
    assert all(w.alarm_time_s == pytest.approx(w.window_s[1] - sc.dt) for w in upd.windows)
    assert all(t == pytest.approx(w.alarm_time_s - sc.dt) for w, t in frame_end.items())
    assert all(w.label is None for w, t in frame_end.items() if t < 2.6 - 1e-9 or t >= 3.6 - 1e-9)
    inside = [w for w, t in frame_end.items() if 2.6 - 1e-9 <= t < 3.6 - 1e-9]
    assert len(inside) == 5 and all(w.label == "leakage" for w in inside)
    assert all(w.channel_states[2] == "fault" and w.states[0] == "fault" for w in inside)
    outside = [w for w in upd.windows if w.label is None and w.time_s > 1.0]
    assert outside and all(w.channel_states == ("healthy",) * 3 for w in outside)


def test_streamed_monitor_records_its_identification(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # the example's rows through standard input (a streamed file): the same per-hop identification as
    # from the file, drawn in the recording with the nominal value (1e-12 m^3/(s Pa): 4.8), and the
    # parameters' lanes at the windows' alarm times
    import sys

    from rerun.chunk import RrdReader

    rec = tmp_path / "s.rrd"
    with (EXAMPLES / "eha_data.csv").open() as fh:
        monkeypatch.setattr(sys, "stdin", fh)
        argv = ["monitor", str(EXAMPLES / "eha_model.toml"), "--data", "-", "--record", str(rec)]
        assert main(argv) == 0
    capsys.readouterr()
    reader = RrdReader(str(rec))
    chunks = reader.stream().filter(content="/identification/leakage", is_static=False).to_chunks()
    rows = [v for c in chunks for v in c.to_record_batch().column("Scalars:scalars").to_pylist()]
    assert len(rows) == 35 and all(len(r) == 4 and r[3] == pytest.approx(4.8) for r in rows)
    assert np.median([r[0] for r in rows[-10:]]) == pytest.approx(90.0, rel=0.05)  # the 9e-11 leak
    lane = reader.stream().filter(content="/state/p1_leakage", is_static=False).to_chunks()
    states = [v[0] for c in lane for v in c.to_record_batch().column("StateChange:state").to_pylist()]
    assert states and states[-1] == "fault"  # named under the spectral alarm at the end


def test_a_files_identification_rows_go_out_in_batches(tmp_path: Path, monkeypatch, capsys) -> None:  # type: ignore[no-untyped-def]
    """A file's identification series, detectability and parameter lanes wait for a batch of windows (one
    chunk per entity and batch): the rows of sending every push's windows at once, in fewer chunks."""
    from rerun.chunk import RrdReader

    from chatterspec.viewer import rerun_log

    def rows(path: Path, prefix: str) -> tuple[dict[str, list[str]], int]:
        """Per entity under ``prefix``: its time-indexed rows (every column but the row ids) and chunks."""
        out: dict[str, list[str]] = {}
        n = 0
        for chunk in RrdReader(str(path)).stream().to_chunks():
            rb = chunk.to_record_batch()
            ent = (rb.schema.metadata or {}).get(b"rerun:entity_path", b"").decode()
            if not ent.startswith(prefix) or "time" not in rb.schema.names:
                continue
            n += 1
            names = [k for k in rb.schema.names if "row" not in k.lower()]
            values = [rb.column(k).cast("int64") if k == "time" else rb.column(k) for k in names]
            out.setdefault(ent, []).extend(
                repr(r) for r in zip(*(v.to_pylist() for v in values), strict=True)
            )
        return {k: sorted(v) for k, v in out.items()}, n

    init = rerun_log.IdentificationLog.__init__
    argv = ["monitor", str(EXAMPLES / "eha_model.toml"), "--data", str(EXAMPLES / "eha_data.csv")]
    argv += [
        "--chunk",
        "1000",
        "--alpha",
        "0.001",
    ]  # 8 pushes; the per-frame rule: no calibration to simulate
    got = {}
    for batch in (1, 300):  # every push's windows at once, then the default batches
        monkeypatch.setattr(
            rerun_log.IdentificationLog,
            "__init__",
            lambda self, sinks, monitor, columns, batch_windows=300, b=batch: init(
                self, sinks, monitor, columns, b
            ),
        )
        rec = tmp_path / f"b{batch}.rrd"
        assert main([*argv, "--json", "--record", str(rec)]) == 0
        capsys.readouterr()
        got[batch] = {p: rows(rec, p) for p in ("/identification", "/state/p")}
    for prefix in ("/identification", "/state/p"):
        (one, n_one), (batched, n_batched) = got[1][prefix], got[300][prefix]
        assert one == batched and len(one) >= 3
        assert n_batched < n_one
