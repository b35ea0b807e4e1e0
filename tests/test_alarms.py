"""The alarm layer (chatterspec.detection.alarms.streams): rule semantics, streaming, both paths."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.detection.alarms import streams
from chatterspec.detection.alarms.rules import (
    RULES,
    CusumRule,
    FrameRule,
    PersistenceRule,
    make_rule,
    rule_from_dict,
    rule_names,
    rule_spec,
)
from chatterspec.detection.alarms.streams import AlarmStream, count_starts, run_rule
from chatterspec.errors import NonFiniteError, ParameterError, ShapeError

FIELDS = ("active", "statistic", "starts", "ends")
RULE_CASES = [FrameRule(3.0), PersistenceRule(2.0, k=2, n=4), CusumRule(6.0, drift=1.5)]


def _scores(seed: int = 1, shape: tuple[int, ...] = (3, 2000, 2)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    s = rng.exponential(size=shape)
    s[..., 700:760, :] += 4.0  # a fault-like stretch: long alarms with ends
    # ties with the thresholds of RULE_CASES (within the first 300 steps, which the kernel's Python form
    # sees too), each after quiet steps so that only ">=" raises the alarm: a frame score of exactly 3,
    # two scores of exactly 2 in a window of 4 (persistence k = 2), and a CUSUM step from g = 0 to
    # exactly 7.5 - 1.5 = 6
    s[..., 200:210, :] = 0.0
    s[..., 210, :] = 3.0
    s[..., 211:230, :] = 0.0
    s[..., 230, :] = s[..., 232, :] = 2.0
    s[..., 233:250, :] = 0.0
    s[..., 250, :] = 7.5
    s[..., 251:260, :] = 0.0
    return s


def _same(a: streams.AlarmBlock, b: streams.AlarmBlock) -> None:
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.shape == y.shape, f
        assert np.array_equal(x, y), f


@pytest.mark.parametrize("rule", RULE_CASES, ids=lambda r: r.name)
def test_chunking_does_not_change_the_alarms(rule, monkeypatch):
    s = _scores()
    whole = run_rule(rule, s)
    rng = np.random.default_rng(5)
    cuts = np.unique(np.r_[0, rng.integers(0, s.shape[1], 25), 1, 2, s.shape[1]])
    st = AlarmStream(rule, (3, 2))
    parts = [st.update(s[:, a:b]) for a, b in itertools.pairwise(cuts)]
    assert [p.first_step for p in parts] == cuts[:-1].tolist()
    for f in FIELDS:
        assert np.array_equal(np.concatenate([getattr(p, f) for p in parts], axis=1), getattr(whole, f)), f
    assert st.steps == s.shape[1]
    assert np.array_equal(st.active, whole.active[:, -1])


@pytest.mark.parametrize("rule", RULE_CASES, ids=lambda r: r.name)
def test_numpy_and_compiled_paths_give_the_same_bits(rule, monkeypatch):
    s = _scores(2)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    ref = run_rule(rule, s)
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    if _jit.enabled():
        _same(run_rule(rule, s), ref)
    # the kernel's own Python form (meaningful without the compiler)
    small = s[:2, :300]
    want = run_rule(rule, small)
    R, K, C = small.shape
    out = [np.empty((R, K, C), dtype=bool), np.empty((R, K, C)), np.empty((R, K, C), dtype=bool),
           np.empty((R, K, C), dtype=bool)]  # fmt: skip
    steps = rule_spec(rule).load_steps()
    kern = _jit.python_form(steps.kernel)
    kern(
        small, rule.threshold, streams.rule_vector(rule), np.zeros((R, C), dtype=bool), np.zeros((R, C)),
        np.zeros((R, C), dtype=np.int64), np.zeros((R, C, streams.ring_length(rule, steps)), dtype=bool),
        np.zeros(1, dtype=np.int64), *out,
    )  # fmt: skip
    for f, o in zip(FIELDS, out, strict=True):
        assert np.array_equal(getattr(want, f), o), f


def test_frame_rule_is_a_threshold_per_step():
    s = np.array([[0.0], [3.0], [5.0], [1.0], [3.0]])
    b = run_rule(FrameRule(3.0), s)
    assert b.active[:, 0].tolist() == [False, True, True, False, True]
    want = [("alarm-start", 1), ("alarm-end", 3), ("alarm-start", 4)]
    assert [(e.kind, e.step) for e in b.events()] == want
    assert np.array_equal(b.statistic, s)


def test_persistence_starts_at_k_of_n_and_ends_after_n_clean_steps():
    ex = [0, 1, 0, 1, 0, 0, 1, 0, 0, 0, 0]  # exceedances of h = 1
    s = np.array(ex, dtype=float)[:, None] * 2.0
    b = run_rule(PersistenceRule(1.0, k=2, n=3), s)
    # window counts over the last 3 steps: 0 1 1 2 1 1 1 1 1 0 0
    assert b.statistic[:, 0].tolist() == [0, 1, 1, 2, 1, 1, 1, 1, 1, 0, 0]
    assert b.active[:, 0].tolist() == [False] * 3 + [True] * 6 + [False] * 2
    assert [(e.kind, e.step) for e in b.events()] == [("alarm-start", 3), ("alarm-end", 9)]


def test_cusum_caps_g_while_active_and_ends_when_g_is_back_at_zero():
    s = np.array([0.0, 4.0, 4.0, 9.0, 0.0, 0.0, 0.0, 0.0, 3.0])[:, None]
    b = run_rule(CusumRule(5.0, drift=1.0), s)
    # g: 0, 3, 6 -> alarm, capped at 5; min(5, 5 + 8) = 5, 4, 3, 2, 1, min(5, 1 + 2) = 3
    assert b.statistic[:, 0].tolist() == [0.0, 3.0, 5.0, 5.0, 4.0, 3.0, 2.0, 1.0, 3.0]
    assert b.starts[:, 0].tolist() == [False, False, True] + [False] * 6
    assert not b.ends.any()
    b2 = run_rule(CusumRule(5.0, drift=1.0), np.r_[s[:, 0], [0.0] * 4][:, None])
    g = b2.statistic[:, 0]
    end = int(np.flatnonzero(b2.ends[:, 0])[0])
    assert g[end] == 0.0 and np.all(g[2:end] > 0) and not b2.active[end, 0]


def test_cusum_renews_after_an_alarm():
    """After an alarm ends, g is 0: the same scores raise the same alarm again (renewal)."""
    burst = [0.0, 8.0, 8.0] + [0.0] * 12
    s = np.array(burst * 3)[:, None]
    b = run_rule(CusumRule(10.0, drift=2.0), s)
    starts = np.flatnonzero(b.starts[:, 0])
    assert starts.tolist() == [2, 17, 32]


def test_event_order_and_indices():
    s = np.zeros((2, 5, 2))
    s[1, 2, 0] = s[0, 2, 1] = s[1, 3, 1] = 10.0
    ev = run_rule(FrameRule(1.0), s).events()
    assert [(e.kind, e.index, e.step, e.channel) for e in ev] == [
        ("alarm-start", (0,), 2, 1),
        ("alarm-start", (1,), 2, 0),
        ("alarm-end", (0,), 3, 1),
        ("alarm-end", (1,), 3, 0),
        ("alarm-start", (1,), 3, 1),
        ("alarm-end", (1,), 4, 1),
    ]


def test_count_starts_and_leading_axes():
    s = _scores(3, (2, 3, 500, 2))
    c = count_starts(CusumRule(5.0), s)
    assert c.shape == (2, 3, 2)
    assert np.array_equal(c[1, 2], run_rule(CusumRule(5.0), s[1, 2]).starts.sum(axis=0))


def test_rules_table_builds_every_rule():
    assert rule_names() == ("frame", "persistence", "cusum")
    for name, spec in RULES.items():
        r = make_rule(name, 4.0)
        assert r.name == name and isinstance(r, spec.cls) and r.threshold == 4.0
        assert r.parameters() == dict(spec.parameters)
        assert rule_from_dict(r.to_dict()) == r
        assert set(spec.style) >= {"color", "marker", "linestyle"}
    assert rule_from_dict(make_rule("cusum").to_dict()).threshold == np.inf  # inf is written as None
    assert make_rule("persistence", 1.0, k=3, n=5) == PersistenceRule(1.0, 3, 5)


def test_bad_rules_and_scores():
    with pytest.raises(ParameterError, match=r"unknown alarm rule 'page'.*frame, persistence, cusum"):
        make_rule("page")
    with pytest.raises(ParameterError, match="persistence k must be <= n"):
        PersistenceRule(1.0, k=4, n=3)
    with pytest.raises(ParameterError, match="persistence n"):
        make_rule("persistence", n=0)
    with pytest.raises(ParameterError, match="no parameter"):
        make_rule("frame", drift=1.0)
    with pytest.raises(ParameterError, match="NaN"):
        CusumRule(float("nan"))
    with pytest.raises(ParameterError, match="drift must be finite"):
        CusumRule(1.0, drift=float("inf"))
    st = AlarmStream(FrameRule(1.0), (2,))
    with pytest.raises(ShapeError, match="scores must have shape"):
        st.update(np.zeros((4, 3)))
    with pytest.raises(NonFiniteError, match="NaN or -inf"):
        st.update(np.array([[0.0, np.nan]]))
    assert st.update(np.array([[np.inf, 0.0]])).active.tolist() == [[True, False]]
    with pytest.raises(ShapeError):
        AlarmStream(FrameRule(1.0), ())
