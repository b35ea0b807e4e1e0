"""The state lanes of every demo recording agree with the detector (read back from the .rrd file).

For each scenario of ``chatterspec demo`` one realization is recorded by the online
monitor and read back with Rerun's own reader. The lanes are then evaluated the
way the viewer draws them (the state at time t is the last change at or before t)
and compared, frame by frame, with the verdicts of the independent batch path
(``spectrogram`` + ``frame_threshold`` + ``detect_frames`` on the whole record),
and change by change with the detection events. Exact comparisons: the online
frames equal the batch frames by construction (same kernel, same frame grid), and
every time in the file is the rounded integer ns of :func:`rerun_log.to_ns`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli.demo import DEMO_SCENARIOS
from chatterspec.detection.detect import detect_frames
from chatterspec.detection.pipeline import chattering_record
from chatterspec.detection.spectral import spectrogram
from chatterspec.detection.thresholds import frame_threshold
from chatterspec.plants.scenarios import scenario

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from chatterspec.online import blueprint, drivers, rerun_log  # noqa: E402


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


def _lane_at(change_ns: np.ndarray, states: list[str], query_ns: np.ndarray) -> np.ndarray:
    """The viewer's latest-at rule: the state of the last change at or before each query time."""
    k = np.searchsorted(change_ns, query_ns, side="right") - 1
    assert np.all(k >= 0), "a frame lies before the lane's first state"
    return np.asarray(states, dtype=object)[k]


def test_to_ns_rounds() -> None:
    # the truncating float path gives 500499999 for 0.5005 s; the recording's rule rounds
    assert int(rerun_log.to_ns(0.5005)) == 500_500_000
    np.testing.assert_array_equal(rerun_log.to_ns([0.0, 2.5005, 1e-9 * 0.6]), [0, 2_500_500_000, 1])


@pytest.mark.parametrize("name", DEMO_SCENARIOS)
def test_lanes_match_events_and_batch_verdicts(tmp_path: Path, name: str) -> None:
    sc = scenario(name)
    sim = cs.simulate(sc, runs=1, seed=3)
    path = tmp_path / f"{name}.rrd"
    summary = drivers.record_detection(sim, path=path)

    # independent batch verdicts of the same realization (default detector: alpha 1e-3, Bonferroni)
    rec = chattering_record(sc.nominal, sim.z, sim.u, scenario=sc)
    spec = spectrogram(rec.values[0], rec.dt, t0=rec.t[0])
    thr = frame_threshold(rec.model, spec.freqs_hz, spec.config, rec.dt)
    flags = detect_frames(spec, thr)
    frame_ns = rerun_log.to_ns(spec.times_s)

    reader = RrdReader(path)
    assert "/spectrum/" in reader.store().summary()  # footer written: the file is complete
    for c, channel in enumerate(rec.channels):
        lane = blueprint.lane_entity(c, channel)
        t_lane, raw = _read(reader, lane, "StateChange:state")
        states = [s[0] for s in raw]
        # one time rule: the frames of the recording sit exactly at the rounded batch frame times
        t_stat, stat = _read(reader, blueprint.STATISTIC, "Scalars:scalars")  # one row per frame, m values
        np.testing.assert_array_equal(t_stat, frame_ns)
        assert all(len(row) == len(rec.channels) for row in stat)
        # no two changes at one time (the viewer's order of equal times is arbitrary)
        assert np.all(np.diff(t_lane) > 0), (name, channel, t_lane)
        # the initial state comes strictly before the first frame
        assert states[0] == "healthy" and t_lane[0] < frame_ns[0]
        # every frame: lane == batch verdict
        shown = _lane_at(t_lane, states, frame_ns)
        np.testing.assert_array_equal(shown == "fault", flags[:, c], err_msg=f"{name}: {channel}")
        # every later change is one of this channel's events, at its time
        mine = [ev for ev in summary.events if ev.channel_index == c]
        assert len(states) == 1 + len(mine)
        for ev, t, s in zip(mine, t_lane[1:], states[1:], strict=True):
            assert t == rerun_log.to_ns(ev.time_s)
            assert s == ("fault" if ev.kind == "fault-start" else "healthy")
            assert flags[ev.frame, c] == (ev.kind == "fault-start")
    # the event log holds each event once, at its time
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    assert len(texts) == len(summary.events)
    np.testing.assert_array_equal(t_ev, np.sort(rerun_log.to_ns([ev.time_s for ev in summary.events])))
    # the truth lane: one change per segment of the scenario, at its start
    t_truth, truth = _read(reader, blueprint.TRUTH_LANE, "StateChange:state")
    expected = drivers.scenario_truth(sc)
    assert [s[0] for s in truth] == [lab for _, lab, _ in expected]
    np.testing.assert_array_equal(t_truth, rerun_log.to_ns([start for start, _, _ in expected]))
