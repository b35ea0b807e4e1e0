"""The arithmetic of the multiple-model banks: mode likelihoods, normalized weights, the spread term.

Shared by SMM-SVSF ([SMM] eq 3.1-3.3) and IMM ([IMM] eq 29-33); see
:mod:`chatterspec.filters.smm_svsf` and :mod:`chatterspec.filters.imm` for the banks and the corrections
to the printed equations.

Likelihoods (:func:`log_gaussian`) use the correlation-scaled ``S`` with eigenvalues floored at
:data:`EIG_FLOOR` (the EHA states span about 20 decades, ``docs/design.md`` S3), so a near-singular
``S`` gives a finite, conservative likelihood instead of NaN. The compiled banks use the same
formulas per run (:mod:`chatterspec.filters._bank_steps`).

See Also
--------
chatterspec.filters.mixture.combine : the mixture's mean and covariance ([SMM] steps 4a-5, [IMM] eq 31-33).
"""

from __future__ import annotations

import numpy as np

from ..errors import SingularMatrixError
from ._engine import LOG2PI

__all__ = ["EIG_FLOOR", "LOG2PI", "log_gaussian", "normalize_log_weights", "pairwise_spread"]

#: Eigenvalue floor of the correlation-scaled innovation covariance (``docs/design.md`` S3).
EIG_FLOOR = 1e-12


def log_gaussian(e: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``log N(e; 0, S)`` over leading axes, robust to badly scaled ``S`` ([SMM] eq 3.2-3.3 vector form).

    ``S`` is scaled to its correlation matrix ``D^-1 S D^-1`` (``D = sqrt(diag S)``), whose eigenvalues
    are floored at 1e-12 ([IMM] eq 29 with ``sqrt(det(2 pi S))``, ``docs/design.md`` I3).

    Parameters
    ----------
    e : (..., m) array
        Innovations (output units).
    S : (..., m, m) array
        Innovation covariances (broadcast against ``e``), positive diagonal.

    Returns
    -------
    (...) ndarray
        Natural-log densities.
    """
    e = np.asarray(e, dtype=float)
    S = np.asarray(S, dtype=float)
    m = e.shape[-1]
    d = np.sqrt(np.maximum(np.diagonal(S, axis1=-2, axis2=-1), np.finfo(float).tiny))
    Sc = S / (d[..., :, None] * d[..., None, :])
    ec = e / d
    w, V = np.linalg.eigh(Sc)
    w = np.maximum(w, EIG_FLOOR)
    proj = np.einsum("...ij,...i->...j", V, ec)
    quad = np.sum(proj * proj / w, axis=-1)
    logdet = np.sum(np.log(w), axis=-1) + 2.0 * np.sum(np.log(d), axis=-1)
    return -0.5 * (quad + logdet + m * LOG2PI)


def normalize_log_weights(logw: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Probabilities from unnormalized log weights over the last axis, with an optional floor.

    ``mu = exp(logw - logsumexp(logw))`` ([SMM] eq 3.1 / [IMM] eq 30 in the log domain); then, if
    ``floor > 0``, ``mu = max(mu, floor)`` and renormalize ([SMM] Table 1 step 3). After the
    renormalization a floored weight is ``floor / (1 + excess)``, still above ``floor / 2``.

    Parameters
    ----------
    logw : (..., r) array
        Log weights; ``-inf`` allowed (not all of them).
    floor : float
        Weight floor in ``[0, 1/r)`` (not re-checked here).

    Returns
    -------
    (..., r) ndarray
    """
    top = np.max(logw, axis=-1, keepdims=True)
    if not np.all(np.isfinite(top)):
        raise SingularMatrixError(
            "every mode likelihood is zero or non-finite in some realization; check R and Q of the mode "
            "models (the innovation covariance) and the measurement units"
        )
    mu = np.exp(logw - top)
    mu /= mu.sum(axis=-1, keepdims=True)
    if floor > 0:
        mu = np.maximum(mu, floor)
        mu /= mu.sum(axis=-1, keepdims=True)
    return mu


def pairwise_spread(mu: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The spread term as printed in [IMM] eq (32)-(33): ``sum_i sum_j mu_i mu_j (x_i - x_j)(x_i - x_j)^T``.

    Exactly twice the standard spread ``sum_j mu_j (x_j - x)(x_j - x)^T`` (tested); kept only to
    document the correction. :func:`~chatterspec.filters.mixture.combine` uses the standard form.

    Parameters
    ----------
    mu : (..., r) array
        Mode probabilities (sum 1).
    xs : (..., r, n) array
        Mode-conditioned estimates.

    Returns
    -------
    (..., n, n) ndarray
    """
    d = xs[..., :, None, :] - xs[..., None, :, :]
    w = mu[..., :, None] * mu[..., None, :]
    return np.einsum("...ij,...ija,...ijb->...ab", w, d, d)
