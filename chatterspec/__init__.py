"""chatterspec: fault detection from the spectral content of SVSF chattering.

The numeric core (models, scenarios, simulation, filters, spectra,
thresholds, detection) imports only numpy and scipy. Plotting
(:mod:`chatterspec.figures.plotting`) and the Rerun viewer (:mod:`chatterspec.online`)
are imported on demand.
"""

from .errors import (
    CalibrationMismatchError,
    ChatterspecError,
    DataFileError,
    ModelFileError,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SingularMatrixError,
    UnknownScenarioError,
)
from .filters.svsf import SVSF, auxiliary_svsf, boundary_layer_chattering, chattering
from .plants.models import LinearModel, discretize, eha_linear, second_order
from .plants.scenarios import Scenario, Segment, catalogue, scenario, scenario_names
from .plants.signals import Chirp, Constant, SquareWave, Step
from .plants.simulate import Simulation, iter_simulations, simulate

__version__ = "0.1.0"

__all__ = [
    "SVSF",
    "CalibrationMismatchError",
    "ChatterspecError",
    "Chirp",
    "Constant",
    "DataFileError",
    "LinearModel",
    "ModelFileError",
    "NonFiniteError",
    "ParameterError",
    "Scenario",
    "Segment",
    "ShapeError",
    "Simulation",
    "SingularMatrixError",
    "SquareWave",
    "Step",
    "UnknownScenarioError",
    "__version__",
    "auxiliary_svsf",
    "boundary_layer_chattering",
    "catalogue",
    "chattering",
    "discretize",
    "eha_linear",
    "iter_simulations",
    "scenario",
    "scenario_names",
    "second_order",
    "simulate",
]
