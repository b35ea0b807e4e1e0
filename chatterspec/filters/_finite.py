"""The outputs of a filter chunk are finite, or a :class:`~chatterspec.errors.DivergenceError` names where
they stopped being finite (private).

A model that diverges (an unstable or badly mismatched ``A``, a nonlinear ``f`` that overflows or
returns NaN mid-run) makes the estimate overflow; numpy's Cholesky of a NaN matrix returns NaN instead
of raising, so without this check the filters would hand back NaN arrays with only numpy warnings. The
check runs at the API boundary (after a chunk, on both the compiled and the numpy path), not inside the
per-sample kernels: the final estimate and covariance are tested (cheap); only when they are not finite
are the stored per-sample outputs searched for the first bad sample.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from .. import _jit
from ..errors import DivergenceError

__all__ = ["finite_sample", "finite_state", "first_nonfinite", "require_finite"]

#: Per-sample outputs searched for the first non-finite sample, in order of preference.
_PER_SAMPLE = ("x_post", "x_prior", "innovation", "e_post", "e_prior", "loglik", "P_post", "P_prior")


@_jit.step
def finite_sample(z: np.ndarray, m: int, u: np.ndarray, p: int) -> bool:
    """Are ``z[:m]`` and ``u[:p]`` finite: the input check of every one-sample kernel, which refuses a
    NaN/inf sample before it touches the state (compiled loops inline it)."""
    for i in range(m):
        if not np.isfinite(z[i]):
            return False
    for i in range(p):
        if not np.isfinite(u[i]):
            return False
    return True


@_jit.step
def finite_state(x: np.ndarray, P: np.ndarray, n: int) -> bool:
    """Are ``x[:n]`` and ``P[:n, :n]`` finite: the output check of every one-sample kernel, which writes
    its state back only when it holds (compiled loops inline it)."""
    for i in range(n):
        if not np.isfinite(x[i]):
            return False
        for j in range(n):
            if not np.isfinite(P[i, j]):
                return False
    return True


def first_nonfinite(values: np.ndarray) -> tuple[int, int] | None:
    """``(sample, realization)`` of the first non-finite entry of a ``(runs, K, ...)`` array, or None.

    Parameters
    ----------
    values : (runs, K, ...) array
        Per-sample outputs (a ``(K, ...)`` array without a runs axis is not accepted here).
    """
    if values.ndim < 2:
        return None
    bad = ~np.isfinite(values.reshape(values.shape[0], values.shape[1], -1)).all(axis=2)  # (runs, K)
    if not bad.any():
        return None
    per_sample = bad.any(axis=0)
    k = int(np.argmax(per_sample))
    return k, int(np.argmax(bad[:, k]))


def require_finite(
    who: str,
    final: tuple[np.ndarray | None, ...],
    outputs: Mapping[str, np.ndarray | None],
    k0: int,
    K: int,
) -> None:
    """Raise :class:`~chatterspec.errors.DivergenceError` unless the chunk's results are finite.

    Parameters
    ----------
    who : str
        The filter, for the message (e.g. ``"KalmanFilter"``).
    final : tuple of arrays
        The state after the chunk (estimate, covariance); None entries are skipped. Only these are
        tested: a non-finite value inside the chunk propagates into them.
    outputs : mapping of str to array or None
        The chunk's stored per-sample outputs, ``(runs, K, ...)`` (covariances may be ``(K, n, n)``
        when shared by every realization).
    k0 : int
        Index of the last sample processed before the chunk (the chunk holds samples ``k0 + 1 ..
        k0 + K``).
    K : int
        Samples in the chunk.

    Raises
    ------
    DivergenceError
        With the first non-finite sample ``k`` (and realization) when the stored outputs locate it,
        otherwise the sample range of the chunk.
    """
    arrays = [a for a in final if a is not None]
    # a NaN or inf anywhere in the chunk propagates into the final estimate or covariance: testing
    # them is enough, and one sum per array is the cheapest test (called once per sample by the banks)
    with np.errstate(over="ignore", invalid="ignore"):
        if all(math.isfinite(float(a.sum())) for a in arrays):
            return
    if all(np.isfinite(a).all() for a in arrays):  # a finite sum overflowed: finite after all
        return
    where = None
    for name in _PER_SAMPLE:
        v = outputs.get(name)
        if v is None:
            continue
        v = np.asarray(v)
        if name.startswith("P_") and v.ndim == 3:  # shared covariance (K, n, n): one realization axis
            v = v[None]
        hit = first_nonfinite(v)
        if hit is not None and (where is None or hit[0] < where[0]):
            where = hit
    if where is not None:
        k, r = where
        at = f"from sample k = {k0 + k + 1} (output index {k}, realization {r})"
    else:
        at = f"within samples k = {k0 + 1} .. {k0 + K}"
    raise DivergenceError(
        f"{who}: the estimate is not finite {at}: the filter diverged. Check the model: an unstable "
        "or mismatched A (or f) makes the estimate overflow, and a transition f(x, u) or Jacobian that "
        "returns NaN/inf does the same; the outputs would be NaN from there on"
    )
