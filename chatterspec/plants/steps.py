"""The compiled step of a plant model, as the filters' loops take it (the plant-step registry).

A filter loop (:mod:`chatterspec.filters._engine`, the IMM and SMM banks) advances a model by
two steps of :mod:`chatterspec._jit` with one signature, ``predict(prm, x, u, xp, n, p)`` for
``x(k+1|k) = f(x(k|k), u(k))`` and ``jacobian(prm, x, u, F, n, p)`` for ``F = df/dx``, and a
parameter vector ``prm``. :func:`plant_steps` finds them for a model: the linear model
(:mod:`chatterspec.plants.linear_steps`), the nonlinear EHA4 (:mod:`chatterspec.plants.eha4`) and a
model built from one-sample functions (:meth:`NonlinearModel.from_steps
<chatterspec.plants.nonlinear.NonlinearModel.from_steps>`, :mod:`chatterspec.plants.sample_functions`,
whose measurement ``h`` the loops also compile: :func:`measurement_steps`); any other model (a user's
Python ``f``) has none, and the filters call its ``transition`` and ``jacobian`` from Python. Adding a
plant = its steps plus one recognizer in :data:`RECOGNIZERS`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import eha4, linear_steps
from .models import LinearModel
from .nonlinear import Model
from .sample_functions import measurement_steps, transition_steps

__all__ = ["RECOGNIZERS", "PlantSteps", "measurement_steps", "plant_steps"]


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
    prm = linear_steps.parameters(model.A, model.B)
    return PlantSteps("linear", linear_steps.predict_step, linear_steps.jacobian_step, True, prm)


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
