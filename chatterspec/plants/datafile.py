"""Measurement data files (CSV / NPZ) for ``chatterspec monitor`` and ``chatterspec detect --data``.

Columns are matched **by name** to the model's outputs and inputs; an optional time column
(``time`` or ``t``, seconds) must be strictly increasing with spacing equal to the model's ``dt``
(within 1 %). Without a time column the samples are taken to be ``dt`` apart starting at 0. The
NaN policy (a NaN or infinite sample stops the run) is explained in :mod:`chatterspec.plants.modelfile`.
"""

from __future__ import annotations

import csv
import io
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

import numpy as np

from ..errors import DataFileError, ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from .modelfile import ModelSpec
    from .nonlinear import Model

__all__ = ["TIME_COLUMNS", "DataSet", "load_data", "load_data_text"]

#: Accepted names of the time column (seconds), in order of preference.
TIME_COLUMNS: tuple[str, ...] = ("time", "t")


@dataclass(frozen=True, eq=False)
class DataSet:
    """Measurements and inputs read from a data file, aligned to a model.

    Attributes
    ----------
    t : (T,) array
        Sample times (s).
    z : (T, m) array
        Measurements in the model's output order.
    u : (T, p) array
        Inputs in the model's input order.
    path : Path
    time_column : str or None
        Name of the time column used, ``None`` if times were generated from dt.
    """

    t: np.ndarray
    z: np.ndarray
    u: np.ndarray
    path: Path
    time_column: str | None

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return self.t.shape[0]


# --------------------------------------------------------------------------- data files
def _the_model(model: Model | ModelSpec) -> Model:
    """``model``, or the model of a :class:`~chatterspec.plants.modelfile.ModelSpec`."""
    from .modelfile import ModelSpec

    if isinstance(model, ModelSpec):
        return model.model
    if not all(hasattr(model, a) for a in ("output_names", "input_names", "dt")):
        raise ParameterError(
            f"load_data needs the model the data belong to: a LinearModel or NonlinearModel, or what "
            f"load_model(MODEL.toml) returns; got {type(model).__name__}"
        )
    return model


