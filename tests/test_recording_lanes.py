"""One fault state per channel: the lanes of a recording change exactly at the alarm times that the JSON
events report and the event log shows (read back from the .rrd file).

For each scenario of ``chatterspec demo`` one realization is recorded as the demo records it (the online
monitor with the per-hop identification beside it) and read back with Rerun's own reader; the per-frame
verdicts are compared frame by frame with the independent batch path (``stft_detect`` on the whole
record), and each lane, change by change, with the state built here from that batch path's flagged
frames (the demo's alarm rule is the frame rule) and the identification's excitation per window. The
same holds for a 30 s streamed leak through ``chatterspec monitor --record`` (CUSUM at a budget), with
and without identification, against its ``--events jsonl`` lines, and with tolerances for the
parameters' events. Exact comparisons: the online frames equal the batch frames by construction (same
kernel, same frame grid), and every time in the file is the rounded integer ns of
:func:`spectrograms.to_ns` of the same float.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli.demo import DEMO_SCENARIOS
from chatterspec.detection.pipeline import chattering_record
from chatterspec.detection.verdicts import stft_detect
from chatterspec.plants.scenarios import scenario

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from chatterspec.online.fault_state import alarm_time  # noqa: E402
from chatterspec.viewer import blueprint, recordings, spectrograms  # noqa: E402
from chatterspec.viewer.events import NOT_EXCITED, state_of  # noqa: E402


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
    assert int(spectrograms.to_ns(0.5005)) == 500_500_000
    np.testing.assert_array_equal(spectrograms.to_ns([0.0, 2.5005, 1e-9 * 0.6]), [0, 2_500_500_000, 1])


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
        np.testing.assert_array_equal(into, spectrograms.to_ns(starts), err_msg=channel)
        np.testing.assert_array_equal(out_of, spectrograms.to_ns(ends), err_msg=channel)
        for e in mine:  # the event log: one row at the alarm time, naming it and the estimate
            word, est = ("ALARM", "onset") if e["kind"] == "fault-start" else ("alarm cleared", "offset")
            k = [
                i
                for i in np.flatnonzero(t_ev == spectrograms.to_ns(e["alarm_time_s"]))
                if word in texts[i][0]
            ]
            assert len(k) == 1, (channel, e)
            want = f"{e['alarm_time_s']:.2f} s {channel} {word} ({est} est. {e['estimate_s']:.2f} s)"
            assert texts[k[0]][0].startswith(want), (texts[k[0]][0], want)
            assert levels[k[0]][0] == ("ERROR" if word == "ALARM" else "INFO")


def _expected_lane(
    frame_ends: list[float], flags: np.ndarray, window_ends: np.ndarray, blind: np.ndarray, start_s: float
) -> tuple[np.ndarray, list[str]]:
    """The lane built from its definition (chatterspec.online.fault_state): no evidence from the start;
    the frame rule's alarm at each frame's end, the channel's excitation at each window's last sample, a
    frame after the window before it (so in time order); no evidence without an alarm until the first
    window and wherever that window says not excited. Returns the changes (ns, states)."""
    items = sorted(
        [(t, 0, bool(f)) for t, f in zip(frame_ends, flags, strict=True)]
        + [(float(t), 1, bool(b)) for t, b in zip(window_ends, blind, strict=True)]
    )
    alarm, no_view = False, True
    times, states = [start_s], ["no-evidence"]
    for t, kind, value in items:
        if kind == 0:
            alarm = value
        else:
            no_view = value
        state = "fault" if alarm else "no-evidence" if no_view else "healthy"
        if state != states[-1]:
            times.append(t)
            states.append(state)
    return spectrograms.to_ns(times), states


@pytest.mark.parametrize("name", DEMO_SCENARIOS)
def test_lanes_match_events_and_batch_verdicts(tmp_path: Path, name: str) -> None:
    from chatterspec.detection.identification import identification_setup
    from chatterspec.detection.parameter_decision import parameter_alarm_settings
    from chatterspec.online.identification_monitor import IdentificationMonitor

    sc = scenario(name)
    sim = cs.simulate(sc, runs=1, seed=3)
    path = tmp_path / f"{name}.rrd"
    setup = identification_setup(sc.nominal)  # every demo scenario declares its parameters
    summary = recordings.record_detection(sim, path=path, identification=setup)
    doc = summary.to_dict()  # what `demo --json` prints of the recording

    # independent batch path on the same realization (default detector: alpha 1e-3, Bonferroni): the
    # per-frame verdicts, whose runs are the frame rule's alarm episodes
    rec = chattering_record(sc.nominal, sim.z, sim.u, scenario=sc)
    found = stft_detect(rec.values[:1], rec.model, t0=float(rec.t[0]))
    spec, flags = found.spectrogram, found.flags[0]
    frame_ns = spectrograms.to_ns(spec.times_s)
    n_window = spec.config.n_window(rec.dt)
    half_win = (n_window - 1) * rec.dt / 2.0
    start_ns = int(spectrograms.to_ns(spec.times_s[0] - half_win))  # the first window's first sample

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
    # the identification's excitation per window, from its own monitor on the same data (the excitation
    # does not depend on the alarms): the windows' last samples and the channels not excited
    hop = spec.config.n_hop(rec.dt)
    ident = IdentificationMonitor(
        setup,
        parameter_alarm_settings(setup, hop_s=hop * rec.dt, window_hops=round(n_window / hop)),
        t0=float(sim.t[0]),
        frame_samples=n_window,
    )
    upd = ident.push(sim.z[0], sim.input_of(0))
    window_ends = np.array([w.alarm_time_s for w in upd.windows])
    np.testing.assert_allclose(window_ends, upd.found.window_s[:, 1] - rec.dt)
    ends = [alarm_time(t, n_window, rec.dt) for t in spec.times_s]
    for c, channel in enumerate(rec.channels):
        t_lane, raw = _read(reader, blueprint.lane_entity(c, channel), "StateChange:state")
        assert t_lane[0] == start_ns  # no evidence from the first window's first sample
        # the frame rule: fault from the end of each run's first flagged frame to the end of the first
        # clean frame after it (no change at the record's end: a fault still open stays open); not
        # excited where the identification says so, from its windows' last samples
        want_t, want = _expected_lane(
            ends, flags[:, c], window_ends, upd.not_excited[:, c], spec.times_s[0] - half_win
        )
        states = [state_of(v[0]) for v in raw]
        np.testing.assert_array_equal(t_lane, want_t, err_msg=f"{name}: {channel}")
        assert states == want, (name, channel)
        # the label says which no evidence it is: before the first window, or not excited
        assert raw[0][0] == "no-evidence" and all(
            v[0] == NOT_EXCITED for v in raw[1:] if state_of(v[0]) == "no-evidence"
        )
    if name == "eha-healthy":  # exercised: the first window's leakage is not excited (1 s of data)
        assert upd.not_excited[0, rec.channels.index("pressure")]
    # the interval estimates of `detect --json` are annotations in the event log, at their onsets
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    for channel, ivs in found.intervals.items():
        for a, b in ivs if channel != "any" else ():
            k = np.flatnonzero(t_ev == spectrograms.to_ns(a))
            when = f"{a:.2f}" if f"{a:.2f}" == f"{b:.2f}" else f"{a:.2f}-{b:.2f}"
            assert any(texts[i][0].startswith(f"{when} s {channel} flagged frames (estimate)") for i in k)
    # the truth lane: one change per segment of the scenario, at its start
    t_truth, truth = _read(reader, blueprint.TRUTH_LANE, "StateChange:state")
    expected = recordings.scenario_truth(sc)
    assert [s[0] for s in truth] == [lab for _, lab, _ in expected]
    np.testing.assert_array_equal(t_truth, spectrograms.to_ns([start for start, _, _ in expected]))


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
        k = int(np.flatnonzero(t_ev == spectrograms.to_ns(a))[0])
        assert texts[k][0].startswith(f"{a:.2f}-{b:.2f} s velocity flagged frames (estimate)")


@pytest.fixture(scope="module")
def leak_stream(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The catalogue's linear EHA as a model file and 30 s of its minor leak as CSV rows."""
    import contextlib
    import io

    from chatterspec.cli import main

    folder = tmp_path_factory.mktemp("leak")
    model, data = folder / "eha.toml", folder / "leak.csv"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["scenarios", "eha-healthy", "--model-toml", str(model)]) == 0
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["simulate", "eha-leak-minor", "--duration", "30", "--rate", "0"]) == 0
    data.write_text(out.getvalue())
    return model, data


