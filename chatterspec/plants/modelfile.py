"""User model files (TOML) and measurement data files (CSV / NPZ) for ``chatterspec monitor``.

Model file (TOML, read with :mod:`tomllib`; see ``examples/README.md``)::

    name = "linear EHA"
    dt = 0.001                         # sampling time, s

    [channels]
    outputs = ["position", "velocity", "pressure"]   # measured channels (rows of C)
    units = ["m", "m/s", "Pa"]                       # optional, one per output
    inputs = ["pump_speed"]                          # columns of B
    states = ["position", "velocity", "pressure"]    # optional

    [matrices]
    form = "discrete"                  # or "continuous": A, B are then discretized with dt
    discretization = "euler"           # continuous only: "euler" (paper) or "zoh"
    A = [[...], ...]                   # (n, n)
    B = [[...], ...]                   # (n, p)
    C = [[...], ...]                   # (m, n)
    Q = [[...], ...]                   # (n, n) discrete process-noise covariance, or Q_diag = [...]
    R = [[...], ...]                   # (m, m) measurement-noise covariance, or R_diag = [...]

    [svsf]
    psi = [...]                        # smoothing boundary layer per output (> 0), output units
    gamma = 0.1                        # convergence rate, 0 < gamma < 1

    [detector]                         # optional; defaults shown
    alpha = 0.001
    correction = "bonferroni"
    window_s = 1.0
    hop_s = 0.2
    window = "hamming"
    band = [5.0, 100.0]                # optional (default: none): test only 5 <= f <= 100 Hz

Data file: CSV with a header row, or NPZ with one 1-D array per name. Columns are
matched **by name** to the model's outputs and inputs; an optional time column
(``time`` or ``t``, seconds) must be strictly increasing with spacing equal to
the model's ``dt`` (within 1 %). Without a time column the samples are taken to
be ``dt`` apart starting at 0.

NaN policy: a NaN or infinite sample **stops the run** with a
:class:`~chatterspec.errors.DataFileError` naming the file, the column, the row
and the time. Skipping a sample is not an option for this detector: the SVSF
prediction and the STFT both assume uniform sampling, and dropping or holding a
sample puts a step into the chattering that itself shows up as broadband power
(a false detection). Clean or interpolate the data first, deliberately.
"""

from __future__ import annotations

import csv
import math
import tomllib
import warnings
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import ChatterspecError, DataFileError, ModelFileError, UnstableModelWarning
from .models import LinearModel, discretize
from .parameters import model_file_parameter_map

__all__ = ["TIME_COLUMNS", "DataSet", "ModelSpec", "load_data", "load_model", "write_model_toml"]

#: Accepted names of the time column (seconds), in order of preference.
TIME_COLUMNS: tuple[str, ...] = ("time", "t")


@dataclass(frozen=True, eq=False)
class ModelSpec:
    """A model file's content.

    Attributes
    ----------
    model : LinearModel
        Nominal discrete model (names and units from ``[channels]``).
    psi : (m,) array
        Smoothing boundary layer of the SVSF per output.
    gamma : float
        SVSF convergence rate.
    detector : dict
        The optional ``[detector]`` table (keys ``alpha``, ``correction``,
        ``window_s``, ``hop_s``, ``window``, ``band``); the STFT fields are checked
        and ``band`` (Hz) is validated into a ``(lo, hi)`` tuple, the rest is unvalidated here.
    path : Path
        The file read.
    """

    model: LinearModel
    psi: np.ndarray
    gamma: float
    detector: Mapping[str, Any]
    path: Path


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
        return self.t.shape[0]


# --------------------------------------------------------------------------- model files
_DETECTOR_KEYS = {"alpha", "correction", "window_s", "hop_s", "window", "threshold", "band"}


