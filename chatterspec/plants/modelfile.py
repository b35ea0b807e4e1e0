"""Model files (TOML): what they hold, the linear and nonlinear readers, and the writer.

User model files (TOML) and measurement data files (CSV / NPZ) for ``chatterspec monitor``.

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
Jacobian are Python functions it names (:func:`load_nonlinear`, below); an optional
``[simulation]`` table (input, initial state, duration) sets the healthy operating condition that
``calibrate``, ``detect`` and ``simulate`` use for either kind. The writers are :func:`write_model_toml`
and :func:`write_nonlinear_model_toml`, the data-file reader :mod:`chatterspec.plants.datafile`.

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

Nonlinear model files: a TOML that names the Python functions of ``f`` and its Jacobian.

A model file with a ``[dynamics]`` table describes a :class:`~chatterspec.plants.nonlinear.NonlinearModel`
(format in ``examples/README.md``)::

    name = "Duffing oscillator"
    dt = 0.001                                  # s

    [channels]
    outputs = ["position", "velocity"]          # rows of C
    inputs = ["force"]

    [dynamics]
    form = "continuous"                         # x' = g(x, u), stepped by explicit Euler (as the papers);
                                                # "discrete": f(x, u) is x(k+1) itself
    f = "duffing.py:g"                          # FILE.py:function, FILE relative to this model file,
    jacobian = "duffing.py:g_jacobian"          # or an importable module: "package.module:function"
    input_jacobian = "duffing.py:g_input"       # optional: d f / d u (continuous: d g / d u; default:
                                                # central differences)
    # h = "duffing.py:h"                        # optional nonlinear measurement z = h(x) + w, with
    # h_jacobian = "duffing.py:h_jacobian"      # its Jacobian (then no [matrices] C; EKF and simulation)

    [dynamics.parameters]                       # optional: keyword arguments of every function above
    stiffness = 3948.0

    [matrices]
    C = [[1, 0], [0, 1]]                        # linear measurement z = C x + w
    Q_diag = [...]                              # discrete process-noise covariance
    R_diag = [...]                              # measurement-noise covariance

    [simulation]                                # optional (linear files too): healthy operating condition
    duration_s = 4.0                            # of `calibrate`, `detect` and `simulate`
    x0 = [0, 0]
    input = { kind = "sine", amplitude = 1.0, frequency_hz = 2.0 }

The functions are called as ``f(x, u, **parameters)`` (``h`` and ``h_jacobian`` as
``h(x, **parameters)``), batched (``x`` ``(..., n)``, ``u`` ``(..., p)`` or ``(p,)``), and receive
``dt=`` (s) too when their signature names a ``dt`` argument.

**Security.** The TOML holds no code and nothing in it is evaluated: the loader imports exactly the module
(or runs exactly the ``.py`` file) that the file names, as ``python`` would run a script. A model file is
therefore as trusted as the Python code it names; read it before using a model file from elsewhere.

**Reproducibility.** A file module is identified by the SHA-256 of its source (its module name is
``chatterspec_modelfile_<stem>_<hash>``), so model fingerprints, and with them calibration files, change
when the code changes. A :class:`ModelFunction` pickles with the source text, so worker processes and
Dask workers run the same code without access to the file.

What a model file holds, :class:`ModelSpec`, and the readers of its TOML fields.

The field readers (tables, scalars, names, matrices, covariances, the ``[svsf]`` gamma and the
``[detector]`` table) are shared by the linear loader (:func:`load_model`), the nonlinear one
(:func:`load_nonlinear`) and the writers; every error names the file and the field.

Write a :class:`~chatterspec.plants.models.LinearModel` as a TOML model file that reads back exactly.
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import math
import os
import re
import sys
import tomllib
import types
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from .._validate import check_band
from ..errors import ChatterspecError, ModelFileError, UnstableModelWarning
from .models import Discretization, LinearModel, discretize
from .nonlinear import Model
from .parameters import model_file_parameter_map

if TYPE_CHECKING:
    from .models import ChannelLabels
    from .nonlinear import NonlinearModel
    from .scenarios import Scenario
    from .signals import Signal

__all__ = [
    "Channels",
    "MeasurementFunction",
    "ModelFunction",
    "ModelSpec",
    "SimulationSpec",
    "detector_table",
    "file_scenario",
    "load_model",
    "load_nonlinear",
    "parse_simulation",
    "provenance_table",
    "read_channels",
    "signal_table",
    "svsf_gamma",
    "toml_table",
    "write_model_toml",
    "write_nonlinear_model_toml",
]


# What a model file holds, and the readers of its fields.


class Channels(NamedTuple):
    """The sampling time and the ``[channels]`` table of a model file (linear and nonlinear alike).

    Attributes
    ----------
    dt : float
        Sampling time in seconds (> 0).
    outputs, inputs : list of str
        Measured channels and inputs (required).
    units : list of str
        One per output (optional: empty).
    states : list of str
        State names (optional: empty).
    """

    dt: float
    outputs: list[str]
    inputs: list[str]
    units: list[str]
    states: list[str]

    def model_names(self) -> ChannelLabels:
        """The channel names and units as the model dataclasses' keyword arguments."""
        return {
            "state_names": tuple(self.states),
            "output_names": tuple(self.outputs),
            "input_names": tuple(self.inputs),
            "output_units": tuple(self.units),
        }


