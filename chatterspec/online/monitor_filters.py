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
from ..filters.nonlinear_svsf import NonlinearSgnSVSF, NonlinearSVSFState
from ..filters.svsf import SVSF, SVSFState, auxiliary_svsf
from ..filters.svsf_steps import rows_times as _rows_times
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel
from ._push_kernels import filters_kernel
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
        self._aux_state: SVSFState | NonlinearSVSFState | None = None
        self._sat_state: SVSFState | None = None
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
        # C = I (every state measured in its own units, the EHA): the estimate C x is x itself
        C = getattr(model, "C", None)
        self._C_identity = C is not None and C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(len(C)))
        self._pending_u: np.ndarray | None = None
        self.n_meas = 0

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
        z3 = np.ascontiguousarray(z)[None]  # one compiled specialization (no copy when contiguous)
        aux = cast(SVSFState, self._aux_state)  # (fused: the linear auxiliary SVSF, initialized)
        e = np.empty((1, K, m))
        sat = self._sat
        none = self._none3
        if sat is None:
            self._kernel(z3, u_used, self._GT, self._aux_PhiT, aux.y, e, none, False, *self._no_sat)
            estimate = None
        else:
            PhiT, L, P, inv_psi, gamma, S_inv = sat._kernel_consts
            st = cast(SVSFState, self._sat_state)  # (initialized with the aux state)
            y, ep = st.y.copy(), st.e_post.copy()
            x_out = np.empty((1, K, self.model.n_states))
            self._kernel(
                z3, u_used, self._GT, self._aux_PhiT, aux.y, e, none, True,
                PhiT, L, P, inv_psi, gamma, S_inv, y, ep, none, x_out, none,
            )  # fmt: skip
            self._sat_state = SVSFState(y=y, e_post=ep, k=st.k + K)
            estimate = self._output(x_out[0])
        # the closed form's state: y(k|k) = z(k) exactly, e(k|k) = 0 (see SVSF.update, Notes)
        self._aux_state = SVSFState(y=z[-1:].copy(), e_post=aux.e_post, k=aux.k + K)
        return e[0], estimate

    def _output(self, x: np.ndarray) -> np.ndarray:
        """The sat-SVSF's output estimate ``C x(k|k)`` (K, m) of its states ``x`` (K, n): ``x`` itself
        when ``C`` is the identity (the same values as the product, which only adds exact zeros:
        the BLAS call cost 8 us of a push's ~150 us)."""
        return x if self._C_identity else x @ self.model.C.T
