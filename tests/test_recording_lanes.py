"""The state lanes of every recording show the fault intervals that ``detect --json`` reports (read
back from the .rrd file).

For each scenario of ``chatterspec demo`` one realization is recorded by the online
monitor and read back with Rerun's own reader. The per-frame verdicts are compared
frame by frame with the independent batch path (the detector's STFT of the whole record),
and the lanes' changes with the ``intervals`` of the detector's JSON document (what
``detect --json`` prints; the batch detector of the same realization, read here as JSON
and turned into lane changes by the drawing rule written out in the test, not by the
viewer's :func:`lane_changes`). Exact comparisons: the online frames equal the batch frames
by construction (same kernel, same frame grid), and every time in the file is the
rounded integer ns of :func:`record_geometry.to_ns`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli.demo import DEMO_SCENARIOS
from chatterspec.plants.scenarios import scenario

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from chatterspec.viewer import blueprint, drivers, record_geometry  # noqa: E402
from chatterspec.viewer.interval_lanes import FaultInterval, lane_changes  # noqa: E402


@pytest.fixture(autouse=True)
def _strict():
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


def _read(reader: RrdReader, entity: str, column: str) -> tuple[np.ndarray, list]:
    """(int64 ns times, values) of the temporal rows of ``entity``, in time order (stable)."""
    times, values = [], []
    for chunk in reader.stream().filter(content=entity, is_static=False).to_chunks():
        rb = chunk.to_record_batch()
        times.extend(rb.column("time").cast("int64").to_pylist())
        values.extend(rb.column(column).to_pylist())
    order = np.argsort(times, kind="stable")
    return np.asarray(times, dtype=np.int64)[order], [values[i] for i in order]


def test_to_ns_rounds() -> None:
    # the truncating float path gives 500499999 for 0.5005 s; the recording's rule rounds
    assert int(record_geometry.to_ns(0.5005)) == 500_500_000
    np.testing.assert_array_equal(record_geometry.to_ns([0.0, 2.5005, 1e-9 * 0.6]), [0, 2_500_500_000, 1])


@pytest.mark.parametrize("name", DEMO_SCENARIOS)
def test_lanes_match_events_and_batch_verdicts(tmp_path: Path, name: str) -> None:
    sc = scenario(name)
    sim = cs.simulate(sc, runs=1, seed=3)
    path = tmp_path / f"{name}.rrd"
    summary = drivers.record_detection(sim, path=path)

    # independent batch path on the same realization (run 0 of seed 3; default detector: alpha 1e-3,
    # Bonferroni): the detector's per-frame verdicts and its JSON document, with the STFT intervals
    # that `detect --json` prints (forced on for the single-segment scenarios too)
    report = cs.detect_scenario(sc, runs=1, seed=3, stft=True)
    found = report.frames
    assert found is not None
    channels, dt = sc.nominal.output_names, sc.dt
    spec, flags = found.spectrogram, found.flags[0]
    frame_ns = record_geometry.to_ns(spec.times_s)
    half_win = (spec.config.n_window(dt) - 1) * dt / 2.0
    start_ns = int(record_geometry.to_ns(spec.times_s[0] - half_win))  # the first window's first sample

    reader = RrdReader(path)
    assert "/spectrum/" in reader.store().summary()  # footer written: the file is complete
    # one time rule: the frames of the recording sit exactly at the rounded batch frame times
    t_stat, stat = _read(reader, blueprint.STATISTIC, "Scalars:scalars")  # one row per frame, m values
    np.testing.assert_array_equal(t_stat, frame_ns)
    assert all(len(row) == len(channels) for row in stat)
    _, verdict = _read(reader, blueprint.VERDICT, "Scalars:scalars")
    np.testing.assert_array_equal(np.asarray(verdict)[:, : len(channels)] == 1.0, flags)
    doc = json.loads(cs.dumps(report.to_dict()))
    json_ivs: dict[str, list[tuple[float, float]]] = {}
    for iv in doc["intervals"]:
        json_ivs.setdefault(iv["channel"], []).append((iv["onset_s"], iv["offset_s"]))
    n_drawn = 0
    for c, channel in enumerate(channels):
        lane = blueprint.lane_entity(c, channel)
        t_lane, raw = _read(reader, lane, "StateChange:state")
        states = [s[0] for s in raw]
        # the lane's changes ARE the JSON intervals of this channel: fault at each onset, healthy at
        # each offset (zero-length intervals are not drawn), healthy from the first window's start
        ivs = [iv for iv in json_ivs.get(channel, []) if iv[1] > iv[0]]
        want_t = [t for iv in ivs for t in iv]
        want_s = ["fault", "healthy"] * len(ivs)
        if not ivs or record_geometry.to_ns(ivs[0][0]) > start_ns:
            want_t, want_s = [spec.times_s[0] - half_win, *want_t], ["healthy", *want_s]
        np.testing.assert_array_equal(t_lane, record_geometry.to_ns(want_t), err_msg=f"{name}: {channel}")
        assert states == want_s, (name, channel)
        # nothing is painted before the record's first window; no two changes at one time
        assert t_lane[0] == start_ns
        assert np.all(np.diff(t_lane) > 0), (name, channel, t_lane)
        n_drawn += len(ivs)
    # the event log: each alarm once, at the end of its deciding frame (when the detector knew), and
    # each drawn or zero-length interval once, at its onset
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    n_iv = sum(len(v) for k, v in json_ivs.items() if k != "any")
    assert len(texts) == len(summary.events) + n_iv
    alarm_ns = record_geometry.to_ns([ev.time_s + half_win for ev in summary.events])
    assert set(alarm_ns) <= set(t_ev.tolist())
    assert n_drawn <= n_iv
    # the truth lane: one change per segment of the scenario, at its start
    t_truth, truth = _read(reader, blueprint.TRUTH_LANE, "StateChange:state")
    expected = drivers.scenario_truth(sc)
    assert [s[0] for s in truth] == [lab for _, lab, _ in expected]
    np.testing.assert_array_equal(t_truth, record_geometry.to_ns([start for start, _, _ in expected]))


def test_lane_changes_skip_zero_length_intervals() -> None:
    # channel 0: an interval, a zero-length one (no order between two changes at one time: not drawn)
    # and another; channel 1: a fault from the record's start (no healthy change before it)
    ivs = [
        FaultInterval(0, 1.0, 2.0, 10.0, 3.0),
        FaultInterval(0, 3.0, 3.0, 12.0, 1.0),
        FaultInterval(0, 4.0, 5.5, 11.0, 2.0),
        FaultInterval(1, 0.25, 0.75, 9.0, 4.0),
        FaultInterval(1, 2.0, 2.0, 9.0, 4.0),
    ]
    assert lane_changes(ivs, 0, 0.25) == (
        [0.25, 1.0, 2.0, 4.0, 5.5],
        ["healthy", "fault", "healthy", "fault", "healthy"],
    )
    assert lane_changes(ivs, 1, 0.25) == ([0.25, 0.75], ["fault", "healthy"])
    assert lane_changes(ivs, 2, 0.25) == ([0.25], ["healthy"])  # no interval: healthy throughout
    assert lane_changes([FaultInterval(0, 3.0, 3.0, 1.0, 1.0)], 0, 0.25) == ([0.25], ["healthy"])


def test_cli_lanes_equal_json_intervals(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the reported case: so-timeline-constant, true faults [0, 2) and [4, 6) s, alarm rule CUSUM (the
    # default of --record): lanes, interval events and `detect --json` give the same numbers
    import json

    from chatterspec.cli import main

    path = tmp_path / "tl.rrd"
    assert main(["detect", "so-timeline-constant", "--record", str(path), "--json", "--no-identify"]) == 0
    doc = json.loads(capsys.readouterr().out)
    ivs = [(iv["onset_s"], iv["offset_s"]) for iv in doc["intervals"] if iv["channel"] == "velocity"]
    assert len(ivs) == 2
    reader = RrdReader(path)
    t_lane, raw = _read(reader, blueprint.lane_entity(1, "velocity"), "StateChange:state")
    assert [s[0] for s in raw] == ["fault", "healthy", "fault", "healthy"]
    np.testing.assert_array_equal(t_lane, record_geometry.to_ns([t for iv in ivs for t in iv]))
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    for a, b in ivs:  # one interval event at each onset, with the same numbers
        k = int(np.flatnonzero(t_ev == record_geometry.to_ns(a))[0])
        assert f"fault {a:.2f}-{b:.2f} s" in texts[k][0]
