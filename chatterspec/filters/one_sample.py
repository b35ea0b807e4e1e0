"""Filters advanced one sample per call, for a user's own control or acquisition loop.

``filter.online(x0, P0)`` (every covariance filter: :class:`~chatterspec.filters.kalman.KalmanFilter`,
:class:`~chatterspec.filters.kalman.ExtendedKalmanFilter`, :class:`~chatterspec.filters.svsf_cov.SVSFCov`,
:class:`~chatterspec.filters.svsf2.SecondOrderSVSF`) returns an :class:`OnlineFilter`: one realization
whose state it holds, advanced by :meth:`OnlineFilter.step` with one measurement ``z(k+1)`` and the
input ``u(k)`` per call, returning ``x(k+1|k+1)``::

    f = cs.KalmanFilter(model).online(x0, P0)
    for z, u in readings:          # z (m,), u (p,): the input that drove x(k) -> x(k+1)
        x = f.step(z, u)

Each call is one call of a compiled loop (:func:`chatterspec.filters._engine._cov_one`) built from the
same steps as the batch loop, so the estimates are bit for bit those of ``filter.update`` /
``filter.run`` on the same data whenever the batch path is compiled (numba installed, a model with
compiled steps: linear, the EHA4, or a model built from compiled functions). Shapes are fixed when the
object is made; a call checks only what keeps it safe: ``z`` of shape ``(m,)`` (a number when
``m = 1``), ``u`` of shape ``(p,)`` or None, and finiteness inside the compiled call (a NaN or inf
input raises :class:`~chatterspec.errors.NonFiniteError`, a non-finite result
:class:`~chatterspec.errors.DivergenceError` naming the sample; either leaves the state as it was).
Without numba, or for a model whose ``transition`` is a Python function, a call is
``filter.update`` on one sample: the same numbers as the batch path, at its per-call cost.

See Also
--------
chatterspec.filters.protocol.Filter : the batch interface (``initialize``, ``update``, ``run``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .. import _jit
from ..errors import DivergenceError, NonFiniteError, ShapeError, SingularMatrixError
from ..plants.nonlinear import has_measurement_function
from ..plants.steps import measurement_steps
from . import _engine
from .protocol import FilterState, sample_rows

__all__ = ["OnlineBank", "OnlineFilter", "OnlineSVSF"]


def _bad_input(who: str, k: int, z: np.ndarray, u: np.ndarray) -> NonFiniteError:
    """The error of a NaN/inf in sample ``k``'s ``z`` or ``u``."""
    bad = "z" if not np.isfinite(z).all() else "u"
    return NonFiniteError(f"{who}: {bad} of sample k = {k} contains NaN/inf; all entries must be finite")


def _finite_input(who: str, k: int, z: np.ndarray, u: np.ndarray) -> None:
    """The compiled calls' input check, for the paths through ``update``."""
    if not (np.isfinite(z).all() and np.isfinite(u).all()):
        raise _bad_input(who, k, z, u)


def _diverged(who: str, k: int) -> DivergenceError:
    """The error of an estimate that is not finite after sample ``k``."""
    return DivergenceError(
        f"{who}: the estimate is not finite from sample k = {k} (realization 0): the filter diverged. "
        "Check the model: an unstable or mismatched A (or f) makes the estimate overflow"
    )


class _OneRealization:
    """What every one-sample filter holds and checks: one realization's sizes and its sample index."""

    __slots__ = ("_buf", "_call", "_cst", "_k", "_m", "_n", "_p", "_state", "_u0", "compiled")
    _buf: np.ndarray  # the compiled step's state buffer

    def _start(self, model: Any, state: Any, ok: bool, expected: str, runs: int, what: str) -> None:
        """Refuse a state of another kind (``ok`` false) or of several realizations; take the sizes."""
        if not ok:
            raise TypeError(f"state must be {expected}; got {type(state).__name__}")
        if runs != 1:
            raise ShapeError(f"an online {what} follows one realization; the state holds {runs}")
        self._n, self._m, self._p = int(model.n_states), int(model.n_outputs), int(model.n_inputs)
        self._u0 = np.zeros(self._p)
        self._k = int(state.k)

    def _field(self, o: int, shape: tuple[int, ...]) -> np.ndarray:
        """A copy of the state buffer's field of ``shape`` at offset ``o``."""
        size = int(np.prod(shape, dtype=np.int64))
        return self._buf[o : o + size].reshape(shape).copy()

    @property
    def k(self) -> int:
        """Index of the last sample processed (0 before the first step)."""
        return self._k


