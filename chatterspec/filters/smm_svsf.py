"""SMM-SVSF: static multiple models inside the SVSF with covariance ([SMM] eq 3.1-3.5, Table 1).

Two readings of the paper (notation and corrections of ``docs/design.md`` §7.5), batched over a
leading realization axis ``runs``:

**Table 1 reading** (default, ``reading="table1"``): one SVSF whose prediction is the mode-weighted
prediction, compiled when every mode has compiled plant steps (below).
Per sample, from the common posterior ``x(k|k), P(k|k)``::

    x_j = f_j(x(k|k), u(k)),  P_j = F_j P(k|k) F_j^T + Q_j,  S_j = C P_j C^T + R       (Table 1 steps 1-2)
    log p_j = log N(z(k+1) - C x_j; 0, S_j)                                           (eq 3.2-3.3, vector)
    mu_j(k+1) ∝ p_j mu_j(k)  (log domain), then mu_j >= floor and renormalize          (eq 3.1, step 3)
    x(k+1|k) = sum_j mu_j x_j,  P(k+1|k) = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]      (steps 4a-5)
    SVSF gain and update (eq 2.5-2.10) on x(k+1|k), P(k+1|k)                           (steps 6-7b)

**Bank reading** (``reading="bank"``): eq (3.4)-(3.5) taken literally, r independent SVSFs
(:class:`~chatterspec.filters.svsf_cov.SVSFCov`, one per mode) each weighted by its own innovation
likelihoods (:func:`~chatterspec.filters.bank.log_gaussian`); the output is the mu-weighted
posterior.

**Compiled Table 1 loop.** :func:`_smm_sample` is the recursion above for one sample of one
realization, built from the same steps as the other loops: the modes' plant steps
(:func:`chatterspec.plants.steps.plant_steps`, two kinds at most,
:func:`chatterspec.filters.bank.bank_plants`), ``predict_cov_step``, ``innovation_step``, the banks'
likelihood, probabilities and combination (:mod:`chatterspec.filters.bank`), and the covariance
filters' sample step with the SVSF-cov correction (``F = I``, ``Q = 0``: ``P(k+1|k)`` as given).
:func:`_smm_loop` runs it over runs (outer) and samples (inner); :func:`_smm_one` is the one-sample
kernel of :class:`~chatterspec.filters.one_sample.OnlineBank` (packed by :meth:`SMMSVSF._one_pack`),
the batch loop called on one run and one sample (one compiled recursion for both).
The numpy path (:meth:`SMMSVSF._update_table1`) evaluates the same formulas with BLAS products,
``einsum`` and LAPACK ``eigh``: the two agree to a few ulps per sample (tests/test_smm_kernel.py),
and each is bit-for-bit invariant to the chunking of runs and samples.

See Also
--------
chatterspec.filters.imm.IMM : the interacting multiple-model bank.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Literal, cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from ..errors import ParameterError
from ..plants.nonlinear import Model, require_linear_measurement
from ._engine import (
    BAD_INPUT,
    DIVERGED,
    NOT_PD,
    CorrectionStep,
    _no_sample,
    innovation_step,
    predict_cov_step,
    sample_step,
    take,
    take2,
    take3,
    workspace,
)
from .bank import (
    BankFilter,
    BankLoop,
    MultipleModelOutput,
    MultipleModelState,
    OnePacked,
    _bank_plant,
    bank_outputs,
    bank_plants,
    bank_results,
    bank_store_numpy,
    bank_store_step,
    combine,
    combine_step,
    log_gaussian,
    log_gaussian_inline,
    mode_probabilities_step,
    normalize_log_weights,
    one_constants,
    one_sample_io,
    run_bank_loop,
)
from .protocol import FilterState, finite_sample, finite_state
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
    _compiled: SMMSpec | None = field(init=False, repr=False, default=None)

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
            object.__setattr__(self, "_compiled", smm_spec(models, svsf._correction_step()))

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

    def _one_pack(self, state: MultipleModelState) -> OnePacked | None:
        """:class:`~chatterspec.filters.one_sample.OnlineBank`'s compiled call (:func:`_smm_one`) and its
        packed arrays, or None (a step is then :meth:`update` on one sample)."""
        nm, mdl = self.n_modes, self._sensor_model()
        n, m = int(mdl.n_states), int(mdl.n_outputs)
        lay = _jit.python_form(one_layout)(nm, n, m)
        spec = self._compiled
        if spec is None or lay[-1] > _jit.BLOCK_CAPACITY:
            return None
        parts = (spec["prm"], spec["fp"], spec["Qs"], spec["C"], spec["R"])
        buf = np.zeros(lay[-1])
        epp = np.zeros(m) if state.e_prev is None else state.e_prev[0]
        rows = (state.x[0], np.broadcast_to(state.P, (1, n, n))[0], state.mu[0], state.e_post[0], epp)
        for o, v in zip((0, *lay[:4]), rows, strict=True):
            buf[o : o + np.size(v)] = np.ravel(v)
        buf[lay[7] : lay[7] + m] = state.z_last[0]
        cst = one_constants(nm, n, m, self.weight_floor, parts)
        slots = np.ascontiguousarray(spec["plant_slot"], dtype=np.int64)
        return spec["one"], buf, cst, slots, (0, lay[0], lay[1], lay[6])

    def _one_state(
        self, read: Callable[[int, tuple[int, ...]], np.ndarray], state: MultipleModelState, k: int
    ) -> MultipleModelState:
        """The one-run state from :func:`_smm_one`'s buffer (``read(offset, shape)``: a copy)."""
        nm, mdl = self.n_modes, self._sensor_model()
        n, m = int(mdl.n_states), int(mdl.n_outputs)
        lay = _jit.python_form(one_layout)(nm, n, m)
        return dataclasses.replace(
            state, x=read(0, (1, n)), P=read(lay[0], (1, n, n)), mu=read(lay[1], (1, nm)),
            e_post=read(lay[2], (1, m)), z_last=read(lay[7], (1, m)), k=k, e_prev=read(lay[3], (1, m)),
        )  # fmt: skip

    def _update_table1_compiled(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        # the same recursion as _update_table1's loop, compiled (the module docstring)
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
        o = run_smm(self._compiled, self.weight_floor, x, P, mu, ep, epp, z, u, store_cov, store_modes)
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


# ----------------------------------------------------------------------------- the compiled Table 1 recursion
#: Bindings of :func:`_smm_sample`: the modes' plant step (:func:`.bank.bank_plants`), the
#: SVSF-cov sample step, sizes (0: from the arrays); of the loops: ``SMM_SAMPLE``.
PLANT = _bank_plant
SAMPLE = _no_sample
NX = NZ = 0
#: Return code of :func:`_smm_sample` when every mode likelihood is zero or non-finite.
NO_LIKELIHOOD = 5


@_jit.step
def smm_scratch(nm: int, n: int, m: int) -> tuple:  # pragma: no cover - compiled
    """The scratch of :func:`_smm_sample`, made once by the loop that calls it (inlined into it):
    ``(ws, F, eye, Q0, xp, lw, Sc, Lc, ec, col, tmp)`` with ``eye`` = I and ``Q0`` = 0 filled in."""
    eye = _jit.scratch2(n, n)
    Q0 = _jit.scratch2(n, n)
    for i in range(n):
        for j in range(n):
            eye[i, j] = 1.0 if i == j else 0.0
            Q0[i, j] = 0.0
    return (
        workspace(n, m), _jit.scratch2(n, n), eye, Q0, _jit.scratch(n), _jit.scratch(nm), _jit.scratch2(m, m),
        _jit.scratch2(m, m), _jit.scratch(m), _jit.scratch(m), _jit.scratch(2 * m),
    )  # fmt: skip


def _smm_sample(prm, plant_slot, Qs, C, R, fp, floor, zk, uk, x, P, mu, ep, epp, xs, Ps, ll, scr, n, m, p):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled (a template)
    """The recursion of the module docstring for one sample of one realization; state rows in place.

    ``zk`` (m,), ``uk`` (p,); ``x`` (n,), ``P`` (n, n), ``mu`` (nm,), ``ep``, ``epp`` (m,); ``xs``
    (nm, n) and ``Ps`` (nm, n, n) receive the mode predictions, ``ll`` (nm,) their log-likelihoods;
    ``scr``: :func:`smm_scratch` (made once by the calling loop). Returns 0, the sample step's code,
    or :data:`NO_LIKELIHOOD`.
    """
    nm = mu.shape[0]
    ws, F, eye, Q0, xp, lw, Sc, Lc, ec, col, tmp = scr
    T1, PCt, PCtT, S, D, e = ws[0], ws[2], ws[3], ws[4], ws[5], ws[7]
    for j in range(nm):  # Table 1 steps 1-2: every mode from the common posterior
        PLANT(plant_slot[j], prm[j], x, uk, xs[j], F, n, p)
        predict_cov_step(F, P, Qs[j], T1, Ps[j], n)
        innovation_step(zk, xs[j], Ps[j], C, R, e, PCt, PCtT, D, S, n, m)
        ll[j] = log_gaussian_inline(e, S, m, Sc, Lc, ec, col, tmp)  # eq 3.2-3.3
    for j in range(nm):  # eq 3.1 in the log domain, with the floor
        lw[j] = np.log(max(mu[j], 1e-300)) + ll[j]
    if not mode_probabilities_step(lw, mu, floor, nm):
        return NO_LIKELIHOOD
    combine_step(mu, xs, Ps, xp, P, nm, n)  # steps 4a-5: P(k+1|k) into P
    # steps 6-7b: the SVSF-cov update from the mixed prior (F = I, Q = 0: P(k+1|k) as given)
    return SAMPLE(fp, x, P, ep, epp, zk, xp, eye, C, Q0, R, ws, n, m)


@_jit.step
def _no_smm_sample(*args):  # type: ignore[no-untyped-def]
    """Placeholder binding of the loops (never called)."""
    return 1


SMM_SAMPLE = SMM_LOOP = _no_smm_sample


def _smm_loop(
    prm: np.ndarray,
    plant_slot: np.ndarray,
    Qs: np.ndarray,
    C: np.ndarray,
    R: np.ndarray,
    fp: np.ndarray,
    floor: float,
    z: np.ndarray,
    u: np.ndarray,
    x: np.ndarray,
    P: np.ndarray,
    mu: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    xs: np.ndarray,
    Ps: np.ndarray,
    o_x: np.ndarray,
    o_mu: np.ndarray,
    o_ll: np.ndarray,
    o_P: np.ndarray,
    o_mx: np.ndarray,
) -> int:  # pragma: no cover - compiled (a template: see run_smm)
    """The recursion of the module docstring (:func:`_smm_sample` per run and sample); in place.

    ``xs`` (nm, n) and ``Ps`` (nm, n, n) are scratch. Returns 0, ``1 + run`` (a matrix not
    positive definite) or ``-(1 + run)`` (every mode likelihood zero or non-finite).
    """
    b = _jit.borrow
    prm, plant_slot, Qs, C, R, fp, z, u = b(prm), b(plant_slot), b(Qs), b(C), b(R), b(fp), b(z), b(u)
    x, P, mu, ep, epp, xs, Ps = b(x), b(P), b(mu), b(ep), b(epp), b(xs), b(Ps)
    o_x, o_mu, o_ll, o_P, o_mx = b(o_x), b(o_mu), b(o_ll), b(o_P), b(o_mx)
    runs, K, _ = z.shape
    nm = mu.shape[1]
    n = NX if NX > 0 else x.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    p = u.shape[2]
    shared_u = u.shape[0] == 1
    ll = _jit.scratch(nm)
    scr = smm_scratch(nm, n, m)
    for r in range(runs):
        ur = 0 if shared_u else r
        for k in range(K):
            status = SMM_SAMPLE(
                prm, plant_slot, Qs, C, R, fp, floor, z[r, k], u[ur, k], x[r], P[r], mu[r], ep[r], epp[r],
                xs, Ps, ll, scr, n, m, p,
            )  # fmt: skip
            if status == NO_LIKELIHOOD:
                return -(1 + r)
            if status != 0:
                return 1 + r
            bank_store_step(r, k, x[r], mu[r], ll, P[r], xs, o_x, o_mu, o_ll, o_P, o_mx, nm, n)
    return 0


def _smm_one(
    buf: np.ndarray, cst: np.ndarray, slots: np.ndarray, z: np.ndarray, u: np.ndarray
) -> int:  # pragma: no cover - compiled
    """One sample of one realization: the batch loop ``SMM_LOOP`` (:func:`_smm_loop`, the same
    compiled code) on one run and one sample of packed arrays (:func:`one_layout`).

    ``buf`` holds ``x``, ``P``, ``mu``, ``e(k|k)``, ``e(k-1|k-1)``, the scratch ``xs``, ``Ps`` and
    receives ``ll`` and ``z``; ``cst`` (:func:`~chatterspec.filters.bank.one_constants`) the header
    ``[nm, n, m, L_prm, L_fp, floor]`` then ``prm``, ``fp``, ``Qs``, ``C``, ``R``; ``slots`` (nm,) int
    the plant slots. The state is written back only when the sample succeeds with a finite estimate.
    Returns 0, the step's code, ``BAD_INPUT`` or ``DIVERGED``.
    """
    b = _jit.borrow
    buf, cst, slots, z, u = b(buf), b(cst), b(slots), b(z), b(u)
    nm = int(cst[0])
    n = NX if NX > 0 else int(cst[1])
    m = NZ if NZ > 0 else int(cst[2])
    p = u.shape[0]
    if not finite_sample(z, m, u, p):
        return BAD_INPUT
    prm, o = take2(cst, 6, nm, int(cst[3]))
    fp, o = take(cst, o, int(cst[4]))
    Qs, o = take3(cst, o, nm, n, n)
    C, o = take2(cst, o, m, n)
    R, o = take2(cst, o, m, m)
    offs = one_layout(nm, n, m)
    size = offs[-1]
    work, z1, u1, o_x, o_mu, none = one_sample_io(buf, size, z, u, n, m, p, nm)
    status = SMM_LOOP(
        prm, slots, Qs, C, R, fp, cst[5], z1, u1,
        work[0 : offs[0]].reshape((1, n)), work[offs[0] : offs[1]].reshape((1, n, n)),
        work[offs[1] : offs[2]].reshape((1, nm)), work[offs[2] : offs[3]].reshape((1, m)),
        work[offs[3] : offs[4]].reshape((1, m)), work[offs[4] : offs[5]].reshape((nm, n)),
        work[offs[5] : offs[6]].reshape((nm, n, n)), o_x, o_mu, work[offs[6] : offs[7]].reshape((1, 1, nm)),
        none, none,
    )  # fmt: skip
    if status != 0:  # the loop's codes for run 0 of 1 back to the step's
        return NO_LIKELIHOOD if status == -1 else NOT_PD
    if not finite_state(work[0 : offs[0]], work[offs[0] : offs[1]].reshape((n, n)), n):
        return DIVERGED
    for i in range(m):
        work[offs[7] + i] = z[i]
    for i in range(size):
        buf[i] = work[i]
    return 0


@_jit.step
def one_layout(nm: int, n: int, m: int) -> tuple[int, int, int, int, int, int, int, int, int]:
    """Offsets in :func:`_smm_one`'s buffer (``x`` at 0): ``P``, ``mu``, ``e(k|k)``, ``e(k-1|k-1)``,
    ``xs``, ``Ps``, ``ll``, the last ``z`` and the length."""
    o_P = n
    o_mu = o_P + n * n
    o_ep = o_mu + nm
    o_epp = o_ep + m
    o_xs = o_epp + m
    o_Ps = o_xs + nm * n
    o_ll = o_Ps + nm * n * n
    o_zl = o_ll + nm
    return o_P, o_mu, o_ep, o_epp, o_xs, o_Ps, o_ll, o_zl, o_zl + m


class SMMSpec(BankLoop):
    """The arrays and the loop of a compiled SMM-SVSF (:func:`smm_spec`)."""

    prm: np.ndarray  # plant parameters, one row per plant kind
    plant_slot: np.ndarray  # (r,) plant row of each mode
    Qs: np.ndarray  # (r, n, n)
    C: np.ndarray  # (m, n), shared
    R: np.ndarray  # (m, m), shared
    fp: np.ndarray  # the shared correction's parameters
    one: Callable[..., int]  # one sample of one realization (:func:`_smm_one`)


def smm_spec(models: tuple[Model, ...], correct: CorrectionStep) -> SMMSpec | None:
    """Arrays and the kernel of the compiled SMM loop, or None (numpy path) when a mode has no plant steps.

    Parameters
    ----------
    models : tuple of models
        The modes.
    correct : CorrectionStep
        The shared SVSF-cov correction (``SMMSVSF._svsf._correction_step()``).

    Returns
    -------
    dict or None
    """
    from ..plants.steps import plant_steps

    found = [plant_steps(mdl) for mdl in models]
    plants = [pl for pl in found if pl is not None]
    n, m = int(models[0].n_states), int(models[0].n_outputs)
    if len(plants) < len(found) or not (_jit.fits(n, m) and _jit.fits(len(models))):
        return None
    plant, plant_slot, prm = bank_plants(plants)
    if plant is None:
        return None
    tag = "_".join(["smm", *dict.fromkeys(pl.name for pl in plants)])
    step = _jit.specialize_sizes(
        _smm_sample,
        tag,
        {},
        inline=True,
        PLANT=plant,
        SAMPLE=sample_step(correct, want_ll=False),
    )
    sizes = {"NX": n, "NZ": m}
    loop = _jit.specialize_sizes(_smm_loop, tag, sizes, SMM_SAMPLE=step)
    return {
        "prm": prm,
        "plant_slot": plant_slot,
        "Qs": np.ascontiguousarray(np.stack([np.asarray(mdl.Q, dtype=float) for mdl in models])),
        # writable copies: a model's read-only arrays are another numba type than the one-sample
        # kernel's views of its packed constants, and would compile the loop a second time
        "C": np.array(models[0].C, dtype=float, order="C"),
        "R": np.array(models[0].R, dtype=float, order="C"),
        "fp": correct.parameters,
        "mapping": correct.mapping,
        "kernel": loop,
        "one": _jit.specialize_sizes(_smm_one, tag, sizes, SMM_LOOP=loop),
    }


def run_smm(
    spec: SMMSpec,
    floor: float,
    x: np.ndarray,
    P: np.ndarray,
    mu: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray,
    store_covariance: bool,
    store_modes: bool,
    *,
    python: bool = False,
) -> dict[str, np.ndarray | None]:
    """Advance the SMM state over ``z``: ``x``, ``P``, ``mu``, ``ep``, ``epp`` (C-contiguous copies) in place.

    Parameters
    ----------
    spec : dict
        From :func:`smm_spec`.
    floor : float
        Weight floor.
    x, P, mu, ep, epp : arrays
        State (runs, n), (runs, n, n), (runs, r), (runs, m), (runs, m).
    z : (runs, K, m) array
        Measurements (validated).
    u : (1 | runs, K, p) array
        Inputs (validated).
    store_covariance, store_modes : bool
        Outputs wanted (see :meth:`SMMSVSF.update`).
    python : bool
        Run the loop's Python form (tests).

    Returns
    -------
    dict
        ``x, mu, ll, P, mx`` per sample.

    Raises
    ------
    SingularMatrixError
        A matrix that is not positive definite, or every mode likelihood zero.
    """
    runs, K, _ = z.shape
    n, r = x.shape[1], mu.shape[1]
    c = np.ascontiguousarray
    args = (
        spec["prm"], spec["plant_slot"], spec["Qs"], spec["C"], spec["R"], spec["fp"], float(floor),
        c(z, dtype=float), c(u, dtype=float), x, P, mu, ep, epp, np.empty((r, n)), np.empty((r, n, n)),
    )  # fmt: skip
    out = bank_outputs(runs, K, n, r, store_covariance, store_modes)
    run_bank_loop(spec, args, out, python=python)
    return bank_results(out, store_covariance, store_modes)
