"""The two extension points of docs/design.md ("Extension points"), exercised as a user would: a toy
alarm rule and a toy filter, each added through its registry alone (no other module edited), run
through the public paths, and removed again so that other tests see the stock registries.

The toy classes below are the ones docs/design.md shows; keep them equal.
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import dataclass, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np
import pytest

from chatterspec import _jit, filter_registry
from chatterspec.cli import build_parser
from chatterspec.cli import main as cli_main
from chatterspec.cli._options import alarm_choice
from chatterspec.cli._report import alarm_doc
from chatterspec.detection.alarms.calibration import calibrate_rule, poisson_count_interval, starts_on_grid
from chatterspec.detection.alarms.rules import (
    RULES,
    RuleSpec,
    alarm_label,
    make_rule,
    register_rule,
    rule_from_dict,
    rule_names,
    rule_spec,
    unregister_rule,
)
from chatterspec.detection.alarms.steps import RuleSteps
from chatterspec.detection.alarms.streams import AlarmStream, count_starts, run_rule
from chatterspec.errors import ParameterError
from chatterspec.filters.protocol import FilterOutput, FilterState, check_chunk, initial_state
from chatterspec.jsonout import finite_or_none
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.studies.estimation import estimate_records, estimation_study


# --------------------------------------------------------------------------- a toy alarm rule
@dataclass(frozen=True)
class TwiceRule:
    """Alarm when two steps in a row have a score >= ``threshold``; it ends at the first step below."""

    threshold: float = float("inf")
    name: ClassVar[str] = "twice"

    def with_threshold(self, threshold: float) -> TwiceRule:
        return replace(self, threshold=threshold)

    def parameters(self) -> dict[str, Any]:
        return {}

    def to_dict(self) -> dict[str, Any]:
        return {"rule": self.name, "threshold": finite_or_none(self.threshold)}

    def describe(self) -> str:
        return f"twice rule: alarm when two steps in a row have a score >= {self.threshold:.4g}"

    def view_label(self) -> str:
        return "score"


@_jit.njit
def _twice_kernel(
    s, h, p, act, g, count, ring, pos, active, stat, starts, ends
):  # pragma: no cover - compiled
    R, K, C = s.shape
    for r in range(R):
        for c in range(C):
            a, n = act[r, c], count[r, c]
            for j in range(K):
                n = min(n + 1, 2) if s[r, j, c] >= h else 0  # steps in a row over h (2 is enough)
                start, end = (not a) and n >= 2, a and n == 0
                a = (a or start) and not end
                active[r, j, c], stat[r, j, c], starts[r, j, c], ends[r, j, c] = a, n, start, end
            act[r, c], count[r, c] = a, n


def _twice_numpy(s, h, p, step0, act, g, count, ring, out, n_starts=None):
    act = act.copy()
    for j in range(s.shape[1]):
        count = np.where(s[:, j, :] >= h, np.minimum(count + 1, 2), 0)
        start, end = ~act & (count >= 2), act & (count == 0)
        act = (act | start) & ~end
        if out is not None:
            out[0][:, j, :], out[1][:, j, :], out[2][:, j, :], out[3][:, j, :] = act, count, start, end
        if n_starts is not None:
            n_starts += start
    return act, g, count


TWICE_STEPS = RuleSteps(_twice_kernel, _twice_numpy, statistic="count")
TWICE = RuleSpec(
    "twice",
    TwiceRule,
    "alarm when two steps in a row have a score >= h; ends at the first step below h",
    statistic="steps in a row over h",
    steps=lambda: TWICE_STEPS,
)


@pytest.fixture
def twice():
    register_rule(TWICE)
    try:
        yield TWICE
    finally:
        unregister_rule("twice")


def _want_twice(s: np.ndarray, h: float) -> np.ndarray:
    """Independent reading of the rule: active at step t iff the alarm started (two in a row) and no
    step since then was below h."""
    over = s >= h
    active = np.zeros_like(over)
    for c in range(s.shape[1]):
        on = False
        for t in range(s.shape[0]):
            on = (on and over[t, c]) or (t > 0 and over[t, c] and over[t - 1, c])
            active[t, c] = on
    return active


@pytest.mark.parametrize("jit", ["1", "0"])
def test_a_registered_rule_runs_through_the_alarm_layer(twice, jit, monkeypatch):
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    assert "twice" in rule_names() and rule_spec("twice") is twice
    rule = make_rule("twice", 2.0)
    assert isinstance(rule, TwiceRule) and rule_from_dict(rule.to_dict()) == rule
    s = np.random.default_rng(5).exponential(1.0, size=(3, 400, 2))  # P(s >= 2) = e^-2: runs are common
    whole = run_rule(rule, s)
    for r in range(3):
        np.testing.assert_array_equal(whole.active[r], _want_twice(s[r], 2.0))
    assert whole.starts.any() and whole.ends.any()
    # streamed in uneven chunks: the same alarms as whole
    st = AlarmStream(rule, (3, 2))
    cuts = [0, 1, 2, 57, 58, 300, 400]
    parts = [st.update(s[:, a:b]) for a, b in itertools.pairwise(cuts)]
    np.testing.assert_array_equal(np.concatenate([p.starts for p in parts], axis=1), whole.starts)
    np.testing.assert_array_equal(st.statistic, whole.statistic[:, -1])
    # counting on a grid of thresholds = one run per threshold
    hs = np.array([0.5, 1.0, 2.0, 3.0])
    grid = starts_on_grid(rule, s, hs)
    for i, h in enumerate(hs):
        np.testing.assert_array_equal(grid[i], count_starts(rule.with_threshold(h), s))


def test_a_registered_rule_is_calibrated_for_a_budget(twice):
    # iid exponential scores (P(s >= h) = q = e^-h), 50 000 steps per hour, a budget of 200 starts per
    # hour on 20 h: the counted method. A start is a step below h then two over it: rate F (1 - q) q^2,
    # so the budget's threshold solves 50 000 q^2 (1 - q) = 200: h = 2.7269. The calibration's 95 %
    # jackknife interval is +- 0.023 here; 0.07 is three of its widths (the frame rule's count, F q,
    # would put h at 5.5).
    s = np.random.default_rng(11).exponential(1.0, size=(20, 50_000, 1))
    cal = calibrate_rule(make_rule("twice"), s, 50_000.0, 200.0, seed=11)
    assert cal.method == "counted" and isinstance(cal.rule, TwiceRule)
    assert abs(cal.threshold - 2.7269) < 0.07
    # on the same streams the rule at that threshold raises the budget's count (4000 over 20 h), up to
    # the 99 % Poisson interval of that count
    lo, hi = poisson_count_interval(4000.0, 0.99)
    assert lo <= count_starts(cal.rule, s).sum() <= hi
    assert cal.describe().startswith("twice rule, threshold")


def test_a_registered_rule_is_a_cli_choice_with_its_texts(twice):
    argv = ["monitor", "m.toml", "--data", "d.csv", "--rule", "twice"]
    args = build_parser().parse_args(argv)
    choice = alarm_choice(args)
    assert choice.rule == "twice" and choice.parameters == {}
    bad = build_parser().parse_args(
        ["monitor", "m.toml", "--data", "d.csv", "--rule", "twice", "--cusum-drift", "2"]
    )
    with pytest.raises(ParameterError, match="--cusum-drift applies to --rule cusum"):
        alarm_choice(bad)
    rule = make_rule("twice", 4.0)
    assert alarm_label(rule.name, 1 / 24) == "twice rule, 1 false alarm per 24 h"
    assert alarm_doc(argparse.Namespace(rule=rule, budget=None))["rule"] == {
        "rule": "twice",
        "threshold": 4.0,
    }
    # the monitor's alarm view title (viewer.blueprint) reads the rule's own label
    from chatterspec.viewer.blueprint import MonitorLayout

    fake = SimpleNamespace(
        monitor=SimpleNamespace(rule=rule, settings=SimpleNamespace(false_alarms_per_hour=0.5))
    )
    fake.budget_per_hour = None
    fake.budget_words = lambda *, rule=True: MonitorLayout.budget_words(fake, rule=rule)
    assert MonitorLayout.alarm_title(fake)[0] == "score vs h = 4 nats, 1 false alarm/2 h"
    assert MonitorLayout.budget_words(fake) == "twice, 1 false alarm/2 h"


def test_a_registered_rule_drives_the_online_monitor(twice):
    from chatterspec.detection.pipeline import chattering_record
    from chatterspec.detection.spectral import frame_columns
    from chatterspec.detection.verdicts import FrameScore
    from chatterspec.plants.simulate import simulate
    from chatterspec.studies.alarm_budget import onset_scenarios

    sc = onset_scenarios("eha-leak-medium", healthy_s=3.0, fault_s=3.0, phases=(1.0,))[0]
    sim = simulate(sc, runs=1, seed=3)
    model = sim.scenario.nominal
    rule = TwiceRule(8.0)
    settings = MonitorSettings(rule=rule)
    mon = ChatteringMonitor(model, settings)
    # a rule without a channel step (RuleSteps.channel): the monitor runs the frame analysis and then the
    # rule's own kernel per push instead of the one fused call the stock rules get
    assert TWICE_STEPS.channel is None and not mon._frames._fused
    assert (
        ChatteringMonitor(model, MonitorSettings(rule=make_rule("cusum", 8.0)))._frames._fused
        is _jit.enabled()
    )
    _, P = frame_columns(chattering_record(model, sim.z, sim.u).values[0], model.dt, settings.stft)
    blk = run_rule(rule, FrameScore(mon.threshold)(P))
    events = mon.push(sim.z[0], sim.u).events
    assert events and [(e.kind, e.frame, e.rule) for e in events] == [
        ("fault-start" if e.kind == "alarm-start" else "fault-end", e.step, "twice") for e in blk.events()
    ]
    # one sample at a time (ChatteringMonitor.step), with a push in between: the same events
    stepped = ChatteringMonitor(model, settings)
    z, u, by_step = sim.z[0], sim.u, []
    for k in range(z.shape[0]):
        by_step += (
            stepped.push(z[k : k + 1], u[k : k + 1]).events if k % 1000 == 500 else stepped.step(z[k], u[k])
        )
    assert by_step == list(events)


def test_the_stock_rules_are_back():
    assert tuple(RULES) == ("frame", "persistence", "cusum")


# --------------------------------------------------------------------------- a toy filter
class FixedGainObserver:
    """Linear observer with a constant gain ``L``: ``x(k+1|k+1) = x(k+1|k) + L (z(k+1) - C x(k+1|k))``,
    and the covariance that gain gives (Joseph form: ``(I - L C) P (I - L C)^T + L R L^T``)."""

    def __init__(self, model: Any, gain: np.ndarray) -> None:
        self._model, self.L = model, np.asarray(gain, dtype=float)

    @property
    def model(self) -> Any:
        return self._model

    def initialize(self, x0, P0, *, runs=None, e0=None, e_prev0=None) -> FilterState:
        return initial_state(self._model, x0, P0, runs=runs, e0=e0, e_prev0=e_prev0, shared_ok=True)

    def correct(self, state, x_prior, P_prior, z, *, store=None):
        m, L = self._model, self.L
        e = z - x_prior @ m.C.T
        x = x_prior + e @ L.T
        IKC = np.eye(m.n_states) - L @ m.C
        P = IKC @ P_prior @ IKC.T + L @ m.R @ L.T
        S = m.C @ P_prior @ m.C.T + m.R
        post = state.replace(x=x, P=P, e_prev=state.e_post, e_post=z - x @ m.C.T, k=state.k + 1)
        return post, FilterOutput(x_post=x, innovation=e, S=S, P_post=P)

    def update(self, state, z, u=None, *, store=None, check=True):
        m = self._model
        z, u = check_chunk(m, state, z, u, check)
        outs = []
        for k in range(z.shape[1]):
            x_prior = state.x @ m.A.T + u[:, k] @ m.B.T
            state, o = self.correct(state, x_prior, m.A @ state.P @ m.A.T + m.Q, z[:, k])
            outs.append(o)
        runs, K = z.shape[0], z.shape[1]

        def stack(field: str, per_run: bool) -> np.ndarray:
            a = np.stack([getattr(o, field) for o in outs])
            return np.moveaxis(a, 0, 1) if per_run else np.broadcast_to(a, (runs, *a.shape))

        out = FilterOutput(
            x_post=stack("x_post", True), innovation=stack("innovation", True), S=stack("S", False),
            P_post=stack("P_post", False),
        )  # fmt: skip
        assert out.x_post.shape[:2] == (runs, K)
        return state, out

    def run(self, z, u=None, *, x0, P0, store=None) -> FilterOutput:
        return self.update(self.initialize(x0, P0, runs=z.shape[0]), z, u, store=store)[1]


def fixed_from_settings(model: Any, settings: Any, source: str) -> FixedGainObserver:
    """The steady-state Kalman gain of ``model`` as the fixed gain."""
    from scipy.linalg import solve_discrete_are

    P = solve_discrete_are(model.A.T, model.C.T, model.Q, model.R)
    return FixedGainObserver(model, P @ model.C.T @ np.linalg.inv(model.C @ P @ model.C.T + model.R))


FIXED = filter_registry.FilterEntry(
    "fixed", "fixed-gain observer (steady-state Kalman gain)", fixed_from_settings, "fixed gain", "purple"
)


@pytest.fixture
def fixed():
    filter_registry.register_filter(FIXED)
    try:
        yield FIXED
    finally:
        filter_registry.unregister_filter("fixed")


def test_a_registered_filter_runs_through_the_estimation_study(fixed, capsys):
    res = estimation_study("detc-normal", "kf,fixed", runs=4, seed=0)
    assert [f.name for f in res.filters] == ["kf", "fixed"]
    kf, fx = res.get("kf").rmse.mean, res.get("fixed").rmse.mean
    # the KF's gain converges to the steady-state one within a few samples, so over the whole record
    # the two RMSEs agree closely; a wrong sign or a missing input term would be off by orders
    np.testing.assert_allclose(fx, kf, rtol=0.05)
    recs = estimate_records("detc-normal", "kf,fixed", runs=1, seed=0)
    d = np.abs(recs.outputs["fixed"].x_post - recs.outputs["kf"].x_post)[0]
    scale = np.abs(recs.error("kf")[0]).max(axis=0)
    assert np.all(d[-d.shape[0] // 10 :].max(axis=0) < 1e-5 * scale)  # the gains have converged by then
    # and the command line takes it
    assert cli_main(["estimate", "detc-normal", "--filters", "fixed", "--runs", "2", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [f["filter"] for f in doc["filters"]] == ["fixed"]
    assert doc["filters"][0]["description"] == FIXED.description


def test_a_registered_filter_is_drawn_with_its_entry(fixed):
    from chatterspec.figures.estimators import _line
    from chatterspec.palette import TAB10, filter_color

    assert filter_color("fixed") == TAB10["purple"]
    assert _line("fixed", 3)["label"] == "fixed gain"


def test_the_stock_filters_are_back():
    assert tuple(filter_registry.FILTERS) == ("kf", "ekf", "svsf", "svsf2")
    with pytest.raises(ParameterError, match="unknown filter"):
        filter_registry.parse_filters("fixed")


def test_the_design_doc_shows_this_code():
    """docs/design.md's examples are the toy rule and filter above, verbatim."""
    here = Path(__file__).read_text(encoding="utf-8")
    doc = (Path(__file__).resolve().parents[1] / "docs" / "design.md").read_text(encoding="utf-8")

    def block(start: str, end: str) -> str:
        a = here.index(start)
        return here[a : here.index(end, a)].rstrip().replace("  # pragma: no cover", "")

    for start, end in (
        ("@dataclass(frozen=True)\nclass TwiceRule:", "\nTWICE_STEPS = "),
        ("class FixedGainObserver:", "\nFIXED = "),
    ):
        assert block(start, end) in doc, start
