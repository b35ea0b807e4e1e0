"""Write a :class:`~chatterspec.plants.models.LinearModel` as a TOML model file that reads back exactly."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import ModelFileError
from .modelfile_fields import _DETECTOR_KEYS, _detector_band
from .models import LinearModel
from .nonlinear import Model

if TYPE_CHECKING:  # pragma: no cover
    from .nonlinear import NonlinearModel
    from .signals import Signal

__all__ = ["signal_table", "toml_table", "write_model_toml", "write_nonlinear_model_toml"]


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
    from .euler import EulerJacobian, EulerStep
    from .modelfile_nonlinear import ModelFunction

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
