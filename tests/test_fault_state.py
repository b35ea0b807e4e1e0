"""One fault state per channel (``chatterspec.online.fault_state``) and the pieces that draw it: the lanes'
labelled episodes, the diagnosis mode lanes' minimum run, fitted titles and identification units."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest

from chatterspec.online.fault_state import (
    FAULT,
    HEALTHY,
    NO_EVIDENCE,
    STATES,
    FaultStates,
    alarm_time,
    frame_states,
)


def test_frame_states_three_values() -> None:
    alarm = np.array([[False, True], [False, False], [True, False]])
    excited = np.array([[True, False], [False, True], [False, False]])
    # the alarm wins; without it, a channel not excited has no evidence
    np.testing.assert_array_equal(frame_states(alarm), [[0, 1], [0, 0], [1, 0]])
    np.testing.assert_array_equal(frame_states(alarm, excited), [[0, 1], [2, 0], [1, 2]])


def test_changes_do_not_depend_on_the_blocks() -> None:
    rng = np.random.default_rng(5)
    alarm = rng.random((40, 3)) < 0.3
    times = 0.5005 + 0.2 * np.arange(40)
    whole = FaultStates(3, 1000, 1e-3)
    start = whole.start(0.001)
    assert list(start.code) == [2, 2, 2]  # no evidence until the first frame is decided
    one = whole.update(times, alarm)
    parts = FaultStates(3, 1000, 1e-3)
    parts.start(0.001)
    pieces = [parts.update(times[a:b], alarm[a:b]) for a, b in ((0, 7), (7, 8), (8, 40))]
    np.testing.assert_array_equal(np.concatenate([p.times_s for p in pieces]), one.times_s)
    np.testing.assert_array_equal(np.concatenate([p.code for p in pieces]), one.code)
    # every change at the alarm time of its frame, the first frame always changes (from no evidence)
    assert one.times_s[0] == alarm_time(times[0], 1000, 1e-3) == pytest.approx(1.0)
    _, states = one.of(1)
    assert states[0] in (HEALTHY, FAULT) and all(a != b for a, b in itertools.pairwise(states))


def test_monitor_events_carry_the_alarm_time() -> None:
    import chatterspec as cs
    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings

    sc = cs.scenario("so-timeline-constant")
    sim = cs.simulate(sc, runs=1, seed=0)
    mon = ChatteringMonitor(sc.nominal, MonitorSettings(), t0=float(sim.t[0]))
    upd = mon.push(sim.z[0], sim.input_of(0))
    assert upd.events
    for ev in upd.events:  # the end of the deciding frame: its centre plus half a window
        assert ev.alarm_time_s == alarm_time(ev.time_s, mon.n_window, mon.dt)
        assert ev.to_dict()["alarm_time_s"] == ev.alarm_time_s
        assert ev.estimate_s < ev.alarm_time_s


def test_lane_episodes_are_labelled_with_their_estimates() -> None:
    pytest.importorskip("rerun")
    from chatterspec.online.monitor import DetectionEvent
    from chatterspec.viewer.events import SLOTS, FaultLanes, state_of

    lanes = FaultLanes(("p",), 1000, 200, 1e-3)
    _, _, first = lanes.start(0.0)
    assert first == [NO_EVIDENCE]
    times = 0.5005 + 0.2 * np.arange(4)
    alarm = np.array([[False], [True], [True], [False]])
    t_on, t_off = alarm_time(times[1], 1000, 1e-3), alarm_time(times[3], 1000, 1e-3)
    evs = [
        DetectionEvent("fault-start", "p", 0, times[1], 1, 20.0, 3.0, 0.6, alarm_time_s=t_on),
        DetectionEvent("fault-end", "p", 0, times[3], 3, 20.0, 3.0, 1.1, alarm_time_s=t_off),
    ]
    t, _, values = lanes.update(times, alarm, evs)
    assert [state_of(v) for v in values] == [HEALTHY, FAULT, HEALTHY]
    np.testing.assert_array_equal(t, [alarm_time(x, 1000, 1e-3) for x in times[[0, 1, 3]]])
    cfg = lanes.configuration(0)
    labels = dict(
        zip(cfg.values.as_arrow_array().to_pylist(), cfg.labels.as_arrow_array().to_pylist(), strict=True)
    )
    assert labels[values[1]] == "FAULT at 1.20 s, onset est. 0.60 s"
    assert labels[values[2]] == "healthy at 1.60 s, offset est. 1.10 s"
    assert SLOTS >= 1 and lanes.n_episodes == [1]


def _update(states: list[tuple[str, ...]], alarm_times: list[float], not_excited: list[list[bool]]) -> Any:
    """An identification push of one parameter over two channels (the second carries it) with the given
    per-window channel states: only what the lanes read (no identification is run)."""
    from chatterspec.online.identification_monitor import IdentificationUpdate, WindowDecision

    windows = tuple(
        WindowDecision(
            index=j, time_s=t - 0.4995, window_s=(t - 0.998, t + 0.001), alarm_time_s=t,
            alarm=ch[1] == "fault", label="leakage" if ch[1] == "fault" else None,
            states=(ch[1],), channel_states=ch,
        )
        for j, (t, ch) in enumerate(zip(alarm_times, states, strict=True))
    )  # fmt: skip
    return IdentificationUpdate(found=None, block=None, windows=windows, not_excited=np.array(not_excited))


def test_not_excited_is_no_evidence_on_the_lanes() -> None:
    # The identification's "not excited" (the data cannot see a change of the parameter's tolerance) is
    # the lanes' "no evidence", never "healthy": with tolerances (the parameters' windows decide) and
    # without (the spectral alarm decides, the windows give the excitation; an alarm still wins).
    pytest.importorskip("rerun")
    from chatterspec.viewer.events import NOT_EXCITED, FaultLanes, state_of

    t = [1.001, 1.201, 1.401, 1.601]
    seq = [
        ("healthy", "healthy"),
        ("healthy", "not-excited"),
        ("healthy", "fault"),
        ("healthy", "not-excited"),
    ]
    blind = [[False, False], [False, True], [False, True], [False, True]]
    upd = _update(seq, t, blind)
    times, codes = upd.channel_codes()  # the seam: the identification's state codes are fault_state's
    np.testing.assert_array_equal(times, t)
    assert [STATES[k] for k in codes[:, 1]] == [HEALTHY, NO_EVIDENCE, FAULT, NO_EVIDENCE]

    tol = FaultLanes(("position", "pressure"), 1000, 200, 1e-3)
    tol.start(0.001)
    tol.follow_identification(tolerances=True, parameters=("leakage",), carried=np.array([[False], [True]]))
    at, ch, values = tol.follow(upd)
    pressure = [
        (x, state_of(v), v) for x, c, v in zip(at.tolist(), ch.tolist(), values, strict=True) if c == 1
    ]
    assert [s for _, s, _ in pressure] == [HEALTHY, NO_EVIDENCE, FAULT, NO_EVIDENCE]
    assert [x for x, _, _ in pressure] == t  # at the windows' alarm times
    assert [v for _, s, v in pressure if s == NO_EVIDENCE] == [NOT_EXCITED, NOT_EXCITED]
    assert [state_of(v) for x, c, v in zip(at, ch, values, strict=True) if c == 0] == [HEALTHY]

    spec = FaultLanes(("position", "pressure"), 1000, 200, 1e-3)
    spec.start(0.001)
    spec.follow_identification(tolerances=False, parameters=("leakage",), carried=np.array([[False], [True]]))
    frames = 0.5005 + 0.2 * np.arange(4)  # frames ending 1.0 .. 1.6 s, one sample before each window
    alarm = np.array([[False, False], [False, False], [False, True], [False, False]])
    got = [spec.update(frames, alarm, []), spec.follow(upd), spec.finish()]
    at = np.concatenate([g[0] for g in got])
    ch = np.concatenate([g[1] for g in got])
    values = [v for g in got for v in g[2]]
    pressure = [state_of(v) for c, v in zip(ch.tolist(), values, strict=True) if c == 1]
    # healthy; not excited from the second window; the frame's alarm wins; no evidence again after it
    assert pressure == [HEALTHY, NO_EVIDENCE, FAULT, NO_EVIDENCE]
    assert HEALTHY not in pressure[1:]


def test_mode_lane_keeps_runs_of_at_least_the_hold() -> None:
    from chatterspec.viewer.recordings import held_changes

    t = np.arange(20) * 0.05
    best = np.array([0] * 5 + [1] * 2 + [0] * 3 + [1] * 10)  # a 0.1 s run of mode 1 at 0.25 s
    np.testing.assert_array_equal(held_changes(best, t, 0.2), [0, 10])
    np.testing.assert_array_equal(held_changes(best, t, 0.05), [0, 5, 7, 10])


def test_titles_are_shortened_never_cut() -> None:
    from chatterspec.viewer.blueprint import fit, title_chars

    assert title_chars(4) < title_chars(3) < title_chars(2)
    variants = [
        "pressure: CUSUM g vs h = 20.4 nats, 1 false alarm/24 h",
        "pressure: CUSUM g vs h = 20.4 nats",
    ]
    assert fit(variants, title_chars(3)) == variants[0]
    assert fit(variants, title_chars(4)) == variants[1] and "20.4" in fit(variants, 10)


def test_identification_units_are_scaled() -> None:
    from chatterspec.viewer.rerun_log import display_scale

    # engineering exponents: a leakage of 4.8e-12 is drawn in 1e-12 units, a bulk modulus in 1e6
    assert display_scale(4.8e-12) == -12 and display_scale(2.07e8) == 6 and display_scale(2144.0) == 3
    assert display_scale(0.0) == 0 and display_scale(8.0) == 0 and display_scale(0.1) == 0
