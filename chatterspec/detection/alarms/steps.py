"""The alarm rules' state machines: per rule a compiled loop and its numpy form (:class:`RuleSteps`).

A rule's :class:`~chatterspec.detection.alarms.rules.RuleSpec` names its :class:`RuleSteps`
(``RuleSpec.steps``); :class:`~chatterspec.detection.alarms.streams.AlarmStream` and
:func:`~chatterspec.detection.alarms.calibration.starts_on_grid` call them and never branch on a rule's
name. Every rule keeps its state in the same arrays, so one stream object serves all of them:

``act`` (R, C) bool
    Alarm state after the last step.
``g`` (R, C) float
    An accumulated statistic (CUSUM ``g``); unused by the other stock rules.
``count`` (R, C) int
    A count (persistence: exceedances in the window); unused by the others.
``ring`` (R, C, W) bool
    The last ``W`` steps' exceedances, slot ``step % W`` (``W`` is the parameter named by
    :attr:`RuleSteps.ring`, 0 when None).

The compiled loop (``kernel``) and the numpy form (``numpy``) compute the same operations in the
same order (``+``, ``-``, ``min``, ``max`` and comparisons), hence the same bits; both are written with
:func:`_alarm_step` / its numpy equivalent: an inactive alarm starts when ``on``, an active one ends
when ``off``.

Signatures (``p``: the rule's ``parameters()`` values in order, as a float array)
    ``kernel(s, h, p, act, g, count, ring, pos, active, stat, starts, ends)``: scores ``s`` (R, K, C),
    state updated in place, ``pos`` (1,) the global step number of ``s[:, 0]``, outputs (R, K, C).
    ``numpy(s, h, p, step0, act, g, count, ring, out, n_starts) -> (act, g, count)``: the state may
    carry extra leading axes (one per threshold of a calibration grid, ``h`` of shape ``(..., 1, 1)``);
    ``out`` = ``(active, stat, starts, ends)`` (R, K, C) or None; ``n_starts`` (state shape, int)
    accumulates the starts when given; ``ring`` is updated in place, the other state is returned.
    ``channel(s, h, p, act, g, count, ring, step0, active, stat, starts, ends, r, c)`` (optional): the
    kernel's work on stream ``r``, channel ``c``, a step (:func:`chatterspec._jit.step`) that compiled
    loops inline; a stock rule's kernel is its channel step over every stream and channel
    (:func:`_rule_loop`), and the online monitor's block-of-frames loop inlines it too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ... import _jit

__all__ = [
    "CUSUM",
    "FRAME",
    "PERSISTENCE",
    "RuleSteps",
    "score_range",
]


_Out = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def score_range(s3: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Thresholds worth calibrating for a rule on the score itself: from the median to the largest score.

    Parameters
    ----------
    s3 : (R, K, C) array
        Healthy scores.
    p : array
        The rule's parameters (unused: the range is the score's).
    """
    return float(np.quantile(s3, 0.5)), float(np.max(s3))


@dataclass(frozen=True)
class RuleSteps:
    """One rule's state machine (see the module docstring for the signatures).

    Attributes
    ----------
    kernel : callable
        The compiled loop (:func:`chatterspec._jit.njit`); its Python form is
        :func:`chatterspec._jit.python_form` of it.
    numpy : callable
        The numpy form: a loop over steps vectorized over streams, channels and thresholds.
    statistic : {"g", "count"} or None
        The state array :attr:`AlarmStream.statistic` reports (None: NaN, the rule keeps none).
    ring : str or None
        The parameter giving the length of the exceedance ring (persistence ``n``), or None.
    statistic_range : callable
        ``(s3, p) -> (lo, hi)``: the thresholds from frequent alarms to none on healthy scores ``s3``
        (R, K, C), the range a calibration grid spans (default :func:`score_range`).
    grid_starts : callable or None
        ``(s3, thresholds) -> (G, R, C)`` starts at each threshold without the state machine (a rule
        with no recursion: the frame rule), used on both paths; None: run the steps per threshold.
    channel : callable or None
        The compiled step (:func:`chatterspec._jit.step`) of one stream and channel over the K steps,
        ``channel(s, h, p, act, g, count, ring, step0, active, stat, starts, ends, r, c)``: what
        ``kernel`` does at ``[r, :, c]`` (``step0 = pos[0]``). The online monitor inlines it into its
        block-of-frames loop, so a push is one compiled call
        (:func:`chatterspec.online._push_kernels.hop_kernel`); None (a rule that gives only ``kernel``):
        the monitor calls the frame analysis and then ``kernel`` per push instead, slower but the same
        numbers. The stock rules build ``kernel`` from it (:func:`_rule_kernel`).
    """

    kernel: Callable[..., None]
    numpy: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]]
    statistic: str | None = None
    ring: str | None = None
    statistic_range: Callable[[np.ndarray, np.ndarray], tuple[float, float]] = score_range
    grid_starts: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    channel: Callable[..., None] | None = None