class OnlineFilter(_OneRealization):
    """A covariance filter and the state of one realization, advanced one sample per :meth:`step`.

    Made by ``filter.online(x0, P0)`` (or from a one-run :class:`~chatterspec.filters.protocol.FilterState`).

    Parameters
    ----------
    filter : covariance filter
        ``KalmanFilter``, ``ExtendedKalmanFilter``, ``SVSFCov`` or ``SecondOrderSVSF``.
    state : FilterState
        The posterior after sample ``k`` of one realization (``runs == 1``).

    Attributes
    ----------
    filter : covariance filter
        The filter.
    compiled : bool
        Whether a step is one compiled call (else ``filter.update`` on one sample).

    Raises
    ------
    ShapeError
        ``state`` holds more than one realization.
    """

    __slots__ = ("_last", "_off", "_stepped", "filter")

    def __init__(self, filter: Any, state: FilterState) -> None:
        model = filter.model
        ok = isinstance(state, FilterState)
        self._start(model, state, ok, "a FilterState", state.runs if ok else 1, "filter")
        self.filter = filter
        n, m, p = self._n, self._m, self._p
        corr = filter._correction_step()
        plant = filter._plant()
        hx = measurement_steps(model) if has_measurement_function(model) else None
        self.compiled = bool(
            _jit.enabled()
            and plant is not None
            and corr.mapping != _engine.MAP_LUEN
            and (hx is not None or not has_measurement_function(model))
            and _jit.fits(n, m)
        )
        self._off = _jit.python_form(_engine.one_offsets)(n, m)
        self._state: FilterState | None = None
        self._last: dict[str, np.ndarray | None] = {}
        self._stepped = False
        if self.compiled:
            self._buf = np.zeros(self._off[-1])
            self._write(state)
            self._cst = _engine.one_sample_constants(
                plant.parameters,
                model.C,
                model.Q,
                model.R,
                corr.parameters,
                p,
            )
            self._call = _engine.one_sample_kernel(corr, plant, n, m, hx)
        else:
            self._state = state

    # ------------------------------------------------------------------ the step
    def step(self, z: object, u: object | None = None) -> np.ndarray:
        """Advance by one sample: ``z(k+1)`` and the input ``u(k)``; returns ``x(k+1|k+1)`` (a new array).

        Parameters
        ----------
        z : (m,) array_like or float
            The measurement (a number when the model has one output).
        u : (p,) array_like or float, optional
            The input that drove ``x(k) -> x(k+1)``; None: zeros.

        Returns
        -------
        (n,) ndarray

        Raises
        ------
        ShapeError
            ``z`` or ``u`` of another shape.
        NonFiniteError
            NaN or inf in ``z`` or ``u``.
        DivergenceError
            The estimate or covariance is not finite after this sample (the model diverges).
        SingularMatrixError
            An innovation covariance that is not positive definite.
        """
        z = sample_rows("z", z, self._m)  # inline: a helper call shows against a 2-3 us step
        u = self._u0 if u is None else sample_rows("u", u, self._p)
        if not self.compiled:
            return self._update(z, u)
        status = self._call(self._buf, self._cst, z, u)
        if status:
            self._fail(status, z, u)
        self._k += 1
        self._stepped = True
        return self._buf[: self._n].copy()

    def _update(self, z: np.ndarray, u: np.ndarray) -> np.ndarray:
        """The step through ``filter.update`` (numpy path, or a model's Python transition)."""
        keep = ("x_prior", "x_post", "innovation", "S", "loglik", "P_prior")
        _finite_input(type(self.filter).__name__, self._k + 1, z, u)
        state, out = self.filter.update(self._state, z[None, None], u[None], store=keep)
        self._state = state
        self._k = state.k
        self._last = {f: getattr(out, f) for f in keep}
        self._stepped = True
        return out.x_post[0, 0].copy()

    def _fail(self, status: int, z: np.ndarray, u: np.ndarray) -> None:
        who = type(self.filter).__name__
        k = self._k + 1
        if status == _engine.BAD_INPUT:
            raise _bad_input(who, k, z, u)
        if status == _engine.DIVERGED or not np.isfinite(self._buf).all():
            raise _diverged(who, k)
        if status == _engine.SINGULAR_PHI12:
            raise SingularMatrixError(_engine._luen_message())
        raise SingularMatrixError(_engine._not_pd_message(self.filter._correction_step().mapping, 0))

    # ------------------------------------------------------------------ state
    def _write(self, state: FilterState) -> None:
        n, m = self._n, self._m
        o_P, o_ep, o_epp = self._off[0], self._off[1], self._off[2]
        buf = self._buf
        buf[:n] = state.x[0]
        buf[o_P : o_P + n * n] = np.broadcast_to(state.P, (1, n, n))[0].ravel()
        buf[o_ep : o_ep + m] = state.e_post[0]
        buf[o_epp : o_epp + m] = state.e_prev[0]

    @property
    def x(self) -> np.ndarray:
        """``x(k|k)`` (n,) (copy)."""
        if not self.compiled:
            return self._state.x[0].copy()  # type: ignore[union-attr]
        return self._buf[: self._n].copy()

    @property
    def P(self) -> np.ndarray:
        """``P(k|k)`` (n, n) (copy)."""
        n = self._n
        if not self.compiled:
            return np.broadcast_to(self._state.P, (1, n, n))[0].copy()  # type: ignore[union-attr]
        return self._field(self._off[0], (n, n))

    @property
    def state(self) -> FilterState:
        """The posterior as a one-run :class:`FilterState` (for ``filter.update`` on later chunks)."""
        if not self.compiled:
            return self._state  # type: ignore[return-value]
        n, m = self._n, self._m
        o_P, o_ep, o_epp = self._off[0], self._off[1], self._off[2]
        return FilterState(
            x=self._field(0, (1, n)),
            P=self._field(o_P, (1, n, n)),
            e_post=self._field(o_ep, (1, m)),
            e_prev=self._field(o_epp, (1, m)),
            k=self._k,
        )

    def _output(self, name: str, index: int, shape: tuple[int, ...]) -> np.ndarray | None:
        if not self._stepped:
            return None
        if not self.compiled:
            v = self._last.get(name)
            return None if v is None else np.array(np.broadcast_to(v, (1, 1, *shape))[0, 0])
        return self._field(self._off[index], shape)

    @property
    def x_prior(self) -> np.ndarray | None:
        """The last sample's prior ``x(k|k-1)`` (n,), None before the first step."""
        return self._output("x_prior", 3, (self._n,))

    @property
    def innovation(self) -> np.ndarray | None:
        """The last sample's innovation ``e(k|k-1) = z(k) - C x(k|k-1)`` (m,), None before the first step."""
        return self._output("innovation", 4, (self._m,))

    @property
    def S(self) -> np.ndarray | None:
        """The last sample's innovation covariance (m, m), None before the first step."""
        return self._output("S", 5, (self._m, self._m))

    @property
    def loglik(self) -> float | None:
        """The last sample's ``log N(e; 0, S)``, None before the first step."""
        v = self._output("loglik", 6, ())
        return None if v is None else float(v)

    @property
    def P_prior(self) -> np.ndarray | None:
        """The last sample's prior covariance ``P(k|k-1)`` (n, n), None before the first step."""
        return self._output("P_prior", 7, (self._n, self._n))

    def __repr__(self) -> str:
        path = "compiled" if self.compiled else "update"
        return f"OnlineFilter({type(self.filter).__name__}, k={self._k}, n={self._n}, m={self._m}, {path})"


