"""The monitor's filter front end: the auxiliary ``sgn`` SVSF and the optional ``sat`` SVSF, pushed.

:class:`MonitorFilters` turns measurement chunks into chattering (the auxiliary filter's a-priori
output error, eq 17 of the core paper) and, when a boundary layer ``psi`` is set, the smoothing
SVSF's output estimate. It keeps the filters' states and the one pending input between pushes, so
any chunking gives the same numbers as :meth:`chatterspec.filters.svsf.SVSF.update` on the whole
record. With numba, both filters of a push run in one compiled call
(:func:`chatterspec.online._push_kernels.filters_kernel`: the same kernels and sums, the same bits).

See Also
--------
chatterspec.online.monitor.ChatteringMonitor : the monitor that owns one of these.
chatterspec.online.monitor_frames.FrameAnalysis : what the chattering goes to next.
"""

from __future__ import annotations

from typing import cast

import numpy as np

from .. import _jit
from ..filters.svsf import SVSF, NonlinearSgnSVSF, NonlinearSVSFState, SVSFState, auxiliary_svsf
from ..filters.svsf_recursion import rows_times as _rows_times
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel
from ._push_kernels import filters_kernel, filters_one_kernel
from .monitor_types import MonitorSettings

__all__ = ["MonitorFilters"]


