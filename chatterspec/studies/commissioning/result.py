"""The result of a commissioning, :class:`Commissioning`: the fitted model, how it was fitted, its check."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ...plants.models import LinearModel
from .adequacy import AdequacyCheck
from .noise_fit import NoiseFit
from .parameter_fit import ParameterFit
from .provenance import DataSource

__all__ = ["PSI_SIGMAS", "Commissioning"]

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
        from .report import report_text

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
        from .provenance import write_model_file

        return write_model_file(self, path, force=force)