@pytest.mark.parametrize("identify", [False, True])
def test_streamed_leak_lanes_equal_jsonl_events(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    leak_stream: tuple[Path, Path],
    identify: bool,
) -> None:
    """A 30 s streamed leak (``simulate | monitor --record --events jsonl``, CUSUM at one false alarm per
    day), with and without identification: the lanes change at the ``sample_time_s`` of the printed
    events (the alarm times), the alarm that never clears leaves the lane in FAULT to the end."""
    import json
    import sys

    from chatterspec.cli import main

    model, data = leak_stream
    path = tmp_path / "leak.rrd"
    with data.open() as fh:
        monkeypatch.setattr(sys, "stdin", fh)
        argv = ["monitor", str(model), "--data", "-", "--record", str(path), "--events", "jsonl"]
        assert main(argv if identify else [*argv, "--no-identify"]) == 0
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
    parameter_lanes = _read(reader, "/state/p1_leakage", "StateChange:state")[1]
    assert bool(parameter_lanes) == identify  # identification drawn where it runs


def test_lanes_follow_the_parameters_with_tolerances(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], leak_stream: tuple[Path, Path]
) -> None:
    """With a tolerance the parameters decide: the pressure lane (its chattering carries the leakage) is
    FAULT from the leakage's alarm time in the JSON events, labelled with the parameter; the spectral
    alarm is a mismatch row of the event log, not a lane change; the parameter's alarm is an ALARM row at
    the same time."""
    import json

    from chatterspec.cli import main

    model, data = leak_stream
    tolerant = tmp_path / "m.toml"
    text = model.read_text()
    assert text.count('unit = "m^3/(s Pa)"') == 1
    tolerant.write_text(text.replace('unit = "m^3/(s Pa)"', 'unit = "m^3/(s Pa)", tolerance = "100%"'))
    path = tmp_path / "tol.rrd"
    argv = ["monitor", str(tolerant), "--data", str(data), "--record", str(path), "--json"]
    assert main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["decision"] == "parameters (tolerances)"
    starts = [e for e in doc["events"] if e["event"] == "fault-start"]
    assert [e["parameter"] for e in starts] == ["leakage"]
    t_alarm = starts[0]["sample_time_s"]
    assert t_alarm == pytest.approx(starts[0]["window_s"][1] - 1e-3) if "window_s" in starts[0] else True
    reader = RrdReader(path)
    t_lane, raw = _read(reader, blueprint.lane_entity(2, "pressure"), "StateChange:state")
    into = [t for t, v in zip(t_lane, raw, strict=True) if state_of(v[0]) == "fault"]
    assert into == [spectrograms.to_ns(t_alarm)]
    rb = reader.stream().filter(content=blueprint.lane_entity(2, "pressure"), is_static=True).to_chunks()
    cfg = rb[-1].to_record_batch()
    labels = dict(
        zip(
            cfg.column("StateConfiguration:values").to_pylist()[-1],
            cfg.column("StateConfiguration:labels").to_pylist()[-1],
            strict=True,
        )
    )
    fault_value = next(v[0] for v in raw if state_of(v[0]) == "fault")
    assert labels[fault_value] == f"FAULT at {t_alarm:.2f} s: leakage"
    for c, ch in enumerate(("position", "velocity")):  # they carry no leakage: never in fault
        _, other = _read(reader, blueprint.lane_entity(c, ch), "StateChange:state")
        assert "fault" not in [state_of(v[0]) for v in other]
    t_ev, texts = _read(reader, "/events", "TextLog:text")
    _, levels = _read(reader, "/events", "TextLog:level")
    rows = [(t, x[0], lv[0]) for t, x, lv in zip(t_ev, texts, levels, strict=True)]
    alarm = [r for r in rows if " leakage ALARM" in r[1]]
    assert len(alarm) == 1 and alarm[0][0] == spectrograms.to_ns(t_alarm) and alarm[0][2] == "ERROR"
    mismatch = [r for r in rows if "pressure mismatch" in r[1]]
    assert mismatch and all(r[2] == "INFO" for r in mismatch)  # the chattering saw it: information
    assert not [r for r in rows if "pressure ALARM" in r[1]]


