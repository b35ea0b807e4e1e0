"""Compiled IMM bank loop: mixing, the mode-matched filters' steps, likelihoods, combination (private).

One call of :meth:`chatterspec.filters.imm.IMM.update` for every realization, in one
compiled loop over runs (outer) and time (inner), instead of three protocol ``update`` calls and a
dozen numpy calls on (runs, 3, 4) arrays per sample. The arithmetic is that of the protocol path
([IMM] eq 15-33 as corrected in ``docs/design.md`` §7.6)::

    (19) c_j = sum_i pi_ij mu_i,  c_j >= 1e-300   (18) w_ij = mu_i pi_ij / c_j
    (20) x_0j = sum_i w_ij x_i                    (21) P_0j = sum_i w_ij [P_i + (x_i - x_0j)(.)^T]
    (22)-(28) mode j's filter step (:func:`chatterspec.filters._engine._sample` with the mode's
         correction step, inlined) from (x_0j, P_0j), its model's compiled ``predict``/``jacobian`` steps, and
         e(k|k) = z(k) - C_0 x_0j (the stored residual before the first sample)
    (29) log N(e_j; 0, S_j) (:func:`chatterspec.filters._bank_steps.log_gaussian_step`)
    (30) mu_j ∝ c_j Lambda_j in the log domain, optional floor
    (31)-(33) x = sum_j mu_j x_j,  P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]

Nothing here is specific to a filter or a plant: the modes' plant steps come from
:func:`chatterspec.plants.steps.plant_steps` (two kinds per bank at most,
:func:`chatterspec.filters._bank_steps.bank_plants`) and their corrections from each filter's
``_correction_step()`` (four kinds at most, ``SAMPLE_0`` .. ``SAMPLE_3``); :func:`fused_spec`
returns None (the protocol path) for anything else and for the variable boundary layer.

**Equality.** The kernel is not bit-identical to the protocol path: numpy evaluates ``mu @ pi``, the
mixing and combination ``einsum`` and the likelihood (eigh) in other summation orders than the
kernel's loops. The differences are a few ulps per sample; the tests bound them (tolerances stated
there). Runs are independent and every sample starts from the stored state, so any chunking of runs
or samples gives the same bits as one call.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import _jit
from ._bank_steps import (
    BankLoop,
    _bank_plant,
    bank_outputs,
    bank_plants,
    bank_results,
    bank_store_step,
    combine_step,
    log_gaussian_step,
    mode_probabilities_step,
    run_bank_loop,
)
from ._engine import (
    BAD_INPUT,
    DIVERGED,
    NOT_PD,
    SINGULAR_PHI12,
    _no_sample,
    sample_step,
    take2,
    take3,
    workspace,
)
from ._finite import finite_sample, finite_state

if TYPE_CHECKING:  # pragma: no cover
    from .bank_common import MultipleModelState
    from .protocol import Filter

#: Bindings of :func:`_imm_sample`: the modes' plant step (:func:`._bank_steps.bank_plants`), four
#: correction kinds (sample steps), sizes; of the loops: ``IMM_SAMPLE`` (:func:`_imm_sample` bound).
PLANT = _bank_plant
SAMPLE_0 = SAMPLE_1 = SAMPLE_2 = SAMPLE_3 = _no_sample
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
    corr_slot,
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
        f_j, x_j, P_j, epp_j = fp[j], xs[j], Ps[j], epps[j]
        slot = corr_slot[j]
        if slot == 0:
            status = SAMPLE_0(f_j, x_j, P_j, em, epp_j, zk, xp, F, C[j], Q[j], R[j], ws, n, m)
        elif slot == 1:
            status = SAMPLE_1(f_j, x_j, P_j, em, epp_j, zk, xp, F, C[j], Q[j], R[j], ws, n, m)
        elif slot == 2:
            status = SAMPLE_2(f_j, x_j, P_j, em, epp_j, zk, xp, F, C[j], Q[j], R[j], ws, n, m)
        else:
            status = SAMPLE_3(f_j, x_j, P_j, em, epp_j, zk, xp, F, C[j], Q[j], R[j], ws, n, m)
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


IMM_SAMPLE = _no_imm_sample


def _imm_loop(
    prm: np.ndarray,
    plant_slot: np.ndarray,
    fp: np.ndarray,
    corr_slot: np.ndarray,
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
    prm, plant_slot, fp, corr_slot, Q, C, R, pi = (
        b(prm),
        b(plant_slot),
        b(fp),
        b(corr_slot),
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
                prm, plant_slot, fp, corr_slot, Q, C, R, pi, floor, z[r, k], u[ur, k], first and k == 0,
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
    """One sample of one realization: :func:`_imm_sample` on packed arrays (:func:`one_layout`).

    ``buf`` holds the state (``first`` flag, ``mu``, ``xs``, ``Ps``, ``eps``, ``epps``, ``zl``, ``x``,
    ``P``), the scratch ``x0``, ``P0`` and receives ``ll``; ``cst`` the header ``[nm, n, m, L_prm,
    L_fp, floor]`` then ``prm``, ``fp``, ``Q``, ``C``, ``R``, ``pi``; ``slots`` (2 nm,) int the plant and
    correction slots; ``z`` (m,), ``u`` (p,). The state is read into a copy and written back only
    when the sample succeeds with a finite estimate. Returns 0, the step's code, ``BAD_INPUT`` or
    ``DIVERGED`` (:mod:`chatterspec.filters._engine`).
    """
    b = _jit.borrow
    buf, cst, slots, z, u = b(buf), b(cst), b(slots), b(z), b(u)
    nm = int(cst[0])
    n = NX if NX > 0 else int(cst[1])
    m = NZ if NZ > 0 else int(cst[2])
    p = u.shape[0]
    if not finite_sample(z, m, u, p):
        return BAD_INPUT
    floor = cst[5]
    prm, o = take2(cst, 6, nm, int(cst[3]))
    fp, o = take2(cst, o, nm, int(cst[4]))
    Q, o = take3(cst, o, nm, n, n)
    C, o = take3(cst, o, nm, m, n)
    R, o = take3(cst, o, nm, m, m)
    pi, o = take2(cst, o, nm, nm)
    offs = one_layout(nm, n, m)
    size = offs[-1]
    work = _jit.scratch_block(size)
    for i in range(size):
        work[i] = buf[i]
    mu = work[offs[0] : offs[1]]
    xs = work[offs[1] : offs[2]].reshape((nm, n))
    Ps = work[offs[2] : offs[3]].reshape((nm, n, n))
    eps = work[offs[3] : offs[4]].reshape((nm, m))
    epps = work[offs[4] : offs[5]].reshape((nm, m))
    zl = work[offs[5] : offs[6]]
    x = work[offs[6] : offs[7]]
    P = work[offs[7] : offs[8]].reshape((n, n))
    x0 = work[offs[8] : offs[9]].reshape((nm, n))
    P0 = work[offs[9] : offs[10]].reshape((nm, n, n))
    ll = work[offs[10] : offs[11]]
    status = IMM_SAMPLE(
        prm, slots[:nm], fp, slots[nm:], Q, C, R, pi, floor, z, u, work[0] != 0.0,
        mu, xs, Ps, eps, epps, zl, x, P, x0, P0, ll, imm_scratch(nm, n, m), n, m, p,
    )  # fmt: skip
    if status != 0:
        return status
    if not finite_state(x, P, n):
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


# ----------------------------------------------------------------------------- Python side
class IMMSpec(BankLoop):
    """The arrays and the loop of a compiled IMM (:func:`fused_spec`): per-mode rows, stacked."""

    prm: np.ndarray  # plant parameters, one row per plant kind
    plant_slot: np.ndarray  # (r,) plant row of each mode
    fp: np.ndarray  # correction parameters, one row per mode
    corr_slot: np.ndarray  # (r,) correction kind of each mode
    Q: np.ndarray  # (r, n, n)
    C: np.ndarray  # (r, m, n)
    R: np.ndarray  # (r, m, m)
    one: Callable[..., int]  # one sample of one realization (:func:`_imm_one`)


def fused_spec(filters: tuple[Filter, ...]) -> IMMSpec | None:
    """Per-mode arrays and steps of the compiled IMM loop, or None when a mode is not supported.

    Supported: a filter with a compiled correction (``_correction_step()``; not the variable
    boundary layer) on a model with compiled plant steps (:func:`chatterspec.plants.steps.plant_steps`),
    at most two plant kinds and four correction kinds per bank.

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
        if corr.name == "vbl":
            return None
        plants.append(steps)
        corrections.append(corr)
    plant, plant_slot, prm = bank_plants(plants)
    corr_kinds = list(dict.fromkeys(c.name for c in corrections))
    mdl = filters[0].model
    sizes_fit = _jit.fits(int(mdl.n_states), int(mdl.n_outputs)) and _jit.fits(len(filters))
    if plant is None or len(corr_kinds) > 4 or not sizes_fit:
        return None

    def rows(vectors: list[np.ndarray]) -> np.ndarray:
        out = np.zeros((len(vectors), max(len(v) for v in vectors)))
        for j, v in enumerate(vectors):
            out[j, : len(v)] = v
        return out

    models = [f.model for f in filters]
    samples = {c.name: c for c in corrections}
    bind: dict[str, Any] = {"PLANT": plant}  # steps and flags bound into the loop
    for i, name in enumerate(corr_kinds):
        bind[f"SAMPLE_{i}"] = sample_step(samples[name], want_ll=False)
    tag = "_".join(["imm", *dict.fromkeys(p.name for p in plants), *corr_kinds])
    n, m = int(models[0].n_states), int(models[0].n_outputs)
    sizes = {"NX": n, "NZ": m}
    step = _jit.specialize_sizes(_imm_sample, tag, {}, inline=True, **bind)
    return {
        "prm": prm,
        "plant_slot": plant_slot,
        "fp": rows([c.parameters for c in corrections]),
        "corr_slot": np.array([corr_kinds.index(c.name) for c in corrections], dtype=np.int64),
        "Q": np.ascontiguousarray(np.stack([np.asarray(md.Q, dtype=float) for md in models])),
        "C": np.ascontiguousarray(np.stack([np.asarray(md.C, dtype=float) for md in models])),
        "R": np.ascontiguousarray(np.stack([np.asarray(md.R, dtype=float) for md in models])),
        "mapping": max(c.mapping for c in corrections),
        "kernel": _jit.specialize_sizes(_imm_loop, tag, sizes, IMM_SAMPLE=step),
        "one": _jit.specialize_sizes(_imm_one, tag, sizes, IMM_SAMPLE=step),
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
        spec["prm"], spec["plant_slot"], spec["fp"], spec["corr_slot"], spec["Q"], spec["C"], spec["R"],
        c(pi, dtype=float), float(floor), c(z, dtype=float), c(u, dtype=float),
        bool(state.k == 0),
        st["mu"], st["xs"], st["Ps"], st["eps"], st["epps"], st["zl"], st["x"], st["P"],
        np.empty((r, n)), np.empty((r, n, n)),
    )  # fmt: skip
    out = bank_outputs(runs, K, n, r, store_covariance, store_modes)
    run_bank_loop(spec, args, out, python=python)
    return st, bank_results(out, store_covariance, store_modes)
