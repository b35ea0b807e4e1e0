"""Bookkeeping of the live stream monitor: latency statistics and the sampling-rate check of a stream.

:class:`LatencyStats` keeps the median and max latency in bounded memory; :func:`rate_mismatch` compares
the first rows' time steps with the model's ``dt`` (:class:`~chatterspec.viewer.live_stream.StreamMonitor`
holds the first :data:`RATE_CHECK_ROWS` rows for it, so a stream sampled at another rate is an error
naming both rates, not a gap at every row).
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import DataFileError
from .stream import RowBlock

__all__ = [
    "GAP_HIGH",
    "GAP_LOW",
    "RATE_CHECK_ROWS",
    "RATE_CHECK_ROWS_MIN",
    "RATE_TOLERANCE",
    "LatencyStats",
    "RateGate",
    "merge_blocks",
    "rate_mismatch",
    "time_gaps",
]

#: The first rows of a stream (with a time column) are held until this many arrived and their time
#: steps are compared with the model's dt; at end of input, at least RATE_CHECK_ROWS_MIN are needed.
RATE_CHECK_ROWS, RATE_CHECK_ROWS_MIN = 5, 3
#: Relative tolerance of that comparison (the data file's: every step within 1 % of dt).
RATE_TOLERANCE = 0.01
#: A time step outside ``(GAP_LOW dt, GAP_HIGH dt]`` is a gap.
GAP_LOW, GAP_HIGH = 0.5, 1.5


class LatencyStats:
    """Median and max of latencies in bounded memory (log-spaced histogram, 0.5 % bins, 1 us .. 1000 s).

    The median is the centre of the histogram bin holding it (relative error
    below 0.3 %), clamped to the exact min and max (a bin centre can lie above
    every observation in it); the max is exact.
    """

    _LO, _HI, _BINS = 1e-6, 1e3, 4200

    def __init__(self) -> None:
        self.counts = np.zeros(self._BINS + 2, dtype=np.int64)
        self.max_s = 0.0
        self.min_s = math.inf
        self.n = 0
        self._scale = self._BINS / math.log(self._HI / self._LO)

    def add(self, seconds: float, count: int = 1) -> None:
        """Record ``count`` observations of ``seconds``.

        Parameters
        ----------
        seconds : float
            Latency (s).
        count : int
            How many frames had it.
        """
        if count <= 0:
            return
        s = max(float(seconds), 0.0)
        k = 0 if s < self._LO else min(int(math.log(s / self._LO) * self._scale) + 1, self._BINS + 1)
        self.counts[k] += count
        self.n += count
        self.max_s = max(self.max_s, s)
        self.min_s = min(self.min_s, s)

    def median(self) -> float | None:
        """Median latency (s), None without observations."""
        if self.n == 0:
            return None
        k = int(np.searchsorted(np.cumsum(self.counts), (self.n + 1) / 2.0))
        centre = self._LO / 2 if k == 0 else self._LO * math.exp((k - 0.5) / self._scale)
        return min(max(centre, self.min_s), self.max_s)

    def to_dict(self) -> dict[str, float | int | None]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        med = self.median()
        return {
            "frames": self.n,
            "median_ms": None if med is None else 1e3 * med,
            "max_ms": None if self.n == 0 else 1e3 * self.max_s,
        }


def rate_mismatch(b: RowBlock, dt: float) -> str | None:
    """Why the first rows of ``b`` are sampled at another rate than ``dt``, or None.

    The first ``RATE_CHECK_ROWS - 1`` time steps must agree with each other (within
    :data:`RATE_TOLERANCE` of their median) and differ from ``dt`` by more than that: a stream at another
    uniform rate. Mixed steps are left to the gap handling.

    Parameters
    ----------
    b : RowBlock
        The first rows of a stream (with a time column).
    dt : float
        The model's sampling time (s).
    """
    assert b.t is not None  # (a stream with a time column)
    steps = np.diff(b.t[:RATE_CHECK_ROWS])
    step = float(np.median(steps))
    consistent = step > 0 and np.all(np.abs(steps - step) <= RATE_TOLERANCE * step)
    if not (consistent and abs(step - dt) > RATE_TOLERANCE * dt):
        return None
    lines = b.lines[: steps.size + 1]
    return (
        f"lines {int(lines[0])}-{int(lines[-1])}: the stream is sampled every {1e3 * step:.6g} ms "
        f"({1 / step:.6g} Hz), but the model's dt is {1e3 * dt:.6g} ms ({1 / dt:.6g} Hz): every "
        "step would be a gap and nothing would be monitored; resample the data or set dt in the "
        "model file"
    )


def merge_blocks(blocks: list[RowBlock]) -> RowBlock:
    """Consecutive row blocks as one (the last arrival time)."""
    if len(blocks) == 1:
        return blocks[0]
    t = None if blocks[0].t is None else np.concatenate([b.t for b in blocks])
    return RowBlock(
        t,
        np.concatenate([b.z for b in blocks]),
        np.concatenate([b.u for b in blocks]),
        np.concatenate([b.lines for b in blocks]),
        blocks[-1].arrival,
    )


class RateGate:
    """Holds the first rows with a time column until :data:`RATE_CHECK_ROWS` arrived, checks their
    sampling interval against ``dt`` (:func:`rate_mismatch`), then lets every row through (a mismatch
    would otherwise make every step a gap: nothing monitored, exit 0). Rows without a time column pass
    at once; after a restart (:meth:`recheck`) the new data is checked again.

    Parameters
    ----------
    dt : float
        The model's sampling interval (s).
    """

    def __init__(self, dt: float) -> None:
        self.dt = float(dt)
        self._held: list[RowBlock] = []
        self._checked = False

    def feed(self, b: RowBlock) -> list[RowBlock]:
        """The blocks to monitor now, in input order (the held rows merged into one block first).

        Raises
        ------
        DataFileError
            The held rows show a sampling interval other than ``dt``.
        """
        if self._checked or b.t is None:
            return [*self.release(), b]
        self._held.append(b)
        if sum(h.n_rows for h in self._held) >= RATE_CHECK_ROWS:
            self._check(merge_blocks(self._held))
            return self.release()
        return []

    def release(self) -> list[RowBlock]:
        """The held rows (as one block, or none), unchecked: something else came first (a bad row, a
        restart, the end of the input)."""
        held, self._held = self._held, []
        if not held:
            return []
        self._checked = True
        return [merge_blocks(held)]

    def end(self) -> list[RowBlock]:
        """The input ended: the held rows, checked first if there are at least :data:`RATE_CHECK_ROWS_MIN`.

        Raises
        ------
        DataFileError
            As :meth:`feed`.
        """
        if sum(h.n_rows for h in self._held) >= RATE_CHECK_ROWS_MIN:
            self._check(merge_blocks(self._held))
        return self.release()

    def recheck(self) -> None:
        """A restart: the new data's sampling is checked again."""
        self._checked = False

    def _check(self, b: RowBlock) -> None:
        self._checked = True
        message = rate_mismatch(b, self.dt)
        if message is not None:
            self._held = []  # not monitored: the run stops here
            raise DataFileError(message)


