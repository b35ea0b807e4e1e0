"""State estimators.

``svsf`` holds the SVSF of eq 4-12 and its auxiliary sgn variant (with its coordinates, the
nonlinear nominal model's auxiliary filter and the healthy chattering variance); ``svsf_recursion``
its per-sample steps, compiled loops, state and update paths. ``protocol`` defines the one interface
of the covariance-carrying filters (state, per-sample output, ``initialize / update / run``) and the
conventions every filter shares; ``kalman`` (KF, EKF), ``svsf_cov`` (SVSF
with covariance, [SMM] eq 2.1-2.10) and ``svsf2`` (dynamic second-order SVSF, [DETC] eq 5-24)
implement it; ``smm_svsf`` (SMM-SVSF, [SMM] eq 3.1-3.5) and ``imm`` (IMM, [IMM] eq 15-33) build
banks from them (``bank`` holds what they share).
"""

from typing import TYPE_CHECKING

from .. import _lazy

# The names load on first use (PEP 562): importing one filter module (e.g. the online monitor's
# ``filters.svsf``) does not import the Kalman family and the multiple-model banks.
_LAZY: dict[str, str] = {
    **dict.fromkeys(("ExtendedKalmanFilter", "KalmanFilter"), ".kalman"),
    "IMM": ".imm",
    "SMMSVSF": ".smm_svsf",
    **dict.fromkeys(("Filter", "FilterOutput", "FilterState"), ".protocol"),
    **dict.fromkeys(
        ("SVSF", "SVSFOutput", "SVSFState", "auxiliary_svsf", "boundary_layer_chattering", "chattering"),
        ".svsf",
    ),
    "SecondOrderSVSF": ".svsf2",
    "SVSFCov": ".svsf_cov",
}

if TYPE_CHECKING:  # pragma: no cover - for type checkers and IDEs only
    from .imm import IMM
    from .kalman import ExtendedKalmanFilter, KalmanFilter
    from .protocol import Filter, FilterOutput, FilterState
    from .smm_svsf import SMMSVSF
    from .svsf import SVSF, SVSFOutput, SVSFState, auxiliary_svsf, boundary_layer_chattering, chattering
    from .svsf2 import SecondOrderSVSF
    from .svsf_cov import SVSFCov


__getattr__, __dir__ = _lazy.lazy_names(__name__, _LAZY)


__all__ = [
    "IMM",
    "SMMSVSF",
    "SVSF",
    "ExtendedKalmanFilter",
    "Filter",
    "FilterOutput",
    "FilterState",
    "KalmanFilter",
    "SVSFCov",
    "SVSFOutput",
    "SVSFState",
    "SecondOrderSVSF",
    "auxiliary_svsf",
    "boundary_layer_chattering",
    "chattering",
]
