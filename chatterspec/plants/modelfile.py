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
:mod:`chatterspec.plants.modelfile_writer`, the data-file reader :mod:`chatterspec.plants.datafile`.

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

import os
import tomllib
import warnings
from pathlib import Path
from typing import cast

import numpy as np

from ..errors import ChatterspecError, ModelFileError, UnstableModelWarning
from .linear_model import Discretization
from .modelfile_fields import (
    ModelSpec,
    _array,
    _covariance,
    _expect_shape,
    _matrix,
    _table,
    detector_table,
    provenance_table,
    read_channels,
    svsf_gamma,
)
from .modelfile_nonlinear import load_nonlinear, parse_simulation
from .models import LinearModel, discretize
from .parameters import model_file_parameter_map

__all__ = ["ModelSpec", "load_model"]


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