class OnlineBank(_OneRealization):
    """A multiple-model bank and the state of one realization, advanced one sample per :meth:`step`.

    The bank is an :class:`~chatterspec.filters.imm.IMM` or an
    :class:`~chatterspec.filters.smm_svsf.SMMSVSF`.

    Made by ``bank.online(x0, P0)``. A step is one call of the bank's compiled sample loop (the
    per-sample step of its batch loop, hence its bits) when the bank's batch path is compiled,
    otherwise ``bank.update`` on one sample.

    Parameters
    ----------
    bank : IMM or SMMSVSF
        The bank.
    state : MultipleModelState
        The state after sample ``k`` of one realization.

    Attributes
    ----------
    bank : IMM or SMMSVSF
        The bank.
    compiled : bool
        Whether a step is one compiled call.
    """

    __slots__ = ("_ll", "_nm", "_offsets", "_slots", "_stepped", "bank")

    def __init__(self, bank: Any, state: Any) -> None:
        ok = all(hasattr(state, a) for a in ("x", "P", "mu", "z_last", "mode_states", "k"))
        self._start(
            bank._sensor_model(), state, ok, "a MultipleModelState", state.x.shape[0] if ok else 1, "bank"
        )
        self.bank = bank
        self._nm = len(bank.modes)
        self._stepped = False
        self._state = state
        self._ll: np.ndarray | None = None
        # the bank's one-sample kernel and its packed arrays (``_one_pack``), or None: update per sample
        packed = bank._one_pack(state) if _jit.enabled() else None
        self.compiled = packed is not None
        if packed is not None:
            self._call, self._buf, self._cst, self._slots, self._offsets = packed

    def step(self, z: object, u: object | None = None) -> np.ndarray:
        """Advance by one sample (``z``, ``u`` as :meth:`OnlineFilter.step`); the combined ``x(k+1|k+1)``.

        Raises
        ------
        ShapeError, NonFiniteError, DivergenceError, SingularMatrixError
            As :meth:`OnlineFilter.step`; SingularMatrixError also when every mode likelihood is zero.
        """
        z = sample_rows("z", z, self._m)  # inline: a helper call shows against a 2-3 us step
        u = self._u0 if u is None else sample_rows("u", u, self._p)
        if not self.compiled:
            _finite_input(type(self.bank).__name__, self._k + 1, z, u)
            state, out = self.bank.update(self._state, z[None, None], u[None])
            self._state = state
            self._ll = out.loglik[0, 0].copy()
            self._k = state.k
            self._stepped = True
            return out.x_post[0, 0].copy()
        status = self._call(self._buf, self._cst, self._slots, z, u)
        if status:
            self._fail(status, z, u)
        self._k += 1
        self._stepped = True
        o = self._offsets[0]
        return self._buf[o : o + self._n].copy()

    def _fail(self, status: int, z: np.ndarray, u: np.ndarray) -> None:
        who = type(self.bank).__name__
        k = self._k + 1
        if status == _engine.BAD_INPUT:
            raise _bad_input(who, k, z, u)
        if status == _engine.DIVERGED:
            raise _diverged(who, k)
        if status == _engine.SINGULAR_PHI12:
            raise SingularMatrixError(_engine._luen_message())
        if status == _engine.NOT_PD:
            raise SingularMatrixError(_engine._not_pd_message(_engine.MAP_CONST, 0))
        raise SingularMatrixError(
            f"{who}: every mode likelihood is zero or non-finite at sample k = {k}; check R and Q of the "
            "mode models (the innovation covariance) and the measurement units"
        )

    @property
    def x(self) -> np.ndarray:
        """The combined ``x(k|k)`` (n,) (copy)."""
        if not self.compiled:
            return self._state.x[0].copy()
        return self._field(self._offsets[0], (self._n,))

    @property
    def P(self) -> np.ndarray:
        """The combined ``P(k|k)`` (n, n) (copy)."""
        n = self._n
        if not self.compiled:
            return np.broadcast_to(self._state.P, (1, n, n))[0].copy()
        return self._field(self._offsets[1], (n, n))

    @property
    def mu(self) -> np.ndarray:
        """Mode probabilities / weights after sample ``k`` (r,) (copy)."""
        if not self.compiled:
            return self._state.mu[0].copy()
        return self._field(self._offsets[2], (self._nm,))

    @property
    def state(self) -> Any:
        """The state as a one-run :class:`~chatterspec.filters.bank.MultipleModelState`."""
        if not self.compiled:
            return self._state
        return self.bank._one_state(self._field, self._state, self._k)

    @property
    def loglik(self) -> np.ndarray | None:
        """The last sample's log-likelihood of each mode (r,), None before the first step."""
        if not self._stepped:
            return None
        if not self.compiled:
            return None if self._ll is None else self._ll.copy()
        return self._field(self._offsets[3], (self._nm,))

    def __repr__(self) -> str:
        path = "compiled" if self.compiled else "update"
        return f"OnlineBank({type(self.bank).__name__}, k={self._k}, modes={self._nm}, {path})"


