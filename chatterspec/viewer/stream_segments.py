"""Gap and restart segmenting of a live stream's rows (:class:`StreamSegments`).

What :class:`~chatterspec.viewer.live_stream.StreamMonitor` delegates between the parser and the
monitor: the rows of :class:`~chatterspec.online.stream.CsvRows` go through the sampling-rate check
(:class:`~chatterspec.online.stream.RateGate`), get their times (the time column, or ``dt``
apart from the last one without it) and are cut into :class:`Segment` objects at every gap (a time
step outside ``(0.5 dt, 1.5 dt]``, :func:`~chatterspec.online.stream.time_gaps`, or a skipped
bad row) and after a restart. Each segment that starts a fresh monitor says so, and why when it is a
gap. Pure bookkeeping: no monitor, no events, no Rerun.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ..online.stream import RateGate, RowBlock, time_gaps

__all__ = ["Segment", "StreamSegments"]


@dataclass(frozen=True)
class Segment:
    """Consecutive rows for one monitor.

    Attributes
    ----------
    z, u : ndarray, shapes (K, m) and (K, p)
        Measurements and inputs.
    t : ndarray, shape (K,)
        Sample times (s).
    arrival : float
        ``time.perf_counter()`` when the bytes holding the rows were read.
    fresh : bool
        A new monitor starts at the first row (the first rows, a gap or a restart before them).
    gap : (str, int) or None
        The reasons (``"; "``-joined) and input line of a gap before the first row.
    """

    z: np.ndarray
    u: np.ndarray
    t: np.ndarray
    arrival: float
    fresh: bool
    gap: tuple[str, int] | None = None


class StreamSegments:
    """Cuts the parsed rows of a live stream into :class:`Segment` objects at gaps and restarts.

    Parameters
    ----------
    dt : float
        The model's sampling interval (s).

    Attributes
    ----------
    last_t : float or None
        Time (s) of the last row segmented since the last restart (None: none yet).
    t_next : float
        Time (s) the next row gets without a time column (one ``dt`` after the last).
    started : bool
        A segment has been handed out (a monitor is running).
    """

    def __init__(self, dt: float) -> None:
        self.dt = dt
        self.last_t: float | None = None
        self.t_next = 0.0  # synthesized time (no time column)
        self.started = False
        self._pending: list[str] = []  # reasons of a gap to emit at the next sample
        self._pending_line: int | None = None
        self._reset_next = False
        self._gate = RateGate(dt)  # the first rows, held until the sampling-rate check

    def rows(self, b: RowBlock) -> Iterator[Segment]:
        """The segments of a block of parsed rows (after the rate check releases them)."""
        for block in self._gate.feed(b):
            yield from self._split(block)

    def release(self) -> Iterator[Segment]:
        """The rows held for the rate check, unchecked: something else came first (a bad row, a restart,
        the end of the input)."""
        for block in self._gate.release():
            yield from self._split(block)

    def end(self) -> Iterator[Segment]:
        """The source ended: the held rows are checked (if >= 3) and segmented.

        Raises
        ------
        DataFileError
            The held rows show a sampling interval other than ``dt``.
        """
        for block in self._gate.end():
            yield from self._split(block)

    def bad_row(self, line: int) -> None:
        """A bad row at input ``line`` was skipped: a gap before the next sample (a sample is missing)."""
        self._pending.append(f"bad row at line {line} skipped")
        self._pending_line = self._pending_line or line
        if self.started:
            self.t_next += self.dt

    def restart(self) -> None:
        """The input restarted (a second header, a truncated or replaced file): the next segment starts a
        fresh monitor, its time base is not compared with the old one and its sampling is checked again."""
        self._reset_next = True
        self._pending, self._pending_line = [], None
        self.last_t = None
        self._gate.recheck()

    def _split(self, b: RowBlock) -> Iterator[Segment]:
        """Split one released block at its gaps (and at a pending gap / restart before its first row)."""
        K = b.n_rows
        if K == 0:
            return
        dt = self.dt
        t = b.t if b.t is not None else self.t_next + dt * np.arange(K)
        self.t_next = float(t[-1]) + dt
        # split points: gaps by time step, a pending gap / restart at the first row
        starts = time_gaps(t, self.last_t, dt) if b.t is not None else {}
        if self._pending and self.started:
            starts.setdefault(0, [])[:0] = self._pending
        elif not self.started:
            self._pending_line = None  # nothing to reset yet
        self._pending = []
        for lo, hi in itertools.pairwise(sorted({0, *starts, K})):
            reasons = starts.get(lo)
            gap = None
            if reasons and self.started:
                line = int(b.lines[lo]) if self._pending_line is None else self._pending_line
                gap, self._pending_line = ("; ".join(reasons), line), None
            fresh = gap is not None or not self.started or self._reset_next
            if fresh:
                self.started, self._reset_next = True, False
            yield Segment(b.z[lo:hi], b.u[lo:hi], t[lo:hi], b.arrival, fresh, gap)
        self.last_t = float(t[-1])
