"""State estimators.

``svsf`` holds the SVSF of eq 4-12 and its auxiliary sgn variant. ``protocol`` defines the
one interface of the covariance-carrying filters (state, per-sample output, ``initialize /
update / run``); ``kalman`` (KF, EKF), ``svsf_cov`` (SVSF with covariance, [SMM] eq 2.1-2.10)
and ``svsf2`` (dynamic second-order SVSF, [DETC] eq 5-24) implement it; ``multiple_model``
builds SMM-SVSF ([SMM] eq 3.1-3.5) and IMM ([IMM] eq 15-33) banks from them.
"""

from .kalman import ExtendedKalmanFilter, KalmanFilter
from .multiple_model import IMM, SMMSVSF
from .protocol import Filter, FilterOutput, FilterState
from .svsf import SVSF, SVSFOutput, SVSFState, auxiliary_svsf, boundary_layer_chattering, chattering
from .svsf2 import SecondOrderSVSF
from .svsf_cov import SVSFCov

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