def read_channels(doc: Mapping[str, Any], where: str) -> Channels:
    """The top-level ``dt`` and the ``[channels]`` table of a model file, checked.

    Parameters
    ----------
    doc : mapping
        The parsed TOML document.
    where : str
        The file, for the messages.

    Raises
    ------
    ModelFileError
        If ``dt`` is missing or not > 0, or ``[channels]`` lacks ``outputs``/``inputs`` or is malformed.
    """
    dt = _scalar(doc, "dt", where, positive=True)
    channels = _table(doc, "channels", where)
    return Channels(
        dt,
        _names(channels, "outputs", where, required=True),
        _names(channels, "inputs", where, required=True),
        _names(channels, "units", where, required=False),
        _names(channels, "states", where, required=False),
    )


@dataclass(frozen=True, eq=False)
class ModelSpec:
    """A model file's content.

    Attributes
    ----------
    model : LinearModel or NonlinearModel
        Nominal discrete model (names and units from ``[channels]``); a file with a ``[dynamics]``
        table gives a :class:`~chatterspec.plants.nonlinear.NonlinearModel`
        (:mod:`~chatterspec.plants.modelfile`).
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
    commissioning : dict or None
        The ``[commissioning]`` table of a file written by ``chatterspec commission``: where the
        fitted values came from (data file and hash, spans, each estimate with its interval and the
        nominal it replaced); read as written, used by nothing else.
    """

    model: LinearModel | NonlinearModel
    psi: np.ndarray | None
    gamma: float
    detector: Mapping[str, Any]
    path: Path
    simulation: SimulationSpec | None = None
    commissioning: Mapping[str, Any] | None = None

    @property
    def is_linear(self) -> bool:
        """False for a nonlinear model file (a ``[dynamics]`` table naming f and its Jacobian)."""
        return isinstance(self.model, LinearModel)


_DETECTOR_KEYS = {"alpha", "correction", "window_s", "hop_s", "window", "threshold", "band"}


def svsf_gamma(svsf: Mapping[str, Any], where: str) -> float:
    """``gamma`` of the ``svsf`` table (default 0.1), checked to lie in (0, 1); errors name ``where``."""
    gamma = float(_scalar(svsf, "gamma", f"{where}: [svsf]", default=0.1))
    if not 0.0 < gamma < 1.0:
        raise ModelFileError(f"{where}: [svsf] gamma must lie in (0, 1); got {gamma}")
    return gamma


def detector_table(doc: Mapping[str, Any], dt: float, where: str) -> dict[str, Any]:
    """The optional ``[detector]`` table of ``doc``, checked (STFT fields at ``dt`` s; ``band`` as a tuple in
    Hz); errors name ``where``."""
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


def provenance_table(doc: Mapping[str, Any], where: str) -> dict[str, Any] | None:
    """The optional ``[commissioning]`` table of ``doc`` (None without one); errors name ``where``.

    Raises
    ------
    ModelFileError
        If ``commissioning`` is not a table.
    """
    table = doc.get("commissioning")
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ModelFileError(
            f"{where}: [commissioning] must be a table (the provenance a commissioned file records)"
        )
    return table


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
    from .models import check_covariance

    try:
        check_covariance(key, M)
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: [matrices] {exc} (a covariance)") from None
    return M


# Nonlinear model files: the functions a file names.

#: Keys of ``[dynamics]``.
_DYNAMICS_KEYS = {
    "form",
    "f",
    "jacobian",
    "input_jacobian",
    "h",
    "h_jacobian",
    "parameters",
    "rest_state",
    "oscillatory_states",
}

#: The loaded functions, by (module name, function name).
_LOADED: dict[tuple[str, str], Callable[..., Any]] = {}


