"""SMM-SVSF: static multiple models inside the SVSF with covariance ([SMM] eq 3.1-3.5, Table 1).

Two readings of the paper (notation and corrections of ``docs/design.md`` §7.5), batched over a
leading realization axis ``runs``:

**Table 1 reading** (default, ``reading="table1"``): one SVSF whose prediction is the mode-weighted
prediction, compiled when every mode has compiled plant steps (:mod:`chatterspec.filters._smm_kernel`).
Per sample, from the common posterior ``x(k|k), P(k|k)``::

    x_j = f_j(x(k|k), u(k)),  P_j = F_j P(k|k) F_j^T + Q_j,  S_j = C P_j C^T + R       (Table 1 steps 1-2)
    log p_j = log N(z(k+1) - C x_j; 0, S_j)                                           (eq 3.2-3.3, vector)
    mu_j(k+1) ∝ p_j mu_j(k)  (log domain), then mu_j >= floor and renormalize          (eq 3.1, step 3)
    x(k+1|k) = sum_j mu_j x_j,  P(k+1|k) = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]      (steps 4a-5)
    SVSF gain and update (eq 2.5-2.10) on x(k+1|k), P(k+1|k)                           (steps 6-7b)

**Bank reading** (``reading="bank"``): eq (3.4)-(3.5) taken literally, r independent SVSFs
(:class:`~chatterspec.filters.svsf_cov.SVSFCov`, one per mode) each weighted by its own innovation
likelihoods (:func:`~chatterspec.filters.bank_math.log_gaussian`); the output is the mu-weighted
posterior.

See Also
--------
chatterspec.filters.imm.IMM : the interacting multiple-model bank.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from ..errors import ParameterError
from ..plants.measurement import require_linear_measurement
from ..plants.nonlinear import Model
from . import _smm_kernel
from ._bank_steps import bank_outputs, bank_results, bank_store_numpy
from .bank_common import (
    BankFilter,
    MultipleModelOutput,
    MultipleModelState,
)
from .bank_math import log_gaussian, normalize_log_weights
from .mixture import combine
from .protocol import FilterState
from .svsf_cov import SVSFCov, check_gamma, check_psi, default_mapping, mapping_matrix

__all__ = ["DEFAULT_WEIGHT_FLOOR", "SMMSVSF"]

#: Default SMM weight floor ([SMM] Table 1 step 3 as resolved in ``docs/design.md`` S4).
DEFAULT_WEIGHT_FLOOR = 1e-3


@dataclass(frozen=True, eq=False)
class SMMSVSF(BankFilter):
    """SMM-SVSF: static multiple models inside the SVSF with covariance ([SMM] eq 3.1-3.5, Table 1).

    Parameters
    ----------
    models : sequence of models
        One model per mode (``transition``, ``jacobian``, ``C``, ``Q``, ``R``, ...), in bank order;
        all with the same C and R (the same sensor).
    psi : float or (m,) array
        SVSF smoothing boundary layer per output channel (> 0, output units), eq (2.5).
    gamma : float or (m,) array
        SVSF convergence rate in (0, 1), eq (2.5).
    mapping : {"full", "pinv", "cov"}, optional
        Output-to-state map of the SVSF gain (see :mod:`~chatterspec.filters.svsf_cov`); default
        ``"full"`` for a square invertible C, else ``"cov"``.
    weight_floor : float
        Lower bound of every mode weight, in ``[0, 1/r)`` (default 1e-3). Without it a weight that
        underflows to 0 can never recover under eq (3.1).
    mu0 : (r,) array, optional
        Initial weights (default uniform, [SMM] eq 3.1).
    reading : {"table1", "bank"}
        ``"table1"`` (default): one SVSF with the mode-weighted prediction (Table 1, Fig 2);
        ``"bank"``: r independent SVSFs combined by eq (3.4)-(3.5).
    modes : sequence of str, optional
        Mode names (default ``mode0, mode1, ...``).

    Raises
    ------
    ShapeError
        Modes with different state / measurement / input sizes, or a wrong-sized ``mu0``.
    ParameterError
        Different C or R between modes, ``weight_floor`` outside ``[0, 1/r)``, negative ``mu0``,
        bad ``psi`` / ``gamma`` / ``reading``.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    models: Sequence[Model]
    psi: float | np.ndarray
    gamma: float | np.ndarray = 0.1
    mapping: Literal["full", "pinv", "cov"] | None = None
    weight_floor: float = DEFAULT_WEIGHT_FLOOR
    mu0: np.ndarray | None = None
    reading: Literal["table1", "bank"] = "table1"
    modes: Sequence[str] | None = None
    _svsf: SVSFCov | None = field(init=False, repr=False, default=None)
    _bank: tuple[SVSFCov, ...] = field(init=False, repr=False, default=())
    _compiled: _smm_kernel.SMMSpec | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        models = tuple(self.models)
        _n, m = self._check_bank(models)
        for mdl in models:
            require_linear_measurement(mdl, "SMM-SVSF")
        C = np.asarray(models[0].C, dtype=float)
        R = np.asarray(models[0].R, dtype=float)
        for j, mdl in enumerate(models[1:], start=1):
            if not (np.array_equal(mdl.C, C) and np.array_equal(mdl.R, R)):
                raise ParameterError(
                    f"SMM-SVSF modes share one sensor: mode {j} has a different C or R from mode 0"
                )
        object.__setattr__(self, "models", models)
        if self.reading not in ("table1", "bank"):
            raise ParameterError(f"reading must be 'table1' or 'bank'; got {self.reading!r}")
        mapping = default_mapping(C) if self.mapping is None else self.mapping
        mapping_matrix(C, mapping)  # named error for an unusable mapping
        object.__setattr__(self, "mapping", mapping)
        psi = check_psi(self.psi, m)
        object.__setattr__(self, "psi", psi)
        object.__setattr__(self, "gamma", check_gamma(self.gamma, m))
        # Table 1 steps 6-7b: one SVSF-cov (the modes share C and R) corrects the mixed prediction
        svsf = SVSFCov(models[0], psi=psi, gamma=self.gamma, mapping=mapping)
        object.__setattr__(self, "_svsf", svsf)
        if self.reading == "bank":
            bank = tuple(SVSFCov(mdl, psi=psi, gamma=self.gamma, mapping=mapping) for mdl in models)
            object.__setattr__(self, "_bank", bank)
        else:  # the compiled Table 1 loop when every mode has compiled plant steps (else numpy)
            object.__setattr__(self, "_compiled", _smm_kernel.smm_spec(models, svsf._correction_step()))

    @property
    def n_modes(self) -> int:
        """Number of modes r."""
        return len(self.models)

    def initialize(self, x0: np.ndarray, P0: np.ndarray, *, runs: int | None = None) -> MultipleModelState:
        """State at k = 0: ``x(0|0) = x0``, ``P(0|0) = P0``, weights ``mu0``, ``e(0|0) = 0``.

        Parameters
        ----------
        x0 : (n,) or (runs, n) array
            Initial estimate.
        P0 : (n, n) or (runs, n, n) array
            Initial covariance (symmetric positive definite).
        runs : int, optional
            Number of realizations when ``x0`` is shared.

        Returns
        -------
        MultipleModelState
        """
        runs, x, P, mu = self._initial_estimate(x0, P0, runs)
        states: tuple[FilterState, ...] = ()
        if self.reading == "bank":
            states = tuple(f.initialize(x, P, runs=runs) for f in self._bank)
        return self._initial_state(x, P, mu, states)

    def _sensor_model(self) -> Model:
        return self.models[0]

    def _advance(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        if self.reading == "bank":
            return self._update_bank(state, z, u, store_cov, store_modes)
        return self._update_table1(state, z, u, store_cov, store_modes)

    def _update_table1(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        if self._compiled is not None and _jit.enabled() and z.shape[1]:
            return self._update_table1_compiled(state, z, u, store_cov, store_modes)
        models = self.models
        r = len(models)
        runs, K, _m = z.shape
        n = state.x.shape[1]
        C = np.asarray(models[0].C, dtype=float)
        R = np.asarray(models[0].R, dtype=float)
        Qs = np.stack([np.asarray(mdl.Q, dtype=float) for mdl in models])
        floor = self.weight_floor
        svsf = self._svsf
        assert svsf is not None  # set by __post_init__
        x, P, mu, ep = state.x.copy(), state.P.copy(), state.mu.copy(), state.e_post.copy()
        epp = np.zeros_like(ep) if state.e_prev is None else state.e_prev.copy()
        rec = bank_outputs(runs, K, n, r, store_cov, store_modes)
        shared_u = u.shape[0] == 1
        xs = np.empty((runs, r, n))
        Fs = np.empty((runs, r, n, n))
        for k in range(K):
            uk = u[0, k] if shared_u else u[:, k]
            zk = z[:, k]
            for j, mdl in enumerate(models):  # Table 1 steps 1-2: every mode from the common posterior
                xs[:, j] = mdl.transition(x, uk)
                Fs[:, j] = mdl.jacobian(x, uk)
            Ps = Fs @ P[:, None] @ np.swapaxes(Fs, -1, -2) + Qs  # (runs, r, n, n)
            Ss = C @ Ps @ C.T + R
            ll = log_gaussian(zk[:, None, :] - xs @ C.T, Ss)  # eq 3.2-3.3
            mu = normalize_log_weights(np.log(np.maximum(mu, 1e-300)) + ll, floor)  # eq 3.1 + floor
            xp, Pp = combine(mu, xs, Ps)  # steps 4a-5
            # steps 6-7b: the SVSF-cov measurement update (eq 2.5-2.10) from the mixed prior, through the
            # protocol's correct() (bit-identical to the second half of SVSFCov.update)
            fstate = FilterState(x=x, P=P, e_post=ep, e_prev=epp, k=state.k + k)
            fstate, _ = svsf.correct(fstate, xp, Pp, zk, store=())
            x, P, ep, epp = fstate.x, fstate.P, fstate.e_post, fstate.e_prev
            bank_store_numpy(rec, k, x, mu, ll, P, xs)
        new = MultipleModelState(
            x=x,
            P=P,
            mu=mu,
            e_post=ep,
            z_last=z[:, -1].copy() if K else state.z_last,
            k=state.k + K,
            e_prev=epp,
        )
        return new, self._output(bank_results(rec, store_cov, store_modes))

    def _update_table1_compiled(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        # the same recursion as _update_table1's loop, compiled (chatterspec.filters._smm_kernel)
        c = lambda a: np.array(a, dtype=float, order="C")  # noqa: E731
        runs = state.x.shape[0]
        x, P, mu, ep = (
            c(state.x),
            c(np.broadcast_to(state.P, (runs, *state.P.shape[-2:]))),
            c(state.mu),
            c(state.e_post),
        )
        epp = np.zeros_like(ep) if state.e_prev is None else c(state.e_prev)
        assert self._compiled is not None  # (the caller checked)
        o = _smm_kernel.run_smm(
            self._compiled, self.weight_floor, x, P, mu, ep, epp, z, u, store_cov, store_modes
        )
        K = z.shape[1]
        new = MultipleModelState(
            x=x, P=P, mu=mu, e_post=ep, z_last=z[:, -1].copy(), k=state.k + K, e_prev=epp
        )
        return new, self._output(o)

    def _update_bank(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        runs, K, _m = z.shape
        keep = {"x_post", "innovation", "S"} | ({"P_post"} if store_cov else set())
        new_states, outs = [], []
        for f, s in zip(self._bank, state.mode_states, strict=True):  # independent filters, eq 3.4
            s2, out = f.update(s, z, u, store=keep)
            new_states.append(s2)
            outs.append(out)
        ll = np.stack(
            [log_gaussian(cast(np.ndarray, o.innovation), cast(np.ndarray, o.S)) for o in outs], axis=-1
        )  # (runs, K, r)
        xs = np.stack([cast(np.ndarray, o.x_post) for o in outs], axis=2)  # (runs, K, r, n)
        mu = state.mu.copy()
        o_mu = np.empty((runs, K, self.n_modes))
        logmu = np.log(np.maximum(mu, 1e-300))
        for k in range(K):  # eq 3.1 with the floor: sequential in time, vectorized over runs
            mu = normalize_log_weights(logmu + ll[:, k], self.weight_floor)
            logmu = np.log(mu)
            o_mu[:, k] = mu
        Ps = np.stack([cast(np.ndarray, o.P_post) for o in outs], axis=2) if store_cov else None
        x, P = combine(o_mu, xs, Ps)  # eq 3.4-3.5
        if K:
            last_P = combine(
                mu, np.stack([s.x for s in new_states], 1), np.stack([s.P for s in new_states], 1)
            )[1]
            new = MultipleModelState(
                x=x[:, -1].copy(),
                P=last_P,
                mu=mu,
                e_post=z[:, -1] - x[:, -1] @ np.asarray(self.models[0].C).T,
                z_last=z[:, -1].copy(),
                mode_states=tuple(new_states),
                k=state.k + K,
            )
        else:
            new = state
        modes = cast(tuple[str, ...], self.modes)  # set by _check_bank
        return new, MultipleModelOutput(x, o_mu, ll, modes, P, xs if store_modes else None)
