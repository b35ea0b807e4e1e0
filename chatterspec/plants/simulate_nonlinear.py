"""Batched simulation of scenarios whose true plant is nonlinear (``x(k+1) = f(x(k), u(k)) + v(k)``).

:func:`chatterspec.plants.simulate.simulate` and ``iter_simulations`` dispatch here when any model
of the scenario (nominal, plant or a fault window) is a
:class:`~chatterspec.plants.nonlinear.NonlinearModel`; callers never call this module directly.

Seeding is *exactly* that of the linear simulation (:mod:`chatterspec.montecarlo`): realization ``r``
draws its process noise from ``block_generator(root, r // 64, 0).standard_normal((64, T, n))`` and
its measurement noise from stream 1 with shape ``(64, T, m)``, each scaled by the Cholesky-like
square root of the active segment's ``Q`` and ``R``. A nonlinear model that happens to be linear
therefore gives the same numbers as the equivalent ``LinearModel`` scenario, and any chunking of
the realizations (``chunk_runs``, ``first_run``, workers) gives bit-identical results: every
operation of a step is element-wise per realization (no BLAS kernel whose rounding depends on the
number of rows).

The true plant is time-segmented like the linear one: the segment active at ``t_k`` advances
``x(k) -> x(k+1)``, and ``z(k) = C x(k) + w(k)`` uses the ``C``/``R`` of the segment active at ``t_k``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..errors import NonFiniteError
from .measurement import measure
from .simulate_kernel import covariance_sqrt, scaled_noise, segment_ranges

if TYPE_CHECKING:  # pragma: no cover
    from .scenario_types import Scenario

__all__ = ["simulate_block_nonlinear"]


def _scale(noise: np.ndarray, L: np.ndarray) -> np.ndarray:
    """``noise @ L.T`` computed element-wise when L is diagonal (the same bits as the matmul)."""
    if np.count_nonzero(L - np.diag(np.diag(L))) == 0:
        return noise * np.diag(L)
    return noise @ L.T


def simulate_block_nonlinear(
    scenario: Scenario, root: np.random.SeedSequence, lo: int, hi: int, t: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate realizations ``lo .. hi - 1`` of a scenario with a nonlinear true plant.

    Parameters
    ----------
    scenario : Scenario
        The scenario (its ``segments`` give the true model per time window, ``x0`` the start).
    root : numpy.random.SeedSequence
        Root of the random streams (see :mod:`chatterspec.montecarlo`).
    lo, hi : int
        Global indices of the first and one-past-the-last realization.
    t : (T,) array
        Sample times in seconds.
    u : (T, p) array
        Input, shared by all realizations.

    Returns
    -------
    x : (hi - lo, T, n) ndarray
        True states.
    z : (hi - lo, T, m) ndarray
        Measurements.

    Raises
    ------
    NonFiniteError
        If the state leaves the finite numbers (e.g. explicit Euler beyond its stability limit);
        the message gives the first time and realization.
    """

    T = len(t)
    runs = hi - lo
    n = scenario.nominal.n_states
    seg_idx = scenario.segment_index(t)
    segments = scenario.segments
    ranges = segment_ranges(scenario, t)
    vt, zt = scaled_noise(scenario, root, lo, hi, t, lambda noise, M: _scale(noise, covariance_sqrt(M)))
    xt = np.empty((T, runs, n))
    xt[0] = scenario.x0
    # NonlinearModel.f was shape-checked when the model was built: call it directly in the loop
    step = [getattr(seg.model, "f", seg.model.transition) for seg in segments]
    for s in set(seg_idx[:-1].tolist()):
        segments[s].model.transition(xt[0], u[0])  # shape check once per model (raises ShapeError)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(T - 1):
            nxt = step[seg_idx[k]](xt[k], u[k])
            np.add(nxt, vt[k], out=xt[k + 1])
    del vt
    bad = ~np.isfinite(xt)
    if bad.any():
        k, r, _ = np.argwhere(bad)[0]
        raise NonFiniteError(
            f"scenario {scenario.name!r}: the true state is not finite from t = {t[k]:.6g} s "
            f"(realization {lo + r}); the plant diverged -- for an explicit Euler model reduce dt "
            "or the input amplitude (EHA4: 2 dt a1 |v| / M must stay below 1)"
        )
    for k0, k1, model in ranges:
        C = model.C
        if getattr(model, "h", None) is not None:  # a nonlinear measurement h(x)
            zt[k0:k1] += measure(model, xt[k0:k1])
        elif C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(C.shape[0])):
            zt[k0:k1] += xt[k0:k1]
        else:
            zt[k0:k1] += xt[k0:k1] @ C.T
    return np.swapaxes(xt, 0, 1), np.swapaxes(zt, 0, 1)
