"""One fault state per channel: the lanes of a recording change exactly at the alarm times that the JSON
events report and the event log shows (read back from the .rrd file).

For each scenario of ``chatterspec demo`` one realization is recorded by the online monitor and read
back with Rerun's own reader; the per-frame verdicts are compared frame by frame with the independent
batch path (``stft_detect`` on the whole record), and, the demo's alarm rule being the frame rule, the
lanes' fault episodes with the runs of flagged frames of that batch path. The same holds for a 30 s
streamed leak through ``chatterspec monitor --record`` (CUSUM at a budget), against its ``--events
jsonl`` lines. Exact comparisons: the online frames equal the batch frames by construction (same
kernel, same frame grid), and every time in the file is the rounded integer ns of
:func:`rerun_log.to_ns` of the same float.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli.demo import DEMO_SCENARIOS
from chatterspec.detection.detect import stft_detect
from chatterspec.detection.pipeline import chattering_record
from chatterspec.plants.scenarios import scenario

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from chatterspec.online.fault_state import alarm_time  # noqa: E402
from chatterspec.viewer import blueprint, drivers, rerun_log  # noqa: E402
from chatterspec.viewer.fault_lanes import state_of  # noqa: E402


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
    assert int(rerun_log.to_ns(0.5005)) == 500_500_000
    np.testing.assert_array_equal(rerun_log.to_ns([0.0, 2.5005, 1e-9 * 0.6]), [0, 2_500_500_000, 1])


def _check_lanes_and_events(reader: RrdReader, channels: tuple[str, ...], events: list[dict]) -> None:
    """Each lane's fault episodes start and end at the alarm times of the JSON ``events`` of its channel
    (``alarm_time_s``), and the event log has a row there naming that time."""
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    _, levels = _read(reader, "/events", "TextLog:level")
    for c, channel in enumerate(channels):
        t_lane, raw = _read(reader, blueprint.lane_entity(c, channel), "StateChange:state")
        states = [state_of(v[0]) for v in raw]
        assert states[0] == "no-evidence" and set(states) <= {"no-evidence", "healthy", "fault"}
        assert np.all(np.diff(t_lane) > 0), (channel, t_lane)  # one change at a time, in order
        into = [t for t, a, b in zip(t_lane[1:], states, states[1:], strict=False) if b == "fault" != a]
        out_of = [t for t, a, b in zip(t_lane[1:], states, states[1:], strict=False) if a == "fault" != b]
        mine = [e for e in events if e["channel"] == channel]
        starts = [e["alarm_time_s"] for e in mine if e["kind"] == "fault-start"]
        ends = [e["alarm_time_s"] for e in mine if e["kind"] == "fault-end"]
        np.testing.assert_array_equal(into, rerun_log.to_ns(starts), err_msg=channel)
        np.testing.assert_array_equal(out_of, rerun_log.to_ns(ends), err_msg=channel)
        for e in mine:  # the event log: one row at the alarm time, naming it and the estimate
            word, est = ("ALARM", "onset") if e["kind"] == "fault-start" else ("alarm cleared", "offset")
            k = [i for i in np.flatnonzero(t_ev == rerun_log.to_ns(e["alarm_time_s"])) if word in texts[i][0]]
            assert len(k) == 1, (channel, e)
            want = f"{e['alarm_time_s']:.2f} s {channel} {word} ({est} est. {e['estimate_s']:.2f} s)"
            assert texts[k[0]][0].startswith(want), (texts[k[0]][0], want)
            assert levels[k[0]][0] == ("ERROR" if word == "ALARM" else "INFO")


@pytest.mark.parametrize("name", DEMO_SCENARIOS)
def test_lanes_match_events_and_batch_verdicts(tmp_path: Path, name: str) -> None:
    sc = scenario(name)
    sim = cs.simulate(sc, runs=1, seed=3)
    path = tmp_path / f"{name}.rrd"
    summary = drivers.record_detection(sim, path=path)
    doc = summary.to_dict()  # what `demo --json` prints of the recording

    # independent batch path on the same realization (default detector: alpha 1e-3, Bonferroni): the
    # per-frame verdicts, whose runs are the frame rule's alarm episodes
    rec = chattering_record(sc.nominal, sim.z, sim.u, scenario=sc)
    found = stft_detect(rec.values[:1], rec.model, t0=float(rec.t[0]))
    spec, flags = found.spectrogram, found.flags[0]
    frame_ns = rerun_log.to_ns(spec.times_s)
    n_window = spec.config.n_window(rec.dt)
    half_win = (n_window - 1) * rec.dt / 2.0
    start_ns = int(rerun_log.to_ns(spec.times_s[0] - half_win))  # the first window's first sample

    reader = RrdReader(path)
    assert "/spectrum/" in reader.store().summary()  # footer written: the file is complete
    # one time rule: the frames of the recording sit exactly at the rounded batch frame times
    t_stat, stat = _read(reader, blueprint.STATISTIC, "Scalars:scalars")  # one row per frame, m values
    np.testing.assert_array_equal(t_stat, frame_ns)
    assert all(len(row) == len(rec.channels) for row in stat)
    _, verdict = _read(reader, blueprint.VERDICT, "Scalars:scalars")
    np.testing.assert_array_equal(np.asarray(verdict)[:, : len(rec.channels)] == 1.0, flags)
    assert (doc["events"] and all(e["rule"] == "frame" for e in doc["events"])) or sc.is_healthy
    _check_lanes_and_events(reader, rec.channels, doc["events"])
    for c, channel in enumerate(rec.channels):
        t_lane, raw = _read(reader, blueprint.lane_entity(c, channel), "StateChange:state")
        assert t_lane[0] == start_ns  # no evidence from the first window's first sample
        # the frame rule: fault from the end of each run's first flagged frame to the end of the first
        # clean frame after it (no change at the record's end: a fault still open stays open)
        edges = np.diff(np.concatenate(([0], flags[:, c].astype(np.int8))))
        ends = [alarm_time(t, n_window, rec.dt) for t in spec.times_s]
        want_on = rerun_log.to_ns([ends[f] for f in np.flatnonzero(edges == 1)])
        want_off = rerun_log.to_ns([ends[f] for f in np.flatnonzero(edges == -1)])
        states = [state_of(v[0]) for v in raw]
        got_on = [t for t, s in zip(t_lane, states, strict=True) if s == "fault"]
        got_off = [t for t, a, b in zip(t_lane[1:], states, states[1:], strict=False) if a == "fault"]
        np.testing.assert_array_equal(got_on, want_on, err_msg=f"{name}: {channel}")
        np.testing.assert_array_equal(got_off, want_off, err_msg=f"{name}: {channel}")
    # the interval estimates of `detect --json` are annotations in the event log, at their onsets
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    for channel, ivs in found.intervals.items():
        for a, b in ivs if channel != "any" else ():
            k = np.flatnonzero(t_ev == rerun_log.to_ns(a))
            when = f"{a:.2f}" if f"{a:.2f}" == f"{b:.2f}" else f"{a:.2f}-{b:.2f}"
            assert any(texts[i][0].startswith(f"{when} s {channel} flagged frames (estimate)") for i in k)
    # the truth lane: one change per segment of the scenario, at its start
    t_truth, truth = _read(reader, blueprint.TRUTH_LANE, "StateChange:state")
    expected = drivers.scenario_truth(sc)
    assert [s[0] for s in truth] == [lab for _, lab, _ in expected]
    np.testing.assert_array_equal(t_truth, rerun_log.to_ns([start for start, _, _ in expected]))


def test_cli_lanes_equal_json_events(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # the reported case: so-timeline-constant, true faults [0, 2) and [4, 6) s, alarm rule CUSUM (the
    # default of --record): ONE fault episode on the lane, from the alarm (1.00 s, the end of the first
    # frame) to its end, the same numbers as the JSON events; the interval estimates annotate it
    import json

    from chatterspec.cli import main

    path = tmp_path / "tl.rrd"
    assert main(["detect", "so-timeline-constant", "--record", str(path), "--json", "--no-identify"]) == 0
    doc = json.loads(capsys.readouterr().out)
    events = doc["recording"]["events"]
    assert [e["kind"] for e in events if e["channel"] == "velocity"] == ["fault-start", "fault-end"]
    assert events[0]["alarm_time_s"] == pytest.approx(1.0, abs=1e-9)  # the first frame's last sample
    reader = RrdReader(path)
    _check_lanes_and_events(reader, ("position", "velocity"), events)
    _, raw = _read(reader, blueprint.lane_entity(1, "velocity"), "StateChange:state")
    assert [state_of(v[0]) for v in raw] == ["no-evidence", "fault", "healthy"]
    # the fault segment's label names its alarm time and onset estimate (the lane's configuration)
    lane = blueprint.lane_entity(1, "velocity")
    rb = reader.stream().filter(content=lane, is_static=True).to_chunks()[-1].to_record_batch()
    values = rb.column("StateConfiguration:values").to_pylist()[-1]
    labels = rb.column("StateConfiguration:labels").to_pylist()[-1]
    label = dict(zip(values, labels, strict=True))[raw[1][0]]
    assert label == f"FAULT at 1.00 s, onset est. {events[0]['estimate_s']:.2f} s"
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    ivs = [(iv["onset_s"], iv["offset_s"]) for iv in doc["intervals"] if iv["channel"] == "velocity"]
    for a, b in ivs:  # one interval event at each onset, with the same numbers
        k = int(np.flatnonzero(t_ev == rerun_log.to_ns(a))[0])
        assert texts[k][0].startswith(f"{a:.2f}-{b:.2f} s velocity flagged frames (estimate)")


def test_streamed_leak_lanes_equal_jsonl_events(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A 30 s streamed leak (``simulate | monitor --record --events jsonl``, CUSUM at one false alarm per
    day): the lanes change at the ``sample_time_s`` of the printed events (the alarm times), the alarm
    that never clears leaves the lane in FAULT to the end."""
    import json
    import sys

    from chatterspec.cli import main

    model = tmp_path / "eha.toml"
    assert main(["scenarios", "eha-healthy", "--model-toml", str(model)]) == 0
    capsys.readouterr()
    assert main(["simulate", "eha-leak-minor", "--duration", "30", "--rate", "0"]) == 0
    data = tmp_path / "leak.csv"
    data.write_text(capsys.readouterr().out)
    path = tmp_path / "leak.rrd"
    with data.open() as fh:
        monkeypatch.setattr(sys, "stdin", fh)
        argv = ["monitor", "--model", str(model), "--data", "-", "--record", str(path), "--events", "jsonl"]
        assert main([*argv, "--no-identify"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines() if x.strip()]
    events = [
        {**e, "kind": e["event"], "alarm_time_s": e["sample_time_s"]}
        for e in lines
        if e["event"] in ("fault-start", "fault-end")
    ]
    assert [e["kind"] for e in events] == ["fault-start"] and events[0]["channel"] == "pressure"
    assert events[0]["estimate_s"] < events[0]["sample_time_s"]  # the onset estimate comes earlier
    reader = RrdReader(path)
    _check_lanes_and_events(reader, ("position", "velocity", "pressure"), events)
    _, raw = _read(reader, blueprint.lane_entity(2, "pressure"), "StateChange:state")
    assert [state_of(v[0]) for v in raw] == ["no-evidence", "fault"]