def test_excitation_lanes_do_not_depend_on_how_the_pushes_split() -> None:
    # Without tolerances the lanes are drawn from the frames' alarms and the identification windows'
    # excitation in time order, each frame once the window before it is known: the same changes whether
    # frames and windows come in one push or several (the alarm and the blindness carried across pushes).
    from types import SimpleNamespace

    from chatterspec.online.fault_state import FAULT, HEALTHY, NO_EVIDENCE
    from chatterspec.viewer.events import FaultLanes

    frames = 0.5005 + 0.2 * np.arange(8)  # frame ends, one sample before each window's alarm time
    alarm = np.zeros((8, 2), dtype=bool)
    alarm[2:5, 1] = alarm[6, 0] = True
    windows = 1.001 + 0.2 * np.arange(8)
    blind = np.zeros((8, 2), dtype=bool)
    blind[1:3, 1] = blind[5:, 0] = True

    def run(splits: list[tuple[tuple[int, int], tuple[int, int]]]) -> list[tuple[float, int, str]]:
        lanes = FaultLanes(("position", "pressure"), 1000, 200, 1e-3)
        lanes.start(0.001)
        carried = np.array([[False], [True]])
        lanes.follow_identification(tolerances=False, parameters=("leakage",), carried=carried)
        got = []
        for (a, b), (c, d) in splits:  # frames [a, b), then windows [c, d)
            got.append(lanes.update(frames[a:b], alarm[a:b], []))
            wins = [SimpleNamespace(alarm_time_s=float(t)) for t in windows[c:d]]
            got.append(lanes.follow(SimpleNamespace(windows=wins, not_excited=blind[c:d])))
        got.append(lanes.finish())
        return [
            (round(t, 9), c, state_of(v))
            for g in got
            for t, c, v in zip(g[0].tolist(), g[1].tolist(), g[2], strict=True)
        ]

    whole = run([((0, 8), (0, 8))])
    assert {s for _, _, s in whole} == {HEALTHY, FAULT, NO_EVIDENCE}
    assert run([((0, 3), (0, 3)), ((3, 5), (3, 5)), ((5, 8), (5, 8))]) == whole
    assert run([((k, k + 1), (k, k + 1)) for k in range(8)]) == whole
    # windows arriving ahead of the frames: a push's first window holds the alarm of the last push's frame
    assert run([((0, 5), (0, 3)), ((5, 5), (3, 5)), ((5, 8), (5, 8))]) == whole
