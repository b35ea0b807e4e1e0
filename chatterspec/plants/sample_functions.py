"""Model functions written for one sample, which the filters' compiled loops inline.

:meth:`NonlinearModel.from_steps <chatterspec.plants.nonlinear.NonlinearModel.from_steps>` builds a
model from four plain functions of **one** sample that write into an output array::

    def f(x, u, out):        # out (n,)    = f(x, u)       x (n,), u (p,)
    def f_jac(x, u, out):    # out (n, n)  = df/dx
    def h(x, out):           # out (m,)    = h(x)          (optional: a nonlinear measurement)
    def h_jac(x, out):       # out (m, n)  = dh/dx

written as the package's own steps are: element indexing (``x[0]``, ``out[1, 0] = ...``), arithmetic and
numpy ufuncs (``np.sin``, ``np.sqrt``); no ``math`` functions and no ``if`` on values, so that the
same code runs compiled on one sample and, on rows of realizations, in the numpy paths. The model
keeps each as a :class:`SampleFunction`: called batched (``f(x (..., n), u)``, what the simulation,
the numpy paths and the checks call), it runs the function on the ``(channels, ...)`` rows of its
arguments; inside a compiled loop (the covariance filters' batch loop, :meth:`online` filters, the
banks) the function is a step (:func:`chatterspec._jit.step`) inlined at each use, so an EKF on such
a model, ``h`` included, runs entirely compiled (:func:`chatterspec.plants.steps.plant_steps`,
:func:`chatterspec.plants.steps.measurement_steps`). The compiled and row forms evaluate the same
operations; numpy's and LLVM's ``sin``/``exp`` may differ in the last bit, so the two paths agree to
rounding. Functions must be module-level (picklable for workers).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any, Literal, Self

import numpy as np

from .. import _jit

__all__ = [
    "FromSteps",
    "MeasurementSteps",
    "SampleFunction",
    "SampleKind",
    "measurement_steps",
    "transition_steps",
]

SampleKind = Literal["f", "jac", "h", "h_jac"]
#: The compiled ``(h, h_jac)`` steps of a model measuring through ``h`` (:func:`measurement_steps`).
MeasurementSteps = tuple[Callable[..., None], Callable[..., None]]


@cache
def _step_of(func: Callable[..., None]) -> Callable[..., None]:
    """The compiled step of ``func`` (one per function for the process)."""
    return _jit.step(func)


@dataclass(frozen=True)
class SampleFunction:
    """A model function written for one sample (see the module docstring), callable batched.

    Attributes
    ----------
    func : callable
        ``func(x, u, out)`` (kinds ``"f"``, ``"jac"``) or ``func(x, out)`` (``"h"``, ``"h_jac"``).
    kind : {"f", "jac", "h", "h_jac"}
        Which function of the model it is (fixes the output shape).
    n_states, n_outputs : int
        The model's sizes ``n``, ``m``.
    """

    func: Callable[..., None]
    kind: SampleKind
    n_states: int
    n_outputs: int

    @property
    def shape(self) -> tuple[int, ...]:
        """The output shape of one sample."""
        n, m = self.n_states, self.n_outputs
        return {"f": (n,), "jac": (n, n), "h": (m,), "h_jac": (m, n)}[self.kind]

    @property
    def step(self) -> Callable[..., None]:
        """The function as a compiled step (inlined by the loops that call it)."""
        return _step_of(self.func)

    def __call__(self, x: np.ndarray, u: np.ndarray | None = None) -> np.ndarray:
        """Batched: ``x`` (..., n) (and ``u`` (..., p) or (p,)) -> (..., *shape), the function on rows."""
        x = np.asarray(x, dtype=float)
        lead = x.shape[:-1]
        rows = np.moveaxis(x, -1, 0)  # (n, ...): x[i] is state i of every realization
        out = np.empty((*self.shape, *lead))
        if self.kind in ("f", "jac"):
            uu = np.asarray(u, dtype=float)
            ur = np.moveaxis(uu, -1, 0) if uu.ndim > 1 else uu
            self.func(rows, ur, out)
        else:
            self.func(rows, out)
        k = len(self.shape)
        return np.moveaxis(out, tuple(range(k)), tuple(range(out.ndim - k, out.ndim)))


#: Bindings of :func:`_predict` / :func:`_jacobian`: the user's steps.
F_STEP = JAC_STEP = None


def _predict(prm: np.ndarray, x: np.ndarray, u: np.ndarray, xp: np.ndarray, n: int, p: int) -> None:
    """The plant-step interface (:mod:`chatterspec.plants.steps`) around ``F_STEP(x, u, xp)``."""
    F_STEP(x, u, xp)  # type: ignore[misc]


def _jacobian(prm: np.ndarray, x: np.ndarray, u: np.ndarray, F: np.ndarray, n: int, p: int) -> None:
    """The plant-step interface around ``JAC_STEP(x, u, F)``."""
    JAC_STEP(x, u, F)  # type: ignore[misc]


@cache
def _plant_pair(
    f: Callable[..., None], jac: Callable[..., None]
) -> tuple[Callable[..., None], Callable[..., None]]:
    tag = "".join(ch if ch.isalnum() else "_" for ch in getattr(f, "__name__", "f"))
    predict = _jit.specialize(_predict, f"user_{tag}", inline=True, F_STEP=_step_of(f))
    jacobian = _jit.specialize(_jacobian, f"user_{tag}", inline=True, JAC_STEP=_step_of(jac))
    return predict, jacobian


def transition_steps(model: object) -> tuple[str, Callable[..., None], Callable[..., None]] | None:
    """``(name, predict, jacobian)``: plant steps of a model whose ``f``, ``jac`` are sample functions.

    None for any other model. ``name`` names the functions (part of the compiled loops' names).
    """
    f, jac = getattr(model, "f", None), getattr(model, "jac", None)
    if not (isinstance(f, SampleFunction) and isinstance(jac, SampleFunction)):
        return None
    predict, jacobian = _plant_pair(f.func, jac.func)
    name = "".join(ch if ch.isalnum() else "_" for ch in getattr(f.func, "__name__", "f"))
    return f"user_{name}", predict, jacobian


def measurement_steps(model: object) -> MeasurementSteps | None:
    """``(h, h_jac)`` steps (``h(x, out)``, ``h_jac(x, out)``) of a model whose measurement functions are
    :class:`SampleFunction` s, None for any other (a linear ``C``, or Python ``h``)."""
    h, h_jac = getattr(model, "h", None), getattr(model, "h_jac", None)
    if not (isinstance(h, SampleFunction) and isinstance(h_jac, SampleFunction)):
        return None
    return h.step, h_jac.step


class FromSteps:
    """``from_steps``, mixed into :class:`~chatterspec.plants.nonlinear.NonlinearModel`."""

    @classmethod
    def from_steps(
        cls,
        f: Callable[..., None],
        f_jac: Callable[..., None],
        Q: np.ndarray,
        R: np.ndarray,
        dt: float,
        *,
        C: np.ndarray | None = None,
        h: Callable[..., None] | None = None,
        h_jac: Callable[..., None] | None = None,
        **kwargs: Any,
    ) -> Self:
        """A model from one-sample functions that the filters compile (module docstring).

        Parameters
        ----------
        f, f_jac : callable
            ``f(x, u, out)``: ``out (n,) = f(x, u)``; ``f_jac(x, u, out)``: ``out (n, n) = df/dx``.
        Q : (n, n) array
            Process-noise covariance per step.
        R : (m, m) array
            Measurement-noise covariance.
        dt : float
            Sampling time (s), already built into ``f``.
        C : (m, n) array, optional
            Linear measurement (give ``C`` or ``h`` and ``h_jac``).
        h, h_jac : callable, optional
            ``h(x, out)``: ``out (m,) = h(x)``; ``h_jac(x, out)``: ``out (m, n) = dh/dx``.
        **kwargs
            The other ``NonlinearModel`` fields (``n_inputs``, names, units, ``rest_state``, ...).

        Returns
        -------
        NonlinearModel
            Whose ``f``, ``jac``, ``h``, ``h_jac`` are :class:`SampleFunction` s.
        """
        n = int(np.shape(Q)[0])
        m = int(np.shape(R)[0]) if np.ndim(R) == 2 else 1

        def wrap(fn: Callable[..., None] | None, kind: SampleKind) -> SampleFunction | None:
            return None if fn is None else SampleFunction(fn, kind, n, m)

        return cls(  # type: ignore[call-arg]
            wrap(f, "f"),
            wrap(f_jac, "jac"),
            C,
            Q,
            R,
            dt,
            h=wrap(h, "h"),
            h_jac=wrap(h_jac, "h_jac"),
            **kwargs,
        )
