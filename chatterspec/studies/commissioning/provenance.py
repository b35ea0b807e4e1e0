"""Where a commissioned model came from: the recording's hash, and the fitted model file.

:func:`read_recording` reads a data file or standard input (CSV read to its end) with
:func:`~chatterspec.plants.datafile.load_data`'s checks and the SHA-256 of the bytes read;
:func:`write_model_file` writes the fitted model as a model file (the writer of
:mod:`chatterspec.plants.modelfile`) with a ``[commissioning]`` table of provenance, atomically:
the file is written beside its target under a temporary name, read back with
:func:`~chatterspec.plants.modelfile.load_model`, and only then renamed over the target, so a failure
at any point leaves the target as it was and no partial file behind.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import CommissioningError, DataFileError

__all__ = ["DataSource", "file_sha256", "provenance_tables", "read_recording", "write_model_file"]


@dataclass(frozen=True)
class DataSource:
    """A recording's origin, as the fitted model file records it.

    Attributes
    ----------
    name : str
        The data file as given (``"-"``: standard input).
    sha256 : str
        SHA-256 (hex) of the bytes read.
    n_bytes : int
        Bytes read.
    """

    name: str
    sha256: str
    n_bytes: int


def file_sha256(path: str | Path) -> tuple[str, int]:
    """``(hex SHA-256, bytes)`` of a file, read in 1 MiB blocks.

    Parameters
    ----------
    path : str or Path
    """
    h, n = hashlib.sha256(), 0
    with open(path, "rb") as fh:
        while block := fh.read(1 << 20):
            h.update(block)
            n += len(block)
    return h.hexdigest(), n


def read_recording(path: str | Path, model: Any) -> tuple[Any, DataSource]:
    """A data file (CSV or NPZ) or standard input (``"-"``: CSV rows, header first, read to the end).

    Parameters
    ----------
    path : str or Path
        The data file, or ``"-"``.
    model : LinearModel
        Gives the columns (outputs and inputs by name) and ``dt``
        (:func:`~chatterspec.plants.datafile.load_data`).

    Returns
    -------
    (DataSet, DataSource)

    Raises
    ------
    DataFileError
        What :func:`~chatterspec.plants.datafile.load_data` refuses (missing columns, another rate,
        NaN/inf, unreadable bytes), naming the file (or standard input) and the column.
    """
    from ...plants.datafile import load_data, load_data_text

    if str(path) == "-":
        raw = sys.stdin.buffer.read()
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise DataFileError(f"data on standard input: not UTF-8 text ({exc})") from None
        return load_data_text(text, model), DataSource("-", hashlib.sha256(raw).hexdigest(), len(raw))
    data = load_data(path, model)
    digest, n = file_sha256(path)
    return data, DataSource(str(path), digest, n)


def _finite(values: Any) -> Any:
    """Floats as they are, ``"inf"`` / ``"-inf"`` for infinities (TOML model files hold finite numbers)."""
    if isinstance(values, (list, tuple, np.ndarray)):
        return [_finite(v) for v in (values.tolist() if isinstance(values, np.ndarray) else values)]
    if isinstance(values, float) and not np.isfinite(values):
        return "inf" if values > 0 else "-inf" if values < 0 else "nan"
    return values


def provenance_tables(result: Any, *, forced: bool = False) -> dict[str, dict[str, Any]]:
    """The ``[commissioning]`` table and its sub-tables for ``result`` (a Commissioning).

    Parameters
    ----------
    result : Commissioning
    forced : bool
        Whether the file is written although the held-out check failed.
    """
    from ... import __version__

    nominal = result.nominal
    top: dict[str, Any] = {"chatterspec_version": __version__, "method": result.METHOD}
    if nominal.path is not None and Path(nominal.path).is_file():
        top["nominal_model"] = str(nominal.path)
        top["nominal_sha256"] = file_sha256(nominal.path)[0]
    if result.source is not None:
        top.update(
            data=result.source.name, data_sha256=result.source.sha256, data_bytes=result.source.n_bytes
        )
    top["fit_span_s"] = list(result.fit_span_s)
    if result.check_span_s is not None:
        top["check_span_s"] = list(result.check_span_s)
    top.update(confidence=result.confidence, passes=result.passes)
    tables: dict[str, dict[str, Any]] = {"commissioning": top}
    if result.parameters is not None:
        pf = result.parameters
        tables["commissioning.parameters"] = {
            p.name: {k: v for k, v in p.to_dict().items() if k not in ("name", "confidence")}
            for p in pf.parameters
        }
        top.update(map_statistic=pf.statistic, map_dof=pf.dof, map_p_value=pf.p_value)
    nf = result.noise
    noise: dict[str, Any] = {}
    for key, label in (("r", "R"), ("q", "Q")):
        noise[f"{label}_diag"] = getattr(nf, key)
        for suffix in ("nominal", "std_error", "ci_low", "ci_high", "identified"):
            noise[f"{label}_{suffix}"] = getattr(nf, f"{key}_{suffix}")
    noise.update(statistic=nf.statistic, dof=nf.dof, p_value=nf.p_value, n_samples=nf.n_samples)
    tables["commissioning.noise"] = {k: _finite(v) for k, v in noise.items()}
    tables["commissioning.psi"] = {"psi": result.psi, "sigmas": result.PSI_SIGMAS}
    if result.check is not None:
        ch = result.check
        tables["commissioning.check"] = {
            "adequate": ch.adequate,
            "forced": bool(forced),
            "alpha": ch.alpha,
            "whiteness": [c.whiteness for c in ch.channels],
            "lags": ch.channels[0].lags,
            "whiteness_p": [c.whiteness_p for c in ch.channels],
            "spectrum_peak_ratio": [c.peak_ratio for c in ch.channels],
            "segments": ch.segments,
            "rule": ch.rule,
            "false_alarms_per_hour": ch.false_alarms_per_hour,
            "alarm_starts": ch.alarm_starts,
            "hours": ch.hours,
            "failures": ch.failures(),
        }
    return {name: {k: _finite(v) for k, v in t.items()} for name, t in tables.items()}


def _simulation_table(nominal: Any) -> Mapping[str, Any] | None:
    """The nominal file's own ``[simulation]`` table, as written (None without one)."""
    import tomllib

    path = nominal.path
    if nominal.simulation is None or path is None or not Path(path).is_file():
        return None
    with open(path, "rb") as fh:
        return tomllib.load(fh).get("simulation")


