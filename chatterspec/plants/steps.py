"""The compiled step of a plant model, as the filters' loops take it: the plant-step registry and the
linear plant's steps.

A filter loop (:mod:`chatterspec.filters._engine`, the IMM and SMM banks) advances a model by
two steps of :mod:`chatterspec._jit` with one signature, ``predict(prm, x, u, xp, n, p)`` for
``x(k+1|k) = f(x(k|k), u(k))`` and ``jacobian(prm, x, u, F, n, p)`` for ``F = df/dx``, and a
parameter vector ``prm``. :func:`plant_steps` finds them for a model: the linear model
(:func:`predict_step`, :func:`jacobian_step`, below), the nonlinear EHA4 (:mod:`chatterspec.plants.eha4`)
and a model built from one-sample functions (:meth:`NonlinearModel.from_steps
<chatterspec.plants.nonlinear.NonlinearModel.from_steps>`, :mod:`chatterspec.plants.nonlinear`,
whose measurement ``h`` the loops also compile: :func:`measurement_steps`); any other model (a user's
Python ``f``) has none, and the filters call its ``transition`` and ``jacobian`` from Python. Adding a
plant = its steps plus one recognizer in :data:`RECOGNIZERS`.

Compiled steps of the linear plant (eq 1-2 of the core paper), for the loops of :mod:`chatterspec._jit`.

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

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .. import _jit
from . import eha4
from .models import LinearModel
from .nonlinear import Model, measurement_steps, transition_steps

__all__ = [
    "CONSTANT_JACOBIAN",
    "RECOGNIZERS",
    "PlantSteps",
    "advance_step",
    "jacobian_step",
    "measure_step",
    "measurement_steps",
    "parameters",
    "plant_steps",
    "predict_step",
]


# The linear plant's steps.

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


# The plant-step registry.


@dataclass(frozen=True, eq=False)
class PlantSteps:
    """A model's compiled steps and parameters.

    Attributes
    ----------
    name : str
        Short name of the plant kind (part of the compiled loops' names).
    predict : callable
        Step ``predict(prm, x, u, xp, n, p)``: ``xp = f(x, u)``.
    jacobian : callable
        Step ``jacobian(prm, x, u, F, n, p)``: ``F = df/dx`` at ``x``.
    constant_jacobian : bool
        ``F`` does not depend on ``x`` or ``u`` (a loop computes it once).
    parameters : (L,) array
        ``prm`` of both steps.
    """

    name: str
    predict: Callable[..., None]
    jacobian: Callable[..., None]
    constant_jacobian: bool
    parameters: np.ndarray


def _linear(model: Model) -> PlantSteps | None:
    if not isinstance(model, LinearModel):
        return None
    prm = parameters(model.A, model.B)
    return PlantSteps("linear", predict_step, jacobian_step, True, prm)


def _eha4(model: Model) -> PlantSteps | None:
    found = eha4.plant_steps(model)
    if found is None:
        return None
    predict, jacobian, constant, prm = found
    return PlantSteps("eha4", predict, jacobian, constant, prm)


def _sample_functions(model: Model) -> PlantSteps | None:
    found = transition_steps(model)
    if found is None:
        return None
    name, predict, jacobian = found
    return PlantSteps(name, predict, jacobian, False, np.zeros(1))


#: Functions that return a model's :class:`PlantSteps`, or None when it is not theirs.
RECOGNIZERS: tuple[Callable[[Model], PlantSteps | None], ...] = (_linear, _eha4, _sample_functions)


def plant_steps(model: Model) -> PlantSteps | None:
    """The compiled steps of ``model``, or None when it has none (its Python methods are used).

    Parameters
    ----------
    model : model object
        A :class:`~chatterspec.plants.models.LinearModel`, a model built by
        :func:`~chatterspec.plants.eha4.eha4`, or any other model.

    Returns
    -------
    PlantSteps or None
    """
    for recognize in RECOGNIZERS:
        found = recognize(model)
        if found is not None:
            return found
    return None
