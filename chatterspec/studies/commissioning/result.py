"""The result of a commissioning, :class:`Commissioning`, with its provenance, its file and its report.

In order: where a commissioned model came from (the recording's hash, :func:`read_recording`) and the
fitted model file (:func:`write_model_file`), the text report (:func:`report_text`), and the result
itself (:class:`Commissioning`).

Provenance: where a commissioned model came from: the recording's hash, and the fitted model file.

:func:`read_recording` reads a data file or standard input (CSV read to its end) with
:func:`~chatterspec.plants.datafile.load_data`'s checks and the SHA-256 of the bytes read;
:func:`write_model_file` writes the fitted model as a model file (the writer of
:mod:`chatterspec.plants.modelfile`) with a ``[commissioning]`` table of provenance, atomically:
the file is written beside its target under a temporary name, read back with
:func:`~chatterspec.plants.modelfile.load_model`, and only then renamed over the target, so a failure
at any point leaves the target as it was and no partial file behind.

The text report of a commissioning: what was fitted, with intervals, and the held-out verdict.

The result of a commissioning, :class:`Commissioning`: the fitted model, how it was fitted, its check.
"""

from __future__ import annotations

import hashlib
import os
import sys
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ...detection.identification import format_with_error
from ...errors import CommissioningError, DataFileError
from ...plants.models import LinearModel
from .adequacy import AdequacyCheck
from .fits import NoiseFit, ParameterFit

__all__ = [
    "PSI_SIGMAS",
    "Commissioning",
    "DataSource",
    "file_sha256",
    "provenance_tables",
    "read_recording",
    "report_text",
    "write_model_file",
]


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


def _g(x: float) -> str:
    return f"{x:.5g}"


def _head(res: Any) -> list[str]:
    src = res.source
    what = "" if src is None else f" from {'standard input' if src.name == '-' else src.name}"
    dur = res.fit_span_s[1] - res.fit_span_s[0]
    lines = [f"commissioning {res.nominal.path}{what}"]
    if src is not None:
        lines.append(f"  data sha256 {src.sha256} ({src.n_bytes} bytes)")
    span = f"  fit on {res.fit_span_s[0]:.3f}-{res.fit_span_s[1]:.3f} s ({dur:.4g} s)"
    if res.check_span_s is not None:
        span += f", held-out check on {res.check_span_s[0]:.3f}-{res.check_span_s[1]:.3f} s"
    return [*lines, span]


def _parameters(res: Any) -> list[str]:
    pf = res.parameters
    if pf is None:
        return ["", "no physical parameters declared: A and B kept as given (only Q, R and psi fitted)"]
    pct = f"{res.confidence:.0%}"
    lines = [
        "",
        f"physical parameters (fitted jointly; {pct} intervals)",
        f"{'parameter':<16} {'nominal':>11} {'fitted':>14} {pct + ' interval':>30}  {'unit':<12} "
        f"{'change':>8}",
    ]
    for p in pf.parameters:
        ci = f"[{format_with_error(p.ci_low, p.std_error)}, {format_with_error(p.ci_high, p.std_error)}]"
        change = f"{100 * p.relative_change:+.2f} %" if np.isfinite(p.relative_change) else "-"
        lines.append(
            f"{p.name:<16} {p.nominal:>11.4g} {format_with_error(p.estimate, p.std_error):>14} {ci:>30}  "
            f"{p.unit:<12} {change:>8}"
        )
    explained = "explain" if pf.p_value > res.options["alpha"] else "do NOT explain"
    lines.append(
        f"(the declared parameters {explained} the estimated entries: chi2 {pf.statistic:.3g} on {pf.dof} "
        f"dof, p = {pf.p_value:.2g}; {res.passes} pass{'es' if res.passes > 1 else ''})"
    )
    return lines


def _covariance_cell(value: float, lo: float, hi: float, identified: bool, nominal: float) -> str:
    if identified:
        return f"{_g(value):>11} [{_g(lo)}, {_g(hi)}]"
    kept = "nominal kept" if value == nominal else "set to the bound"
    bound = f"<= {_g(hi)}" if np.isfinite(hi) else "unbounded"
    return f"{_g(value):>11} {bound} (not identified: {kept})"


