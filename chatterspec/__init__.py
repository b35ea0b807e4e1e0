"""chatterspec: fault detection from the spectral content of SVSF chattering.

The numeric core (models, scenarios, simulation, filters, spectra,
thresholds, detection) imports only numpy and scipy. Plotting
(:mod:`chatterspec.figures.plotting`) and the Rerun viewer (:mod:`chatterspec.online`)
are imported on demand.
"""

from typing import TYPE_CHECKING

from . import _lazy
from .errors import (
    CalibrationMismatchError,
    ChatterspecError,
    CommissioningError,
    DataFileError,
    DivergenceError,
    IdentifiabilityError,
    ModelFileError,
    ModelKindError,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SingularMatrixError,
    UnknownScenarioError,
    UnstableLoopError,
    UnstableModelWarning,
    ViewerUnavailableError,
)

# THE PUBLIC API: every name a user reaches as ``chatterspec.NAME``, grouped by topic, in this one
# table (``docs/api.md`` lists them; ``tests/test_public_api.py`` checks that each resolves and has a
# numpydoc docstring documenting its parameters). The names load on first use (PEP 562), so that
# ``import chatterspec`` -- and with it every CLI command's argument and output-path checks -- does
# not wait for scipy or numba.
_GROUPS: dict[str, dict[str, str]] = {
    "models": {
        **dict.fromkeys(("LinearModel", "discretize", "eha_linear", "second_order"), ".plants.models"),
        "NonlinearModel": ".plants.nonlinear",
        "eha4": ".plants.eha4",
        "load_model": ".plants.modelfile",
        "write_model_toml": ".plants.modelfile",
        "load_data": ".plants.datafile",
    },
    "scenarios": {
        **dict.fromkeys(
            ("Scenario", "Segment", "catalogue", "scenario", "scenario_names"), ".plants.scenarios"
        ),
        **dict.fromkeys(("Chirp", "Constant", "SquareWave", "Step"), ".plants.signals"),
    },
    "simulation": {
        **dict.fromkeys(("Simulation", "iter_simulations", "simulate"), ".plants.simulate"),
    },
    "filters": {
        **dict.fromkeys(("KalmanFilter", "ExtendedKalmanFilter"), ".filters.kalman"),
        "SVSFCov": ".filters.svsf_cov",
        "SecondOrderSVSF": ".filters.svsf2",
        "IMM": ".filters.imm",
        "SMMSVSF": ".filters.smm_svsf",
        "MultipleModelOutput": ".filters.bank",
        **dict.fromkeys(("FilterOutput", "FilterState"), ".filters.protocol"),
        **dict.fromkeys(("SVSF", "SVSFOutput", "auxiliary_svsf"), ".filters.svsf"),
    },
    "chattering": {
        **dict.fromkeys(("boundary_layer_chattering", "chattering"), ".filters.svsf"),
        **dict.fromkeys(("ChatteringRecord", "chattering_record"), ".detection.pipeline"),
        **dict.fromkeys(("periodogram", "spectrogram", "STFTConfig"), ".detection.spectral"),
    },
    "detection": {
        **dict.fromkeys(
            ("DetectionReport", "detect_chunks", "detect_record", "detect_scenario"), ".detection.detect"
        ),
        **dict.fromkeys(("Threshold", "threshold"), ".detection.thresholds"),
    },
    "calibration": {
        **dict.fromkeys(("Calibration", "load_calibration"), ".studies.calibration.result"),
        "calibrate": ".studies.calibration.thresholds",
        "calibrate_recorded": ".online.recorded_calibration",
    },
    "estimation": {
        **dict.fromkeys(("EstimationResult", "build_filter", "estimation_study"), ".studies.estimation"),
    },
    "diagnosis": {
        **dict.fromkeys(("ChatteringDiagnosis", "diagnose_chattering"), ".studies.diagnosis"),
        **dict.fromkeys(("ModeDiagnosis", "diagnose_modes"), ".studies.diagnosis"),
    },
    "identification": {
        **dict.fromkeys(
            ("Identification", "IdentificationReport", "identification_setup", "identify", "identify_record"),
            ".detection.identification",
        ),
        **dict.fromkeys(("Tolerance", "with_tolerances"), ".plants.parameters"),
        **dict.fromkeys(("ParameterDecisions", "parameter_alarm_settings"), ".detection.parameter_decision"),
        "monitor_parameters": ".detection.parameter_decision",
    },
    "commissioning": {
        **dict.fromkeys(("Commissioning", "commission"), ".studies.commissioning"),
    },
    "alarms": {
        **dict.fromkeys(
            ("CusumRule", "FrameRule", "PersistenceRule", "make_rule"), ".detection.alarms.rules"
        ),
        **dict.fromkeys(("AlarmEvent", "AlarmStream", "run_rule"), ".detection.alarms.streams"),
        **dict.fromkeys(("RuleCalibration", "calibrate_rule"), ".detection.alarms.calibration"),
        **dict.fromkeys(("FrameScore", "frame_scores"), ".detection.verdicts"),
        "calibrate_alarm": ".studies.alarm_budget",
        "diagnose_at_budget": ".studies.budget_diagnosis",
    },
    "output": {
        **dict.fromkeys(("dumps", "rounded"), ".jsonout"),
    },
}
_LAZY: dict[str, str] = {name: mod for group in _GROUPS.values() for name, mod in group.items()}

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .detection.alarms.calibration import RuleCalibration, calibrate_rule
    from .detection.alarms.rules import CusumRule, FrameRule, PersistenceRule, make_rule
    from .detection.alarms.streams import AlarmEvent, AlarmStream, run_rule
    from .detection.detect import DetectionReport, detect_chunks, detect_record, detect_scenario
    from .detection.identification import (
        Identification,
        IdentificationReport,
        identification_setup,
        identify,
        identify_record,
    )
    from .detection.parameter_decision import ParameterDecisions, monitor_parameters, parameter_alarm_settings
    from .detection.pipeline import ChatteringRecord, chattering_record
    from .detection.spectral import STFTConfig, periodogram, spectrogram
    from .detection.thresholds import Threshold, threshold
    from .detection.verdicts import FrameScore, frame_scores
    from .filters.bank import MultipleModelOutput
    from .filters.imm import IMM
    from .filters.kalman import ExtendedKalmanFilter, KalmanFilter
    from .filters.protocol import FilterOutput, FilterState
    from .filters.smm_svsf import SMMSVSF
    from .filters.svsf import SVSF, SVSFOutput, auxiliary_svsf, boundary_layer_chattering, chattering
    from .filters.svsf2 import SecondOrderSVSF
    from .filters.svsf_cov import SVSFCov
    from .jsonout import dumps, rounded
    from .online.recorded_calibration import calibrate_recorded
    from .plants.datafile import load_data
    from .plants.eha4 import eha4
    from .plants.modelfile import load_model, write_model_toml
    from .plants.models import LinearModel, discretize, eha_linear, second_order
    from .plants.nonlinear import NonlinearModel
    from .plants.parameters import Tolerance, with_tolerances
    from .plants.scenarios import Scenario, Segment, catalogue, scenario, scenario_names
    from .plants.signals import Chirp, Constant, SquareWave, Step
    from .plants.simulate import Simulation, iter_simulations, simulate
    from .studies.alarm_budget import calibrate_alarm
    from .studies.budget_diagnosis import diagnose_at_budget
    from .studies.calibration.result import Calibration, load_calibration
    from .studies.calibration.thresholds import calibrate
    from .studies.commissioning import Commissioning, commission
    from .studies.diagnosis import ChatteringDiagnosis, ModeDiagnosis, diagnose_chattering, diagnose_modes
    from .studies.estimation import EstimationResult, build_filter, estimation_study


