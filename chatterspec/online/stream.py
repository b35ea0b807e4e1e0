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
"""

from __future__ import annotations

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
    "BadRow",
    "CsvRows",
    "Restart",
    "RowBlock",
    "follow_file",
    "read_fd",
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
