"""``chatterspec diagnose`` in chunks: memory bounded independently of ``--runs``, the same table
and JSON whatever the chunking, the recording of realization 0, and a scenario faulty from the start."""

from __future__ import annotations

import json

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.plants.simulate import iter_simulations
from chatterspec.studies.diagnosis import (
    ChatteringTally,
    ModeTally,
    calibrate_for_diagnosis,
    diagnose_chattering,
    diagnose_modes,
    healthy_version,
)

ALPHA = 0.01  # per-frame level of the test calibration (40 runs x 46 frames: ~18 exceedances expected)


@pytest.fixture(scope="module")
def cal_path(tmp_path_factory):  # type: ignore[no-untyped-def]
    cal = calibrate_for_diagnosis(cs.scenario("eha4-leak-timeline"), seed=5, runs=40, alpha=ALPHA)
    return cal.save(tmp_path_factory.mktemp("cal") / "cal.npz")


def _without_timings(doc: dict) -> dict:
    """The JSON minus the wall-clock figures (the only ones allowed to differ between two calls)."""
    doc = dict(doc)
    doc.pop("simulation_s")
    doc.pop("recording", None)
    methods = []
    for m in doc["methods"]:
        m = dict(m)
        m.pop("steps_per_second")
        if "calibration" in m:
            m["calibration"] = {k: v for k, v in m["calibration"].items() if k != "seconds"}
        methods.append(m)
    doc["methods"] = methods
    return doc


def test_chunked_json_and_table_equal_one_chunk(cal_path, capsys) -> None:  # type: ignore[no-untyped-def]
    # 3 runs of eha4-leak-timeline (two onsets), the three methods on the same realizations: one chunk of
    # 3, chunks of 2 + 1 and chunks of 1 must give the same JSON (exact equality, not a tolerance: every
    # realization's numbers depend only on that realization, the counts are integers and the confusion
    # sums continue the whole-array summation order)
    base = ["diagnose", "eha4-leak-timeline", "--methods", "chattering,smm,imm", "--runs", "3", "--seed", "7"]
    base += ["--calibration", str(cal_path), "--no-progress", "--per-record"]
    docs, tables = [], []
    for chunk in ("3", "2", "1"):
        assert main([*base, "--chunk-runs", chunk, "--json"]) == 0
        out, err = capsys.readouterr()
        assert err == ""  # no progress bar when stderr is not a terminal
        docs.append(_without_timings(json.loads(out)))
        assert main([*base, "--chunk-runs", chunk]) == 0
        out = capsys.readouterr().out
        # the table's steps/s column and the threshold's seconds are timings: drop them
        tables.append([line.rsplit("  ", 1)[0] for line in out.splitlines() if "threshold" not in line])
    assert [m["method"] for m in docs[0]["methods"]] == ["chattering", "smm", "imm"]
    assert docs[0]["methods"][0]["runs"] == 3 and docs[0]["methods"][1]["onsets_s"] == pytest.approx([3, 6])
    assert docs[1] == docs[0] and docs[2] == docs[0]
    assert tables[1] == tables[0] and tables[2] == tables[0]


def test_tallies_equal_the_whole_simulation_functions(cal_path) -> None:  # type: ignore[no-untyped-def]
    from chatterspec.studies.calibration.result import load_calibration

    sc = cs.scenario("eha4-leak-timeline")
    thr = load_calibration(cal_path, sc.nominal).threshold("frame-family-wise")
    sim = cs.simulate(sc, runs=3, seed=2)
    whole = diagnose_chattering(sim, thr).describe()
    (smm_whole,) = diagnose_modes(sim, ("smm",))
    chat, smm = ChatteringTally(sc, thr), ModeTally(sc, "smm")
    keep: dict = {}
    for chunk in iter_simulations(sc, 3, 2, chunk_runs=2):
        chat.add(chunk)
        smm.add(chunk, keep=keep)
    a, b = chat.result().describe(), smm.result().describe()
    for d in (whole, a, b):
        d.pop("steps_per_second")
    assert a == whole
    smm_doc = smm_whole.describe()
    smm_doc.pop("steps_per_second")
    assert b == smm_doc
    np.testing.assert_array_equal(smm.result().confusion, smm_whole.confusion)
    # only realization 0 is kept for the recording (not the chunk's mode probabilities)
    t, mu, modes = keep["smm"]
    assert mu.shape == (1, sc.n_samples - 1, 3) and t.shape == (sc.n_samples - 1,) and modes[0] == "normal"
    with pytest.raises(cs.errors.ParameterError, match="add"):
        ModeTally(sc, "imm").result()
    with pytest.raises(cs.errors.ParameterError, match="add"):
        ChatteringTally(sc, thr).result()


def test_record_of_realization_zero_with_chunks(cal_path, tmp_path) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    path = tmp_path / "d.rrd"
    argv = ["diagnose", "eha4-leak-timeline", "--methods", "chattering,smm", "--runs", "3", "--seed", "6"]
    argv += [
        "--chunk-runs",
        "2",
        "--calibration",
        str(cal_path),
        "--record",
        str(path),
        "--json",
        "--per-record",
    ]
    assert main(argv) == 0
    reader = RrdReader(path)
    summary = reader.store().summary()  # needs the footer: the file is complete
    assert "/spectrogram/" in summary and "/modes/smm/" in summary
    # the recorded probabilities are those of realization 0 (run alone through the filter)
    sim = cs.simulate(cs.scenario("eha4-leak-timeline"), runs=1, seed=6)
    keep: dict = {}
    diagnose_modes(sim, ("smm",), keep=keep)
    _, mu, modes = keep["smm"]
    values, times = [], []
    for chunk in reader.stream().filter(content=f"/modes/smm/{modes[1]}", is_static=False).to_chunks():
        rb = chunk.to_record_batch()
        times.extend(rb.column("time").cast("int64").to_pylist())
        values.extend(v[0] for v in rb.column("Scalars:scalars").to_pylist())
    order = np.argsort(times)
    np.testing.assert_array_equal(np.asarray(values)[order], mu[0, :, 1])


def test_scenario_faulty_from_the_start(capsys) -> None:  # type: ignore[no-untyped-def]
    # eha-leak-minor's base plant is the leaky model over the whole record: its healthy version is the
    # nominal plant over the same input (dropping the windows alone left it faulty), and the fault's
    # onset is t = 0
    sc = cs.scenario("eha-leak-minor")
    assert not sc.is_healthy and sc.fault_intervals == ((0.0, 4.0),)
    h = healthy_version(sc)
    assert h.is_healthy and h.segments[0].model is sc.nominal
    assert h.n_samples == sc.n_samples and h.input == sc.input
    # a base plant with the nominal A, B, C is kept (only the faulty part goes)
    timeline = cs.scenario("eha4-leak-timeline")
    assert healthy_version(timeline).plant is timeline.plant
    argv = ["diagnose", "eha-leak-minor", "--runs", "2", "--calibration-runs", "20", "--alpha", "0.01"]
    assert main([*argv, "--json", "--per-record"]) == 0
    (doc,) = json.loads(capsys.readouterr().out)["methods"]
    assert doc["onsets_s"] == [0.0] and doc["healthy_frames_per_run"] == 0 and doc["in_alarm_at_onset"] == [0]
    # the fault is flagged from the first frame on its channel in both runs (seeded); no frame ends before
    # 1 s (one window), so the delay from t = 0 is exactly one window
    assert doc["missed"] == [0] and doc["detection_delay_median_s"][0] == pytest.approx(1.0)
    assert doc["isolation"][0]["flagged_channel"] == sc.fault_channel