def _transitions(
    was: np.ndarray, start: np.ndarray, end: np.ndarray, value: np.ndarray, j: int, out: _Out | None,
    n_starts: np.ndarray | None,
) -> np.ndarray:  # fmt: skip
    """Numpy form of :func:`_alarm_step` for step ``j``: the new state; writes the outputs."""
    act = (was | start) & ~end
    if out is not None:
        out[0][:, j, :], out[1][:, j, :], out[2][:, j, :], out[3][:, j, :] = act, value, start, end
    if n_starts is not None:
        n_starts += start
    return act


@_jit.step
def _alarm_step(
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    r: int,
    j: int,
    c: int,
    a: bool,
    on: bool,
    off: bool,
    value: float,
) -> bool:  # pragma: no cover - compiled (inlined into the rules' kernels)
    """One step of every rule's alarm at ``[r, j, c]``: an inactive alarm starts when ``on``, an
    active one ends when ``off`` (``start``/``end`` of the numpy forms); writes the outputs and
    returns the new state."""
    if a:
        st, en, a = False, off, not off
    else:
        st, en, a = on, False, on
    active[r, j, c] = a
    stat[r, j, c] = value
    starts[r, j, c] = st
    ends[r, j, c] = en
    return a


# --------------------------------------------------------------------------- the loop over streams
def _rule_loop(
    s: np.ndarray,
    h: float,
    p: np.ndarray,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    pos: np.ndarray,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
) -> None:  # pragma: no cover - compiled (a template: see _rule_kernel)
    """A rule's ``kernel``: its channel step ``CHANNEL`` (bound by :func:`_rule_kernel`) on each stream."""
    R, C = s.shape[0], s.shape[2]
    step0 = pos[0]
    for r in range(R):
        for c in range(C):
            CHANNEL(s, h, p, act, g, count, ring, step0, active, stat, starts, ends, r, c)


def _rule_kernel(channel: Callable[..., None], tag: str) -> Callable[..., None]:
    """The compiled ``kernel`` of a rule whose channel step is ``channel`` (:func:`_rule_loop`)."""
    return _jit.specialize(_rule_loop, tag, CHANNEL=channel)


# --------------------------------------------------------------------------- frame
@_jit.step
def _frame_channel(
    s: np.ndarray,
    h: float,
    p: np.ndarray,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    step0: int,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    r: int,
    c: int,
) -> None:  # pragma: no cover - compiled (inlined into the rule's kernel and the monitor's hop loop)
    """Frame rule, stream ``r``, channel ``c``: active while the score is over the threshold."""
    a = act[r, c]
    for j in range(s.shape[1]):
        x = s[r, j, c]
        on = x >= h
        a = _alarm_step(active, stat, starts, ends, r, j, c, a, on, not on, x)
    act[r, c] = a


#: The channel step :func:`_rule_loop` calls (each rule's kernel binds its own; default: the frame rule's).
CHANNEL = _frame_channel


