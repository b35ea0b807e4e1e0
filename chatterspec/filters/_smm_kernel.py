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
from ._engine import CorrectionStep, _no_sample, innovation_step, predict_cov_step, sample_step, workspace

#: Bindings of :func:`_smm_loop`: the modes' plant step (:func:`._bank_steps.bank_plants`), the
#: SVSF-cov sample step, sizes (0: from the arrays).
PLANT = _bank_plant
SAMPLE = _no_sample
NX = NZ = 0


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
    """The recursion of the module docstring; ``x``, ``P``, ``mu``, ``ep``, ``epp`` updated in place.

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
    ws = workspace(n, m)
    T1, PCt, PCtT, S, D, e = ws[0], ws[2], ws[3], ws[4], ws[5], ws[7]
    F = _jit.scratch2(n, n)
    eye = _jit.scratch2(n, n)
    Q0 = _jit.scratch2(n, n)
    xp = _jit.scratch(n)
    ll = _jit.scratch(nm)
    lw = _jit.scratch(nm)
    Sc = _jit.scratch2(m, m)
    Lc = _jit.scratch2(m, m)
    ec = _jit.scratch(m)
    col = _jit.scratch(m)
    tmp = _jit.scratch(2 * m)
    for i in range(n):
        for j in range(n):
            eye[i, j] = 1.0 if i == j else 0.0
            Q0[i, j] = 0.0
    for r in range(runs):
        ur = 0 if shared_u else r
        for k in range(K):
            for j in range(nm):  # Table 1 steps 1-2: every mode from the common posterior
                PLANT(plant_slot[j], prm[j], x[r], u[ur, k], xs[j], F, n, p)
                predict_cov_step(F, P[r], Qs[j], T1, Ps[j], n)
                innovation_step(z[r, k], xs[j], Ps[j], C, R, e, PCt, PCtT, D, S, n, m)
                ll[j] = log_gaussian_inline(e, S, m, Sc, Lc, ec, col, tmp)  # eq 3.2-3.3
            for j in range(nm):  # eq 3.1 in the log domain, with the floor
                lw[j] = np.log(max(mu[r, j], 1e-300)) + ll[j]
            if not mode_probabilities_step(lw, mu[r], floor, nm):
                return -(1 + r)
            combine_step(mu[r], xs, Ps, xp, P[r], nm, n)  # steps 4a-5: P(k+1|k) into P[r]
            # steps 6-7b: the SVSF-cov update from the mixed prior (F = I, Q = 0: P(k+1|k) as given)
            status = SAMPLE(fp, x[r], P[r], ep[r], epp[r], z[r, k], xp, eye, C, Q0, R, ws, n, m)
            if status != 0:
                return 1 + r
            bank_store_step(r, k, x[r], mu[r], ll, P[r], xs, o_x, o_mu, o_ll, o_P, o_mx, nm, n)
    return 0


class SMMSpec(BankLoop):
    """The arrays and the loop of a compiled SMM-SVSF (:func:`smm_spec`)."""

    prm: np.ndarray  # plant parameters, one row per plant kind
    plant_slot: np.ndarray  # (r,) plant row of each mode
    Qs: np.ndarray  # (r, n, n)
    C: np.ndarray  # (m, n), shared
    R: np.ndarray  # (m, m), shared
    fp: np.ndarray  # the shared correction's parameters


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
    kernel = _jit.specialize_sizes(
        _smm_loop,
        tag,
        {"NX": n, "NZ": m},
        PLANT=plant,
        SAMPLE=sample_step(correct, want_ll=False),
    )
    return {
        "prm": prm,
        "plant_slot": plant_slot,
        "Qs": np.ascontiguousarray(np.stack([np.asarray(mdl.Q, dtype=float) for mdl in models])),
        "C": np.ascontiguousarray(models[0].C, dtype=float),
        "R": np.ascontiguousarray(models[0].R, dtype=float),
        "fp": correct.parameters,
        "mapping": correct.mapping,
        "kernel": kernel,
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
