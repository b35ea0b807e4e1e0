"""chatterspec: fault detection from the spectral content of SVSF chattering.

The numeric core (models, scenarios, simulation, filters, spectra,
thresholds, detection) imports only numpy and scipy. Plotting
(:mod:`chatterspec.figures.plotting`) and the Rerun viewer (:mod:`chatterspec.online`)
are imported on demand.
"""

import importlib
from typing import TYPE_CHECKING, Any

from .errors import (
    CalibrationMismatchError,
    ChatterspecError,
    DataFileError,
    DivergenceError,
    ModelFileError,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SingularMatrixError,
    UnknownScenarioError,
)

# The numeric names load on first use (PEP 562), so that ``import chatterspec`` -- and with
# it every CLI command's argument and output-path checks -- does not wait for scipy.
_LAZY: dict[str, str] = {
    **dict.fromkeys(("SVSF", "auxiliary_svsf", "boundary_layer_chattering", "chattering"), ".filters.svsf"),
    **dict.fromkeys(("LinearModel", "discretize", "eha_linear", "second_order"), ".plants.models"),
    **dict.fromkeys(("Scenario", "Segment", "catalogue", "scenario", "scenario_names"), ".plants.scenarios"),
    **dict.fromkeys(("Chirp", "Constant", "SquareWave", "Step"), ".plants.signals"),
    **dict.fromkeys(("Simulation", "iter_simulations", "simulate"), ".plants.simulate"),
}

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .filters.svsf import SVSF, auxiliary_svsf, boundary_layer_chattering, chattering
    from .plants.models import LinearModel, discretize, eha_linear, second_order
    from .plants.scenarios import Scenario, Segment, catalogue, scenario, scenario_names
    from .plants.signals import Chirp, Constant, SquareWave, Step
    from .plants.simulate import Simulation, iter_simulations, simulate


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'chatterspec' has no attribute {name!r}")
    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))


__version__ = "0.1.0"

__all__ = [
    "SVSF",
    "CalibrationMismatchError",
    "ChatterspecError",
    "Chirp",
    "Constant",
    "DataFileError",
    "DivergenceError",
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