__getattr__, __dir__ = _lazy.lazy_names(__name__, _LAZY)


__version__ = "0.1.0"

# The literal list (for linters); tests/test_public_api.py checks it equals the table above plus the errors.
__all__ = [
    "IMM",
    "SMMSVSF",
    "SVSF",
    "AlarmEvent",
    "AlarmStream",
    "Calibration",
    "CalibrationMismatchError",
    "ChatteringDiagnosis",
    "ChatteringRecord",
    "ChatterspecError",
    "Chirp",
    "Commissioning",
    "CommissioningError",
    "Constant",
    "CusumRule",
    "DataFileError",
    "DetectionReport",
    "DivergenceError",
    "EstimationResult",
    "ExtendedKalmanFilter",
    "FilterOutput",
    "FilterState",
    "FrameRule",
    "FrameScore",
    "IdentifiabilityError",
    "Identification",
    "IdentificationReport",
    "KalmanFilter",
    "LinearModel",
    "ModeDiagnosis",
    "ModelFileError",
    "ModelKindError",
    "MultipleModelOutput",
    "NonFiniteError",
    "NonlinearModel",
    "ParameterDecisions",
    "ParameterError",
    "PersistenceRule",
    "RuleCalibration",
    "STFTConfig",
    "SVSFCov",
    "SVSFOutput",
    "Scenario",
    "SecondOrderSVSF",
    "Segment",
    "ShapeError",
    "Simulation",
    "SingularMatrixError",
    "SquareWave",
    "Step",
    "Threshold",
    "Tolerance",
    "UnknownScenarioError",
    "UnstableLoopError",
    "UnstableModelWarning",
    "ViewerUnavailableError",
    "__version__",
    "auxiliary_svsf",
    "boundary_layer_chattering",
    "build_filter",
    "calibrate",
    "calibrate_alarm",
    "calibrate_recorded",
    "calibrate_rule",
    "catalogue",
    "chattering",
    "chattering_record",
    "commission",
    "detect_chunks",
    "detect_record",
    "detect_scenario",
    "diagnose_at_budget",
    "diagnose_chattering",
    "diagnose_modes",
    "discretize",
    "dumps",
    "eha4",
    "eha_linear",
    "estimation_study",
    "frame_scores",
    "identification_setup",
    "identify",
    "identify_record",
    "iter_simulations",
    "load_calibration",
    "load_data",
    "load_model",
    "make_rule",
    "monitor_parameters",
    "parameter_alarm_settings",
    "periodogram",
    "rounded",
    "run_rule",
    "scenario",
    "scenario_names",
    "second_order",
    "simulate",
    "spectrogram",
    "threshold",
    "with_tolerances",
    "write_model_toml",
]
