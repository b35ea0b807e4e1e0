"""Nonlinear model files: a TOML that names the Python functions of ``f`` and its Jacobian.

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
"""

from __future__ import annotations

import hashlib
import importlib
import inspect
import re
import sys
import types
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ChatterspecError, ModelFileError
from .modelfile_fields import (
    ModelSpec,
    _array,
    _covariance,
    _matrix,
    _scalar,
    _table,
    detector_table,
    read_channels,
    svsf_gamma,
)

if TYPE_CHECKING:  # pragma: no cover
    from .nonlinear import Model
    from .scenario_types import Scenario
    from .signals import Signal

__all__ = [
    "MeasurementFunction",
    "ModelFunction",
    "SimulationSpec",
    "file_scenario",
    "load_nonlinear",
    "parse_simulation",
]

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
