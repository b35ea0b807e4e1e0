"""Interacting multiple-model estimator ([IMM] eq 15-33, corrected), batched over realizations.

Notation and corrections of ``docs/design.md`` §7.5-§7.6. Per sample, with the transition matrix
``pi[i, j] = P(j at k | i at k-1)``::

    (19) c_j = sum_i pi_ij mu_i(k-1)          (18) mu_{i|j} = pi_ij mu_i(k-1) / c_j  (printed 1/mu_j)
    (20) x_0j = sum_i mu_{i|j} x_i            (21) P_0j = sum_i mu_{i|j} [P_i + (x_i - x_0j)(.)^T]
    (22)-(28) mode-matched filter j (any :class:`~chatterspec.filters.protocol.Filter`) from (x_0j, P_0j)
    (29) Lambda_j = N(e_j; 0, S_j)            (30) mu_j(k) ∝ c_j Lambda_j   (log domain)
    (31) x = sum_j mu_j x_j                   (32)-(33) P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]

The printed (32)-(33) sum ``mu_i mu_j (x_i - x_j)(x_i - x_j)^T`` over all ``i, j``; that is exactly twice
the spread of (33) here (:func:`~chatterspec.filters.bank_math.pairwise_spread`, tested), so it is read
with a factor 1/2. For the SVSF-type mode filters, ``e(k|k)`` of mode j is the residual of its mixed
estimate ``z(k) - C x_0j`` (``docs/design.md`` I4); ``e(k-1|k-1)`` stays the value that mode stored.
Likelihoods are :func:`~chatterspec.filters.bank_math.log_gaussian`.

**Compiled step.** When :func:`chatterspec._jit.enabled` and every mode is supported (EKF/KF,
SVSF-cov without ``vbl``, second-order SVSF, on nonlinear-EHA or linear models; see
:mod:`chatterspec.filters._imm_kernel`), :meth:`IMM.update` runs the whole recursion in one compiled
loop over runs and samples; otherwise it drives the mode filters through the protocol, one sample at
a time. The two agree to rounding (summation order; tolerances in ``tests/test_imm_kernel.py``), and
each is chunk-invariant bit for bit.

See Also
--------
chatterspec.filters.smm_svsf.SMMSVSF : the static multiple-model SVSF.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .. import _jit
from .._repr import short_repr
from ..plants.nonlinear import Model
from . import _imm_kernel
from ._bank_steps import bank_outputs, bank_results, bank_store_numpy
from ._conventions import mode_initial
from .bank_common import (
    BankFilter,
    MultipleModelOutput,
    MultipleModelState,
    check_transition_matrix,
)
from .bank_math import log_gaussian, normalize_log_weights
from .mixture import combine
from .protocol import Filter, FilterState

__all__ = ["IMM"]


@dataclass(frozen=True, eq=False)
class IMM(BankFilter):
    """Interacting multiple model estimator ([IMM] eq 15-33, corrected per ``docs/design.md`` §7.6), batched.

    Parameters
    ----------
    filters : sequence of Filter
        One mode-matched filter per mode, each satisfying
        :class:`~chatterspec.filters.protocol.Filter` (KF/EKF, SVSF-cov, second-order SVSF; a
        heterogeneous bank is allowed). All must measure the same outputs (same ``n_outputs``) and
        estimate the same states.
    transition_matrix : (r, r) array
        ``pi[i, j] = P(mode j at sample k | mode i at k-1)``, applied at every sample (per step).
    mu0 : (r,) array, optional
        Initial mode probabilities (default uniform).
    weight_floor : float
        Optional floor of the mode probabilities in ``[0, 1/r)`` (default 0: the IMM paper has
        none; the transition matrix already keeps every mode alive).
    modes : sequence of str, optional
        Mode names (default ``mode0, mode1, ...``).

    Raises
    ------
    ShapeError
        Filters with different measurement, state or input sizes; wrong-sized ``mu0`` or
        ``transition_matrix``.
    ParameterError
        Transition-matrix rows not summing to 1, negative probabilities, ``weight_floor`` outside
        ``[0, 1/r)``.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    filters: Sequence[Filter]
    transition_matrix: np.ndarray
    mu0: np.ndarray | None = None
    weight_floor: float = 0.0
    modes: Sequence[str] | None = None
    _fused: _imm_kernel.IMMSpec | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        filters = tuple(self.filters)
        for j, f in enumerate(filters):
            if not all(hasattr(f, a) for a in ("initialize", "update", "model")):
                raise TypeError(
                    f"IMM filter {j} ({type(f).__name__}) does not satisfy the Filter protocol "
                    "(initialize, update, model)"
                )
        self._check_bank([f.model for f in filters])
        object.__setattr__(self, "filters", filters)
        object.__setattr__(
            self, "transition_matrix", check_transition_matrix(self.transition_matrix, len(filters))
        )
        # arrays of the compiled fused step when every mode is supported (else the protocol path)
        object.__setattr__(self, "_fused", _imm_kernel.fused_spec(filters))

    @property
    def n_modes(self) -> int:
        """Number of modes r."""
        return len(self.filters)

    def initialize(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        *,
        runs: int | None = None,
        mode_x0: np.ndarray | None = None,
        mode_P0: np.ndarray | None = None,
    ) -> MultipleModelState:
        """State at k = 0: every mode filter at ``(x0, P0)`` (or its own start), probabilities ``mu0``.

        Parameters
        ----------
        x0 : (n,) or (runs, n) array
            Initial estimate.
        P0 : (n, n) or (runs, n, n) array
            Initial covariance (symmetric positive definite).
        runs : int, optional
            Number of realizations when ``x0`` is shared.
        mode_x0 : (r, n) or (runs, r, n) array, optional
            Initial estimate of each mode-matched filter (default ``x0`` for every mode).
        mode_P0 : (r, n, n) or (runs, r, n, n) array, optional
            Initial covariance of each mode-matched filter (default ``P0``). With either given, the
            combined ``x(0|0)``, ``P(0|0)`` are their ``mu0``-weighted combination (eq 31-33).

        Returns
        -------
        MultipleModelState
        """
        runs, x, P, mu = self._initial_estimate(x0, P0, runs)
        xs, Ps, x, P = mode_initial(x, P, mu, mode_x0, mode_P0, self.n_modes)
        states = tuple(f.initialize(xs[:, j], Ps[:, j], runs=runs) for j, f in enumerate(self.filters))
        return self._initial_state(x, P, mu, states)

    def _sensor_model(self) -> Model:
        return self.filters[0].model

    def _advance(
        self,
        state: MultipleModelState,
        z: np.ndarray,
        u: np.ndarray,
        store_covariance: bool,
        store_modes: bool,
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        """[IMM] eq (18)-(33) over the checked chunk (compiled when every mode is supported)."""
        runs = state.x.shape[0]
        K = z.shape[1]
        if K and self._fused is not None and len(state.mode_states) == self.n_modes and _jit.enabled():
            return self._update_fused(state, z, u, store_covariance, store_modes)
        n = state.x.shape[1]
        r = self.n_modes
        C = np.asarray(self._sensor_model().C, dtype=float)
        pi = self.transition_matrix
        keep = ("x_post", "innovation", "S")
        mu = state.mu.copy()
        sts = list(state.mode_states)
        zl = state.z_last
        rec = bank_outputs(runs, K, n, r, store_covariance, store_modes)
        ll = np.empty((runs, r))
        m = C.shape[0]
        es = np.empty((runs, r, m))
        Ss = np.empty((runs, r, m, m))
        first = state.k == 0
        x = state.x
        P = state.P
        for k in range(K):
            xs = np.stack([s.x for s in sts], axis=1)  # (runs, r, n)
            Ps = np.stack([np.broadcast_to(s.P, (runs, n, n)) for s in sts], axis=1)
            c = mu @ pi  # (19)
            c = np.maximum(c, 1e-300)
            w = mu[:, :, None] * pi[None] / c[:, None, :]  # (18) mu_{i|j}
            x0s = np.einsum("rij,rin->rjn", w, xs)  # (20)
            d = xs[:, :, None, :] - x0s[:, None, :, :]  # (runs, i, j, n)
            P0s = np.einsum("rij,rijab->rjab", w, Ps[:, :, None] + d[..., :, None] * d[..., None, :])  # (21)
            zk = z[:, k : k + 1]
            uk = u[:, k : k + 1]
            for j, f in enumerate(self.filters):
                s = sts[j]
                # design.md I4: e(k|k) of mode j is the residual of its mixed estimate (0 before any data)
                e_mix = s.e_post if first else zl - x0s[:, j] @ C.T
                s = FilterState(x=x0s[:, j], P=P0s[:, j], e_post=e_mix, e_prev=s.e_prev, k=s.k)
                s, out = f.update(s, zk, uk, store=keep, check=False)
                sts[j] = s
                innovation, S = out.innovation, out.S
                assert innovation is not None and S is not None  # in ``keep``
                es[:, j] = innovation[:, 0]
                Ss[:, j] = S[:, 0] if S.ndim == 4 else S[0]
            ll = log_gaussian(es, Ss)  # (29), all modes at once
            mu = normalize_log_weights(np.log(c) + ll, self.weight_floor)  # (30)
            xs = np.stack([s.x for s in sts], axis=1)
            if store_covariance or k == K - 1:
                Ps = np.stack([np.broadcast_to(s.P, (runs, n, n)) for s in sts], axis=1)
                x, P = combine(mu, xs, Ps)  # (31)-(33) with the factor 1/2
            else:
                x, _ = combine(mu, xs)
            bank_store_numpy(rec, k, x, mu, ll, P, xs)
            zl = z[:, k]
            first = False
        if K == 0:
            return state, self._output(bank_results(rec, store_covariance, store_modes))
        new = MultipleModelState(
            x=x,
            P=np.broadcast_to(P, (runs, n, n)).copy(),
            mu=mu,
            e_post=zl - x @ C.T,
            z_last=zl.copy(),
            mode_states=tuple(sts),
            k=state.k + K,
        )
        return new, self._output(bank_results(rec, store_covariance, store_modes))

    def _update_fused(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        # the same recursion as update()'s loop, compiled (chatterspec.filters._imm_kernel)
        assert self._fused is not None  # (the caller checked)
        st, o = _imm_kernel.run_fused(
            self._fused, self.transition_matrix, self.weight_floor, state, z, u, store_cov, store_modes
        )
        K = z.shape[1]
        sts = tuple(
            FilterState(
                x=st["xs"][:, j].copy(),
                P=st["Ps"][:, j].copy(),
                e_post=st["eps"][:, j].copy(),
                e_prev=st["epps"][:, j].copy(),
                k=s.k + K,
            )
            for j, s in enumerate(state.mode_states)
        )
        C = np.asarray(self.filters[0].model.C, dtype=float)
        new = MultipleModelState(
            x=st["x"],
            P=st["P"],
            mu=st["mu"],
            e_post=st["zl"] - st["x"] @ C.T,
            z_last=st["zl"],
            mode_states=sts,
            k=state.k + K,
        )
        return new, self._output(o)