@dataclass(frozen=True, eq=False)
class ModelFunction:
    """A function named by a model file, called as ``function(x, u, **keywords)``.

    Attributes
    ----------
    module : str
        Importable module name, or the synthetic name of a ``.py`` file
        (``chatterspec_modelfile_<stem>_<sha256 prefix>``).
    name : str
        Function name in the module.
    keywords : dict
        ``[dynamics.parameters]`` (and ``dt`` when the function takes it).
    source : str or None
        The ``.py`` file's text (None for an importable module): a worker process re-creates the module
        from it.
    filename : str or None
        The ``.py`` file (for tracebacks).
    ref : str
        The reference as written in the model file (e.g. ``"duffing.py:g"``).
    key : str
        The ``[dynamics]`` key that names it (``f``, ``jacobian``, ...), for messages.

    Raises
    ------
    ModelFileError
        When called, if the function raises: its exception, named with the file's key and
        reference, replaces the traceback (a user's code failing mid-run is a model-file error).
    """

    module: str
    name: str
    keywords: dict[str, Any] = field(default_factory=dict)
    source: str | None = None
    filename: str | None = None
    ref: str = ""
    key: str = "f"

    @property
    def func(self) -> Callable[..., Any]:
        """The Python function (for model fingerprints: module, name and keywords identify it)."""
        key = (self.module, self.name)
        fn = _LOADED.get(key)
        if fn is None:
            module = _module(self.module, self.source, self.filename)
            fn = getattr(module, self.name)
            _LOADED[key] = fn
        return fn

    @property
    def args(self) -> tuple[()]:
        """Extra positional arguments of the function (none)."""
        return ()

    def __repr__(self) -> str:
        kw = "".join(f", {k}={v!r}" for k, v in self.keywords.items())
        return f"ModelFunction({self.ref or f'{self.module}:{self.name}'!r}{kw})"

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        try:
            return self.func(x, u, **self.keywords)
        except ChatterspecError:
            raise
        except Exception as exc:
            raise self._failed(exc, x) from exc

    def _failed(self, exc: Exception, x: np.ndarray) -> ModelFileError:
        where = self.ref or f"{self.module}:{self.name}"
        return ModelFileError(
            f"[dynamics] {self.key} = {where!r} raised {type(exc).__name__}: {exc} (called with x of "
            f"shape {np.shape(x)})"
        )


@dataclass(frozen=True, eq=False)
class MeasurementFunction(ModelFunction):
    """A measurement function named by a model file, called as ``function(x, **keywords)``
    (``h(x) -> (..., m)`` or its Jacobian ``(..., m, n)``).

    Attributes
    ----------
    module, name, keywords, source, filename, ref, key
        As :class:`ModelFunction`'s.
    """

    def __call__(self, x: np.ndarray) -> np.ndarray:  # type: ignore[override]  # h(x): no input u
        try:
            return self.func(x, **self.keywords)
        except ChatterspecError:
            raise
        except Exception as exc:
            raise self._failed(exc, x) from exc


@dataclass(frozen=True)
class _TimesDt:
    """``dt * fn(x, u)``: the explicit Euler step's ``df/du`` from a continuous model's ``dg/du``."""

    fn: ModelFunction
    dt: float

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return self.dt * np.asarray(self.fn(x, u), dtype=float)


def _module(name: str, source: str | None, filename: str | None) -> types.ModuleType:
    """Import ``name``, or create it from ``source`` (a model file's ``.py``) once per process."""
    if source is None:
        return importlib.import_module(name)
    module = sys.modules.get(name)
    if module is None:
        module = types.ModuleType(name)
        module.__file__ = filename
        sys.modules[name] = module  # before exec: dataclasses and pickling look the module up
        try:
            exec(compile(source, filename or name, "exec"), module.__dict__)  # the file the user named
        except BaseException:
            del sys.modules[name]
            raise
    return module


def _function(ref: object, base: Path, where: str, key: str) -> tuple[str, str, str | None, str | None]:
    """``(module, name, source, filename)`` of ``"file.py:function"`` or ``"package.module:function"``."""
    if not isinstance(ref, str) or ref.count(":") < 1 or not ref.rsplit(":", 1)[1].isidentifier():
        raise ModelFileError(
            f"{where}: [dynamics] {key} must be 'file.py:function' or 'package.module:function'; got {ref!r}"
        )
    target, name = ref.rsplit(":", 1)
    if target.endswith(".py"):
        path = Path(target) if Path(target).is_absolute() else base / target
        try:
            source = path.read_text()
        except OSError as exc:
            raise ModelFileError(
                f"{where}: [dynamics] {key} = {ref!r}: cannot read {str(path)!r} ({exc.strerror or exc})"
            ) from None
        digest = hashlib.sha256(source.encode()).hexdigest()[:16]
        stem = re.sub(r"\W", "_", path.stem)
        module = f"chatterspec_modelfile_{stem}_{digest}"
        return module, name, source, str(path.resolve())
    if not all(part.isidentifier() for part in target.split(".")):
        raise ModelFileError(
            f"{where}: [dynamics] {key} = {ref!r}: {target!r} is neither a .py file nor a module name"
        )
    return target, name, None, None


