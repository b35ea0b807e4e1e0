"""Alarm rules: score streams in, alarm start / end events out (sequential change detection).

A *score stream* is an array ``(..., steps, channels)``: the leading axes are independent
streams (Monte Carlo realizations), a step is a frame or a sample, and a larger score means
more anomalous (for the chattering: ``-log p`` of the frame's p-value,
:mod:`chatterspec.detection.verdicts`). A *rule* turns each channel's stream into an
alarm state (active or not) per step; an alarm **start** is a step where the state turns
active, an **end** one where it turns inactive. False-alarm budgets count starts
(:mod:`chatterspec.detection.alarms.calibration`).

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
    recursion is the rule's own (:class:`~chatterspec.detection.alarms.steps.RuleSteps`, named by
    its :class:`RuleSpec`): one compiled loop (through :func:`chatterspec._jit.njit`) when
    :func:`chatterspec._jit.enabled`, otherwise a numpy loop over steps vectorized over every
    stream and channel; both compute the same operations in the same order (``+``, ``-``,
    ``min``, ``max`` and comparisons), hence the same bits. Nothing loops over streams in
    Python, and nothing here branches on a rule's name: a registered rule
    (:func:`~chatterspec.detection.alarms.rules.register_rule`) runs as the stock ones do.

Public interface (stable; additions only)
    In :mod:`chatterspec.detection.alarms.rules`: :class:`FrameRule`, :class:`PersistenceRule`,
    :class:`CusumRule` (frozen; ``.name``, ``.threshold``, ``.with_threshold(h)``,
    ``.parameters()``, ``.to_dict()``, ``.describe()``), :data:`RULES` (name -> :class:`RuleSpec`),
    :func:`rule_names`, :func:`make_rule`, :func:`rule_from_dict`. Here: :class:`AlarmStream`
    (``.update(scores) -> AlarmBlock``),
    :class:`AlarmBlock` (``active``, ``statistic``, ``starts``, ``ends``, ``first_step``,
    ``.events()``), :class:`AlarmEvent`, :func:`run_rule` (one call on whole streams) and
    :func:`count_starts`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from ... import _jit
from ...errors import NonFiniteError, ParameterError, ShapeError
from .rules import (
    AlarmRule,
    is_rule,
    rule_spec,
)
from .steps import RuleSteps

__all__ = [
    "AlarmBlock",
    "AlarmEvent",
    "AlarmStream",
    "count_starts",
    "ring_length",
    "rule_vector",
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
    rule : AlarmRule
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
    >>> from chatterspec.detection.alarms.streams import AlarmStream, CusumRule
    >>> s = AlarmStream(CusumRule(threshold=5.0, drift=1.0), shape=(1,))
    >>> blk = s.update(np.array([[0.0], [4.0], [4.0], [0.0], [0.0], [0.0], [0.0]]))
    >>> blk.active[:, 0].tolist()
    [False, False, True, True, True, True, True]
    >>> [(e.kind, e.step) for e in blk.events()]
    [('alarm-start', 2)]
    """

    def __init__(self, rule: AlarmRule, shape: tuple[int, ...], *, compiled: bool | None = None) -> None:
        if not is_rule(rule):
            raise ParameterError(f"rule must be one of the alarm rules; got {type(rule).__name__}")
        shape = tuple(int(s) for s in shape)
        if len(shape) < 1 or any(s < 0 for s in shape) or shape[-1] < 1:
            raise ShapeError(f"shape must be (..., channels) with channels >= 1; got {shape}")
        self.rule = rule
        self.shape = shape
        R = int(np.prod(shape[:-1], dtype=np.int64))
        C = shape[-1]
        self._R, self._C = R, C
        self._steps = rule_spec(rule).load_steps()
        self._h = float(rule.threshold)
        self._p = rule_vector(rule)
        self._W = ring_length(rule, self._steps)
        self._compiled = None if compiled is None else bool(compiled and _jit.HAVE_NUMBA)
        self.reset()

    def reset(self) -> None:
        """Back to the initial state (no alarm, ``g = 0``, clean window, step 0)."""
        R, C = self._R, self._C
        self._active = np.zeros((R, C), dtype=np.bool_)
        self._g = np.zeros((R, C))
        self._count = np.zeros((R, C), dtype=np.int64)
        self._ring = np.zeros((R, C, self._W), dtype=np.bool_)
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
        kept = {"g": self._g, "count": self._count}.get(self._steps.statistic or "")
        return np.full(self.shape, np.nan) if kept is None else kept.reshape(self.shape).astype(float)

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
            state = (self._active, self._g, self._count, self._ring)
            if compiled:
                pos = self._pos
                pos[0] = self._step
                self._steps.kernel(s3, self._h, self._p, *state, pos, active, stat, starts, ends)
            else:
                self._active[...], self._g[...], self._count[...] = self._steps.numpy(
                    s3, self._h, self._p, self._step, *state, (active, stat, starts, ends)
                )
            self._step += K
        shape = (*self.shape[:-1], K, C)
        return AlarmBlock(
            first, active.reshape(shape), stat.reshape(shape), starts.reshape(shape), ends.reshape(shape)
        )


def rule_vector(rule: AlarmRule) -> np.ndarray:
    """The rule's parameters (``rule.parameters()`` values, in order): the float array ``p`` of its steps."""
    return np.array([float(v) for v in rule.parameters().values()], dtype=float)


def ring_length(rule: AlarmRule, steps: RuleSteps) -> int:
    """Length of the rule's exceedance ring (the parameter :attr:`RuleSteps.ring` names; 0 if none).

    Parameters
    ----------
    rule : AlarmRule
    steps : RuleSteps
        The rule's steps (its spec's).
    """
    return 0 if steps.ring is None else int(rule.parameters()[steps.ring])


# --------------------------------------------------------------------------- one-shot helpers
def run_rule(rule: AlarmRule, scores: np.ndarray) -> AlarmBlock:
    """Apply ``rule`` to whole score streams ``(..., steps, channels)`` from the initial state.

    Equal to feeding the same scores to a fresh :class:`AlarmStream` in any chunking.

    Parameters
    ----------
    rule : AlarmRule
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
    rule : AlarmRule
    scores : (..., steps, channels) array
    """
    return run_rule(rule, scores).starts.sum(axis=-2)
