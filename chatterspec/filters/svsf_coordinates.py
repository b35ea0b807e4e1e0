"""The SVSF's measurement-aligned coordinates and boundary layer (eq 8-11 of the core paper).

The SVSF runs in coordinates ``y = S x`` with ``S = [[C], [E_l]]`` (``E_l`` selects the states not
used by ``C1``), so that the first ``m`` coordinates *are* the measured outputs (``C S^-1 = [I 0]``).
For full measurement ``S = C`` and ``Phi = C A C^-1`` (eq 8); for fewer measurements than states it
is Luenberger's reduced-order form (eq 9-11) with ``L = Phi22 Phi12^-1`` and ``P = Phi12^-1``.

See Also
--------
chatterspec.filters.svsf.SVSF : the filter that holds these constants.
chatterspec.filters.svsf_recursion : the recursion that uses them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .._repr import short_repr
from .._validate import finite_array
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.models import LinearModel

__all__ = ["SVSFCoordinates", "boundary_layer_inverse", "reduced_order_transform", "svsf_coordinates"]


@dataclass(frozen=True, eq=False)
class SVSFCoordinates:
    """The SVSF's model in measurement-aligned coordinates ``y = S x`` (eq 8-11).

    Attributes
    ----------
    S, S_inv : (n, n) arrays
        The transformation and its inverse.
    Phi : (n, n) array
        ``S A S^-1``.
    G : (n, p) array
        ``S B``.
    L : (n - m, m) array or None
        ``Phi22 Phi12^-1`` (eq 10); None for full measurement.
    P : (n - m, m) array or None
        ``Phi12^-1`` (pseudo-inverse, eq 10); None for full measurement.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    S: np.ndarray
    S_inv: np.ndarray
    Phi: np.ndarray
    G: np.ndarray
    L: np.ndarray | None
    P: np.ndarray | None


def svsf_coordinates(model: LinearModel) -> SVSFCoordinates:
    """The SVSF's coordinates for ``model``: ``S = C`` (full measurement) or Luenberger's form.

    Parameters
    ----------
    model : LinearModel
        Nominal model (A-hat, B-hat, C-hat of eq 3).

    Returns
    -------
    SVSFCoordinates

    Raises
    ------
    SingularMatrixError
        ``C`` square but singular, or ``Phi12`` without full column rank (eq 10: the unmeasured
        states must drive the measured ones, and ``n - m <= m``).
    """
    n, m = model.n_states, model.n_outputs
    if model.full_measurement:
        S = model.C.copy()
        S_inv = model.C_inv
    elif m == n:
        raise SingularMatrixError("C is square but singular: the SVSF needs C^-1 (eq 8)")
    else:
        S, S_inv = reduced_order_transform(model.C)
    Phi = S @ model.A @ S_inv
    G = S @ model.B
    L = P = None
    if m < n:
        Phi12, Phi22 = Phi[:m, m:], Phi[m:, m:]
        if np.linalg.matrix_rank(Phi12) < n - m:
            raise SingularMatrixError(
                f"reduced-order SVSF needs Phi12 ({m}x{n - m}) of full column rank "
                f"{n - m} (eq 10): the unmeasured states must drive the measured ones "
                "(and n - m <= m)"
            )
        P = np.linalg.pinv(Phi12)
        L = Phi22 @ P
    return SVSFCoordinates(S=S, S_inv=S_inv, Phi=Phi, G=G, L=L, P=P)


def boundary_layer_inverse(
    switching: str, psi: npt.ArrayLike | None, psi_lower: npt.ArrayLike | None, n: int, m: int
) -> np.ndarray | None:
    """``1 / psi`` per switching channel (measured first), or None for ``sgn`` (eq 8-10).

    Parameters
    ----------
    switching : {"sat", "sgn"}
        ``"sgn"`` needs no boundary layer.
    psi : float or array or None
        Boundary layer (> 0, output units): 1 or ``m`` values, or ``n`` for the reduced order.
    psi_lower : float or array or None
        Boundary layer of the ``n - m`` unmeasured coordinates when ``psi`` has ``m`` values.
    n, m : int
        States and outputs.

    Returns
    -------
    (m,) or (n,) array or None

    Raises
    ------
    ParameterError
        ``psi`` missing for ``sat``, or not > 0; ``psi_lower`` missing where needed.
    ShapeError
        ``psi`` with a number of entries that fits neither ``m`` nor ``n``.
    """
    if switching == "sgn":
        return None
    if psi is None:
        raise ParameterError("psi (smoothing boundary layer) is required for switching='sat'")
    psi = np.atleast_1d(finite_array("psi", psi, ndim=(0, 1)))
    if psi.size == 1:
        psi = np.full(m, psi[0])
    if m < n:
        if psi.size == m:
            lower = psi_lower
            if lower is None:
                raise ParameterError(
                    "the reduced-order SVSF needs psi for all n states, or psi_lower for the unmeasured ones"
                )
            lower = np.atleast_1d(finite_array("psi_lower", lower, ndim=(0, 1)))
            psi = np.concatenate([psi, np.broadcast_to(lower, (n - m,))])
        if psi.size != n:
            raise ShapeError(f"psi must have 1, {m} or {n} entries; got {psi.size}")
    elif psi.size != m:
        raise ShapeError(f"psi must have 1 or {m} entries; got {psi.size}")
    if np.any(psi <= 0):
        raise ParameterError(f"psi must be > 0 (smoothing boundary layer); got {psi.tolist()}")
    return 1.0 / psi


def reduced_order_transform(C: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Luenberger transformation ``S = [[C], [E_l]]`` for eq (9)-(11).

    ``E_l`` selects the states left out of ``C1`` (the m columns of C chosen by pivoted QR, i.e. the
    best-conditioned square sub-block). Measured coordinates come first.

    Parameters
    ----------
    C : (m, n) array
        Output matrix, m < n.

    Returns
    -------
    (S, S_inv) : tuple of (n, n) arrays

    Raises
    ------
    SingularMatrixError
        No square invertible ``C1`` block exists in ``C``.
    """
    import scipy.linalg  # on first use: importing the SVSF does not import scipy.linalg

    m, n = C.shape
    _, _, piv = scipy.linalg.qr(C, pivoting=True, mode="economic")
    measured = sorted(piv[:m].tolist())
    lower = [j for j in range(n) if j not in measured]
    E = np.zeros((n - m, n))
    E[np.arange(n - m), lower] = 1.0
    S = np.vstack([C, E])
    if np.linalg.cond(S) > 1e12:
        raise SingularMatrixError("no square invertible C1 block exists in C (eq 9)")
    return S, np.linalg.inv(S)