def _resolve(
    ref: object,
    base: Path,
    where: str,
    key: str,
    parameters: Mapping[str, float],
    dt: float,
    measurement: bool = False,
) -> ModelFunction:
    module, name, source, filename = _function(ref, base, where, key)
    try:
        fn = getattr(_module(module, source, filename), name)
    except AttributeError:
        raise ModelFileError(
            f"{where}: [dynamics] {key} = {ref!r}: the module has no function {name!r}"
        ) from None
    except Exception as exc:  # the user's module failed to import: its own error, named
        raise ModelFileError(
            f"{where}: [dynamics] {key} = {ref!r}: importing it failed ({type(exc).__name__}: {exc})"
        ) from None
    if not callable(fn):
        raise ModelFileError(f"{where}: [dynamics] {key} = {ref!r} is not a function")
    keywords = dict(parameters)
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):  # a builtin or compiled callable: pass the parameters as they are
        sig = None
    if sig is not None:
        names = sig.parameters
        var_kw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in names.values())
        unknown = [k for k in parameters if k not in names and not var_kw]
        if unknown:
            skip = 1 if measurement else 2
            accepted = [k for k, p in names.items() if p.kind is not inspect.Parameter.VAR_POSITIONAL][skip:]
            raise ModelFileError(
                f"{where}: [dynamics.parameters] {unknown} are not arguments of {key} = {ref!r} "
                f"(it takes {accepted or 'no parameters'} after {'x' if measurement else 'x, u'})"
            )
        if "dt" in names:
            keywords["dt"] = dt
    _LOADED[(module, name)] = fn
    return (MeasurementFunction if measurement else ModelFunction)(
        module=module, name=name, keywords=keywords, source=source, filename=filename, ref=str(ref), key=key
    )


