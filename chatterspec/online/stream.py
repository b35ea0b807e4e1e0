"""Live CSV sources for ``chatterspec monitor``: standard input and a growing file.

Pure Python + numpy (no Rerun). Two pieces (a simulated stream, the source of ``chatterspec
simulate``, is :mod:`chatterspec.online.simulated_stream`):

* **Byte sources** yield ``(bytes, arrival)`` as data arrives: :func:`read_fd`
  (a pipe or standard input: one ``os.read`` returns whatever is available, so
  rows are handled as they come, without waiting for end of input) and
  :func:`follow_file` (``tail -f``: polls a file another process appends to,
  from the start or from the end, and reports truncation or replacement as a
  restart). ``arrival`` is the ``time.perf_counter()`` at which the bytes were
  read: the start of the latency the monitor reports.
* :class:`CsvRows` turns those bytes into rows: header first (columns matched
  by name to the model's outputs and inputs, optional ``time`` / ``t`` column,
  extra columns ignored, ``#`` comments and blank lines skipped), every row
  tagged with its line number in the input. A block of well-formed rows is
  parsed in one numpy call; a block with a problem is re-read line by line to
  name the first bad line. A row that does not parse, has the wrong number of
  fields, or holds NaN/inf in a needed column is a *bad row*; a second header
  line is a *restart* (a producer that started over).

The stream's checks (used by :class:`~chatterspec.viewer.live_stream.StreamMonitor`):
:class:`LatencyStats` keeps the median and max latency in bounded memory; :func:`rate_mismatch`
compares the first rows' time steps with the model's ``dt`` (the monitor holds the first
:data:`RATE_CHECK_ROWS` rows for it, so a stream sampled at another rate is an error naming both
rates, not a gap at every row); :class:`RateGate` holds those rows; :func:`time_gaps` finds the
steps outside ``(GAP_LOW dt, GAP_HIGH dt]``.
"""

from __future__ import annotations

import math
import os
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from ..errors import DataFileError
from ..plants.datafile import TIME_COLUMNS
from ..plants.nonlinear import Model

__all__ = [
    "GAP_HIGH",
    "GAP_LOW",
    "RATE_CHECK_ROWS",
    "RATE_CHECK_ROWS_MIN",
    "RATE_TOLERANCE",
    "BadRow",
    "CsvRows",
    "LatencyStats",
    "RateGate",
    "Restart",
    "RowBlock",
    "follow_file",
    "merge_blocks",
    "rate_mismatch",
    "read_fd",
    "time_gaps",
]

#: Bytes asked for per read (a pipe hands over at most what it holds, 64 KiB on Linux).
READ_BYTES = 1 << 16
#: Marker a byte source yields when the followed file was truncated or replaced.
RESTART = b"\0restart\0"


# --------------------------------------------------------------------------- byte sources
def read_fd(fd: int, *, read_bytes: int = READ_BYTES) -> Iterator[tuple[bytes, float]]:
    """Yield ``(data, arrival)`` from a file descriptor as data arrives, until end of input.

    Parameters
    ----------
    fd : int
        Open descriptor (``0`` for standard input, a pipe, a file).
    read_bytes : int
        Most bytes per read; a read returns as soon as any data is available.

    Yields
    ------
    (bytes, float)
        The data and ``time.perf_counter()`` when it was read (s).
    """
    while True:
        data = os.read(fd, read_bytes)
        if not data:
            return
        yield data, time.perf_counter()


