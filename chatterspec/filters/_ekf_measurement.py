"""The EKF step with a nonlinear measurement ``h(x)`` (private): numpy, vectorized over realizations.

For a model that measures through ``h`` (``NonlinearModel(..., h=..., h_jac=...)``), one step is the
step of :mod:`chatterspec.filters._engine` with ``C`` replaced by ``H = dh/dx`` at the prior::

    x(k+1|k) = f(x(k|k), u(k)),   P(k+1|k) = F P(k|k) F^T + Q,   F = df/dx at x(k|k)
    e = z(k+1) - h(x(k+1|k)),     H = dh/dx at x(k+1|k),         S = H P(k+1|k) H^T + R
    K = P(k+1|k) H^T S^-1,        x(k+1|k+1) = x(k+1|k) + K e
    P(k+1|k+1) = (I - K H) P(k+1|k) (I - K H)^T + K R K^T                    (Joseph form)
    e(k+1|k+1) = z(k+1) - h(x(k+1|k+1))

The model's ``transition``/``jacobian``/``h`` are Python callables, so the loop over samples is in
Python (as for every nonlinear model without compiled steps); realizations are vectorized.
"""

from __future__ import annotations

import numpy as np

from ..plants.measurement import measure, measurement_jacobian
from ._engine import FIELDS, LOG2PI, MAP_CONST, _alloc, _shapes
from ._engine_numpy import chol_np

__all__ = ["ekf_h_numpy"]


def ekf_h_numpy(
    model: object,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray | None,
    Q: np.ndarray,
    R: np.ndarray,
    keep: frozenset[str],
    *,
    xp_in: np.ndarray | None = None,
    F_in: np.ndarray | None = None,
) -> dict[str, np.ndarray | None]:
    """Every sample of ``z`` (runs, K, m) through the EKF with ``h``; ``x``, ``P``, ``ep``, ``epp`` in place.

    ``u`` is (1|runs, K, p); or ``xp_in``/``F_in`` give the one sample's prediction (``correct()``).
    Returns the output fields of :data:`~chatterspec.filters._engine.FIELDS` (None when not kept).
    """
    runs, K, m = z.shape
    n = x.shape[1]
    flags, out = _alloc(keep, _shapes(runs, K, n, m))
    eye = np.eye(n)
    shared_u = u is not None and u.shape[0] == 1
    for k in range(K):
        if xp_in is None:
            uk = u[0, k] if shared_u else u[:, k]  # type: ignore[index]
            xp = np.asarray(model.transition(x, uk), dtype=float)  # type: ignore[attr-defined]
            F = np.broadcast_to(np.asarray(model.jacobian(x, uk), dtype=float), (runs, n, n))  # type: ignore[attr-defined]
        else:
            xp, F = np.array(xp_in, dtype=float), F_in
        Pp = F @ P @ np.swapaxes(F, -1, -2) + Q  # type: ignore[operator]
        e = z[:, k] - measure(model, xp)
        H = measurement_jacobian(model, xp)
        PHt = Pp @ np.swapaxes(H, -1, -2)
        S = H @ PHt + R
        L = chol_np(S, MAP_CONST)
        Kg = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
        w = np.linalg.solve(S, e[..., None])[..., 0]
        ll = -0.5 * (m * LOG2PI + 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1))
        ll = ll - 0.5 * np.einsum("ri,ri->r", e, w)
        x[...] = xp + np.einsum("rij,rj->ri", Kg, e)
        IKH = eye - Kg @ H
        P[...] = IKH @ Pp @ np.swapaxes(IKH, -1, -2) + Kg @ R @ np.swapaxes(Kg, -1, -2)
        epp[...] = ep
        ep[...] = z[:, k] - measure(model, x)
        for f, flag, val in zip(FIELDS, flags, (xp, x, e, S, ll, ep, Pp, P), strict=True):
            if flag:
                out[f][:, k] = val
    return {f: (out[f] if f in keep else None) for f in FIELDS}