def load_nonlinear(doc: Mapping[str, Any], path: Path, where: str) -> Any:
    """The :class:`~chatterspec.plants.modelfile.ModelSpec` of a model file with a ``[dynamics]`` table.

    Parameters
    ----------
    doc : mapping
        The parsed TOML.
    path : Path
        The model file (function files are relative to its folder).
    where : str
        ``"model file '...'"``, for messages.

    Raises
    ------
    ModelFileError
        A missing or malformed field, a function that cannot be found or imported, parameters the
        functions do not take, or a model that fails its checks (shapes, NaN at the rest state); the
        message names the file and the field.
    """
    from .nonlinear import NonlinearModel

    channels = read_channels(doc, where)
    dt, outputs, inputs, _, states = channels
    dyn = _table(doc, "dynamics", where)
    unknown = set(dyn) - _DYNAMICS_KEYS
    if unknown:
        raise ModelFileError(
            f"{where}: [dynamics] has unknown key(s) {sorted(unknown)}; allowed: {sorted(_DYNAMICS_KEYS)}"
        )
    form = str(dyn.get("form", "discrete"))
    if form not in ("discrete", "continuous"):
        raise ModelFileError(f"{where}: [dynamics] form must be 'discrete' or 'continuous'; got {form!r}")
    params = dyn.get("parameters", {})
    if not isinstance(params, dict):
        raise ModelFileError(f"{where}: [dynamics.parameters] must be a table of numbers")
    parameters = {str(k): _scalar(params, k, f"{where}: [dynamics.parameters]") for k in params}
    for key in ("f", "jacobian"):
        if key not in dyn:
            raise ModelFileError(
                f"{where}: [dynamics] {key} (a 'file.py:function' or 'module:function') is missing"
            )
    base = path.parent
    f = _resolve(dyn["f"], base, where, "f", parameters, dt)
    jac = _resolve(dyn["jacobian"], base, where, "jacobian", parameters, dt)
    input_jac = None
    if "input_jacobian" in dyn:
        input_jac = _resolve(dyn["input_jacobian"], base, where, "input_jacobian", parameters, dt)
    h = h_jac = None
    if ("h" in dyn) != ("h_jacobian" in dyn):
        raise ModelFileError(f"{where}: [dynamics] h and h_jacobian go together (a nonlinear measurement)")
    if "h" in dyn:
        h = _resolve(dyn["h"], base, where, "h", parameters, dt, measurement=True)
        h_jac = _resolve(dyn["h_jacobian"], base, where, "h_jacobian", parameters, dt, measurement=True)
    mats = _table(doc, "matrices", where)
    extra = set(mats) - {"C", "Q", "Q_diag", "R", "R_diag"}
    if extra:
        raise ModelFileError(
            f"{where}: [matrices] of a nonlinear model holds only C, Q (or Q_diag), R (or R_diag); "
            f"{sorted(extra)} belong to a linear model (drop [dynamics] for one)"
        )
    if h is None:
        C = _matrix(mats, "C", where, "matrices", vector_ok=True)
        C = C[None, :] if C.ndim == 1 else C
        m, n = C.shape
    else:
        if "C" in mats:
            raise ModelFileError(
                f"{where}: give either [matrices] C (a linear measurement) or [dynamics] h, not both"
            )
        C, m = None, len(outputs)
        if states:
            n = len(states)
        elif "rest_state" in dyn:
            n = int(np.size(dyn["rest_state"]))
        else:
            raise ModelFileError(
                f"{where}: with [dynamics] h, name the states ([channels] states) or give "
                "[dynamics] rest_state, so that the number of states is known"
            )
    if m != len(outputs):
        raise ModelFileError(
            f"{where}: [matrices] C has {m} rows; [channels] outputs has {len(outputs)} names"
        )
    kwargs: dict[str, Any] = {
        "C": C,
        "h": h,
        "h_jac": h_jac,
        "Q": _covariance(mats, "Q", n, where),
        "R": _covariance(mats, "R", m, where),
        "dt": dt,
        "n_inputs": len(inputs),
        "input_jacobian": input_jac,
        **channels.model_names(),
        "parameters": parameters,
        "name": str(doc.get("name", path.stem)),
    }
    if "rest_state" in dyn:
        kwargs["rest_state"] = np.asarray(dyn["rest_state"], dtype=float)
    if "oscillatory_states" in dyn:
        kwargs["oscillatory_states"] = tuple(dyn["oscillatory_states"])
    try:
        if form == "continuous":
            if input_jac is not None:  # the file gives dg/du; the discrete model's df/du is dt dg/du
                kwargs["input_jacobian"] = _TimesDt(input_jac, dt)
            model = NonlinearModel.from_continuous(f, jac, **kwargs)
        else:
            model = NonlinearModel(f=f, jac=jac, **kwargs)
    except ModelFileError as exc:  # the user's f or Jacobian raised on the probe at the rest state
        raise ModelFileError(
            f"{where}: [dynamics] calling f = {f.ref!r} / jacobian = {jac.ref!r} at the rest state (x "
            f"batched as (2, {n}), u as (2, {len(inputs)})) failed: {exc}"
        ) from None
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: invalid model: {exc}") from None
    svsf = doc.get("svsf", {})
    if not isinstance(svsf, dict):
        raise ModelFileError(f"{where}: [svsf] must be a table")
    return ModelSpec(
        model=model,
        psi=None,
        gamma=svsf_gamma(svsf, where),
        detector=detector_table(doc, dt, where),
        path=path,
        simulation=parse_simulation(doc, model, where),
    )


# --------------------------------------------------------------------------- [simulation]
@dataclass(frozen=True, eq=False)
class SimulationSpec:
    """A model file's ``[simulation]`` table: the healthy operating condition to simulate.

    Attributes
    ----------
    input : Signal or None
        The input (None: zero on every input).
    x0 : (n,) array or None
        Initial true state (None: the model's rest state, or zeros).
    duration_s : float or None
        Record length in seconds (None: the command's default, 4 s).
    """

    input: Signal | None = None
    x0: np.ndarray | None = None
    duration_s: float | None = None


_SIGNALS = ("constant", "step", "sine", "square", "chirp")


@dataclass(frozen=True)
class _Stacked:
    """One signal per input channel, sampled side by side ``(T, p)``."""

    signals: tuple[Signal, ...]

    def sample(self, t: np.ndarray) -> np.ndarray:
        return np.column_stack([np.asarray(s.sample(t), dtype=float).reshape(-1) for s in self.signals])

    def describe(self) -> str:
        return "; ".join(s.describe() for s in self.signals)


