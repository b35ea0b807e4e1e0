"""The small-signal linearization of a :class:`~chatterspec.plants.nonlinear.NonlinearModel`.

:class:`Linearization` is the part of the nonlinear model that linearizes it about an operating
point: the input matrix ``G = df/du`` (given or by central differences), the
:class:`~chatterspec.plants.linear_model.LinearModel` ``dx(k+1) = F dx(k) + G du(k)``, and the
natural frequency / damping of the oscillatory block ``(F - I) / dt`` (the continuous-equivalent
block, the inverse of explicit Euler), all evaluated at ``(x0, u0)`` (default: the rest state,
zero input).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from .._validate import finite_array
from ..errors import NonFiniteError, ShapeError
from .linear_model import LinearModel, OscillatoryMode, oscillatory_mode

__all__ = ["Linearization"]


class Linearization:
    """Linearization of a nonlinear model (mixed into :class:`~chatterspec.plants.nonlinear.NonlinearModel`).

    Uses the model's ``transition``, ``jacobian``, ``measurement_jacobian``, ``input_jacobian``,
    sizes, names, ``rest_state``, ``oscillatory_states`` and ``dt``.
    """

    if TYPE_CHECKING:  # what it reads from the model (fields, properties and methods of NonlinearModel)
        dt: float
        n_inputs: int
        rest_state: np.ndarray
        oscillatory_states: tuple[int, int] | None
        input_jacobian: Callable[[np.ndarray, np.ndarray], np.ndarray] | None
        name: str
        Q: np.ndarray
        R: np.ndarray
        state_names: tuple[str, ...]
        output_names: tuple[str, ...]
        input_names: tuple[str, ...]
        output_units: tuple[str, ...]

        @property
        def n_states(self) -> int: ...

        def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray: ...

        def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray: ...

        def measurement_jacobian(self, x: np.ndarray) -> np.ndarray: ...

    def _operating_point(self, x0: np.ndarray | None, u0: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """``(x0, u0)`` checked, or the rest state and zero input."""
        x0 = self.rest_state if x0 is None else finite_array("x0", x0, shape=(self.n_states,))
        u0 = np.zeros(self.n_inputs) if u0 is None else finite_array("u0", u0, shape=(self.n_inputs,))
        return x0, u0

    def input_matrix(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """``df/du`` at one point ``(x, u)``: the supplied ``input_jacobian`` or central differences.

        Parameters
        ----------
        x : (n,) array
            State.
        u : (p,) array
            Input.

        Returns
        -------
        (n, p) ndarray
            Central differences use the step ``h = 1e-6 max(1, |u_j|)`` per input (error
            O(h^2) times the third derivative; exact for inputs that enter affinely, as in the EHA).
        """
        x = finite_array("x", x, shape=(self.n_states,))
        u = finite_array("u", u, shape=(self.n_inputs,))
        if self.input_jacobian is not None:
            B = np.asarray(self.input_jacobian(x, u), dtype=float)
            if B.shape != (self.n_states, self.n_inputs):
                raise ShapeError(
                    f"input_jacobian returned shape {B.shape}; expected ({self.n_states}, {self.n_inputs})"
                )
            return B
        B = np.empty((self.n_states, self.n_inputs))
        for j in range(self.n_inputs):
            h = 1e-6 * max(1.0, abs(u[j]))
            up, um = u.copy(), u.copy()
            up[j] += h
            um[j] -= h
            B[:, j] = (self.transition(x, up) - self.transition(x, um)) / (2 * h)
        return B

    def linearize(self, x0: np.ndarray | None = None, u0: np.ndarray | None = None) -> LinearModel:
        """Small-signal linear model about ``(x0, u0)``: ``dx(k+1) = F dx(k) + G du(k)``.

        ``F = jac(x0, u0)`` and ``G = df/du`` (see :meth:`input_matrix`); ``C``, ``Q``, ``R``, ``dt``
        and the names are kept. The returned model acts on *deviations* from the operating point:
        the offset ``f(x0, u0) - x0`` is not represented (it is zero at an equilibrium such as the
        EHA at rest). Its ``oscillatory_block`` is the continuous-equivalent block of
        ``oscillatory_states``, ``(F - I) / dt`` (the inverse of explicit Euler).

        Parameters
        ----------
        x0 : (n,) array, optional
            Operating state (default :attr:`rest_state`).
        u0 : (p,) array, optional
            Operating input (default zeros).

        Returns
        -------
        LinearModel
        """
        x0, u0 = self._operating_point(x0, u0)
        F = self.jacobian(x0, u0)
        if not np.all(np.isfinite(F)):
            raise NonFiniteError(f"{self.name}: the Jacobian at the operating point is not finite")
        G = self.input_matrix(x0, u0)
        return LinearModel(
            A=F,
            B=G,
            C=self.measurement_jacobian(x0),
            Q=self.Q,
            R=self.R,
            dt=self.dt,
            state_names=self.state_names,
            output_names=self.output_names,
            input_names=self.input_names,
            output_units=self.output_units,
            oscillatory_block=self._block(F),
            name=f"{self.name} linearized",
        )

    def _block(self, F: np.ndarray) -> np.ndarray | None:
        if self.oscillatory_states is None:
            return None
        idx = list(self.oscillatory_states)
        return (F[np.ix_(idx, idx)] - np.eye(2)) / self.dt

    def mode_at(self, x0: np.ndarray | None = None, u0: np.ndarray | None = None) -> OscillatoryMode | None:
        """Natural frequency (Hz) and damping of the linearization at ``(x0, u0)``.

        Parameters
        ----------
        x0, u0 : arrays, optional
            The operating point, as in :meth:`linearize`.

        Returns
        -------
        OscillatoryMode or None
            None without ``oscillatory_states`` or when the block has no oscillatory mode
            (non-positive determinant).
        """
        x0, u0 = self._operating_point(x0, u0)
        block = self._block(self.jacobian(x0, u0))
        if block is None or not np.all(np.isfinite(block)) or np.linalg.det(block) <= 0:
            return None
        return oscillatory_mode(block)

    @property
    def mode(self) -> OscillatoryMode | None:
        """:meth:`mode_at` the rest state with zero input (a linearized value)."""
        return self.mode_at()
