"""Exception types raised by chatterspec.

Every error is a subclass of :class:`ChatterspecError` (itself a
:class:`ValueError`), so ``except ValueError`` keeps working for callers that
do not care about the detail, while tests and applications can catch the
specific problem.
"""

from __future__ import annotations

__all__ = [
    "CalibrationMismatchError",
    "ChatterspecError",
    "CommissioningError",
    "DataFileError",
    "DivergenceError",
    "IdentifiabilityError",
    "ModelFileError",
    "ModelKindError",
    "NonFiniteError",
    "ParameterError",
    "ShapeError",
    "SingularMatrixError",
    "UnknownScenarioError",
    "UnstableLoopError",
    "UnstableModelWarning",
    "ViewerUnavailableError",
]


class ChatterspecError(ValueError):
    """Base class of every chatterspec error."""


class ShapeError(ChatterspecError):
    """An array has the wrong number of dimensions or the wrong size."""


class NonFiniteError(ChatterspecError):
    """An array holds NaN or infinite values where finite numbers are required."""


class DivergenceError(NonFiniteError):
    """A filter's estimate stopped being finite (diverging model, or f(x, u) returned NaN/inf); the
    message names the first non-finite sample and realization."""


class SingularMatrixError(ChatterspecError):
    """A matrix that must be inverted (e.g. C for the full-measurement SVSF) is singular."""


class ParameterError(ChatterspecError):
    """A scalar parameter is out of its admissible range (psi <= 0, gamma outside (0, 1), ...)."""


class UnknownScenarioError(ChatterspecError, KeyError):
    """A scenario name is not in the catalogue; the message lists the valid names."""

    def __str__(self) -> str:  # KeyError would repr() the message
        return str(self.args[0]) if self.args else ""


class ModelFileError(ChatterspecError):
    """A model file (TOML) cannot be read or describes an invalid model."""


class DataFileError(ChatterspecError):
    """A measurement data file (CSV/NPZ) cannot be read or is inconsistent."""


class CalibrationMismatchError(ChatterspecError):
    """A saved calibration does not belong to the model/settings it is applied to."""


class UnstableModelWarning(UserWarning):
    """The nominal model has eigenvalues outside the unit circle."""


class ModelKindError(ParameterError):
    """A code path that needs a linear model (A, B) was handed a nonlinear one, or vice versa."""


class IdentifiabilityError(ParameterError):
    """A physical parameter cannot be identified from this model's chattering (reduced-order
    measurement, a nonlinear model, no declared parameters, or parameters that cannot be told apart)."""


class ViewerUnavailableError(ChatterspecError):
    """The Rerun viewer cannot be started here (not installed, no display) or ended with an error."""


class CommissioningError(ChatterspecError):
    """Commissioning cannot give a trustworthy model from this recording: a fitted noise covariance that
    the data make negative (coloured noise, a disturbance the model lacks), or a fitted model that fails
    its held-out check (then nothing is written unless forced). The message says which channel and why."""


class UnstableLoopError(ParameterError):
    """A controller's gains make the closed loop unstable; the message gives each gain's stable range."""