def _signal(table: object, where: str) -> Signal:
    from . import signals

    if not isinstance(table, dict) or "kind" not in table:
        raise ModelFileError(
            f"{where}: [simulation] input must be a table with a kind ({', '.join(_SIGNALS)})"
        )
    kind = str(table["kind"])
    cls = {
        "constant": signals.Constant,
        "step": signals.Step,
        "sine": signals.Sine,
        "square": signals.SquareWave,
        "chirp": signals.Chirp,
    }.get(kind)
    if cls is None:
        raise ModelFileError(
            f"{where}: [simulation] input kind must be one of {', '.join(_SIGNALS)}; got {kind!r}"
        )
    args = {k: v for k, v in table.items() if k != "kind"}
    try:
        return cls(**args)
    except TypeError as exc:
        raise ModelFileError(f"{where}: [simulation] input of kind {kind!r}: {exc}") from None
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: [simulation] input of kind {kind!r}: {exc}") from None


def parse_simulation(doc: Mapping[str, Any], model: Model, where: str) -> SimulationSpec | None:
    """The optional ``[simulation]`` table (keys ``duration_s``, ``x0``, ``input``), validated.

    ``input`` is one table for a one-input model, or a list of tables (one per input); each has a
    ``kind`` (``constant``, ``step``, ``sine``, ``square``, ``chirp``) and the keyword arguments of the
    matching class of :mod:`chatterspec.plants.signals` (e.g. ``amplitude``, ``frequency_hz``).

    Parameters
    ----------
    doc : mapping
        The parsed TOML.
    model : LinearModel or NonlinearModel
        The file's model (sizes of ``x0`` and of the input).
    where : str
        ``"model file '...'"``, for messages.

    Returns
    -------
    SimulationSpec or None
        None when the file has no ``[simulation]`` table.
    """

    sim = doc.get("simulation")
    if sim is None:
        return None
    if not isinstance(sim, dict):
        raise ModelFileError(f"{where}: [simulation] must be a table")
    unknown = set(sim) - {"duration_s", "x0", "input"}
    if unknown:
        raise ModelFileError(
            f"{where}: [simulation] has unknown key(s) {sorted(unknown)}; allowed: duration_s, x0, input"
        )
    duration = (
        _scalar(sim, "duration_s", f"{where}: [simulation]", positive=True) if "duration_s" in sim else None
    )
    x0 = None
    if "x0" in sim:
        x0 = _array(sim["x0"], where, "[simulation] x0")
        if x0.shape != (model.n_states,):
            raise ModelFileError(
                f"{where}: [simulation] x0 must have {model.n_states} entries; got shape {x0.shape}"
            )
    signal = None
    if "input" in sim:
        raw = sim["input"]
        tables = raw if isinstance(raw, list) else [raw]
        if len(tables) != model.n_inputs:
            raise ModelFileError(
                f"{where}: [simulation] input needs one table per input ({model.n_inputs}); got {len(tables)}"
            )
        parts = tuple(_signal(t, where) for t in tables)
        signal = parts[0] if len(parts) == 1 else _Stacked(parts)
    return SimulationSpec(input=signal, x0=x0, duration_s=duration)


def file_scenario(spec: ModelSpec, default_duration: float = 4.0, name: str | None = None) -> Scenario:
    """A healthy scenario for a model file: its model as nominal and true plant, its ``[simulation]``.

    Parameters
    ----------
    spec : ModelSpec
        A loaded model file.
    default_duration : float
        Record length (s) when the file's ``[simulation]`` gives none.
    name : str, optional
        Scenario name (default: the file's stem).

    Returns
    -------
    Scenario
        Family ``"user"``, healthy; zero input and the rest state (or zeros) unless ``[simulation]`` says
        otherwise.
    """
    from .scenarios import Scenario
    from .signals import ZeroInput

    sim = spec.simulation or SimulationSpec()
    model = spec.model
    x0 = sim.x0 if sim.x0 is not None else getattr(model, "rest_state", np.zeros(model.n_states))
    signal = sim.input if sim.input is not None else ZeroInput(model.n_inputs)
    what = signal.describe() if sim.input is not None else "zero"
    return Scenario(
        name=name or Path(spec.path).stem,
        nominal=model,
        input=signal,
        duration=sim.duration_s or default_duration,
        x0=x0,
        description=f"model file {Path(spec.path).name}, healthy; input: {what}",
        family="user",
    )


# Writing model files.


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


