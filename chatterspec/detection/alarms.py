"""Alarm rules: score streams in, alarm start / end events out (sequential change detection).

A *score stream* is an array ``(..., steps, channels)``: the leading axes are independent
streams (Monte Carlo realizations), a step is a frame or a sample, and a larger score means
more anomalous (for the chattering: ``-log p`` of the frame's p-value,
:mod:`chatterspec.detection.frame_score`). A *rule* turns each channel's stream into an
alarm state (active or not) per step; an alarm **start** is a step where the state turns
active, an **end** one where it turns inactive. False-alarm budgets count starts
(:mod:`chatterspec.detection.alarm_calibration`).

Rules (the table :data:`RULES`, which the CLI ``choices`` and the plot styles read)
    ``frame`` (:class:`FrameRule`)
        Active at the steps with ``s >= h`` (today's per-frame verdict when ``s`` is the frame
        score and ``h = -log(alpha)``). Ends at the first step with ``s < h``.
    ``persistence`` (:class:`PersistenceRule`)
        Starts when at least ``k`` of the last ``n`` steps had ``s >= h``; ends after ``n``
        clean steps in a row (no exceedance in the window), so that a run of exceedances with
        short gaps is one alarm, not several.
    ``cusum`` (:class:`CusumRule`, Page 1954)
        ``g = max(0, g + s - drift)``; starts when ``g >= h``. From the start on, while the alarm
        is active, ``g`` is capped at ``h`` (``g = min(h, max(0, g + s - drift))``) and the alarm ends
        when ``g`` returns to 0. The cap bounds how long the alarm outlives the anomaly
        (at least ``h / drift`` steps, since ``s >= 0`` for a p-value score), and ending
        at 0, not at ``h``, is the hysteresis that keeps an alarm from flapping when the
        score hovers near the threshold.

Renewal
    Every rule is back in its initial state when an alarm ends (``frame``: trivially;
    ``persistence``: the window is clean; ``cusum``: ``g = 0``), so the healthy times between
    alarm starts are independent and identically distributed if the scores are: the number of
    starts in a long healthy stretch is close to Poisson with rate ``1 / ARL0`` (the average run
    length to a false alarm), the quantity a budget in false alarms per hour sets.

Streaming
    :class:`AlarmStream` keeps the state between calls, so feeding a stream in any chunking
    gives the same alarms as feeding it whole (``tests/test_alarms.py``). The per-step
    recursion runs in one compiled loop (:func:`_alarm_kernel`, through
    :func:`chatterspec._jit.njit`) when :func:`chatterspec._jit.enabled`, otherwise a numpy
    loop over steps vectorized over every stream and channel; both compute the same
    operations in the same order (``+``, ``-``, ``min``, ``max`` and comparisons), hence the
    same bits. Nothing loops over streams in Python.

Public interface (stable; additions only)
    :class:`FrameRule`, :class:`PersistenceRule`, :class:`CusumRule` (frozen; ``.name``,
    ``.threshold``, ``.with_threshold(h)``, ``.parameters()``, ``.to_dict()``, ``.describe()``),
    :data:`RULES` (name -> :class:`RuleSpec`), :func:`rule_names`, :func:`make_rule`,
    :func:`rule_from_dict`, :class:`AlarmStream` (``.update(scores) -> AlarmBlock``),
    :class:`AlarmBlock` (``active``, ``statistic``, ``starts``, ``ends``, ``first_step``,
    ``.events()``), :class:`AlarmEvent`, :func:`run_rule` (one call on whole streams) and
    :func:`count_starts`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from .. import _jit
from ..errors import NonFiniteError, ParameterError, ShapeError
from .alarm_rules import (
    _CUSUM,
    _FRAME,
    _PERSISTENCE,
    RULES,
    AlarmRule,
    CusumRule,
    FrameRule,
    PersistenceRule,
    RuleSpec,
    make_rule,
    rule_from_dict,
    rule_names,
)

__all__ = [
    "RULES",
    "AlarmBlock",
    "AlarmEvent",
    "AlarmRule",
    "AlarmStream",
    "CusumRule",
    "FrameRule",
    "PersistenceRule",
    "RuleSpec",
    "count_starts",
    "make_rule",
    "rule_from_dict",
    "rule_names",
    "run_rule",
]


# --------------------------------------------------------------------------- events
@dataclass(frozen=True)
class AlarmEvent:
    """An alarm start or end.

    Attributes
    ----------
    kind : {"alarm-start", "alarm-end"}
    index : tuple of int
        Index of the stream in the leading axes (``()`` for a single stream).
    step : int
        Global step number (counted from the stream's first step).
    channel : int
    """

    kind: Literal["alarm-start", "alarm-end"]
    index: tuple[int, ...]
    step: int
    channel: int


@dataclass(frozen=True, eq=False)
class AlarmBlock:
    """What one :meth:`AlarmStream.update` produced (arrays ``(..., steps, channels)``).

    Attributes
    ----------
    first_step : int
        Global step number of the block's first step.
    active : bool array
        Alarm state after each step.
    statistic : float array
        The rule's statistic after each step: the score (``frame``), the exceedances in the
        last ``n`` steps (``persistence``), ``g`` (``cusum``).
    starts, ends : bool arrays
        Steps where an alarm starts (state turns active) / ends (turns inactive).
    """

    first_step: int
    active: np.ndarray
    statistic: np.ndarray
    starts: np.ndarray
    ends: np.ndarray

    @property
    def n_steps(self) -> int:
        """Number of steps."""
        return self.active.shape[-2]

    def events(self) -> list[AlarmEvent]:
        """Every start and end, ordered by step, then stream index, channel, and end before start."""
        out: list[tuple[int, tuple[int, ...], int, int]] = []
        for kind_order, arr in ((0, self.ends), (1, self.starts)):
            for idx in zip(*np.nonzero(arr), strict=True):
                *lead, step, ch = (int(i) for i in idx)
                out.append((step, tuple(lead), ch, kind_order))
        out.sort()
        return [
            AlarmEvent("alarm-start" if o else "alarm-end", lead, self.first_step + s, c)
            for s, lead, c, o in out
        ]


# --------------------------------------------------------------------------- streaming
class AlarmStream:
    """A rule's state over ``(..., channels)`` streams, advanced chunk by chunk.

    Parameters
    ----------
    rule : FrameRule, PersistenceRule or CusumRule
        The rule (its threshold must be set, i.e. not NaN; ``inf`` never alarms).
    shape : tuple of int
        ``(..., channels)``: the leading (streams) axes and the number of channels of the
        scores that :meth:`update` will get.
    compiled : bool, optional
        Use the compiled loop (default: :func:`chatterspec._jit.enabled` at each update; the
        online monitor fixes it at construction, as for its other kernels).

    Examples
    --------
    >>> import numpy as np
    >>> from chatterspec.detection.alarms import AlarmStream, CusumRule
    >>> s = AlarmStream(CusumRule(threshold=5.0, drift=1.0), shape=(1,))
    >>> blk = s.update(np.array([[0.0], [4.0], [4.0], [0.0], [0.0], [0.0], [0.0]]))
    >>> blk.active[:, 0].tolist()
    [False, False, True, True, True, True, True]
    >>> [(e.kind, e.step) for e in blk.events()]
    [('alarm-start', 2)]
    """

    def __init__(self, rule: AlarmRule, shape: tuple[int, ...], *, compiled: bool | None = None) -> None:
        if not isinstance(rule, FrameRule | PersistenceRule | CusumRule):
            raise ParameterError(f"rule must be one of the alarm rules; got {type(rule).__name__}")
        shape = tuple(int(s) for s in shape)
        if len(shape) < 1 or any(s < 0 for s in shape) or shape[-1] < 1:
            raise ShapeError(f"shape must be (..., channels) with channels >= 1; got {shape}")
        self.rule = rule
        self.shape = shape
        R = int(np.prod(shape[:-1], dtype=np.int64))
        C = shape[-1]
        self._R, self._C = R, C
        self._code = {"frame": _FRAME, "persistence": _PERSISTENCE, "cusum": _CUSUM}[rule.name]
        self._h = float(rule.threshold)
        self._drift = float(getattr(rule, "drift", 0.0))
        self._k = int(getattr(rule, "k", 1))
        self._n = int(getattr(rule, "n", 1))
        self._compiled = None if compiled is None else bool(compiled and _jit.HAVE_NUMBA)
        self.reset()

    def reset(self) -> None:
        """Back to the initial state (no alarm, ``g = 0``, clean window, step 0)."""
        R, C = self._R, self._C
        self._active = np.zeros((R, C), dtype=np.bool_)
        self._g = np.zeros((R, C))
        self._count = np.zeros((R, C), dtype=np.int64)
        self._ring = np.zeros((R, C, self._n if self._code == _PERSISTENCE else 0), dtype=np.bool_)
        self._step = 0
        self._pos = np.zeros(1, dtype=np.int64)  # the kernel's step number, one array for every call

    @property
    def steps(self) -> int:
        """Steps processed so far."""
        return self._step

    @property
    def active(self) -> np.ndarray:
        """Current alarm state ``(..., channels)`` (copy)."""
        return self._active.reshape(self.shape).copy()

    @property
    def statistic(self) -> np.ndarray:
        """Current statistic ``(..., channels)``: ``g`` (cusum), window count (persistence), NaN (frame)."""
        if self._code == _CUSUM:
            return self._g.reshape(self.shape).copy()
        if self._code == _PERSISTENCE:
            return self._count.reshape(self.shape).astype(float)
        return np.full(self.shape, np.nan)

    def update(self, scores: np.ndarray) -> AlarmBlock:
        """Advance by ``scores`` ``(..., K, channels)`` (leading axes as ``shape``; K >= 0).

        Raises
        ------
        ShapeError
            Scores whose leading axes or channels differ from ``shape``.
        NonFiniteError
            NaN or ``-inf`` scores (``+inf`` is allowed: a p-value of 0).
        """
        s = np.asarray(scores, dtype=float)
        lead, C = self.shape[:-1], self.shape[-1]
        if s.ndim != len(self.shape) + 1 or s.shape[:-2] != lead or s.shape[-1] != C:
            raise ShapeError(f"scores must have shape (*{lead}, steps, {C}) for this stream; got {s.shape}")
        if np.isnan(s).any() or np.isneginf(s).any():
            raise NonFiniteError("scores contain NaN or -inf; every score must be a real number or +inf")
        return self._advance(s)

    def _advance(self, s: np.ndarray) -> AlarmBlock:
        """:meth:`update` without the checks (the caller passes a float array of the right shape)."""
        K = s.shape[-2]
        R, C = self._R, self._C
        s3 = s.reshape(R, K, C)
        active = np.empty((R, K, C), dtype=np.bool_)
        stat = np.empty((R, K, C))
        starts = np.empty((R, K, C), dtype=np.bool_)
        ends = np.empty((R, K, C), dtype=np.bool_)
        first = self._step
        if K:
            compiled = _jit.enabled() if self._compiled is None else self._compiled
            if self._code == _FRAME and not compiled:
                _frame_numpy(s3, self._h, self._active, active, stat, starts, ends)
            elif compiled:
                pos = self._pos
                pos[0] = self._step
                _alarm_kernel(
                    self._code, s3, self._h, self._drift, self._k, self._n,
                    self._active, self._g, self._count, self._ring, pos,
                    active, stat, starts, ends,
                )  # fmt: skip
            else:
                _alarm_numpy(self, s3, active, stat, starts, ends)
            self._step += K
        shape = (*self.shape[:-1], K, C)
        return AlarmBlock(
            first, active.reshape(shape), stat.reshape(shape), starts.reshape(shape), ends.reshape(shape)
        )


def _frame_numpy(
    s: np.ndarray,
    h: float,
    state: np.ndarray,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
) -> None:
    """The frame rule, vectorized over steps too (no recursion): ``active = s >= h``."""
    np.greater_equal(s, h, out=active)
    stat[...] = s
    prev = np.concatenate([state[:, None, :], active[:, :-1, :]], axis=1)
    np.logical_and(active, ~prev, out=starts)
    np.logical_and(~active, prev, out=ends)
    state[...] = active[:, -1, :]


def _alarm_numpy(
    st: AlarmStream,
    s: np.ndarray,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
) -> None:
    """Persistence / CUSUM of one stream object: :func:`_steps_numpy` on its state."""
    st._active[...], st._g[...], st._count[...] = _steps_numpy(
        st._code, s, st._h, st._drift, st._k, st._n, st._step,
        st._active, st._g, st._count, st._ring, (active, stat, starts, ends),
    )  # fmt: skip


def _steps_numpy(
    code: int,
    s: np.ndarray,
    h: float | np.ndarray,
    drift: float,
    k: int,
    n: int,
    step0: int,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None,
    n_starts: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Persistence / CUSUM: a loop over steps, vectorized over streams and channels.

    ``s`` (R, K, C); the state ``act``, ``g``, ``count`` has shape ``(..., R, C)`` (extra
    leading axes, e.g. one per threshold of a calibration grid, with ``h`` of shape
    ``(..., 1, 1)``) and ``ring`` ``(..., R, C, n)`` (updated in place). ``out`` = ``(active,
    stat, starts, ends)`` (R, K, C) or None; ``n_starts`` (state shape, int) accumulates the
    starts when given. Returns the new ``(act, g, count)``. The same operations as
    :func:`_alarm_kernel` (the CUSUM's ``(g + s) - drift``, then ``max(., 0)`` and, at
    the start and while active, ``min(., h)``), hence the same bits.
    """
    K = s.shape[1]
    act = act.copy()
    for j in range(K):
        sj = s[:, j, :]
        was = act
        if code == _CUSUM:
            x = np.maximum((g + sj) - drift, 0.0)
            start = ~was & (x >= h)
            x = np.where(was | start, np.minimum(x, h), x)
            end = was & (x <= 0.0)
            g = x
            value = x
        else:  # persistence
            p = (step0 + j) % n
            ex = sj >= h
            count = count - ring[..., p] + ex
            ring[..., p] = ex
            start = ~was & (count >= k)
            end = was & (count <= 0)
            value = count
        act = (was | start) & ~end
        if out is not None:
            out[0][:, j, :], out[1][:, j, :], out[2][:, j, :], out[3][:, j, :] = act, value, start, end
        if n_starts is not None:
            n_starts += start
    return act, g, count


@_jit.njit
def _alarm_kernel(
    code: int,
    s: np.ndarray,
    h: float,
    drift: float,
    k: int,
    n: int,
    act: np.ndarray,
    g: np.ndarray,
    count: np.ndarray,
    ring: np.ndarray,
    pos: np.ndarray,
    active: np.ndarray,
    stat: np.ndarray,
    starts: np.ndarray,
    ends: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_alarms.py)
    """Frame (``code`` 0), persistence (1) or CUSUM (2) rule over scores ``s`` (R, K, C).

    State (updated in place): ``act`` (R, C) bool, ``g`` (R, C), ``count`` (R, C) int,
    ``ring`` (R, C, n) bool (persistence: exceedance of the last n steps, slot ``step % n``),
    ``pos`` (1,) = global step number of ``s[:, 0]``. Outputs (R, K, C): ``active``,
    ``stat`` (g or the window count), ``starts``, ``ends``. The operations and their order
    are those of :func:`_alarm_numpy`.
    """
    R, C = s.shape[0], s.shape[2]
    step0 = pos[0]
    for r in range(R):
        for c in range(C):
            alarm_channel_step(
                code, s, h, drift, k, n, act, g, count, ring, step0, active, stat, starts, ends, r, c
            )


@_jit.step
def alarm_channel_step(
    code: int,
    s: np.ndarray,
    h: float,
    drift: float,
    k: int,
    n: int,
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
) -> None:  # pragma: no cover - compiled (inlined into _alarm_kernel and the monitor's hop loop)
    """Stream ``r``, channel ``c`` of :func:`_alarm_kernel` over its K steps (its arguments)."""
    K = s.shape[1]
    a = act[r, c]
    if code == 0:  # frame: active while the score is over the threshold
        for j in range(K):
            x = s[r, j, c]
            on = x >= h
            a = _alarm_step(active, stat, starts, ends, r, j, c, a, on, not on, x)
    elif code == 2:  # CUSUM, held at h from the start and while active
        x = g[r, c]
        for j in range(K):
            x = max((x + s[r, j, c]) - drift, 0.0)
            on = x >= h
            x = min(x, h)  # x < h stays x: only a start or an active alarm is held at h
            a = _alarm_step(active, stat, starts, ends, r, j, c, a, on, x <= 0.0, x)
        g[r, c] = x
    else:  # persistence: count of the last n steps over the threshold
        cnt = count[r, c]
        for j in range(K):
            p = (step0 + j) % n
            ex = s[r, j, c] >= h
            cnt = cnt - ring[r, c, p] + ex
            ring[r, c, p] = ex
            a = _alarm_step(active, stat, starts, ends, r, j, c, a, cnt >= k, cnt <= 0, cnt)
        count[r, c] = cnt
    act[r, c] = a


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
) -> bool:  # pragma: no cover - compiled (inlined into _alarm_kernel)
    """One step of every rule's alarm at ``[r, j, c]``: an inactive alarm starts when ``on``, an
    active one ends when ``off`` (``start``/``end`` of :func:`_alarm_numpy`); writes the outputs and
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


# --------------------------------------------------------------------------- one-shot helpers
def run_rule(rule: AlarmRule, scores: np.ndarray) -> AlarmBlock:
    """Apply ``rule`` to whole score streams ``(..., steps, channels)`` from the initial state.

    Equal to feeding the same scores to a fresh :class:`AlarmStream` in any chunking.

    Parameters
    ----------
    rule : FrameRule, PersistenceRule or CusumRule
    scores : (..., steps, channels) array
        At least 2-D (one stream: ``(steps, channels)``).
    """
    s = np.asarray(scores, dtype=float)
    if s.ndim < 2:
        raise ShapeError(f"scores must be (..., steps, channels); got shape {s.shape}")
    return AlarmStream(rule, (*s.shape[:-2], s.shape[-1])).update(s)


def count_starts(rule: AlarmRule, scores: np.ndarray) -> np.ndarray:
    """Alarm starts per stream and channel ``(..., channels)`` of :func:`run_rule`.

    Parameters
    ----------
    rule : FrameRule, PersistenceRule or CusumRule
    scores : (..., steps, channels) array
    """
    return run_rule(rule, scores).starts.sum(axis=-2)