def load_model(path: str | Path) -> ModelSpec:
    """Read a TOML model file (format in the module docstring).

    Parameters
    ----------
    path : str or Path
        The TOML file: top-level ``dt`` (sampling time, s), ``[channels]``,
        ``[matrices]`` (``A``, ``B``, ``C``, ``Q``, ``R``; discrete, or continuous
        and discretized with ``dt``), ``[svsf]`` (``psi`` > 0 per output in output
        units, ``gamma`` in (0, 1), default 0.1) and an optional ``[detector]`` table.

    Returns
    -------
    ModelSpec
        The validated nominal model, ``psi``, ``gamma``, the raw ``[detector]``
        table and ``path``.

    Raises
    ------
    ModelFileError
        If the file is missing, is not valid TOML, lacks a field, has a matrix of
        the wrong shape, holds NaN/inf, or describes an invalid model. The
        message names the file and the field.

    Warns
    -----
    UnstableModelWarning
        If the nominal ``A`` has eigenvalues outside the unit circle.
    """
    path = Path(path)
    where = f"model file {str(path)!r}"
    try:
        with path.open("rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise ModelFileError(f"{where}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ModelFileError(f"{where}: not valid TOML ({exc})") from None
    except OSError as exc:
        raise ModelFileError(f"{where}: cannot be read ({exc})") from None

    dt = _scalar(doc, "dt", where, positive=True)
    channels = _table(doc, "channels", where)
    outputs = _names(channels, "outputs", where, required=True)
    inputs = _names(channels, "inputs", where, required=True)
    units = _names(channels, "units", where, required=False)
    states = _names(channels, "states", where, required=False)
    mats = _table(doc, "matrices", where)
    form = str(mats.get("form", "discrete"))
    if form not in ("discrete", "continuous"):
        raise ModelFileError(f"{where}: [matrices] form must be 'discrete' or 'continuous'; got {form!r}")

    A = _matrix(mats, "A", where, "matrices")
    n = A.shape[0]
    if A.shape != (n, n):
        raise ModelFileError(f"{where}: [matrices] A must be square (n x n); got shape {A.shape}")
    m, p = len(outputs), len(inputs)
    B = _matrix(mats, "B", where, "matrices", vector_ok=True)
    if B.ndim == 1:
        B = B[:, None]
    C_raw = _matrix(mats, "C", where, "matrices", vector_ok=True)
    n_B, n_C = B.shape[0], C_raw.shape[-1]
    if n not in (n_B, n_C) and (n_B == n_C or (states and len(states) in (n_B, n_C))):
        # B's rows and C's columns agree on the state count: A is the odd one out
        n_other = n_B if n_B == n_C else len(states)
        raise ModelFileError(
            f"{where}: [matrices] A must have shape ({n_other}, {n_other}) (n = {n_other} states, as B's "
            f"rows and C's columns say); got {A.shape}"
        )
    _expect_shape(B, (n, p), "B", where, f"n = {n} states x p = {p} inputs")
    C = C_raw
    if C.ndim == 1:
        C = C[None, :]
    _expect_shape(C, (m, n), "C", where, f"m = {m} outputs x n = {n} states")
    Q = _covariance(mats, "Q", n, where)
    R = _covariance(mats, "R", m, where)
    if states and len(states) != n:
        raise ModelFileError(f"{where}: [channels] states has {len(states)} names; A has n = {n} states")
    if units and len(units) != m:
        raise ModelFileError(f"{where}: [channels] units has {len(units)} entries; there are {m} outputs")
    if len(set(outputs) | set(inputs)) != m + p:
        raise ModelFileError(f"{where}: [channels] output and input names must all be distinct")

    method = str(mats.get("discretization", "euler"))
    if form == "continuous":
        if method not in ("euler", "zoh"):
            raise ModelFileError(
                f"{where}: [matrices] discretization must be 'euler' or 'zoh'; got {method!r}"
            )
        A, B = discretize(A, B, dt, method)  # type: ignore[arg-type]
    pmap = model_file_parameter_map(doc, where, form, method)
    try:
        model = LinearModel(
            A=A,
            B=B,
            C=C,
            Q=Q,
            R=R,
            dt=dt,
            state_names=tuple(states),
            output_names=tuple(outputs),
            input_names=tuple(inputs),
            output_units=tuple(units),
            name=str(doc.get("name", path.stem)),
            parameter_map=pmap,
        )
        if pmap is not None:
            pmap.check(model)
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: invalid model: {exc}") from exc
    rho = model.spectral_radius
    if rho > 1.0 + 1e-3:
        warnings.warn(
            f"{where}: the nominal model is unstable (spectral radius of A = {rho:.6f} > 1); "
            "the SVSF still runs but its predictions diverge between corrections",
            UnstableModelWarning,
            stacklevel=2,
        )

    svsf = _table(doc, "svsf", where)
    psi_raw = svsf.get("psi")
    if psi_raw is None:
        raise ModelFileError(f"{where}: [svsf] psi (smoothing boundary layer, one per output) is missing")
    psi = _array(psi_raw, where, "[svsf] psi")
    if psi.ndim == 0:
        psi = np.full(m, float(psi))
    if psi.shape != (m,):
        raise ModelFileError(
            f"{where}: [svsf] psi must have one entry per output ({m}); got shape {psi.shape}"
        )
    if np.any(psi <= 0):
        raise ModelFileError(f"{where}: [svsf] psi must be > 0; got {psi.tolist()}")
    gamma = float(_scalar(svsf, "gamma", f"{where}: [svsf]", default=0.1))
    if not 0.0 < gamma < 1.0:
        raise ModelFileError(f"{where}: [svsf] gamma must lie in (0, 1); got {gamma}")
    detector = doc.get("detector", {})
    if not isinstance(detector, dict):
        raise ModelFileError(f"{where}: [detector] must be a table")
    unknown = set(detector) - _DETECTOR_KEYS
    if unknown:
        raise ModelFileError(
            f"{where}: [detector] has unknown key(s) {sorted(unknown)}; allowed: {sorted(_DETECTOR_KEYS)}"
        )
    _check_detector(detector, model.dt, where)
    detector = dict(detector)
    if "band" in detector:
        detector["band"] = _detector_band(detector["band"], where)
    return ModelSpec(model=model, psi=psi, gamma=gamma, detector=detector, path=path)


def _detector_band(value: object, where: str) -> tuple[float, float]:
    """``[detector] band = [lo, hi]`` (Hz) validated into a tuple; errors name the file and field."""
    from ..detection.thresholds import check_band

    if isinstance(value, (str, bytes)):
        raise ModelFileError(f"{where}: [detector] band must be [lo, hi] in Hz (two numbers); got {value!r}")
    try:
        return check_band(value)
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: [detector] {exc}") from None


def _check_detector(detector: Mapping[str, Any], dt: float, where: str) -> None:
    """The STFT fields of ``[detector]`` (window_s, hop_s, window) make a valid STFT at ``dt``."""
    if not {"window_s", "hop_s", "window"} & set(detector):
        return
    from ..detection.spectral import STFTConfig

    field = "window"
    try:
        field = "window_s"
        window_s = float(detector.get("window_s", 1.0))
        field = "hop_s"
        hop_s = float(detector.get("hop_s", 0.2))
        field = "window"
        cfg = STFTConfig(window_s=window_s, hop_s=hop_s, window=str(detector.get("window", "hamming")))
        cfg.n_window(dt)
        cfg.n_hop(dt)
        cfg.taper(dt)
    except (ChatterspecError, ValueError, TypeError) as exc:
        msg = str(exc)
        if field == "window" and "window" in msg and "hop" in msg:
            field = "hop_s"
        named = msg if msg.startswith(field) else f"{field}: {msg}"
        raise ModelFileError(f"{where}: [detector] {named}") from None


def _table(doc: Mapping[str, Any], key: str, where: str) -> Mapping[str, Any]:
    value = doc.get(key)
    if value is None:
        raise ModelFileError(f"{where}: table [{key}] is missing")
    if not isinstance(value, dict):
        raise ModelFileError(f"{where}: [{key}] must be a table; got {type(value).__name__}")
    return value


def _scalar(
    doc: Mapping[str, Any], key: str, where: str, *, positive: bool = False, default: float | None = None
) -> float:
    if key not in doc:
        if default is not None:
            return default
        raise ModelFileError(f"{where}: field {key!r} is missing")
    value = doc[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ModelFileError(f"{where}: field {key!r} must be a number; got {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ModelFileError(f"{where}: field {key!r} must be finite; got {value!r}")
    if positive and value <= 0:
        raise ModelFileError(f"{where}: field {key!r} must be > 0; got {value!r}")
    return value


def _names(table: Mapping[str, Any], key: str, where: str, *, required: bool) -> list[str]:
    value = table.get(key)
    if value is None:
        if required:
            raise ModelFileError(f"{where}: [channels] {key} (list of names) is missing")
        return []
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
        raise ModelFileError(f"{where}: [channels] {key} must be a list of non-empty strings; got {value!r}")
    if len(set(value)) != len(value):
        raise ModelFileError(f"{where}: [channels] {key} has duplicate names: {value}")
    return list(value)


def _array(value: object, where: str, field: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ModelFileError(
            f"{where}: {field} must be a number or a (nested) list of numbers with equal row lengths"
        ) from None
    if not np.all(np.isfinite(arr)):
        raise ModelFileError(f"{where}: {field} contains NaN or infinite values")
    return arr


def _matrix(
    table: Mapping[str, Any], key: str, where: str, section: str, *, vector_ok: bool = False
) -> np.ndarray:
    if key not in table:
        raise ModelFileError(f"{where}: [{section}] matrix {key} is missing")
    arr = _array(table[key], where, f"[{section}] {key}")
    if arr.ndim != 2 and not (vector_ok and arr.ndim == 1):
        raise ModelFileError(
            f"{where}: [{section}] {key} must be a 2-D matrix (list of rows); got shape {arr.shape}"
        )
    return arr


def _expect_shape(arr: np.ndarray, shape: tuple[int, int], key: str, where: str, what: str) -> None:
    if arr.shape != shape:
        raise ModelFileError(f"{where}: [matrices] {key} must have shape {shape} ({what}); got {arr.shape}")


def _covariance(table: Mapping[str, Any], key: str, size: int, where: str) -> np.ndarray:
    diag_key = f"{key}_diag"
    if key in table and diag_key in table:
        raise ModelFileError(f"{where}: [matrices] give either {key} or {diag_key}, not both")
    if diag_key in table:
        d = _array(table[diag_key], where, f"[matrices] {diag_key}")
        if d.shape != (size,):
            raise ModelFileError(
                f"{where}: [matrices] {diag_key} must have {size} entries; got shape {d.shape}"
            )
        return np.diag(d)
    if key not in table:
        raise ModelFileError(f"{where}: [matrices] matrix {key} (or {diag_key}) is missing")
    M = _matrix(table, key, where, "matrices")
    _expect_shape(M, (size, size), key, where, "covariance")
    return M


# --------------------------------------------------------------------------- data files
def load_data(path: str | Path, model: LinearModel, *, dt_tolerance: float = 0.01) -> DataSet:
    """Read measurements and inputs for ``model`` from a CSV or NPZ file (columns matched by name).

    Parameters
    ----------
    path : str or Path
        ``.csv`` (header row, comma separated) or ``.npz`` (one 1-D array per name).
    model : LinearModel
        Gives the column names (``output_names``, ``input_names``) and ``dt``.
    dt_tolerance : float
        Allowed relative deviation of every time step from ``model.dt``.

    Raises
    ------
    DataFileError
        Missing file or column, unparsable value, NaN/inf sample (see the NaN
        policy in the module docstring), non-monotonic or irregular timestamps,
        or fewer than two samples. The message names the file and the column.
    """
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
            reader = csv.reader(fh)
            rows, lines = [], []
            for r in reader:
                if r and not r[0].lstrip().startswith("#"):
                    rows.append(r)
                    lines.append(reader.line_num)  # 1-based line of the file (comments counted)
    except (OSError, UnicodeDecodeError) as exc:
        raise DataFileError(f"{where}: cannot be read ({exc})") from None
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
    if off.size:
        i = int(off[0])
        raise DataFileError(
            f"{where}: column {column!r} is not sampled at the model's dt = {dt:g} s: step "
            f"{step[i]:.9g} s between {_where_row(i, lines)} and {_where_row(i + 1, lines)} "
            f"({off.size} irregular step(s)); "
            "resample the data or set dt in the model file"
        )


# --------------------------------------------------------------------------- model-file writer
def _toml_number(v: float) -> str:
    """A float as TOML text that reads back bit-identically (``repr`` is the shortest round trip)."""
    v = float(v)
    if not math.isfinite(v):
        raise ModelFileError(f"cannot write a non-finite value {v!r} to a model file")
    return repr(v)


def _toml_vector(v: np.ndarray) -> str:
    return "[" + ", ".join(_toml_number(x) for x in np.asarray(v, dtype=float).ravel()) + "]"


def _toml_matrix(M: np.ndarray) -> str:
    return "[" + ", ".join(_toml_vector(row) for row in np.atleast_2d(M)) + "]"


def _toml_strings(names: tuple[str, ...] | list[str]) -> str:
    import json

    return "[" + ", ".join(json.dumps(str(n)) for n in names) + "]"


def _toml_covariance(key: str, M: np.ndarray) -> str:
    if np.count_nonzero(M - np.diag(np.diag(M))) == 0:
        return f"{key}_diag = {_toml_vector(np.diag(M))}"
    return f"{key} = {_toml_matrix(M)}"


def write_model_toml(
    path: str | Path,
    model: LinearModel,
    psi: np.ndarray | tuple[float, ...] | list[float],
    *,
    gamma: float = 0.1,
    detector: Mapping[str, Any] | None = None,
    comment: str = "",
) -> Path:
    """Write ``model`` as a TOML model file that :func:`load_model` reads back exactly.

    The matrices are written in discrete form (``form = "discrete"``) with every
    float as its shortest round-trip decimal (``repr``), so ``load_model`` gives
    back bit-identical ``A``, ``B``, ``C``, ``Q``, ``R`` and ``dt``; a diagonal
    ``Q`` / ``R`` is written as ``Q_diag`` / ``R_diag``.

    Parameters
    ----------
    path : str or Path
        File to write (parent folders are created; an existing file is replaced).
    model : LinearModel
        Nominal discrete model (``dt`` in s); its channel names and units are written too.
    psi : array-like
        Smoothing boundary layer of the SVSF, one value > 0 per output (output units).
    gamma : float
        SVSF convergence rate, 0 < gamma < 1.
    detector : mapping, optional
        ``[detector]`` table (keys ``alpha``, ``correction``, ``window_s`` (s),
        ``hop_s`` (s), ``window``, ``band`` (``(lo, hi)`` in Hz)); omitted when None (the
        loader's defaults apply).
    comment : str
        Text written as ``#`` comment lines at the top of the file.

    Returns
    -------
    Path
        The file written.

    Raises
    ------
    ModelFileError
        If ``psi`` does not have one positive finite entry per output, ``gamma``
        is outside (0, 1), a ``[detector]`` key is unknown, or a value is not finite.
    """
    path = Path(path)
    where = f"model file {str(path)!r}"
    m = model.n_outputs
    psi_arr = np.atleast_1d(np.asarray(psi, dtype=float))
    if psi_arr.shape != (m,) or not np.all(np.isfinite(psi_arr)) or np.any(psi_arr <= 0):
        raise ModelFileError(f"{where}: psi must hold {m} finite values > 0 (one per output); got {psi!r}")
    if not 0.0 < float(gamma) < 1.0:
        raise ModelFileError(f"{where}: gamma must lie in (0, 1); got {gamma!r}")
    detector = dict(detector or {})
    unknown = set(detector) - _DETECTOR_KEYS
    if unknown:
        raise ModelFileError(
            f"{where}: [detector] has unknown key(s) {sorted(unknown)}; allowed: {sorted(_DETECTOR_KEYS)}"
        )
    lines = [f"# {line}".rstrip() for line in comment.splitlines()]
    lines += [f"name = {_toml_strings([model.name])[1:-1]}", f"dt = {_toml_number(model.dt)}  # s", ""]
    lines += ["[channels]", f"outputs = {_toml_strings(model.output_names)}"]
    if any(model.output_units):
        lines.append(f"units = {_toml_strings(model.output_units)}")
    lines.append(f"inputs = {_toml_strings(model.input_names)}")
    if model.state_names:
        lines.append(f"states = {_toml_strings(model.state_names)}")
    lines += [
        "",
        "[matrices]",
        'form = "discrete"',
        f"A = {_toml_matrix(model.A)}",
        f"B = {_toml_matrix(model.B)}",
        f"C = {_toml_matrix(model.C)}",
        _toml_covariance("Q", model.Q),
        _toml_covariance("R", model.R),
        "",
        "[svsf]",
        f"psi = {_toml_vector(psi_arr)}",
        f"gamma = {_toml_number(gamma)}",
    ]
    if model.parameter_map is not None:  # fault identification: how physical parameters enter A and B
        lines += ["", model.parameter_map.to_toml()]
    if detector:
        lines += ["", "[detector]"]
        for key, value in detector.items():
            if isinstance(value, str):
                text = _toml_strings([value])[1:-1]
            elif key == "band":
                text = _toml_vector(np.asarray(_detector_band(value, where)))
            else:
                text = _toml_number(value)
            lines.append(f"{key} = {text}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path