def load_data(path: str | Path, model: Model | ModelSpec, *, dt_tolerance: float = 0.01) -> DataSet:
    """Read measurements and inputs for ``model`` from a CSV or NPZ file (columns matched by name).

    Parameters
    ----------
    path : str or Path
        ``.csv`` (header row, comma separated) or ``.npz`` (one 1-D array per name).
    model : LinearModel, NonlinearModel or ModelSpec
        Gives the column names (``output_names``, ``input_names``) and ``dt``; the ``ModelSpec``
        that :func:`~chatterspec.plants.modelfile.load_model` returns stands for its ``model``.
    dt_tolerance : float
        Allowed relative deviation of every time step from ``model.dt``.

    Raises
    ------
    DataFileError
        Missing file or column, unparsable value, NaN/inf sample (see the NaN
        policy in the module docstring), non-monotonic or irregular timestamps,
        or fewer than two samples. The message names the file and the column.
    ParameterError
        ``model`` is not a model (nor a model file's ``ModelSpec``).
    """
    model = _the_model(model)
    path = Path(path)
    where = f"data file {str(path)!r}"
    if not path.exists():
        raise DataFileError(f"{where}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        columns = _read_npz(path, where)
    elif suffix in (".csv", ".txt"):
        columns = _read_csv(path, where)
    else:
        raise DataFileError(f"{where}: unknown format {suffix!r}; use .csv or .npz")
    return _dataset(columns, model, path, where, dt_tolerance)


def load_data_text(
    text: str, model: Model | ModelSpec, *, name: str = "-", dt_tolerance: float = 0.01
) -> DataSet:
    """:func:`load_data` on CSV text, e.g. standard input read to its end (the same checks and messages).

    Parameters
    ----------
    text : str
        The CSV content: a header row, then one row per sample.
    model : LinearModel, NonlinearModel or ModelSpec
        Gives the column names (``output_names``, ``input_names``) and ``dt`` (as in :func:`load_data`).
    name : str
        What the messages call the data (``"-"``: standard input); also ``DataSet.path``.
    dt_tolerance : float
        Allowed relative deviation of every time step from ``model.dt``.

    Raises
    ------
    DataFileError
        As :func:`load_data`.
    """
    model = _the_model(model)
    where = "data on standard input" if name == "-" else f"data {name!r}"
    columns = _parse_csv(io.StringIO(text, newline=""), where)
    return _dataset(columns, model, Path(name), where, dt_tolerance)


def _dataset(
    columns: dict[str, np.ndarray], model: Model, path: Path, where: str, dt_tolerance: float
) -> DataSet:
    """The columns of a data file checked against ``model`` (names, lengths, times, finiteness)."""
    lines = columns.pop(_LINES, None)
    needed = [*model.output_names, *model.input_names]
    missing = [c for c in needed if c not in columns]
    if missing:
        raise DataFileError(
            f"{where}: missing column(s) {missing}; the model needs outputs {list(model.output_names)} and "
            f"inputs {list(model.input_names)}; the file has {sorted(columns)}"
        )
    lengths = {c: columns[c].shape[0] for c in needed}
    T = max(lengths.values())
    short = {c: n for c, n in lengths.items() if n != T}
    if short:
        raise DataFileError(f"{where}: columns have different lengths: {lengths}")
    if T < 2:
        raise DataFileError(f"{where}: needs at least 2 samples; got {T}")
    time_column = next((c for c in TIME_COLUMNS if c in columns), None)
    if time_column is not None:
        t = columns[time_column]
        if t.shape[0] != T:
            raise DataFileError(f"{where}: column {time_column!r} has {t.shape[0]} rows; the data has {T}")
        _check_finite(t, time_column, None, where, lines)
        _check_times(t, time_column, model.dt, dt_tolerance, where, lines)
    else:
        t = np.arange(T) * model.dt
    for c in needed:
        _check_finite(columns[c], c, t, where, lines)
    z = np.column_stack([columns[c] for c in model.output_names])
    u = np.column_stack([columns[c] for c in model.input_names])
    return DataSet(t=t, z=z, u=u, path=path, time_column=time_column)


def _read_csv(path: Path, where: str) -> dict[str, np.ndarray]:
    try:
        with path.open(newline="") as fh:
            return _parse_csv(fh, where)
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFileError(f"{where}: cannot be read ({exc})") from None


def _parse_csv(fh: TextIO, where: str) -> dict[str, np.ndarray]:
    """The columns of CSV text read from the open text stream ``fh`` (header first, ``#`` comment lines)."""
    text = fh.read()
    fast = _plain_csv(text)
    return fast if fast is not None else _parse_rows(io.StringIO(text, newline=""), where)


def _plain_csv(text: str) -> dict[str, np.ndarray] | None:
    """The columns of a plain CSV (a header, then rows of numbers: no quotes, comments, blank lines or CR)
    parsed by :func:`numpy.loadtxt` (a third of the CPU of the row-by-row reader on a 10-minute 1 kHz
    file, the same correctly rounded values); None for anything else, which the row-by-row reader
    takes, with its messages."""
    if any(c in text for c in '"#\r') or "\n\n" in text:
        return None
    head, sep, body = text.partition("\n")
    header = [h.strip() for h in head.split(",")]
    if not sep or not body.strip() or len(set(header)) != len(header):
        return None
    try:
        data = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2, dtype=float)
    except ValueError:
        return None
    if data.shape[1] != len(header):
        return None
    out = {h: data[:, j] for j, h in enumerate(header)}
    out[_LINES] = np.arange(2, data.shape[0] + 2, dtype=float)
    return out