def _noise(res: Any) -> list[str]:
    nf, model = res.noise, res.model
    pct = f"{res.confidence:.0%}"
    lines = ["", f"noise covariances (diagonals; {pct} intervals, or the bound the data give)"]
    lines.append(
        f"{'channel':<12} {'R nominal':>10} {'R fitted':>11} {'':<26} {'Q nominal':>10} {'Q fitted':>11}"
    )
    for c, name in enumerate(model.output_names):
        r = _covariance_cell(nf.r[c], nf.r_ci_low[c], nf.r_ci_high[c], nf.r_identified[c], nf.r_nominal[c])
        q = _covariance_cell(nf.q[c], nf.q_ci_low[c], nf.q_ci_high[c], nf.q_identified[c], nf.q_nominal[c])
        lines.append(f"{name:<12} {_g(nf.r_nominal[c]):>10} {r:<38} {_g(nf.q_nominal[c]):>10} {q}")
    lines.append(
        f"(autocovariances at lags 0 and 1 fitted: chi2 {nf.statistic:.3g} on {nf.dof} dof, "
        f"p = {nf.p_value:.2g})"
    )
    psi = ", ".join(f"{n} {_g(v)}" for n, v in zip(model.output_names, res.psi, strict=True))
    lines.append(f"psi ({res.PSI_SIGMAS:g} x the fitted chattering std): {psi}")
    return lines


def _check(res: Any) -> list[str]:
    ch = res.check
    if ch is None:
        return ["", "no held-out check (the whole recording was used for the fit)"]
    lines = [
        "",
        f"held-out check ({ch.span_s[0]:.1f}-{ch.span_s[1]:.1f} s; at most {ch.alpha:g} to fail on a "
        "plant the model describes)",
        f"{'channel':<12} {'whiteness (lags 2-' + str(ch.channels[0].lags + 1) + ')':<34} "
        f"{'spectrum (' + str(ch.segments) + ' x ' + _g(ch.segment_s) + ' s averaged)':<44} alarm starts",
    ]
    for c in ch.channels:
        white = f"{c.whiteness:.4g}, p = {c.whiteness_p:.2g} {'ok' if c.white else 'CORRELATED'}"
        where = ", ".join(f"{lo:.4g}-{hi:.4g} Hz" for lo, hi in c.bands_hz)
        spec = f"{c.peak_ratio:.3g} x threshold at {c.peak_hz:.4g} Hz " + (
            "ok" if c.spectrum_ok else f"OVER {where}"
        )
        times = "" if not c.alarm_starts else f" (at {', '.join(f'{t:.2f}' for t in c.alarm_times_s)} s)"
        lines.append(f"{c.channel:<12} {white:<34} {spec:<44} {c.alarm_starts}{times}")
    per = 1.0 / ch.false_alarms_per_hour
    lines.append(
        f"alarms ({ch.rule} rule, 1 false alarm per {per:.3g} h): {ch.alarm_starts} start(s) in "
        f"{ch.hours:.3g} h (expected {ch.expected_starts:.2g}; 95 % interval of the rate "
        f"{_g(ch.rate_interval[0])}-{_g(ch.rate_interval[1])} per hour)"
    )
    if ch.adequate:
        lines.append("verdict: ADEQUATE")
    else:
        lines.append("verdict: NOT ADEQUATE")
        lines += [f"  - {f}" for f in ch.failures()]
    return lines


def report_text(res: Any) -> str:
    """The report of a :class:`~chatterspec.studies.commissioning.result.Commissioning` as plain text.

    Parameters
    ----------
    res : Commissioning
    """
    return "\n".join(_head(res) + _parameters(res) + _noise(res) + _check(res))


#: The boundary layer is this many standard deviations of the healthy chattering per output (eq 58;
#: what ``chatterspec scenarios NAME --model-toml`` and ``examples/eha_model.toml`` use).
PSI_SIGMAS = 3.0