class OnlineSVSF(_OneRealization):
    """The chattering SVSF (:class:`~chatterspec.filters.svsf.SVSF`, sat or sgn) advanced one sample per call.

    Made by ``svsf.online(z0)``. A step is one compiled call built from the steps of
    :meth:`SVSF.update <chatterspec.filters.svsf.SVSF.update>`'s compiled paths, the choice made
    once for the whole stream as ``update`` makes it for a record (the closed form of eq 23 for the
    auxiliary sgn filter started with ``e(k|k) = 0``, else eq 4-12), hence the bits of ``update``
    (or ``run``) on the whole record; without numba (or for sizes beyond the compiled scratch),
    ``update`` on one sample.

    Parameters
    ----------
    svsf : SVSF
        The filter.
    state : SVSFState
        Its state after sample ``k``, one realization.

    Attributes
    ----------
    svsf : SVSF
        The filter.
    compiled : bool
        Whether a step is one compiled call.
    """

    __slots__ = ("_closed", "_last", "svsf")

    def __init__(self, svsf: Any, state: Any) -> None:
        from . import svsf_recursion
        from .svsf_recursion import SVSFState

        model = svsf.model
        ok = isinstance(state, SVSFState)
        self._start(model, state, ok, "an SVSFState", state.runs if ok else 1, "filter")
        n, m, p = self._n, self._m, self._p
        self.svsf = svsf
        self._state = state
        self._last: np.ndarray | None = None
        # the closed form of eq (23) for a record that starts with e(k|k) = 0, as update() picks it
        self._closed = bool(svsf._inv_psi is None and svsf._L is None and not state.e_post.any())
        self.compiled = bool(_jit.enabled() and _jit.fits(n, m, vectors_only=True))
        if self.compiled:
            PhiT, L, P, inv_psi, gamma, S_inv = svsf._kernel_consts
            nl = L.shape[0]
            psi_n = np.zeros(n)
            psi_n[: inv_psi.size] = inv_psi
            head = [n, m, p, nl, float(inv_psi.size > 0), gamma, float(self._closed), 0.0]
            parts = [head, svsf._GT, PhiT, L, P, psi_n, S_inv, S_inv.T]
            self._cst = np.ascontiguousarray(
                np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in parts])
            )
            self._buf = np.zeros(2 * n + 2 * m)
            self._buf[:n] = state.y[0]
            self._buf[n : n + m] = state.e_post[0]
            self._call = svsf_recursion.svsf_one_kernel(n, m)

    def step(self, z: object, u: object | None = None) -> np.ndarray:
        """Advance by one sample: ``z(k+1)`` and ``u(k)``; returns ``x(k+1|k+1)`` (n,) (a new array).

        The chattering of this sample, ``e(k+1|k)``, is then :attr:`e_prior`.

        Raises
        ------
        ShapeError, NonFiniteError, DivergenceError
            As :meth:`OnlineFilter.step`.
        """
        z = sample_rows("z", z, self._m)  # inline: a helper call shows against a 2-3 us step
        u = self._u0 if u is None else sample_rows("u", u, self._p)
        if not self.compiled:
            _finite_input("SVSF", self._k + 1, z, u)
            # the whole record's choice of path (a chunk of update() would take the closed form
            # as soon as e(k|k) reaches exactly 0)
            state, out = self.svsf.update(
                self._state, z[None, None], u[None], store={"x_post"}, closed_form=self._closed
            )
            self._state, self._k = state, state.k
            self._last = out.e_prior[0, 0].copy()
            return out.x_post[0, 0].copy()
        status = self._call(self._buf, self._cst, z, u)
        if status == _engine.BAD_INPUT:
            raise _bad_input("SVSF", self._k + 1, z, u)
        if status:
            raise _diverged("SVSF", self._k + 1)
        self._k += 1
        n, m = self._n, self._m
        return self._buf[n + 2 * m :].copy()

    @property
    def e_prior(self) -> np.ndarray | None:
        """The last sample's a-priori error ``e(k|k-1)`` (m,): the chattering (eq 17); None before a step."""
        if not self.compiled:
            return None if self._last is None else self._last.copy()
        n, m = self._n, self._m
        return None if self._k == self._state.k else self._buf[n + m : n + 2 * m].copy()

    @property
    def state(self) -> Any:
        """The state as a one-run :class:`~chatterspec.filters.svsf.SVSFState` (``update`` takes it on)."""
        if not self.compiled:
            return self._state
        from .svsf_recursion import SVSFState

        n, m = self._n, self._m
        return SVSFState(y=self._buf[None, :n].copy(), e_post=self._buf[None, n : n + m].copy(), k=self._k)

    @property
    def x(self) -> np.ndarray:
        """``x(k|k)`` (n,) (copy)."""
        st = self.state
        return (
            (st.y @ self.svsf._S_inv.T)[0]
            if self._k == self._state.k
            else self._buf[self._n + 2 * self._m :].copy()
        )

    def __repr__(self) -> str:
        path = "compiled" if self.compiled else "update"
        return f"OnlineSVSF({self.svsf.switching}, k={self._k}, n={self._n}, m={self._m}, {path})"
