"""Compiled SMM-SVSF loop, Table 1 reading ([SMM] eq 3.1-3.5 with eq 2.1-2.10) (private).

:meth:`chatterspec.filters.smm_svsf.SMMSVSF.update` (``reading="table1"``) in one compiled
loop over runs (outer) and samples (inner), built from the same steps as the other loops::

    x_j = f_j(x(k|k), u(k)),  P_j = F_j P(k|k) F_j^T + Q_j      plant steps, predict_cov_step
    S_j = C P_j C^T + R,  log p_j = log N(z - C x_j; 0, S_j)    innovation_step, log_gaussian_step
    mu_j ∝ p_j mu_j (log domain), floor, renormalize           mode_probabilities_step
    x(k+1|k) = sum_j mu_j x_j,  P(k+1|k) = sum_j mu_j [...]     combine_step
    the SVSF-cov correction from (x(k+1|k), P(k+1|k))           the covariance filters' sample step
                                                                 (F = I, Q = 0: P(k+1|k) as given)

The modes' plant steps come from :func:`chatterspec.plants.steps.plant_steps` (two kinds at most,
:func:`chatterspec.filters._bank_steps.bank_plants`).
The numpy path (:meth:`SMMSVSF._update_table1`) evaluates the same formulas with BLAS products,
``einsum`` and LAPACK ``eigh``: the two agree to a few ulps per sample (tests/test_smm_kernel.py),
and each is bit-for-bit invariant to the chunking of runs and samples.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from .. import _jit
from ..plants.nonlinear import Model
from ._bank_steps import (
    BankLoop,
    _bank_plant,
    bank_outputs,
    bank_plants,
    bank_results,
    bank_store_step,
    combine_step,
    log_gaussian_inline,
    mode_probabilities_step,
    run_bank_loop,
)
from ._engine import (
    BAD_INPUT,
    DIVERGED,
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
from ._finite import finite_sample, finite_state

#: Bindings of :func:`_smm_sample`: the modes' plant step (:func:`._bank_steps.bank_plants`), the
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


SMM_SAMPLE = _no_smm_sample


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
    """One sample of one realization: :func:`_smm_sample` on packed arrays (:func:`one_layout`).

    ``buf`` holds ``x``, ``P``, ``mu``, ``e(k|k)``, ``e(k-1|k-1)``, the scratch ``xs``, ``Ps`` and
    receives ``ll`` and ``z``; ``cst`` the header ``[nm, n, m, L_prm, L_fp, floor]`` then ``prm``,
    ``Qs``, ``C``, ``R``, ``fp``; ``slots`` (nm,) int the plant slots. The state is written back only
    when the sample succeeds with a finite estimate. Returns 0, the step's code, ``BAD_INPUT`` or
    ``DIVERGED``.
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
    Qs, o = take3(cst, o, nm, n, n)
    C, o = take2(cst, o, m, n)
    R, o = take2(cst, o, m, m)
    fp, o = take(cst, o, int(cst[4]))
    offs = one_layout(nm, n, m)
    size = offs[-1]
    work = _jit.scratch_block(size)
    for i in range(size):
        work[i] = buf[i]
    x = work[0 : offs[0]]
    P = work[offs[0] : offs[1]].reshape((n, n))
    mu = work[offs[1] : offs[2]]
    ep = work[offs[2] : offs[3]]
    epp = work[offs[3] : offs[4]]
    xs = work[offs[4] : offs[5]].reshape((nm, n))
    Ps = work[offs[5] : offs[6]].reshape((nm, n, n))
    ll = work[offs[6] : offs[7]]
    scr = smm_scratch(nm, n, m)
    status = SMM_SAMPLE(prm, slots, Qs, C, R, fp, floor, z, u, x, P, mu, ep, epp, xs, Ps, ll, scr, n, m, p)
    if status != 0:
        return status
    if not finite_state(x, P, n):
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
    return {
        "prm": prm,
        "plant_slot": plant_slot,
        "Qs": np.ascontiguousarray(np.stack([np.asarray(mdl.Q, dtype=float) for mdl in models])),
        "C": np.ascontiguousarray(models[0].C, dtype=float),
        "R": np.ascontiguousarray(models[0].R, dtype=float),
        "fp": correct.parameters,
        "mapping": correct.mapping,
        "kernel": _jit.specialize_sizes(_smm_loop, tag, sizes, SMM_SAMPLE=step),
        "one": _jit.specialize_sizes(_smm_one, tag, sizes, SMM_SAMPLE=step),
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