@dataclass(frozen=True, eq=False)
class Commissioning:
    """A model fitted to a plant's healthy recording, and its check on held-out data.

    Attributes
    ----------
    nominal : ModelSpec
        The nominal model file (or the spec built for a model given in Python).
    model : LinearModel
        The fitted model: parameters replaced by their estimates, A and B recomputed from the
        parameter map, Q and R diagonal as fitted.
    psi : (m,) array
        The fitted boundary layer (``PSI_SIGMAS`` x the fitted chattering's standard deviation, eq 58).
    gamma : float
        The nominal file's SVSF rate (kept).
    detector : dict
        The nominal file's ``[detector]`` table (kept).
    parameters : ParameterFit or None
        The joint fit of the declared parameters (None when the model declares none).
    noise : NoiseFit
        The fit of diag(Q) and diag(R).
    passes : int
        Identifications run: 2 when the fitted noise moved the first one's weights.
    fit_span_s : (float, float)
        Times (s) of the fit span's first sample and one past its last.
    check_span_s : (float, float) or None
        The same for the held-out span (None without a check).
    check : AdequacyCheck or None
        The held-out check.
    source : DataSource or None
        The recording's name and SHA-256.
    confidence : float
        Level of every interval.
    options : dict
        ``holdout``, ``alpha``, ``lags`` as used.
    """

    #: What the fit does, in one line (recorded in the model file).
    METHOD: ClassVar[str] = (
        "joint instrumental-variables fit of every declared parameter (eq 23), diagonal Q and R from the "
        "chattering's lag-0 and lag-1 autocovariances (MA(1) law, eq 23/56), psi = 3 x chattering std"
    )
    #: psi in standard deviations of the chattering (:data:`PSI_SIGMAS`).
    PSI_SIGMAS: ClassVar[float] = PSI_SIGMAS

    nominal: Any
    model: LinearModel
    psi: np.ndarray
    gamma: float
    detector: dict[str, Any]
    parameters: ParameterFit | None
    noise: NoiseFit
    passes: int
    fit_span_s: tuple[float, float]
    check_span_s: tuple[float, float] | None
    check: AdequacyCheck | None
    source: DataSource | None
    confidence: float
    options: dict[str, Any] = field(default_factory=dict)

    def __repr__(self) -> str:
        fitted = (
            ""
            if self.parameters is None
            else ", ".join(f"{p.name}={p.estimate:.4g}" for p in self.parameters.parameters)
        )
        verdict = "unchecked" if self.check is None else "adequate" if self.check.adequate else "NOT adequate"
        return f"Commissioning({fitted}{', ' if fitted else ''}{verdict})"

    @property
    def adequate(self) -> bool | None:
        """The held-out verdict (None without a check)."""
        return None if self.check is None else self.check.adequate

    @property
    def spec(self) -> Any:
        """The fitted model as a :class:`~chatterspec.plants.modelfile.ModelSpec` (what :func:`load_model`
        gives for the written file, without its provenance): for a monitor without a file."""
        from ...plants.modelfile import ModelSpec

        nom = self.nominal
        return ModelSpec(self.model, self.psi, self.gamma, dict(self.detector), nom.path, nom.simulation)

    def estimate(self, name: str) -> float:
        """The fitted value of parameter ``name`` (its unit).

        Parameters
        ----------
        name : str
        """
        from ...errors import ParameterError

        for p in () if self.parameters is None else self.parameters.parameters:
            if p.name == name:
                return p.estimate
        raise ParameterError(f"no fitted parameter {name!r}")

    def table(self) -> str:
        """The plain-text report ``chatterspec commission`` prints."""
        return report_text(self)

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: spans, source, parameters, noise, psi, check, ``adequate``."""
        return {
            "nominal_model": str(self.nominal.path),
            "data": None if self.source is None else {"name": self.source.name, "sha256": self.source.sha256},
            "fit_span_s": list(self.fit_span_s),
            "check_span_s": None if self.check_span_s is None else list(self.check_span_s),
            "confidence": self.confidence,
            "passes": self.passes,
            "parameters": None
            if self.parameters is None
            else {
                "estimates": [p.to_dict() for p in self.parameters.parameters],
                "statistic": self.parameters.statistic,
                "dof": self.parameters.dof,
                "p_value": self.parameters.p_value,
                "worst_relative_se": self.parameters.worst_relative_se,
            },
            "noise": self.noise.to_dict(),
            "psi": [float(p) for p in self.psi],
            "check": None if self.check is None else self.check.to_dict(),
            "adequate": self.adequate,
            "options": dict(self.options),
        }

    def write(self, path: str | Path, *, force: bool = False) -> Path:
        """Write the fitted model file with its ``[commissioning]`` provenance, atomically.

        Parameters
        ----------
        path : str or Path
        force : bool
            Write even when the held-out check failed.

        Raises
        ------
        CommissioningError
            The check failed and ``force`` is False (nothing is written).
        """
        return write_model_file(self, path, force=force)