def write_model_file(result: Any, path: str | Path, *, force: bool = False) -> Path:
    """Write ``result``'s fitted model as a model file with its provenance, atomically (module docstring).

    Parameters
    ----------
    result : Commissioning
    path : str or Path
        The model file to write (an existing one is replaced only once the new one is complete).
    force : bool
        Write even when the held-out check failed (the ``[commissioning.check]`` table says so).

    Raises
    ------
    CommissioningError
        The held-out check failed and ``force`` is False: nothing is written.
    """
    from ...plants.modelfile import load_model, write_model_toml

    check = result.check
    if check is not None and not check.adequate and not force:
        raise CommissioningError(
            "the fitted model is not adequate on the held-out data ("
            + "; ".join(check.failures())
            + f"): nothing written to {str(path)!r} (force=True, `--force`, writes it anyway)"
        )
    path = Path(path)
    tables = {}
    sim = _simulation_table(result.nominal)
    if sim is not None:
        tables["simulation"] = sim
    tables.update(provenance_tables(result, forced=check is not None and not check.adequate))
    source = result.source.name if result.source is not None else "data given in Python"
    comment = (
        f"Commissioned by chatterspec from {source} on the nominal model {result.nominal.path}:\n"
        "physical parameters, Q, R and psi fitted; what was fitted from what is in [commissioning]."
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write_model_toml(
            tmp, result.model, result.psi, gamma=result.gamma, detector=result.detector,
            comment=comment, tables=tables,
        )  # fmt: skip
        load_model(tmp)  # reads back (and checks the parameter map against A and B) before it replaces path
        mask = os.umask(0)
        os.umask(mask)
        os.chmod(tmp, 0o666 & ~mask)  # mkstemp's file is private; the model file gets the usual mode
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path
