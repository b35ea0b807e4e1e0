"""What a model file holds, :class:`ModelSpec`, and the readers of its TOML fields.

The field readers (tables, scalars, names, matrices, covariances, the ``[svsf]`` gamma and the
``[detector]`` table) are shared by the linear loader (:mod:`chatterspec.plants.modelfile`), the
nonlinear one (:mod:`~chatterspec.plants.modelfile_nonlinear`) and the writer
(:mod:`~chatterspec.plants.modelfile_writer`); every error names the file and the field.
:class:`ModelSpec` is re-exported by :mod:`chatterspec.plants.modelfile`, its documented home.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from .._validate import check_band
from ..errors import ChatterspecError, ModelFileError
from .models import LinearModel

if TYPE_CHECKING:  # pragma: no cover
    from .linear_model import ChannelLabels
    from .modelfile_nonlinear import SimulationSpec
    from .nonlinear import NonlinearModel


__all__ = ["Channels", "ModelSpec", "detector_table", "provenance_table", "read_channels", "svsf_gamma"]


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
    from .model_base import check_covariance

    try:
        check_covariance(key, M)
    except ChatterspecError as exc:
        raise ModelFileError(f"{where}: [matrices] {exc} (a covariance)") from None
    return M