def _frame_numpy(
    s: np.ndarray,
    h: float | np.ndarray,
    p: np.ndarray,
    step0: int,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    out: _Out | None,
    n_starts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The frame rule, vectorized over steps too (no recursion): ``active = s >= h``."""
    if out is None:  # a grid of thresholds: step by step
        act = act.copy()
        for j in range(s.shape[1]):
            on = s[:, j, :] >= h
            act = _transitions(act, ~act & on, act & ~on, s[:, j, :], j, None, n_starts)
        return act, g, count
    active, stat, starts, ends = out
    np.greater_equal(s, h, out=active)
    stat[...] = s
    prev = np.concatenate([act[:, None, :], active[:, :-1, :]], axis=1)
    np.logical_and(active, ~prev, out=starts)
    np.logical_and(~active, prev, out=ends)
    if n_starts is not None:
        n_starts += starts.sum(axis=1)
    return active[:, -1, :].copy(), g, count


def _frame_grid_starts(s3: np.ndarray, thresholds: np.ndarray) -> np.ndarray:
    """Frame-rule starts at each threshold: runs of steps over it, counted directly."""
    out = np.zeros((thresholds.size, s3.shape[0], s3.shape[2]), dtype=np.int64)
    for i, h in enumerate(thresholds):
        ex = s3 >= h
        out[i] = ex[:, 0, :] + np.count_nonzero(ex[:, 1:, :] & ~ex[:, :-1, :], axis=1)
    return out


# --------------------------------------------------------------------------- persistence
@_jit.step
def _persistence_channel(
    s: np.ndarray,
    h: float,
    p: np.ndarray,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    step0: int,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    r: int,
    c: int,
) -> None:  # pragma: no cover - compiled (inlined into the rule's kernel and the monitor's hop loop)
    """Persistence rule (``p = (k, n)``), stream ``r``, channel ``c``: count of the last n steps over
    the threshold."""
    k = p[0]
    n = ring.shape[2]
    a = act[r, c]
    cnt = count[r, c]
    for j in range(s.shape[1]):
        q = (step0 + j) % n
        ex = s[r, j, c] >= h
        cnt = cnt - ring[r, c, q] + ex
        ring[r, c, q] = ex
        a = _alarm_step(active, stat, starts, ends, r, j, c, a, cnt >= k, cnt <= 0, cnt)
    count[r, c] = cnt
    act[r, c] = a


def _persistence_numpy(
    s: np.ndarray,
    h: float | np.ndarray,
    p: np.ndarray,
    step0: int,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    out: _Out | None,
    n_starts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Numpy form of :func:`_persistence_channel` (over every stream and channel at once)."""
    k, n = p[0], ring.shape[-1]
    act = act.copy()
    for j in range(s.shape[1]):
        q = (step0 + j) % n
        ex = s[:, j, :] >= h
        count = count - ring[..., q] + ex
        ring[..., q] = ex
        act = _transitions(act, ~act & (count >= k), act & (count <= 0), count, j, out, n_starts)
    return act, g, count


# --------------------------------------------------------------------------- CUSUM
@_jit.step
def _cusum_channel(
    s: np.ndarray,
    h: float,
    p: np.ndarray,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    step0: int,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
    r: int,
    c: int,
) -> None:  # pragma: no cover - compiled (inlined into the rule's kernel and the monitor's hop loop)
    """CUSUM (``p = (drift,)``), stream ``r``, channel ``c``: held at h from the start and while active."""
    drift = p[0]
    a = act[r, c]
    x = g[r, c]
    for j in range(s.shape[1]):
        x = max((x + s[r, j, c]) - drift, 0.0)
        on = x >= h
        x = min(x, h)  # x < h stays x: only a start or an active alarm is held at h
        a = _alarm_step(active, stat, starts, ends, r, j, c, a, on, x <= 0.0, x)
    g[r, c] = x
    act[r, c] = a


def _cusum_numpy(
    s: np.ndarray,
    h: float | np.ndarray,
    p: np.ndarray,
    step0: int,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    out: _Out | None,
    n_starts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Numpy form of :func:`_cusum_channel`: ``(g + s) - drift``, ``max(., 0)`` and, at the start and
    while active, ``min(., h)``."""
    drift = p[0]
    act = act.copy()
    for j in range(s.shape[1]):
        x = np.maximum((g + s[:, j, :]) - drift, 0.0)
        start = ~act & (x >= h)
        x = np.where(act | start, np.minimum(x, h), x)
        g = x
        act = _transitions(act, start, act & (x <= 0.0), x, j, out, n_starts)
    return act, g, count


def _cusum_range(s3: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """From 0 to the largest excursion of ``g = max(0, g + s - drift)`` without alarms (from 0)."""
    # g_t = S_t - min_{j <= t} S_j with S the partial sums of (s - drift) and S_0 = 0: vectorized in time
    x = np.cumsum(s3 - float(p[0]), axis=1)
    run_min = np.minimum.accumulate(np.minimum(x, 0.0), axis=1)
    return 0.0, float(np.max(x - run_min))


#: The stock rules' steps (named by their :class:`~chatterspec.detection.alarms.rules.RuleSpec`).
FRAME = RuleSteps(
    _rule_kernel(_frame_channel, "frame"),
    _frame_numpy,
    grid_starts=_frame_grid_starts,
    channel=_frame_channel,
)
PERSISTENCE = RuleSteps(
    _rule_kernel(_persistence_channel, "persistence"), _persistence_numpy, statistic="count", ring="n",
    channel=_persistence_channel,
)  # fmt: skip
CUSUM = RuleSteps(
    _rule_kernel(_cusum_channel, "cusum"), _cusum_numpy, statistic="g", statistic_range=_cusum_range,
    channel=_cusum_channel,
)  # fmt: skip
