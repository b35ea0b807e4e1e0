"""State estimators. ``svsf`` holds the SVSF of eq 4-12 and its auxiliary sgn variant."""

from .svsf import SVSF, SVSFOutput, SVSFState, auxiliary_svsf, boundary_layer_chattering, chattering

__all__ = [
    "SVSF",
    "SVSFOutput",
    "SVSFState",
    "auxiliary_svsf",
    "boundary_layer_chattering",
    "chattering",
]
