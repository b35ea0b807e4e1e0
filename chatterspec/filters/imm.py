"""Interacting multiple-model estimator ([IMM] eq 15-33, corrected), batched over realizations.

Notation and corrections of ``docs/design.md`` §7.5-§7.6. Per sample, with the transition matrix
``pi[i, j] = P(j at k | i at k-1)``::

    (19) c_j = sum_i pi_ij mu_i(k-1)          (18) mu_{i|j} = pi_ij mu_i(k-1) / c_j  (printed 1/mu_j)
    (20) x_0j = sum_i mu_{i|j} x_i            (21) P_0j = sum_i mu_{i|j} [P_i + (x_i - x_0j)(.)^T]
    (22)-(28) mode-matched filter j (any :class:`~chatterspec.filters.protocol.Filter`) from (x_0j, P_0j)
    (29) Lambda_j = N(e_j; 0, S_j)            (30) mu_j(k) ∝ c_j Lambda_j   (log domain)
    (31) x = sum_j mu_j x_j                   (32)-(33) P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]

The printed (32)-(33) sum ``mu_i mu_j (x_i - x_j)(x_i - x_j)^T`` over all ``i, j``; that is exactly twice
the spread of (33) here (:func:`pairwise_spread`, tested), so it is read with a factor 1/2. For the
SVSF-type mode filters, ``e(k|k)`` of mode j is the residual of its mixed estimate ``z(k) - C x_0j``
(``docs/design.md`` I4; the stored residual before the first sample); ``e(k-1|k-1)`` stays the value
that mode stored. Likelihoods, probabilities and the combination are the banks' shared arithmetic
(:mod:`chatterspec.filters.bank`). ``IMM.initialize(..., mode_x0=, mode_P0=)`` starts each mode from
its own estimate (:func:`mode_initial`).

**Two paths, one recursion.** :meth:`IMM.update` drives the mode filters through the protocol, one
sample at a time (numpy), or, when :func:`chatterspec._jit.enabled` and every mode is supported, runs
the whole recursion in one compiled loop over runs (outer) and samples (inner): :func:`_imm_sample`
is one sample of one realization (the mode's step is :func:`chatterspec.filters._engine._sample`
with its correction, inlined, from its model's compiled ``predict``/``jacobian`` steps),
:func:`_imm_loop` the batch loop and :func:`_imm_one` the one-sample kernel of
:class:`~chatterspec.filters.one_sample.OnlineBank` (packed by :meth:`IMM._one_pack`), which calls
the batch loop on one run and one sample (one compiled recursion for both).
Supported (:func:`fused_spec`): KF/EKF, SVSF-cov without ``vbl``, the second-order SVSF, on models
with compiled plant steps (:func:`chatterspec.plants.steps.plant_steps`, two kinds per bank at most,
:func:`chatterspec.filters.bank.bank_plants`); anything else takes the protocol path. A mode's
correction is chosen at run time by the code its parameter row starts with (:func:`mode_sample`,
:func:`_mode_correct`): the modes' filter step is compiled once for all of them, the corrections once
per kind (compiling is most of a cold start's cost: tens of seconds per correction kind).

**Equality.** The compiled loop is not bit-identical to the protocol path: numpy evaluates ``mu @ pi``,
the mixing and combination ``einsum`` and the likelihood (eigh) in other summation orders than the
loop. The differences are a few ulps per sample; ``tests/test_imm_kernel.py`` bounds them (tolerances
stated there). Runs are independent and every sample starts from the stored state, so any chunking of
runs or samples gives the same bits as one call, on either path.

See Also
--------
chatterspec.filters.smm_svsf.SMMSVSF : the static multiple-model SVSF.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array
from ..errors import ShapeError
from ..plants.nonlinear import Model
from ._engine import (
    BAD_INPUT,
    DIVERGED,
    NOT_PD,
    SINGULAR_PHI12,
    CorrectionStep,
    NumpyPrior,
    _no_sample,
    sample_step,
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
    check_transition_matrix,
    combine,
    combine_step,
    log_gaussian,
    log_gaussian_step,
    mode_probabilities_step,
    normalize_log_weights,
    one_constants,
    one_sample_io,
    run_bank_loop,
)
from .protocol import Filter, FilterState, check_spd, finite_sample, finite_state

__all__ = ["IMM", "mode_initial", "pairwise_spread"]


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
    _fused: IMMSpec | None = field(init=False, repr=False, default=None)

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
        object.__setattr__(self, "_fused", fused_spec(filters))

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

    def _one_pack(self, state: MultipleModelState) -> OnePacked | None:
        """:class:`~chatterspec.filters.one_sample.OnlineBank`'s compiled call (:func:`_imm_one`) and its
        packed arrays, or None (a step is then :meth:`update` on one sample)."""
        nm, mdl = self.n_modes, self._sensor_model()
        n, m = int(mdl.n_states), int(mdl.n_outputs)
        lay = _jit.python_form(one_layout)(nm, n, m)
        spec = self._fused
        if spec is None or len(state.mode_states) != nm or lay[-1] > _jit.BLOCK_CAPACITY:
            return None
        parts = (spec["prm"], spec["fp"], spec["Q"], spec["C"], spec["R"], self.transition_matrix)
        slots = np.ascontiguousarray(spec["plant_slot"], dtype=np.int64)
        sts = state.mode_states
        buf = np.zeros(lay[-1])
        buf[0] = 1.0 if state.k == 0 else 0.0
        rows = (
            state.mu[0],
            np.stack([s.x[0] for s in sts]),
            np.stack([np.broadcast_to(s.P, (1, n, n))[0] for s in sts]),
            np.stack([s.e_post[0] for s in sts]),
            np.stack([s.e_prev[0] for s in sts]),
            state.z_last[0],
            state.x[0],
            np.broadcast_to(state.P, (1, n, n))[0],
        )
        for i, v in enumerate(rows):
            buf[lay[i] : lay[i + 1]] = np.ravel(v)
        cst = one_constants(nm, n, m, self.weight_floor, parts)
        return spec["one"], buf, cst, slots, (lay[6], lay[7], lay[0], lay[10])

    def _one_state(
        self, read: Callable[[int, tuple[int, ...]], np.ndarray], state: MultipleModelState, k: int
    ) -> MultipleModelState:
        """The one-run state from :func:`_imm_one`'s buffer (``read(offset, shape)``: a copy)."""
        nm, mdl = self.n_modes, self._sensor_model()
        n, m = int(mdl.n_states), int(mdl.n_outputs)
        lay = _jit.python_form(one_layout)(nm, n, m)
        C = np.asarray(mdl.C, dtype=float)
        xs, Ps = read(lay[1], (nm, n)), read(lay[2], (nm, n, n))
        eps, epps = read(lay[3], (nm, m)), read(lay[4], (nm, m))
        zl, x = read(lay[5], (1, m)), read(lay[6], (1, n))
        modes = tuple(
            FilterState(x=xs[j : j + 1], P=Ps[j : j + 1], e_post=eps[j : j + 1], e_prev=epps[j : j + 1], k=k)
            for j in range(nm)
        )
        return dataclasses.replace(
            state, x=x, P=read(lay[7], (1, n, n)), mu=read(lay[0], (1, nm)), e_post=zl - x @ C.T,
            z_last=zl, mode_states=modes, k=k,
        )  # fmt: skip

    def _update_fused(
        self, state: MultipleModelState, z: np.ndarray, u: np.ndarray, store_cov: bool, store_modes: bool
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        # the same recursion as update()'s loop, compiled (the module docstring)
        assert self._fused is not None  # (the caller checked)
        st, o = run_fused(
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


def mode_initial(
    x: np.ndarray,
    P: np.ndarray,
    mu: np.ndarray,
    mode_x0: npt.ArrayLike | None,
    mode_P0: npt.ArrayLike | None,
    r: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-mode starts ``xs`` (runs, r, n), ``Ps`` (runs, r, n, n) and the combined ``x``, ``P``.

    Parameters
    ----------
    x, P : (runs, n), (runs, n, n) arrays
        The common ``x0``/``P0`` (used for the modes not given per mode).
    mu : (runs, r) array
        Initial mode probabilities.
    mode_x0 : (r, n) or (runs, r, n) array or None
        Per-mode initial estimates.
    mode_P0 : (r, n, n) or (runs, r, n, n) array or None
        Per-mode initial covariances (each symmetric positive definite).
    r : int
        Number of modes.

    Returns
    -------
    (xs, Ps, x, P)
        With both None: the common values for every mode and ``x``, ``P`` unchanged.
    """
    runs, n = x.shape
    if mode_x0 is None:
        xs = np.broadcast_to(x[:, None], (runs, r, n))
    else:
        xs = finite_array("mode_x0", mode_x0, ndim=(2, 3))
        if xs.shape[-2:] != (r, n) or (xs.ndim == 3 and xs.shape[0] not in (1, runs)):
            raise ShapeError(f"mode_x0 must have shape ({r}, {n}) or ({runs}, {r}, {n}); got {xs.shape}")
        xs = np.broadcast_to(xs, (runs, r, n))
    if mode_P0 is None:
        Ps = np.broadcast_to(P[:, None], (runs, r, n, n))
    else:
        Ps = finite_array("mode_P0", mode_P0, ndim=(3, 4))
        if Ps.shape[-3:] != (r, n, n) or (Ps.ndim == 4 and Ps.shape[0] not in (1, runs)):
            raise ShapeError(
                f"mode_P0 must have shape ({r}, {n}, {n}) or ({runs}, {r}, {n}, {n}); got {Ps.shape}"
            )
        check_spd("mode_P0", Ps)
        Ps = np.broadcast_to(Ps, (runs, r, n, n))
    if mode_x0 is None and mode_P0 is None:
        return np.array(xs), np.array(Ps), x, P
    xc, Pc = combine(mu, xs, Ps)
    return np.array(xs), np.array(Ps), xc, Pc


def pairwise_spread(mu: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The spread term as printed in [IMM] eq (32)-(33): ``sum_i sum_j mu_i mu_j (x_i - x_j)(x_i - x_j)^T``.

    Exactly twice the standard spread ``sum_j mu_j (x_j - x)(x_j - x)^T`` (tested); kept only to
    document the correction. :func:`~chatterspec.filters.bank.combine` uses the standard form.

    Parameters
    ----------
    mu : (..., r) array
        Mode probabilities (sum 1).
    xs : (..., r, n) array
        Mode-conditioned estimates.

    Returns
    -------
    (..., n, n) ndarray
    """
    d = xs[..., :, None, :] - xs[..., None, :, :]
    w = mu[..., :, None] * mu[..., None, :]
    return np.einsum("...ij,...ija,...ijb->...ab", w, d, d)


# ----------------------------------------------------------------------------- the compiled recursion
#: The mode corrections the compiled IMM supports, in the order a bank's kinds are numbered.
CORRECTIONS = ("kf", "svsf", "svsf2", "svsf_luen", "svsf2_luen")


@_jit.step
def _no_correction(fp: np.ndarray, e: np.ndarray, ep: np.ndarray, epp: np.ndarray, xp: np.ndarray,
    PCtT: np.ndarray, D: np.ndarray, L: np.ndarray, C: np.ndarray, F: np.ndarray, x: np.ndarray,
    KgT: np.ndarray, ws: tuple[np.ndarray, ...], n: int, m: int) -> int:  # fmt: skip
    """Placeholder binding of :func:`_mode_correct` beyond a bank's kinds (never called)."""
    return NOT_PD


#: Bindings of :func:`_mode_correct`: the correction steps of a bank's kinds (placeholders beyond).
CORRECT_0 = CORRECT_1 = CORRECT_2 = CORRECT_3 = CORRECT_4 = _no_correction


def _mode_correct(fp, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled (a template)
    """A mode's correction, ``CORRECT_<fp[0]>``, on its parameters ``fp[1:]``.

    Signature of :mod:`chatterspec.filters._engine`'s correction steps. The modes' filter step
    (:func:`chatterspec.filters._engine._sample`) is compiled once for every kind of the bank, only
    the corrections are per kind: a step per kind would compile the predictions and the Joseph
    update once per kind.
    """
    kind = fp[0]
    f = fp[1:]
    if kind == 0.0:
        return CORRECT_0(f, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)
    if kind == 1.0:
        return CORRECT_1(f, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)
    if kind == 2.0:
        return CORRECT_2(f, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)
    if kind == 3.0:
        return CORRECT_3(f, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)
    return CORRECT_4(f, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)


def _no_numpy(prior: NumpyPrior) -> tuple[np.ndarray, np.ndarray]:
    """The numpy form of the modes' correction (none: the IMM's numpy path runs the mode filters)."""
    raise NotImplementedError("the IMM's numpy path runs each mode filter's own correction")


def mode_sample(corrections: Sequence[CorrectionStep]) -> tuple[Callable[..., int], list[str]]:
    """The modes' filter step for a bank's corrections and its kinds (a mode's code: its kind's index).

    The kinds are numbered in the order of :data:`CORRECTIONS`, so banks with the same kinds in any
    order share one compiled loop.
    """
    names = {c.name: c.step for c in corrections}
    kinds = [k for k in CORRECTIONS if k in names]
    bind: dict[str, Any] = {f"CORRECT_{i}": names[k] for i, k in enumerate(kinds)}
    tag = "_".join(kinds)
    correct = _jit.specialize_sizes(_mode_correct, tag, {}, inline=True, **bind)
    step = CorrectionStep(f"imm_{tag}", correct, np.zeros(0), _no_numpy)
    return sample_step(step, want_ll=False), kinds


#: Bindings of :func:`_imm_sample`: the modes' plant step (:func:`.bank.bank_plants`), their filter
#: step (:func:`mode_sample`), sizes; of the loops: ``IMM_SAMPLE`` (:func:`_imm_sample` bound).
PLANT = _bank_plant
MODE_SAMPLE = _no_sample
NX = NZ = 0
#: Return code of :func:`_imm_sample` when every mode likelihood is zero or non-finite.
NO_LIKELIHOOD = 5


@_jit.step
def imm_scratch(nm: int, n: int, m: int) -> tuple:  # pragma: no cover - compiled
    """The scratch of :func:`_imm_sample`, made once by the loop that calls it (inlined into it):
    ``(c, w, lw, xp, F, em, Sc, Lc, ec, col, tmp, ws)`` (``ws``: :func:`._engine.workspace`)."""
    return (
        _jit.scratch(nm), _jit.scratch2(nm, nm), _jit.scratch(nm), _jit.scratch(n), _jit.scratch2(n, n),
        _jit.scratch(m), _jit.scratch2(m, m), _jit.scratch2(m, m), _jit.scratch(m), _jit.scratch(m),
        _jit.scratch(2 * m), workspace(n, m),
    )  # fmt: skip


def _imm_sample(  # type: ignore[no-untyped-def]  # (a template: the bank loops' arguments)
    prm,
    plant_slot,
    fp,
    Q,
    C,
    R,
    pi,
    floor,
    zk,
    uk,
    first,
    mu,
    xs,
    Ps,
    eps,
    epps,
    zl,
    x,
    P,
    x0,
    P0,
    ll,
    scr,
    n,
    m,
    p,
):  # pragma: no cover - compiled (a template: see imm_sample_step)
    """[IMM] eq (18)-(33) for one sample of one realization (the module docstring); state in place.

    ``zk`` (m,) = z(k+1), ``uk`` (p,) = u(k); ``first``: no measurement before (the stored
    residuals are e(k|k)). State rows: ``mu`` (nm,), ``xs`` (nm, n), ``Ps`` (nm, n, n), ``eps``,
    ``epps`` (nm, m), ``zl`` (m,) = z(k), ``x`` (n,), ``P`` (n, n); ``x0``, ``P0`` scratch of the
    mixed initial conditions; ``ll`` (nm,) receives eq (29); ``scr``: :func:`imm_scratch` (made once
    by the calling loop: views made per sample cost a sixth of the bank's time). Returns 0,
    :data:`NOT_PD`, :data:`SINGULAR_PHI12` or :data:`NO_LIKELIHOOD`.
    """
    nm = mu.shape[0]
    c, w, lw, xp, F, em, Sc, Lc, ec, col, tmp, ws = scr
    S, e = ws[4], ws[7]
    # (19), (18): predicted mode probabilities and mixing weights
    for j in range(nm):
        s = 0.0
        for i in range(nm):
            s += mu[i] * pi[i, j]
        c[j] = s if s > 1e-300 else 1e-300
    for i in range(nm):
        for j in range(nm):
            w[i, j] = mu[i] * pi[i, j] / c[j]
    # (20), (21): mixed initial conditions
    for j in range(nm):
        for a in range(n):
            s = 0.0
            for i in range(nm):
                s += w[i, j] * xs[i, a]
            x0[j, a] = s
        for a in range(n):
            for bb in range(n):
                s = 0.0
                for i in range(nm):
                    da = xs[i, a] - x0[j, a]
                    s += w[i, j] * (Ps[i, a, bb] + da * (xs[i, bb] - x0[j, bb]))
                P0[j, a, bb] = s
    # (22)-(29): mode-matched filters
    for j in range(nm):
        for i in range(m):  # e(k|k) of mode j: residual of its mixed estimate (design.md I4)
            if first:
                em[i] = eps[j, i]
            else:
                s = zl[i]
                for q in range(n):
                    s -= C[0, i, q] * x0[j, q]
                em[i] = s
        PLANT(plant_slot[j], prm[j], x0[j], uk, xp, F, n, p)
        for a in range(n):
            for bb in range(n):
                Ps[j, a, bb] = P0[j, a, bb]
        status = MODE_SAMPLE(fp[j], xs[j], Ps[j], em, epps[j], zk, xp, F, C[j], Q[j], R[j], ws, n, m)
        if status != 0:
            return status
        for i in range(m):
            eps[j, i] = em[i]
        ll[j] = log_gaussian_step(e, S, m, Sc, Lc, ec, col, tmp)  # (29)
    # (30): log-domain mode probabilities, optional floor
    for j in range(nm):
        lw[j] = np.log(c[j]) + ll[j]
    if not mode_probabilities_step(lw, mu, floor, nm):
        return NO_LIKELIHOOD
    # (31)-(33): combination
    combine_step(mu, xs, Ps, x, P, nm, n)
    for i in range(m):
        zl[i] = zk[i]
    return 0


@_jit.step
def _no_imm_sample(*args):  # type: ignore[no-untyped-def]
    """Placeholder binding of the loops (never called)."""
    return NOT_PD


IMM_SAMPLE = IMM_LOOP = _no_imm_sample


def _imm_loop(
    prm: np.ndarray,
    plant_slot: np.ndarray,
    fp: np.ndarray,
    Q: np.ndarray,
    C: np.ndarray,
    R: np.ndarray,
    pi: np.ndarray,
    floor: float,
    z: np.ndarray,
    u: np.ndarray,
    first: bool,
    mu: np.ndarray,
    xs: np.ndarray,
    Ps: np.ndarray,
    eps: np.ndarray,
    epps: np.ndarray,
    zl: np.ndarray,
    x: np.ndarray,
    P: np.ndarray,
    x0: np.ndarray,
    P0: np.ndarray,
    o_x: np.ndarray,
    o_mu: np.ndarray,
    o_ll: np.ndarray,
    o_P: np.ndarray,
    o_mx: np.ndarray,
) -> int:  # pragma: no cover - compiled (a template: see run_fused)
    """The IMM recursion of the module docstring (:func:`_imm_sample` per run and sample); in place.

    Per mode j: ``prm[j]`` (its plant's parameters, plant kind ``plant_slot[j]`` of ``PLANT``),
    ``fp[j]`` (its correction's parameters, ``corr_slot[j]`` = 0 .. 3), ``Q[j]``, ``C[j]``, ``R[j]``.
    ``x0``, ``P0`` (nm, n), (nm, n, n): scratch of the mixed initial conditions. Returns 0,
    ``1 + run`` when an innovation covariance (or the ``cov`` mapping's ``C P C^T``) is not positive
    definite, ``-(1 + run)`` when every mode likelihood is zero or
    non-finite, or ``-(1 + runs + run)`` when the ``luen`` form meets a singular ``Phi12``.
    """
    b = _jit.borrow
    prm, plant_slot, fp, Q, C, R, pi = (
        b(prm),
        b(plant_slot),
        b(fp),
        b(Q),
        b(C),
        b(R),
        b(pi),
    )
    z, u, mu, xs, Ps, eps, epps, zl, x, P = (
        b(z),
        b(u),
        b(mu),
        b(xs),
        b(Ps),
        b(eps),
        b(epps),
        b(zl),
        b(x),
        b(P),
    )
    x0, P0, o_x, o_mu, o_ll, o_P, o_mx = b(x0), b(P0), b(o_x), b(o_mu), b(o_ll), b(o_P), b(o_mx)
    runs, K, _ = z.shape
    nm = mu.shape[1]
    n = NX if NX > 0 else x.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    p = u.shape[2]
    shared_u = u.shape[0] == 1
    ll = _jit.scratch(nm)
    scr = imm_scratch(nm, n, m)
    for r in range(runs):
        ur = 0 if shared_u else r
        for k in range(K):
            status = IMM_SAMPLE(
                prm, plant_slot, fp, Q, C, R, pi, floor, z[r, k], u[ur, k], first and k == 0,
                mu[r], xs[r], Ps[r], eps[r], epps[r], zl[r], x[r], P[r], x0, P0, ll, scr, n, m, p,
            )  # fmt: skip
            if status == NOT_PD:
                return 1 + r
            if status == SINGULAR_PHI12:
                return -(1 + runs + r)
            if status == NO_LIKELIHOOD:
                return -(1 + r)
            bank_store_step(r, k, x[r], mu[r], ll, P[r], xs[r], o_x, o_mu, o_ll, o_P, o_mx, nm, n)
    return 0


def _imm_one(buf, cst, slots, z, u):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled
    """One sample of one realization: the batch loop ``IMM_LOOP`` (:func:`_imm_loop`, the same
    compiled code) on one run and one sample of packed arrays (:func:`one_layout`).

    ``buf`` holds the state (``first`` flag, ``mu``, ``xs``, ``Ps``, ``eps``, ``epps``, ``zl``, ``x``,
    ``P``), the scratch ``x0``, ``P0`` and receives ``ll``; ``cst``
    (:func:`~chatterspec.filters.bank.one_constants`) the header ``[nm, n, m, L_prm, L_fp, floor]``
    then ``prm``, ``fp``, ``Q``, ``C``, ``R``, ``pi``; ``slots`` (nm,) int the plant slots; ``z``
    (m,), ``u`` (p,). The state is read into a copy and written back only when the sample succeeds
    with a finite estimate. Returns 0, the step's code, ``BAD_INPUT`` or ``DIVERGED``
    (:mod:`chatterspec.filters._engine`).
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
    fp, o = take2(cst, o, nm, int(cst[4]))
    Q, o = take3(cst, o, nm, n, n)
    C, o = take3(cst, o, nm, m, n)
    R, o = take3(cst, o, nm, m, m)
    pi, o = take2(cst, o, nm, nm)
    offs = one_layout(nm, n, m)
    size = offs[-1]
    work, z1, u1, o_x, o_mu, none = one_sample_io(buf, size, z, u, n, m, p, nm)
    status = IMM_LOOP(
        prm, slots, fp, Q, C, R, pi, cst[5], z1, u1, work[0] != 0.0,
        work[offs[0] : offs[1]].reshape((1, nm)), work[offs[1] : offs[2]].reshape((1, nm, n)),
        work[offs[2] : offs[3]].reshape((1, nm, n, n)), work[offs[3] : offs[4]].reshape((1, nm, m)),
        work[offs[4] : offs[5]].reshape((1, nm, m)), work[offs[5] : offs[6]].reshape((1, m)),
        work[offs[6] : offs[7]].reshape((1, n)), work[offs[7] : offs[8]].reshape((1, n, n)),
        work[offs[8] : offs[9]].reshape((nm, n)), work[offs[9] : offs[10]].reshape((nm, n, n)),
        o_x, o_mu, work[offs[10] : offs[11]].reshape((1, 1, nm)), none, none,
    )  # fmt: skip
    if status != 0:  # the loop's codes for run 0 of 1 back to the step's
        return NOT_PD if status == 1 else (NO_LIKELIHOOD if status == -1 else SINGULAR_PHI12)
    if not finite_state(work[offs[6] : offs[7]], work[offs[7] : offs[8]].reshape((n, n)), n):
        return DIVERGED
    work[0] = 0.0
    for i in range(size):
        buf[i] = work[i]
    return 0


@_jit.step
def one_layout(nm: int, n: int, m: int) -> tuple[int, int, int, int, int, int, int, int, int, int, int, int]:
    """Offsets in :func:`_imm_one`'s buffer (``first`` flag at 0): ``mu``, ``xs``, ``Ps``, ``eps``, ``epps``,
    ``zl``, ``x``, ``P``, ``x0``, ``P0``, ``ll`` and the length."""
    o_mu = 1
    o_xs = o_mu + nm
    o_Ps = o_xs + nm * n
    o_eps = o_Ps + nm * n * n
    o_epps = o_eps + nm * m
    o_zl = o_epps + nm * m
    o_x = o_zl + m
    o_P = o_x + n
    o_x0 = o_P + n * n
    o_P0 = o_x0 + nm * n
    o_ll = o_P0 + nm * n * n
    return o_mu, o_xs, o_Ps, o_eps, o_epps, o_zl, o_x, o_P, o_x0, o_P0, o_ll, o_ll + nm


class IMMSpec(BankLoop):
    """The arrays and the loop of a compiled IMM (:func:`fused_spec`): per-mode rows, stacked."""

    prm: np.ndarray  # plant parameters, one row per plant kind
    plant_slot: np.ndarray  # (r,) plant row of each mode
    fp: np.ndarray  # correction code (:func:`mode_sample`) and parameters, one row per mode
    Q: np.ndarray  # (r, n, n)
    C: np.ndarray  # (r, m, n)
    R: np.ndarray  # (r, m, m)
    one: Callable[..., int]  # one sample of one realization (:func:`_imm_one`)


def fused_spec(filters: tuple[Filter, ...]) -> IMMSpec | None:
    """Per-mode arrays and steps of the compiled IMM loop, or None when a mode is not supported.

    Supported: a filter with a compiled correction (``_correction_step()``; not the variable
    boundary layer) on a model with compiled plant steps (:func:`chatterspec.plants.steps.plant_steps`),
    at most two plant kinds per bank.

    Parameters
    ----------
    filters : tuple of Filter
        The IMM's mode-matched filters.

    Returns
    -------
    dict or None
    """
    from ..plants.steps import plant_steps

    plants, corrections = [], []
    for f in filters:
        get = getattr(f, "_correction_step", None)
        steps = plant_steps(f.model)
        if get is None or steps is None or getattr(f.model, "h", None) is not None:  # h(x): protocol path
            return None
        corr = get()
        if corr.name not in CORRECTIONS:  # the variable boundary layer
            return None
        plants.append(steps)
        corrections.append(corr)
    plant, plant_slot, prm = bank_plants(plants)
    mdl = filters[0].model
    sizes_fit = _jit.fits(int(mdl.n_states), int(mdl.n_outputs)) and _jit.fits(len(filters))
    if plant is None or not sizes_fit:
        return None

    def rows(vectors: list[np.ndarray]) -> np.ndarray:
        out = np.zeros((len(vectors), max(len(v) for v in vectors)))
        for j, v in enumerate(vectors):
            out[j, : len(v)] = v
        return out

    models = [f.model for f in filters]
    sample, kinds = mode_sample(corrections)
    tag = "_".join(["imm", *dict.fromkeys(p.name for p in plants), *kinds])
    n, m = int(models[0].n_states), int(models[0].n_outputs)
    sizes = {"NX": n, "NZ": m}
    step = _jit.specialize_sizes(_imm_sample, tag, {}, inline=True, PLANT=plant, MODE_SAMPLE=sample)
    loop = _jit.specialize_sizes(_imm_loop, tag, sizes, IMM_SAMPLE=step)
    return {
        "prm": prm,
        "plant_slot": plant_slot,
        "fp": rows([np.concatenate([[kinds.index(c.name)], c.parameters]) for c in corrections]),
        "Q": np.ascontiguousarray(np.stack([np.asarray(md.Q, dtype=float) for md in models])),
        "C": np.ascontiguousarray(np.stack([np.asarray(md.C, dtype=float) for md in models])),
        "R": np.ascontiguousarray(np.stack([np.asarray(md.R, dtype=float) for md in models])),
        "mapping": max(c.mapping for c in corrections),
        "kernel": loop,
        "one": _jit.specialize_sizes(_imm_one, tag, sizes, IMM_LOOP=loop),
    }


def run_fused(
    spec: IMMSpec,
    pi: np.ndarray,
    floor: float,
    state: MultipleModelState,
    z: np.ndarray,
    u: np.ndarray,
    store_covariance: bool,
    store_modes: bool,
    *,
    python: bool = False,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray | None]]:
    """Advance an IMM state over ``z`` (runs, K, m) with the compiled loop.

    Parameters
    ----------
    spec : dict
        From :func:`fused_spec`.
    pi : (r, r) array
        Transition matrix.
    floor : float
        Mode-probability floor.
    state : MultipleModelState
        The IMM state after sample k.
    z : (runs, K, m) array
        Measurements (validated).
    u : (1 | runs, K, p) array
        Inputs (validated).
    store_covariance, store_modes : bool
        Outputs wanted (see :meth:`IMM.update`).
    python : bool
        Run the loop's Python form (tests: the meaning does not depend on the compiler).

    Returns
    -------
    (state arrays, outputs)
        ``mu, xs, Ps, eps, epps, zl, x, P`` after the last sample, and ``x, mu, ll, P, mx``.

    Raises
    ------
    SingularMatrixError
        An innovation covariance that is not positive definite, or every mode likelihood zero.
    """
    runs, K, _m = z.shape
    n = state.x.shape[1]
    sts = state.mode_states
    r = len(sts)
    st = {
        "mu": np.array(state.mu, dtype=float, order="C"),
        "xs": np.ascontiguousarray(np.stack([s.x for s in sts], axis=1), dtype=float),
        "Ps": np.ascontiguousarray(
            np.stack([np.broadcast_to(s.P, (runs, n, n)) for s in sts], axis=1), dtype=float
        ),
        "eps": np.ascontiguousarray(np.stack([s.e_post for s in sts], axis=1), dtype=float),
        "epps": np.ascontiguousarray(np.stack([s.e_prev for s in sts], axis=1), dtype=float),
        "zl": np.array(state.z_last, dtype=float, order="C"),
        "x": np.array(state.x, dtype=float, order="C"),
        "P": np.array(np.broadcast_to(state.P, (runs, n, n)), dtype=float, order="C"),
    }
    c = np.ascontiguousarray
    args = (
        spec["prm"], spec["plant_slot"], spec["fp"], spec["Q"], spec["C"], spec["R"],
        c(pi, dtype=float), float(floor), c(z, dtype=float), c(u, dtype=float),
        bool(state.k == 0),
        st["mu"], st["xs"], st["Ps"], st["eps"], st["epps"], st["zl"], st["x"], st["P"],
        np.empty((r, n)), np.empty((r, n, n)),
    )  # fmt: skip
    out = bank_outputs(runs, K, n, r, store_covariance, store_modes)
    run_bank_loop(spec, args, out, python=python)
    return st, bank_results(out, store_covariance, store_modes)
