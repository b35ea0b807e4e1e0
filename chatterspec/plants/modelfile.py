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

A file with a ``[dynamics]`` table instead of ``A`` and ``B`` describes a nonlinear model whose ``f`` and
Jacobian are Python functions it names (:mod:`chatterspec.plants.modelfile_nonlinear`); an optional
``[simulation]`` table (input, initial state, duration) sets the healthy operating condition that
``calibrate``, ``detect`` and ``simulate`` use for either kind. The writer is
:mod:`chatterspec.plants.modelfile_writer`, the data-file reader :mod:`chatterspec.plants.datafile`
(both re-exported here).

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

import math
import tomllib
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._validate import check_band
from ..errors import ChatterspecError, ModelFileError, UnstableModelWarning
from .datafile import TIME_COLUMNS, DataSet, load_data
from .models import LinearModel, discretize
from .parameters import model_file_parameter_map

if TYPE_CHECKING:  # pragma: no cover
    from .modelfile_nonlinear import SimulationSpec
    from .nonlinear import NonlinearModel

__all__ = ["TIME_COLUMNS", "DataSet", "ModelSpec", "load_data", "load_model", "write_model_toml"]


@dataclass(frozen=True, eq=False)
class ModelSpec:
    """A model file's content.

    Attributes
    ----------
    model : LinearModel or NonlinearModel
        Nominal discrete model (names and units from ``[channels]``); a file with a ``[dynamics]``
        table gives a :class:`~chatterspec.plants.nonlinear.NonlinearModel`
        (:mod:`~chatterspec.plants.modelfile_nonlinear`).
    psi : (m,) array or None
        Smoothing boundary layer of the SVSF per output (None for a nonlinear model: its monitor
        runs the auxiliary SVSF only).
    gamma : float
        SVSF convergence rate.
    detector : dict
        The optional ``[detector]`` table (keys ``alpha``, ``correction``,
        ``window_s``, ``hop_s``, ``window``, ``band``); the STFT fields are checked
        and ``band`` (Hz) is validated into a ``(lo, hi)`` tuple, the rest is unvalidated here.
    path : Path
        The file read.
    simulation : SimulationSpec or None
        The optional ``[simulation]`` table (input, initial state, duration) used by ``calibrate``,
        ``detect`` and ``simulate`` on the file.
    """

    model: LinearModel | NonlinearModel
    psi: np.ndarray | None
    gamma: float
    detector: Mapping[str, Any]
    path: Path
    simulation: SimulationSpec | None = None

    @property
    def is_linear(self) -> bool:
        """False for a nonlinear model file (a ``[dynamics]`` table naming f and its Jacobian)."""
        return isinstance(self.model, LinearModel)


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

    if "dynamics" in doc:  # a nonlinear model: f and its Jacobian named as Python functions
        from .modelfile_nonlinear import load_nonlinear

        return load_nonlinear(doc, path, where)
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
    pmap = model_file_parameter_map(doc, where, form, method)  # fault identification (optional)
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
    gamma = svsf_gamma(svsf, where)
    from .modelfile_nonlinear import parse_simulation

    return ModelSpec(
        model=model,
        psi=psi,
        gamma=gamma,
        detector=detector_table(doc, model.dt, where),
        path=path,
        simulation=parse_simulation(doc, model, where),
    )


def svsf_gamma(svsf: Mapping[str, Any], where: str) -> float:
    """``[svsf] gamma`` (default 0.1), checked to lie in (0, 1)."""
    gamma = float(_scalar(svsf, "gamma", f"{where}: [svsf]", default=0.1))
    if not 0.0 < gamma < 1.0:
        raise ModelFileError(f"{where}: [svsf] gamma must lie in (0, 1); got {gamma}")
    return gamma


def detector_table(doc: Mapping[str, Any], dt: float, where: str) -> dict[str, Any]:
    """The optional ``[detector]`` table, checked (STFT fields at ``dt``; ``band`` as a tuple in Hz)."""
    detector = doc.get("detector", {})
    if not isinstance(detector, dict):
        raise ModelFileError(f"{where}: [detector] must be a table")
    unknown = set(detector) - _DETECTOR_KEYS
    if unknown:
        raise ModelFileError(
            f"{where}: [detector] has unknown key(s) {sorted(unknown)}; allowed: {sorted(_DETECTOR_KEYS)}"
        )
    _check_detector(detector, dt, where)
    detector = dict(detector)
    if "band" in detector:
        detector["band"] = _detector_band(detector["band"], where)
    return detector


def _detector_band(value: object, where: str) -> tuple[float, float]:
    """``[detector] band = [lo, hi]`` (Hz) validated into a tuple; errors name the file and field."""
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
    from .._stft import STFTConfig  # the settings only: the spectra module stays unloaded

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
        if np.any(d < 0):
            i = int(np.flatnonzero(d < 0)[0])
            raise ModelFileError(
                f"{where}: [matrices] {diag_key} holds variances, which must be >= 0; entry {i} is {d[i]:g}"
            )
        return np.diag(d)
    if key not in table:
        raise ModelFileError(f"{where}: [matrices] matrix {key} (or {diag_key}) is missing")
    M = _matrix(table, key, where, "matrices")
    _expect_shape(M, (size, size), key, where, "covariance")
    from .models import _check_covariance

    try:
        _check_covariance(key, M)
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: [matrices] {exc} (a covariance)") from None
    return M


from .modelfile_writer import write_model_toml  # noqa: E402  (it uses the helpers above)