def time_gaps(t: np.ndarray, last_t: float | None, dt: float) -> dict[int, list[str]]:
    """Rows of a block at which a gap starts, with the reason: a time step outside
    ``(GAP_LOW dt, GAP_HIGH dt]`` (a jump, a repeated or a backwards time).

    Parameters
    ----------
    t : (K,) float array
        The block's times (s).
    last_t : float or None
        The previous row's time (None: the first row of new data is not a gap).
    dt : float
        Sampling interval (s).

    Returns
    -------
    dict of int to list of str
        Row index -> reasons.
    """
    prev = np.r_[last_t if last_t is not None else t[0] - dt, t]
    step = np.diff(prev)
    bad = np.flatnonzero((step <= GAP_LOW * dt) | (step > GAP_HIGH * dt))
    if last_t is None:
        bad = bad[bad > 0]
    starts: dict[int, list[str]] = {}
    for i in bad.tolist():
        a, s = float(prev[i]), float(step[i])
        if s <= 0:
            why = f"time went from {a:.6g} s to {t[i]:.6g} s (not increasing)"
        elif s > GAP_HIGH * dt:
            why = f"time jumped from {a:.6g} s to {t[i]:.6g} s ({s / dt:.3g} dt > {GAP_HIGH:g} dt)"
        else:
            why = f"time step {s:.3g} s is below {GAP_LOW:g} dt"
        starts.setdefault(i, []).append(why)
    return starts