def follow_file(
    path: str | Path,
    *,
    from_end: bool = False,
    poll_s: float = 0.05,
    idle_timeout_s: float | None = None,
    read_bytes: int = READ_BYTES,
) -> Iterator[tuple[bytes, float]]:
    """Yield ``(data, arrival)`` from a file another process is appending to (like ``tail -f``).

    Parameters
    ----------
    path : str or Path
        The CSV file; it must exist when following starts.
    from_end : bool
        Start at the end of the file instead of its beginning: the header line is
        read first, then everything already written after it is skipped (up to
        the last complete line).
    poll_s : float
        Seconds between two looks at the file when no new data is there.
    idle_timeout_s : float, optional
        Stop after this many seconds without new data (default: follow until
        interrupted).
    read_bytes : int
        Most bytes per read.

    Yields
    ------
    (bytes, float)
        Data and ``time.perf_counter()`` when it was read (s); the marker
        :data:`RESTART` (with its time) when the file was truncated or replaced
        by a new one (reading restarts at its beginning).

    Raises
    ------
    DataFileError
        If the file does not exist or cannot be read.
    """
    path = Path(path)
    where = f"data file {str(path)!r}"
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise DataFileError(f"{where}: cannot be followed ({exc.strerror or exc})") from None
    try:
        head: list[bytes] = []
        if from_end:  # positions fixed now (not when the consumer resumes us)
            size = os.fstat(fh.fileno()).st_size
            buf = fh.read(min(size, 1 << 20))
            offset, found = 0, False
            while not found:  # comment lines and the header
                nl = buf.find(b"\n", offset)
                if nl < 0:
                    break
                line = buf[offset : nl + 1]
                head.append(line)
                offset = nl + 1
                found = bool(line.strip()) and not line.lstrip().startswith(b"#")
            start = 0
            if found:
                back = min(size - offset, read_bytes)
                fh.seek(size - back)
                cut = fh.read(back).rfind(b"\n")
                start = size - back + cut + 1 if cut >= 0 else offset
            else:
                head = []
            fh.seek(start if found else 0)
        for line in head:
            yield line, time.perf_counter()
        last_data = time.perf_counter()
        inode = os.fstat(fh.fileno()).st_ino
        while True:
            data = fh.read(read_bytes)
            if data:
                last_data = time.perf_counter()
                yield data, last_data
                continue
            try:
                st = os.stat(path)
            except FileNotFoundError:
                st = None
            if st is not None and (st.st_ino != inode or st.st_size < fh.tell()):
                fh.close()
                fh = path.open("rb")
                inode = os.fstat(fh.fileno()).st_ino
                last_data = time.perf_counter()
                yield RESTART, last_data
                continue
            if idle_timeout_s is not None and time.perf_counter() - last_data > idle_timeout_s:
                return
            time.sleep(poll_s)
    finally:
        fh.close()


# --------------------------------------------------------------------------- rows
@dataclass(frozen=True, eq=False)
class RowBlock:
    """Consecutive well-formed rows.

    Attributes
    ----------
    t : (K,) array or None
        The time column (s), None when the input has none.
    z : (K, m) array
        Measurements in the model's output order.
    u : (K, p) array
        Inputs in the model's input order.
    lines : (K,) int array
        Line number of each row in the input (1 = first line).
    arrival : float
        ``time.perf_counter()`` when the last of these bytes was read (s).
    """

    t: np.ndarray | None
    z: np.ndarray
    u: np.ndarray
    lines: np.ndarray
    arrival: float

    @property
    def n_rows(self) -> int:
        """Number of rows."""
        return self.z.shape[0]


@dataclass(frozen=True)
class BadRow:
    """A row that does not parse, has the wrong number of fields, or holds NaN/inf.

    Attributes
    ----------
    line : int
        Line number in the input.
    message : str
        What is wrong (names the line and the column).
    """

    line: int
    message: str


@dataclass(frozen=True)
class Restart:
    """The input started over: a second header line, or the followed file was truncated / replaced.

    Attributes
    ----------
    line : int
        Line number (of the input as read so far) where it was seen.
    reason : str
        Human-readable cause.
    """

    line: int
    reason: str


