"""The auxiliary ``sgn`` SVSF of a nonlinear nominal model (full measurement): its chattering signal.

The chattering paper (Saeedzadeh et al. 2023) defines the chattering as the a priori output error
``e(k|k-1)`` of the SVSF with ``sgn`` instead of ``sat`` (eq 17), for a linear model. With a
nonlinear nominal model ``x(k+1) = f(x(k), u(k))`` (:class:`~chatterspec.plants.nonlinear.NonlinearModel`)
only the prediction (eq 4) changes; the correction (eq 8) and update (eq 12) are the paper's:

* prediction (eq 4, nonlinear): ``x(k+1|k) = f(x(k|k), u(k))``;
* output errors (eq 6-7): ``e(k+1|k) = z(k+1) - C x(k+1|k)``, ``e(k|k) = z(k) - C x(k|k)``;
* correction (eq 8, sgn): ``K = C^-1 (|e(k+1|k)| + gamma |e(k|k)|) o sgn(e(k+1|k))``;
* update (eq 12): ``x(k+1|k+1) = x(k+1|k) + K``.

As in :mod:`chatterspec.filters.svsf`, the update is written in measured coordinates
``y = C x``: ``y(k+1|k+1) = z(k+1) - e(k+1|k+1)`` with ``e(k+1|k+1) = e(k+1|k) - C K``. When
``e(k|k) = 0`` then ``C K = |e| sgn(e) = e`` exactly, so ``e(k+1|k+1) = 0`` and ``y(k+1|k+1) = z(k+1)``
bit for bit (eq 20-22 of the paper, which do not use linearity). With the default initialization
``x(0|0) = C^-1 z(0)`` this holds at every sample, and the chattering has the closed form

    e(k+1|k) = z(k+1) - C f(C^-1 z(k), u(k))                                    (eq 23, nonlinear)

which :meth:`NonlinearSgnSVSF.update` evaluates vectorized over realizations *and* time. For a
linear ``f = A x + B u`` it is eq 23 itself (``z(k+1) - C A C^-1 z(k) - C B u(k)``). The recursion
is used otherwise (``x0`` given, so ``e(0|0) != 0``); both agree to rounding.

Beyond the paper: the paper has the chattering only for a linear model and derives its expected
spectrum (eq 56) from linearity; for a nonlinear model there is no closed-form spectrum, so its
thresholds are estimated from healthy runs (:mod:`chatterspec.detection.thresholds`).

Only full measurement (``C`` square and invertible) is supported: the reduced-order form
(eq 9-11) needs the constant ``Phi = T^-1 A T`` of a linear model.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field

import numpy as np

from .._repr import short_repr
from .._validate import open_unit
from ..errors import ParameterError, SingularMatrixError
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel, require_linear_measurement
from ._conventions import check_chunk, check_initial_rows, check_record, store_flags
from ._finite import require_finite
from .protocol import channel_rows
from .svsf_steps import rows_times as _rows_times

__all__ = ["NonlinearSVSFOutput", "NonlinearSVSFState", "NonlinearSgnSVSF", "nonlinear_chattering"]


@dataclass(frozen=True, eq=False)
class NonlinearSVSFState:
    """Filter state after sample ``k`` (one row per realization).

    Attributes
    ----------
    y : (runs, m) array
        Measured coordinates ``C x(k|k)`` (equal to ``z(k)`` while ``e(k|k) = 0``).
    e_post : (runs, m) array
        A posteriori output error ``e(k|k)`` (eq 7).
    k : int
        Index of the last processed sample.
    """

    y: np.ndarray
    e_post: np.ndarray
    k: int = 0

    @property
    def runs(self) -> int:
        """Number of realizations."""
        return self.y.shape[0]


@dataclass(frozen=True, eq=False)
class NonlinearSVSFOutput:
    """Per-sample outputs of :meth:`NonlinearSgnSVSF.update` / :meth:`NonlinearSgnSVSF.run`.

    Attributes
    ----------
    e_prior : (runs, K, m) array
        A priori output error ``e(k|k-1)``: the chattering (eq 17), in output units.
    x_post : (runs, K, n) array or None
        ``x(k|k)`` if requested.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    e_prior: np.ndarray
    x_post: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class NonlinearSgnSVSF:
    """Auxiliary ``sgn`` SVSF (eq 4-8, 12, 17) of a nonlinear (or linear) nominal model, full measurement.

    Parameters
    ----------
    model : NonlinearModel or LinearModel
        Nominal model; only ``transition(x, u)``, ``C``, ``n_inputs`` and the sizes are used.
    gamma : float
        Convergence rate in (0, 1) (eq 8); without effect while ``e(k|k) = 0``.

    Raises
    ------
    SingularMatrixError
        If ``C`` is not square and invertible (only full measurement is supported).
    ParameterError
        If ``gamma`` is outside (0, 1).
    """

    model: NonlinearModel | LinearModel
    gamma: float = 0.1
    _CT: np.ndarray = field(init=False, repr=False)
    _CinvT: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        require_linear_measurement(self.model, "the chattering SVSF")
        if not isinstance(self.model, NonlinearModel | LinearModel):
            raise ParameterError(
                f"model must be a NonlinearModel or LinearModel; got {type(self.model).__name__}"
            )
        object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        if not self.model.full_measurement:
            raise SingularMatrixError(
                f"the nonlinear sgn-SVSF needs full measurement (C square and invertible, eq 8); "
                f"{self.model.name!r} measures {self.model.n_outputs} of {self.model.n_states} states"
            )
        object.__setattr__(self, "_CT", np.ascontiguousarray(self.model.C.T))
        object.__setattr__(self, "_CinvT", np.ascontiguousarray(self.model.C_inv.T))

    def initialize(self, z0: np.ndarray, x0: np.ndarray | None = None) -> NonlinearSVSFState:
        """Initial state from the first measurement ``z0`` (runs, m) or (m,).

        Parameters
        ----------
        z0 : (runs, m) or (m,) array
            Measurement z(0).
        x0 : (n,) or (runs, n) array, optional
            Initial estimate x(0|0); default ``C^-1 z(0)`` (zero initial output error, so the
            chattering is the closed form of the module docstring).

        Returns
        -------
        NonlinearSVSFState
        """
        m = self.model.n_outputs
        z0 = channel_rows("z0", z0, m)
        runs = z0.shape[0]
        if x0 is None:
            y = z0.copy()
        else:
            x0 = check_initial_rows(x0, m, runs)
            y = np.broadcast_to(_rows_times(x0, self._CT), (runs, m)).copy()
        return NonlinearSVSFState(y=y, e_post=z0 - y, k=0)

    def update(
        self,
        state: NonlinearSVSFState,
        z: np.ndarray,
        u: np.ndarray,
        *,
        store: Collection[str] | None = None,
        closed_form: bool = True,
        check: bool = True,
    ) -> tuple[NonlinearSVSFState, NonlinearSVSFOutput]:
        """Advance all realizations by a chunk of K samples (online: K = 1; batch: the record).

        Parameters
        ----------
        state : NonlinearSVSFState
            State after sample ``k``.
        z : (runs, K, m) or (K, m) array
            Measurements ``z(k+1) .. z(k+K)``.
        u : (K, p) or (runs, K, p) array
            Inputs ``u(k) .. u(k+K-1)``.
        store : collection of str, optional
            ``{"x_post"}``: also return ``x(k|k)`` per sample (``e_prior`` is always returned).
        closed_form : bool
            Allow the closed form (eq 23, nonlinear) when ``e(k|k) = 0``; ``False`` forces the
            sample-by-sample recursion (same numbers up to rounding).
        check : bool
            Validate finiteness (turn off only in trusted hot loops); shapes are always checked.

        Returns
        -------
        (NonlinearSVSFState, NonlinearSVSFOutput)
            The chattering of every sample depends only on ``z(k)``, ``z(k+1)`` and ``u(k)``,
            evaluated element-wise, so any chunking gives the same bits.
        """
        (store_states,) = store_flags(
            store, ("x_post",), frozenset({"x_post"}), "NonlinearSgnSVSF", "e_prior is always returned"
        )
        m = self.model.n_outputs
        runs = state.runs
        z, u = check_chunk(z, u, runs, m, self.model.n_inputs, check)
        K = z.shape[1]
        if closed_form and not np.any(state.e_post):
            y_prev = np.concatenate([state.y[:, None, :], z[:, :-1, :]], axis=1)  # y(j|j) = z(j)
            x_prev = _rows_times(y_prev, self._CinvT)
            with np.errstate(over="ignore", invalid="ignore"):  # checked just below
                x_pred = np.asarray(self.model.transition(x_prev, u), dtype=float)  # eq 4
                e = z - _rows_times(x_pred, self._CT)  # eq 6
            require_finite(type(self).__name__, (e,), {"e_prior": e}, state.k, K)
            x_post = _rows_times(z, self._CinvT) if store_states else None
            new = NonlinearSVSFState(y=z[:, -1, :].copy(), e_post=np.zeros((runs, m)), k=state.k + K)
            return new, NonlinearSVSFOutput(e_prior=e, x_post=x_post)
        e_out = np.empty((runs, K, m))
        x_out = np.empty((runs, K, m)) if store_states else None
        y, ep = state.y.copy(), state.e_post.copy()
        for k in range(K):
            uk = u[..., k, :]
            x_pred = np.asarray(self.model.transition(_rows_times(y, self._CinvT), uk), dtype=float)
            e = z[:, k] - _rows_times(x_pred, self._CT)  # eq 6
            CK = (np.abs(e) + self.gamma * np.abs(ep)) * np.sign(e)  # C K of eq 8 (sgn)
            ep = e - CK  # e(k+1|k+1)
            y = z[:, k] - ep  # eq 12 in measured coordinates
            e_out[:, k] = e
            if x_out is not None:
                x_out[:, k] = _rows_times(y, self._CinvT)
        require_finite(type(self).__name__, (y, e_out), {"e_prior": e_out}, state.k, K)
        new = NonlinearSVSFState(y=y, e_post=ep, k=state.k + K)
        return new, NonlinearSVSFOutput(e_prior=e_out, x_post=x_out)

    def run(self, z: np.ndarray, u: np.ndarray, *, x0: np.ndarray | None = None) -> NonlinearSVSFOutput:
        """Filter whole records (batch): ``e_prior[:, 0] = 0`` (no prediction of z(0)).

        Parameters
        ----------
        z : (runs, T, m) or (T, m) array
            Measurements z(0) .. z(T-1).
        u : (T, p), (runs, T, p) or (T,) array
            Inputs u(0) .. u(T-1) (the last one is not used).
        x0 : array, optional
            Initial estimate x(0|0); default ``C^-1 z(0)``.

        Returns
        -------
        NonlinearSVSFOutput
            ``e_prior`` with T samples (2-D for a 2-D ``z``).
        """
        z, u, single = check_record(z, u)
        state = self.initialize(z[:, 0], x0)
        _, out = self.update(state, z[:, 1:], u[..., :-1, :])
        e = np.zeros(z.shape)
        e[:, 1:] = out.e_prior
        return NonlinearSVSFOutput(e_prior=e[0] if single else e)


def nonlinear_chattering(
    model: NonlinearModel | LinearModel,
    z: np.ndarray,
    u: np.ndarray,
    *,
    gamma: float = 0.1,
    x0: np.ndarray | None = None,
) -> np.ndarray:
    """Chattering ``e(k|k-1)`` (eq 17) of the auxiliary sgn-SVSF of a nonlinear nominal model.

    Parameters
    ----------
    model : NonlinearModel or LinearModel
        Nominal model (full measurement).
    z : (runs, T, m) or (T, m) array
        Measurements.
    u : (T, p), (runs, T, p) or (T,) array
        Inputs.
    gamma : float
        Convergence rate in (0, 1) (eq 8).
    x0 : array, optional
        Initial estimate; default ``C^-1 z(0)``.

    Returns
    -------
    ndarray, same shape as ``z``
        ``out[..., k, :] = e(k|k-1)`` for k >= 1; ``out[..., 0, :] = 0``.
    """
    return NonlinearSgnSVSF(model, gamma).run(z, u, x0=x0).e_prior