def _matrices_and_svsf(model: Model, matrices: tuple[str, ...], svsf: tuple[str, ...]) -> list[str]:
    """The ``[matrices]`` table (``matrices`` lines, then C, Q, R) and the ``[svsf]`` table of a file."""
    C, Q, R = model.C, model.Q, model.R
    matrix_lines = [*matrices, f"C = {_toml_matrix(C)}", _toml_covariance("Q", Q), _toml_covariance("R", R)]
    return ["", "[matrices]", *matrix_lines, "", "[svsf]", *svsf]


def write_model_toml(
    path: str | Path,
    model: LinearModel,
    psi: np.ndarray | tuple[float, ...] | list[float],
    *,
    gamma: float = 0.1,
    detector: Mapping[str, Any] | None = None,
    comment: str = "",
    tables: Mapping[str, Mapping[str, Any]] | None = None,
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
    tables : mapping of str to mapping, optional
        Further tables written last, in order, each with :func:`toml_table` (e.g.
        ``{"simulation": {...}}``; a dotted name such as ``"commissioning.parameters"`` is a
        sub-table).

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
    lines += _matrices_and_svsf(
        model,
        ('form = "discrete"', f"A = {_toml_matrix(model.A)}", f"B = {_toml_matrix(model.B)}"),
        (f"psi = {_toml_vector(psi_arr)}", f"gamma = {_toml_number(gamma)}"),
    )
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
    for name, table in (tables or {}).items():
        lines += ["", toml_table(name, table)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


# --------------------------------------------------------------------------- generic tables
def _toml_value(v: Any) -> str:
    """A TOML value: string, boolean, integer, float (shortest round trip), array or inline table."""
    if isinstance(v, str):
        return _toml_strings([v])[1:-1]
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, Mapping):
        return _inline_table(v)
    if isinstance(v, (list, tuple, np.ndarray)):
        items = list(v.tolist() if isinstance(v, np.ndarray) else v)
        return "[" + ", ".join(_toml_value(x) for x in items) + "]"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    return _toml_number(v)


def _toml_key(key: str) -> str:
    """A bare key when it is one (letters, digits, ``_``, ``-``), else a quoted one."""
    import re

    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else _toml_strings([key])[1:-1]


def _inline_table(d: Mapping[str, Any]) -> str:
    return "{ " + ", ".join(f"{_toml_key(str(k))} = {_toml_value(v)}" for k, v in d.items()) + " }"


def toml_table(name: str, table: Mapping[str, Any]) -> str:
    """The TOML text of table ``[name]`` holding ``table`` (no trailing newline).

    Parameters
    ----------
    name : str
        Table name; a dotted name (``"commissioning.parameters"``) is a sub-table.
    table : mapping
        Key -> value: strings, booleans, integers, floats (written as their shortest round-trip
        decimal, so they read back bit-identically), sequences of these (arrays) and mappings
        (inline tables).

    Raises
    ------
    ModelFileError
        A float that is not finite (TOML has no NaN a model file may hold).
    """
    head = ".".join(_toml_key(part) for part in name.split("."))
    return "\n".join([f"[{head}]", *(f"{_toml_key(str(k))} = {_toml_value(v)}" for k, v in table.items())])


# --------------------------------------------------------------------------- nonlinear models


def signal_table(signal: Signal) -> dict[str, Any] | None:
    """A :mod:`chatterspec.plants.signals` input as a ``[simulation] input`` table (None if it has none).

    Parameters
    ----------
    signal : Signal
        ``Constant``, ``Step``, ``Sine``, ``SquareWave`` or ``Chirp`` (other signals have no table form).
    """
    import dataclasses

    from . import signals

    kinds = {
        signals.Constant: "constant",
        signals.Step: "step",
        signals.Sine: "sine",
        signals.SquareWave: "square",
        signals.Chirp: "chirp",
    }
    kind = kinds.get(type(signal))
    if kind is None or not dataclasses.is_dataclass(signal):  # (every kind above is a dataclass)
        return None
    return {"kind": kind, **{f.name: getattr(signal, f.name) for f in dataclasses.fields(signal)}}


def _function_refs(model: NonlinearModel) -> tuple[str, str, str | None, str, dict[str, float]]:
    """``(f, jacobian, input_jacobian, form, parameters)`` naming a nonlinear model's functions."""
    from functools import partial

    from .eha4 import eha4_transition
    from .nonlinear import EulerJacobian, EulerStep

    f, jac = model.f, model.jac
    if isinstance(f, partial) and f.func is eha4_transition:
        mod = "chatterspec.plants.eha4"
        return (
            f"{mod}:eha4_step",
            f"{mod}:eha4_step_jacobian",
            f"{mod}:eha4_step_input",
            "discrete",
            dict(model.parameters),
        )
    form = "discrete"
    if isinstance(f, EulerStep) and isinstance(jac, EulerJacobian):
        f, jac, form = f.g, jac.g_jac, "continuous"
    if isinstance(f, ModelFunction) and isinstance(jac, ModelFunction):

        def ref(fn: ModelFunction) -> str:
            return f"{fn.filename}:{fn.name}" if fn.source is not None else f"{fn.module}:{fn.name}"

        inp = model.input_jacobian
        params = {k: v for k, v in f.keywords.items() if k != "dt"}
        return ref(f), ref(jac), ref(inp) if isinstance(inp, ModelFunction) else None, form, params
    raise ModelFileError(
        f"{model.name!r}: its f is not a function named in a module (a model file names f as "
        "'module:function'), so it cannot be written as a model file"
    )


def write_nonlinear_model_toml(
    path: str | Path,
    model: NonlinearModel,
    *,
    gamma: float = 0.1,
    simulation: Mapping[str, Any] | None = None,
    detector: Mapping[str, Any] | None = None,
    comment: str = "",
) -> Path:
    """Write a nonlinear model as a model file that names its functions (:mod:`.modelfile_nonlinear`).

    Parameters
    ----------
    path : str or Path
        File to write (parent folders are created).
    model : NonlinearModel
        A model whose ``f`` and Jacobian are named functions: the catalogue's nonlinear EHA
        (written as ``chatterspec.plants.eha4:eha4_step`` with its ten parameters) or one loaded from a
        model file.
    gamma : float
        SVSF convergence rate, 0 < gamma < 1.
    simulation : mapping, optional
        ``[simulation]`` table (``duration_s`` in s, ``x0``, ``input`` as from :func:`signal_table`).
    detector : mapping, optional
        ``[detector]`` table, as for :func:`write_model_toml`.
    comment : str
        Text written as ``#`` comment lines at the top of the file.

    Returns
    -------
    Path
        The file written; :func:`~chatterspec.plants.modelfile.load_model` reads back the same
        transition (the same numbers), ``C``, ``Q``, ``R`` and ``dt``.

    Raises
    ------
    ModelFileError
        If the model's functions are not named functions of a module.
    """
    path = Path(path)
    f, jac, inp, form, params = _function_refs(model)
    lines = [f"# {line}".rstrip() for line in comment.splitlines()]
    lines += [f"name = {_toml_strings([model.name])[1:-1]}", f"dt = {_toml_number(model.dt)}  # s", ""]
    lines += ["[channels]", f"outputs = {_toml_strings(model.output_names)}"]
    if any(model.output_units):
        lines.append(f"units = {_toml_strings(model.output_units)}")
    lines += [f"inputs = {_toml_strings(model.input_names)}", f"states = {_toml_strings(model.state_names)}"]
    lines += ["", "[dynamics]", f'form = "{form}"', f"f = {_toml_value(f)}", f"jacobian = {_toml_value(jac)}"]
    if inp is not None:
        lines.append(f"input_jacobian = {_toml_value(inp)}")
    if model.oscillatory_states is not None:
        lines.append(f"oscillatory_states = [{', '.join(str(i) for i in model.oscillatory_states)}]")
    if np.any(model.rest_state):
        lines.append(f"rest_state = {_toml_vector(model.rest_state)}")
    if params:
        lines += ["", "[dynamics.parameters]", *(f"{k} = {_toml_number(v)}" for k, v in params.items())]
    lines += _matrices_and_svsf(model, (), (f"gamma = {_toml_number(gamma)}",))
    if simulation:
        lines += ["", toml_table("simulation", simulation)]
    if detector:
        lines += ["", "[detector]", *(f"{k} = {_toml_value(v)}" for k, v in detector.items())]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


# Reading a model file.


# --------------------------------------------------------------------------- model files
def load_model(path: str | os.PathLike[str]) -> ModelSpec:
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
        return load_nonlinear(doc, path, where)
    channels = read_channels(doc, where)
    dt, outputs, inputs, units, states = channels
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
        A, B = discretize(A, B, dt, cast(Discretization, method))  # one of the two (checked above)
    pmap = model_file_parameter_map(doc, where, form, method)  # fault identification (optional)
    try:
        model = LinearModel(
            A=A,
            B=B,
            C=C,
            Q=Q,
            R=R,
            dt=dt,
            **channels.model_names(),
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
    return ModelSpec(
        model=model,
        psi=psi,
        gamma=gamma,
        detector=detector_table(doc, model.dt, where),
        path=path,
        simulation=parse_simulation(doc, model, where),
        commissioning=provenance_table(doc, where),
    )
