"""The mode-weighted mixture of a multiple-model bank's estimates (one function, no state).

Kept apart from the banks (:mod:`chatterspec.filters.smm_svsf`, :mod:`chatterspec.filters.imm`) so
that the filters' conventions (:mod:`chatterspec.filters._conventions`, the banks' per-mode start)
use it without an import circle.
"""

from __future__ import annotations

from typing import overload

import numpy as np

__all__ = ["combine"]


@overload
def combine(mu: np.ndarray, xs: np.ndarray, Ps: None = None) -> tuple[np.ndarray, None]: ...
@overload
def combine(mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def combine(
    mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]: ...


def combine(
    mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Mode-weighted estimate and covariance ([SMM] eq 3.4-3.5, [IMM] eq 31-33 with the factor 1/2).

    ``x = sum_j mu_j x_j``, ``P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]``.

    Parameters
    ----------
    mu : (..., r) array
        Mode probabilities.
    xs : (..., r, n) array
        Mode-conditioned estimates.
    Ps : (..., r, n, n) array, optional
        Mode-conditioned covariances (None: return ``P = None``).

    Returns
    -------
    (x (..., n), P (..., n, n) or None)
    """
    x = np.einsum("...j,...jn->...n", mu, xs)
    if Ps is None:
        return x, None
    d = xs - x[..., None, :]
    P = np.einsum("...j,...jab->...ab", mu, Ps + d[..., :, None] * d[..., None, :])
    return x, P