def _parse_rows(fh: TextIO, where: str) -> dict[str, np.ndarray]:
    """:func:`_parse_csv` row by row (``csv`` module): comments, quotes and per-cell messages."""
    reader = csv.reader(fh)
    rows, lines = [], []
    for r in reader:
        if r and not r[0].lstrip().startswith("#"):
            rows.append(r)
            lines.append(reader.line_num)  # 1-based line of the file (comments counted)
    if not rows:
        raise DataFileError(f"{where}: empty file (a header row with column names is required)")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        raise DataFileError(f"{where}: duplicate column names in the header {header}")
    data = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            raise DataFileError(
                f"{where}: line {lines[i + 1]} has {len(row)} fields; the header has {len(header)} columns"
            )
        for j, cell in enumerate(row):
            s = cell.strip()
            try:
                data[i, j] = float(s) if s else np.nan
            except ValueError:
                raise DataFileError(
                    f"{where}: column {header[j]!r}, line {lines[i + 1]}: {s!r} is not a number"
                ) from None
    out = {h: data[:, j] for j, h in enumerate(header)}
    out[_LINES] = np.asarray(lines[1:], dtype=float)
    return out


#: Hidden column of :func:`_read_csv`: the file line of every data row (messages use file lines).
_LINES = "\x00lines"


def _where_row(i: int, lines: np.ndarray | None) -> str:
    """Position of data row ``i`` (0-based): the CSV file line, or the array index of an NPZ file."""
    return f"line {int(lines[i])}" if lines is not None else f"index {i}"


def _read_npz(path: Path, where: str) -> dict[str, np.ndarray]:
    with path.open("rb") as fh:
        if fh.read(4) != b"PK\x03\x04":  # .npz is a zip archive; never fall back to pickle
            raise DataFileError(
                f"{where}: not a .npz archive (a .npz file is a zip of .npy arrays, as numpy.savez writes)"
            )
    try:
        with np.load(path, allow_pickle=False) as npz:
            out = {}
            for k in npz.files:
                arr = np.asarray(npz[k])
                if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.number):
                    raise DataFileError(
                        f"{where}: array {k!r} must be 1-D numeric (one array per column); got "
                        f"shape {arr.shape}, dtype {arr.dtype}"
                    )
                out[k] = arr.astype(float)
            return out
    except DataFileError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        reason = "it holds Python objects, which are never loaded" if "pickle" in str(exc) else str(exc)
        raise DataFileError(f"{where}: not a readable .npz archive ({reason})") from None


def _check_finite(
    x: np.ndarray, column: str, t: np.ndarray | None, where: str, lines: np.ndarray | None = None
) -> None:
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        i = int(bad[0])
        at = "" if t is None else f" (t = {t[i]:.6g} s)"
        raise DataFileError(
            f"{where}: column {column!r} has {bad.size} NaN/inf sample(s), "
            f"first at {_where_row(i, lines)}{at}; "
            "the monitor needs uniformly sampled finite data (clean or interpolate the file first)"
        )


def _check_times(
    t: np.ndarray, column: str, dt: float, tol: float, where: str, lines: np.ndarray | None = None
) -> None:
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        i = int(bad[0])
        raise DataFileError(
            f"{where}: column {column!r} is not strictly increasing: {_where_row(i + 1, lines)} "
            f"(t = {t[i + 1]:.9g} s) follows t = {t[i]:.9g} s"
        )
    off = np.flatnonzero(np.abs(step - dt) > tol * dt)
    med = float(np.median(step)) if off.size else dt
    if off.size and np.all(np.abs(step - med) <= tol * med):  # uniformly sampled at another rate
        raise DataFileError(
            f"{where}: column {column!r}: the data is sampled every {1e3 * med:.6g} ms ({1 / med:.6g} Hz), "
            f"but the model's dt is {1e3 * dt:.6g} ms ({1 / dt:.6g} Hz); resample the data or set dt in "
            "the model file"
        )
    if off.size:
        i = int(off[0])
        raise DataFileError(
            f"{where}: column {column!r} is not sampled at the model's dt = {dt:g} s: step "
            f"{step[i]:.9g} s between {_where_row(i, lines)} and {_where_row(i + 1, lines)} "
            f"({off.size} irregular step(s)); "
            "resample the data or set dt in the model file"
        )
