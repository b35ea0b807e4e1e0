"""Compiled steps of the linear plant (eq 1-2 of the core paper), for the loops of :mod:`chatterspec._jit`.

Two uses of the same model, with their own summation orders (kept: every number of the package
depends on them):

* the **true plant** of a simulation (:func:`measure_step`, :func:`advance_step`):
  ``z(k) = C_s x(k) + Lr_s w(k)`` and ``x(k+1) = (A_s x(k) + B_s u(k)) + Lq_s v(k)`` for the
  segment ``s`` active at sample k, ``v``, ``w`` standard normals, ``Lq Lq^T = Q``, ``Lr Lr^T = R``;
* the **filter model's prediction** (:func:`predict_step`, :func:`jacobian_step`):
  ``x(k+1|k) = B u(k) + A x(k|k)`` (``B u`` summed first, as :func:`~chatterspec.filters.svsf._rows_times`
  does) and ``F = A``, from a parameter vector ``prm = [A.ravel(), B.ravel()]`` (:func:`parameters`).
  This is the plant-step interface the covariance filters' loops take (a plant passes its
  ``predict``/``jacobian`` steps and parameters; :mod:`chatterspec.plants.eha4` is the other one).

Steps are inlined by numba into the loops that call them; with numba absent they are plain
Python (the loops' numpy twins are the vectorized form of the same equations).
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__ = ["CONSTANT_JACOBIAN", "advance_step", "jacobian_step", "measure_step", "parameters", "predict_step"]

#: The Jacobian of :func:`predict_step` does not depend on the state (a loop computes it once).
CONSTANT_JACOBIAN = True


@_jit.step
def noise_step(L: np.ndarray, s: int, i: int, v: np.ndarray, diag: bool, k: int) -> float:  # pragma: no cover
    """Component i of ``L_s v``: ``L_s[i, i] v_i`` when ``diag`` (the other terms are exact zeros: the
    same bits), else the sum from 0.0 over j = 0 .. k-1."""
    if diag:
        return L[s, i, i] * v[i]
    acc = 0.0
    for j in range(k):
        acc += L[s, i, j] * v[j]
    return acc


@_jit.step
def measure_step(
    s: int,
    x: np.ndarray,
    wk: np.ndarray,
    C: np.ndarray,
    Lr: np.ndarray,
    diag: np.ndarray,
    z: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover
    """Eq (2): ``z = C_s x + Lr_s w(k)`` into ``z`` (m,); ``C_s x`` summed from 0.0 over j = 0, 1, ...
    (``diag[s, 1]``: ``Lr_s`` diagonal)."""
    for i in range(m):
        cx = 0.0
        for j in range(n):
            cx += C[s, i, j] * x[j]
        z[i] = cx + noise_step(Lr, s, i, wk, diag[s, 1], m)


@_jit.step
def advance_step(
    s: int,
    x: np.ndarray,
    bu: np.ndarray,
    vk: np.ndarray,
    A: np.ndarray,
    Lq: np.ndarray,
    diag: np.ndarray,
    xn: np.ndarray,
    n: int,
) -> None:  # pragma: no cover
    """Eq (1): ``x(k+1) = (A_s x(k) + B_s u(k)) + Lq_s v(k)`` into ``xn`` (n,), given ``bu`` = B_s u(k).

    ``A_s x`` is summed from 0.0 over j = 0, 1, ...; ``diag[s, 0]`` says ``Lq_s`` is diagonal.
    """
    for i in range(n):
        ax = 0.0
        for j in range(n):
            ax += A[s, i, j] * x[j]
        xn[i] = (ax + bu[i]) + noise_step(Lq, s, i, vk, diag[s, 0], n)


@_jit.step
def predict_step(prm: np.ndarray, x: np.ndarray, u: np.ndarray, xp: np.ndarray, n: int, p: int) -> None:
    """The filter model's prediction ``x(k+1|k) = B u(k) + A x(k|k)`` into ``xp`` (n,).

    ``prm`` = :func:`parameters` (A row-major, then B row-major); ``B u`` is summed first
    (``u_0 B_i0``, then ``+ u_q B_iq``), then ``+ A_ij x_j`` for j = 0, 1, ...
    """
    nn = n * n
    for i in range(n):
        s = 0.0
        if p > 0:
            s = u[0] * prm[nn + i * p]
            for q in range(1, p):
                s += u[q] * prm[nn + i * p + q]
        for j in range(n):
            s += prm[i * n + j] * x[j]
        xp[i] = s


@_jit.step
def jacobian_step(prm: np.ndarray, x: np.ndarray, u: np.ndarray, F: np.ndarray, n: int, p: int) -> None:
    """``F = d x(k+1|k) / d x = A`` (constant: see :data:`CONSTANT_JACOBIAN`)."""
    for i in range(n):
        for j in range(n):
            F[i, j] = prm[i * n + j]


def parameters(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``prm`` of :func:`predict_step`: ``[A.ravel(), B.ravel()]`` as one contiguous float vector."""
    return np.ascontiguousarray(np.concatenate([np.ravel(A), np.ravel(B)]), dtype=float)