class MonitorFilters:
    """Both SVSFs of a :class:`~chatterspec.online.monitor.ChatteringMonitor`, advanced push by push.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        Nominal model (already checked by the monitor).
    settings : MonitorSettings
        ``gamma`` for both filters, ``psi`` (boundary layer of the ``sat`` SVSF, None: no estimate).

    Attributes
    ----------
    fused : bool
        Whether a push runs both filters in one compiled call (full measurement, at least one input,
        numba installed; the call is also skipped while compiled kernels are disabled).
    n_meas : int
        Measurements consumed so far (the first one only initializes the filters).
    """

    def __init__(self, model: LinearModel | NonlinearModel, settings: MonitorSettings) -> None:
        s = settings
        self.model = model
        nonlinear = isinstance(model, NonlinearModel)
        self._aux = NonlinearSgnSVSF(model, s.gamma) if nonlinear else auxiliary_svsf(model, s.gamma)
        self._sat = None if s.psi is None else SVSF(model, psi=np.asarray(s.psi), gamma=s.gamma)
        self._aux_state_obj: SVSFState | NonlinearSVSFState | None = None
        self._sat_state_obj: SVSFState | None = None
        # one compiled call per push for both filters (full measurement: the closed form of eq 23;
        # at least one input; numba installed, and enabled at push time)
        self.fused = (
            isinstance(self._aux, SVSF)
            and self._aux._L is None
            and model.n_inputs >= 1
            and _jit.HAVE_NUMBA
            and _jit.fits(model.n_states, model.n_outputs, vectors_only=True)
        )
        if self.fused:
            aux = cast(SVSF, self._aux)  # (fused: the linear auxiliary SVSF)
            self._GT = np.ascontiguousarray(aux._GT, dtype=float)
            self._aux_PhiT = np.ascontiguousarray(aux._PhiT, dtype=float)
            self._none3 = np.empty((0, 0, 0))
            e2 = np.empty((0, 0))
            self._no_sat = (e2, e2, e2, np.empty(0), 0.0, e2, e2, e2, self._none3, self._none3, self._none3)
            # the push loop, unrolled for small models (the EHA's 3 states): same steps, same bits
            self._kernel = filters_kernel(model.n_states, model.n_outputs)
            self._one = filters_one_kernel(model.n_states, model.n_outputs)
            self._one_cst = self._one_constants()
        # C = I (every state measured in its own units, the EHA): the estimate C x is x itself
        C = getattr(model, "C", None)
        self._C_identity = C is not None and C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(len(C)))
        self._pending_obj: np.ndarray | None = None
        # the fused path's state between samples and pushes, in one array (the per-sample kernel's
        # layout): pending u(k), the aux y(k|k) = z(k), the sat filter's y and e(k|k), its estimate
        self._st: np.ndarray | None = None
        self.n_meas = 0

    def _one_constants(self) -> np.ndarray:
        """``cst`` of :func:`._push_kernels._filters_one` (zeros in the sat filter's place without one)."""
        model, sat = self.model, self._sat
        n, m, p = model.n_states, model.n_outputs, model.n_inputs
        if sat is None:
            head = [n, m, p, 0, 0.0, 0.0, 0.0, 0.0]
            sat_parts: list[np.ndarray] = [np.zeros(n * n), np.zeros(n), np.zeros(n * n)]
        else:
            PhiT, L_, P_, inv_psi_, gamma, S_inv = sat._kernel_consts
            # (the kernel's constants: empty arrays, never None)
            L, P, inv_psi = cast(np.ndarray, L_), cast(np.ndarray, P_), cast(np.ndarray, inv_psi_)
            psi_n = np.zeros(n)
            psi_n[: inv_psi.size] = inv_psi
            head = [n, m, p, L.shape[0], 1.0, gamma, 0.0, 0.0]
            sat_parts = [PhiT, L, P, psi_n, S_inv]
        parts = [np.asarray(head, dtype=float), self._GT, self._aux_PhiT, *sat_parts]
        return np.ascontiguousarray(np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in parts]))

    def _pack(self) -> None:
        """Move the states into the fused path's array (after the first push, whichever path made them)."""
        n, m, p = self.model.n_states, self.model.n_outputs, self.model.n_inputs
        st = np.zeros(p + m + n + m + n + m)
        st[:p] = cast(np.ndarray, self._pending_obj)  # (the first push set them all)
        st[p : p + m] = cast(SVSFState, self._aux_state_obj).y[0]
        if self._sat is not None:
            sat = cast(SVSFState, self._sat_state_obj)
            st[p + m : p + m + n] = sat.y[0]
            st[p + m + n : p + 2 * m + n] = sat.e_post[0]
            st[p + 2 * m + n : p + 2 * m + 2 * n] = (sat.y @ self._sat._S_inv.T)[0]
        self._st = st

    @property
    def _pending_u(self) -> np.ndarray | None:
        return self._pending_obj if self._st is None else self._st[: self.model.n_inputs]

    @_pending_u.setter
    def _pending_u(self, value: np.ndarray) -> None:
        if self._st is None:
            self._pending_obj = value
        else:
            self._st[: self.model.n_inputs] = value

    # the states as SVSFState objects (views of the fused path's array when it holds them)
    @property
    def _aux_state(self) -> SVSFState | NonlinearSVSFState | None:
        if self._st is None:
            return self._aux_state_obj
        p, m = self.model.n_inputs, self.model.n_outputs
        return SVSFState(y=self._st[None, p : p + m], e_post=np.zeros((1, m)), k=self.n_meas - 1)

    @_aux_state.setter
    def _aux_state(self, value: SVSFState | NonlinearSVSFState | None) -> None:
        self._aux_state_obj = value
        if self._st is not None and value is not None:
            p, m = self.model.n_inputs, self.model.n_outputs
            self._st[p : p + m] = value.y[0]

    @property
    def _sat_state(self) -> SVSFState | None:
        if self._st is None or self._sat is None:
            return self._sat_state_obj
        p, m, n = self.model.n_inputs, self.model.n_outputs, self.model.n_states
        o = p + m
        return SVSFState(
            y=self._st[None, o : o + n], e_post=self._st[None, o + n : o + n + m], k=self.n_meas - 1
        )

    @_sat_state.setter
    def _sat_state(self, value: SVSFState | None) -> None:
        self._sat_state_obj = value
        if self._st is not None and value is not None:
            p, m, n = self.model.n_inputs, self.model.n_outputs, self.model.n_states
            o = p + m
            self._st[o : o + n] = value.y[0]
            self._st[o + n : o + n + m] = value.e_post[0]

    @property
    def has_estimate(self) -> bool:
        """Whether pushes return the ``sat`` SVSF's output estimate (``psi`` was given)."""
        return self._sat is not None

    def advance(self, z: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Consume measurements ``z`` (K, m) and inputs ``u`` (K, p) (checked, K >= 1).

        ``u(k)`` drives x(k) -> x(k+1), so each push uses the previous push's last input first.
        The very first measurement only initializes the filters.

        Returns
        -------
        z_used : (K', m) array
            The measurements that produced chattering (``z`` without its first row on the first push).
        e : (K', m) array
            The chattering ``e(k+1|k)``, one row per row of ``z_used``.
        estimate : (K', m) array or None
            The ``sat`` SVSF's output estimate ``C x(k|k)`` (None without ``psi``).
        """
        if self._aux_state is None:
            self._aux_state = self._aux.initialize(z[:1])
            if self._sat is not None:
                self._sat_state = self._sat.initialize(z[:1])
            self._pending_u = u[0].copy()  # not a view of the caller's array
            self.n_meas = 1
            if self.fused:
                self._pack()
            z, u = z[1:], u[1:]
        K = z.shape[0]
        if K == 0:
            return z, z[:0], None
        u_used = np.empty((K, u.shape[1]))
        u_used[0] = self._pending_u
        u_used[1:] = u[:-1]
        self._pending_u = u[-1].copy()
        if self.fused and _jit.enabled():
            e, estimate = self._advance_fused(z, u_used)
        elif isinstance(self._aux, SVSF):
            # the checks of SVSF.update are done by the monitor; both filters share the model, hence G u(k)
            Gu = _rows_times(u_used, self._aux._GT, channel_major=True)
            self._aux_state, out = self._aux._advance(cast(SVSFState, self._aux_state), z[None], Gu)
            e, estimate = out.e_prior[0], None
            if self._sat is not None:
                sat_state = cast(SVSFState, self._sat_state)  # (initialized with the aux state)
                self._sat_state, sat_out = self._sat._advance(sat_state, z[None], Gu, store_states=True)
                estimate = self._output(cast(np.ndarray, sat_out.x_post)[0])  # (store_states)
        else:  # nonlinear auxiliary filter (no sat SVSF)
            aux_state = cast(NonlinearSVSFState, self._aux_state)
            self._aux_state, nl_out = self._aux.update(aux_state, z[None], u_used, check=False)
            e, estimate = nl_out.e_prior[0], None
        self.n_meas += K
        return z, e, estimate

    def _advance_fused(self, z: np.ndarray, u_used: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Both filters over one push in one compiled call (:func:`._push_kernels.filters_kernel`).

        The same steps and sums as :meth:`SVSF.update` with compiled kernels on (closed form of
        eq 23 for the aux filter, whose a-posteriori error stays exactly 0; the recursion for
        the sat SVSF), without its per-call Python work; returns ``(e, estimate)``.
        """
        K, m = z.shape
        n, p = self.model.n_states, self.model.n_inputs
        z3 = np.ascontiguousarray(z)[None]  # one compiled specialization (no copy when contiguous)
        st = cast(np.ndarray, self._st)  # views of the state array: the kernel updates y, e(k|k) in place
        aux_y = st[None, p : p + m]
        e = np.empty((1, K, m))
        sat = self._sat
        none = self._none3
        if sat is None:
            self._kernel(z3, u_used, self._GT, self._aux_PhiT, aux_y, e, none, False, *self._no_sat)
            estimate = None
        else:
            PhiT, L, P, inv_psi, gamma, S_inv = sat._kernel_consts
            o = p + m
            y, ep = st[None, o : o + n], st[None, o + n : o + n + m]
            x_out = np.empty((1, K, n))
            self._kernel(
                z3, u_used, self._GT, self._aux_PhiT, aux_y, e, none, True,
                PhiT, L, P, inv_psi, gamma, S_inv, y, ep, none, x_out, none,
            )  # fmt: skip
            st[o + n + m : o + n + m + n] = x_out[0, -1]
            estimate = self._output(x_out[0])
        # the closed form's state: y(k|k) = z(k) exactly, e(k|k) = 0 (see SVSF.update, Notes)
        aux_y[0] = z[-1]
        st[-m:] = e[0, -1]
        return e[0], estimate

    def step(self, z: np.ndarray, u: np.ndarray, ebuf: np.ndarray, row: int) -> int:
        """One sample of both filters in one compiled call (:func:`._push_kernels.filters_one_kernel`).

        Only on the fused path after the first measurement. ``z`` (m,), ``u`` (p,) (float,
        contiguous); the chattering goes to ``ebuf[row]``. Returns 0, or 3 when ``z`` or ``u`` is
        not finite (nothing consumed). The sample's estimate is then :meth:`last_estimate`.
        """
        status = int(self._one(self._one_cst, self._st, z, u, ebuf, row))
        if status == 0:
            self.n_meas += 1
        return status

    def last_estimate(self) -> np.ndarray | None:
        """The sat SVSF's output estimate ``C x(k|k)`` (m,) of the last sample (None without ``psi``)."""
        if self._sat is None or self._st is None:
            return None
        n, m = self.model.n_states, self.model.n_outputs
        x = self._st[-n - m : -m]
        return x.copy() if self._C_identity else self.model.C @ x

    def last_chattering(self) -> np.ndarray | None:
        """The chattering ``e(k|k-1)`` (m,) of the last sample (fused path)."""
        return None if self._st is None else self._st[-self.model.n_outputs :].copy()

    def _output(self, x: np.ndarray) -> np.ndarray:
        """The sat-SVSF's output estimate ``C x(k|k)`` (K, m) of its states ``x`` (K, n): ``x`` itself
        when ``C`` is the identity (the same values as the product, which only adds exact zeros:
        the BLAS call cost 8 us of a push's ~150 us)."""
        return x if self._C_identity else x @ self.model.C.T