class CsvRows:
    """Incremental CSV parser: bytes in, :class:`RowBlock` / :class:`BadRow` / :class:`Restart` out.

    Parameters
    ----------
    model : LinearModel
        Gives the needed columns (``output_names``, ``input_names``).
    where : str
        Name of the input used in messages (e.g. ``"standard input"``).
    """

    def __init__(self, model: Model, where: str = "standard input") -> None:
        self.model = model
        self.where = where
        self.needed = (*model.output_names, *model.input_names)
        self.m, self.p = model.n_outputs, model.n_inputs
        self.header: list[str] | None = None
        self.time_column: str | None = None
        self._cols: np.ndarray | None = None  # column index of [time?, outputs, inputs]
        self._ncol = 0
        self._partial = b""
        self.line_no = 0  # lines completed so far
        self.has_time = False

    # ------------------------------------------------------------------ input
    def feed(self, data: bytes, arrival: float) -> list[RowBlock | BadRow | Restart]:
        """Parse the complete lines in ``data`` (plus what was held back); keep a trailing partial line.

        Parameters
        ----------
        data : bytes
            Bytes read (:data:`RESTART` resets the parser: a header is expected next).
        arrival : float
            When they were read (``time.perf_counter()``, s).

        Returns
        -------
        list
            In input order.
        """
        if data is RESTART or data == RESTART:
            self._partial = b""
            had, line = self.header is not None, self.line_no
            self.header = None
            self.line_no = 0  # line numbers of the new file
            return [Restart(line, "the followed file was truncated or replaced")] if had else []
        buf = self._partial + data
        cut = buf.rfind(b"\n")
        if cut < 0:
            self._partial = buf
            return []
        self._partial = buf[cut + 1 :]
        return self._lines(buf[:cut].split(b"\n"), arrival)

    def finish(self, arrival: float) -> list[RowBlock | BadRow | Restart]:
        """End of input: parse a last line that had no newline.

        Parameters
        ----------
        arrival : float
            Time of the end of input (``time.perf_counter()``, s).
        """
        rest, self._partial = self._partial, b""
        if not rest.strip():
            return []
        return self._lines([rest], arrival)

    # --------------------------------------------------------------- internals
    def _lines(self, raw: list[bytes], arrival: float) -> list[RowBlock | BadRow | Restart]:
        out: list[RowBlock | BadRow | Restart] = []
        first = self.line_no + 1
        self.line_no += len(raw)
        try:
            text = [r.decode() for r in raw]
        except UnicodeDecodeError:
            text = [r.decode(errors="replace") for r in raw]
        lo = 0
        while lo < len(text) and self.header is None:  # header (after comments / blank lines)
            s = text[lo].strip()
            if s and not s.startswith("#"):
                self._set_header(s, first + lo)
            lo += 1
        if lo >= len(text):
            return out
        body = text[lo:]
        block = self._fast(body)
        if block is not None:
            t, z, u = block
            out.append(RowBlock(t, z, u, np.arange(first + lo, first + len(text)), arrival))
            return out
        return self._slow(body, first + lo, arrival)

    def _set_header(self, line: str, line_no: int) -> None:
        header = [h.strip() for h in line.split(",")]
        where = f"{self.where}, line {line_no}"
        if len(set(header)) != len(header):
            raise DataFileError(f"{where}: duplicate column names in the header {header}")
        missing = [c for c in self.needed if c not in header]
        if missing:
            raise DataFileError(
                f"{where}: the header lacks column(s) {missing}; the model needs outputs "
                f"{list(self.model.output_names)} and inputs {list(self.model.input_names)}; "
                f"the header is {header} (the first line that is not a # comment must be the header)"
            )
        self.time_column = next((c for c in TIME_COLUMNS if c in header), None)
        names = ([self.time_column] if self.time_column else []) + list(self.needed)
        self._cols = np.array([header.index(c) for c in names])
        self.has_time = self.time_column is not None
        self.header = header
        self._ncol = len(header)

    def _split(self, vals: np.ndarray) -> tuple[np.ndarray | None, np.ndarray, np.ndarray]:
        k = 1 if self.has_time else 0
        t = vals[:, 0].copy() if self.has_time else None
        return t, vals[:, k : k + self.m], vals[:, k + self.m :]

    def _fast(self, body: list[str]) -> tuple[np.ndarray | None, np.ndarray, np.ndarray] | None:
        """All lines well formed: one numpy parse (None sends the block to the line-by-line path)."""
        n, commas = len(body), self._ncol - 1
        if any(line.count(",") != commas for line in body):
            return None
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # numpy warns (instead of raising) on unparsable text
            try:
                flat = np.fromstring(",".join(body), sep=",")
            except (ValueError, DeprecationWarning):
                return None
        if flat.size != n * self._ncol:
            return None
        vals = flat.reshape(n, self._ncol)[:, self._cols]
        if not np.isfinite(vals).all():
            return None
        return self._split(vals)

    def _slow(self, body: list[str], first: int, arrival: float) -> list[RowBlock | BadRow | Restart]:
        out: list[RowBlock | BadRow | Restart] = []
        rows: list[np.ndarray] = []
        nums: list[int] = []
        cols = cast(np.ndarray, self._cols)  # (set with the header, before any data row)
        names = [self.header[j] for j in cols] if self.header else []

        def flush() -> None:
            if rows:
                t, z, u = self._split(np.array(rows))
                out.append(RowBlock(t, z, u, np.array(nums), arrival))
                rows.clear()
                nums.clear()

        for i, line in enumerate(body):
            no = first + i
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            fields = [f.strip() for f in s.split(",")]
            if self.header is None or (fields == self.header) or self._looks_like_header(fields):
                flush()
                restart = self.header is not None
                self._set_header(s, no)
                if restart:
                    out.append(Restart(no, f"a new header at line {no} (the producer started over)"))
                continue
            where = f"{self.where}, line {no}"
            if len(fields) != self._ncol:
                flush()
                out.append(
                    BadRow(no, f"{where}: {len(fields)} field(s); the header has {self._ncol} columns")
                )
                continue
            vals = np.empty(len(cols))
            bad = None
            for k, j in enumerate(cols):
                try:
                    vals[k] = float(fields[j]) if fields[j] else np.nan
                except ValueError:
                    bad = f"{where}: column {names[k]!r}: {fields[j]!r} is not a number"
                    break
                if not np.isfinite(vals[k]):
                    bad = (
                        f"{where}: column {names[k]!r} is {fields[j] or 'empty'!r} (NaN/inf): the "
                        "monitor needs finite samples"
                    )
                    break
            if bad is not None:
                flush()
                out.append(BadRow(no, bad))
                continue
            rows.append(vals)
            nums.append(no)
        flush()
        return out

    def _looks_like_header(self, fields: list[str]) -> bool:
        return all(c in fields for c in self.needed) and not _is_number(fields[0])


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


# --------------------------------------------------------------------------- checks
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
