"""The covariance filters' per-sample step and the loop around it (private).

One step, for every realization (notation of ``docs/design.md`` §7)::

    x(k+1|k) = f(x(k|k), u(k)),            F = df/dx at x(k|k)      (linear: A x + B u, F = A)
    P(k+1|k) = F P(k|k) F^T + Q
    e = z(k+1) - C x(k+1|k),   S = C P(k+1|k) C^T + R,   loglik = log N(e; 0, S)
    correction:  x(k+1|k+1) and the gain K of the filter (its own step, see below)
    P(k+1|k+1) = (I - K C) P(k+1|k) (I - K C)^T + K R K^T            (Joseph form)
    e(k-1|k-1) <- e(k|k),   e(k+1|k+1) = z(k+1) - C x(k+1|k+1)

**Compiled.** :func:`_sample` is that step for one realization; it takes the prediction from the
loop and calls the filter's **correction step** ``CORRECT(fp, e, ep, epp, xp, PCtT, D, L, C, F, x,
KgT, ws, n, m)``, bound by :func:`chatterspec._jit.specialize`: the Kalman gain
(:func:`chatterspec.filters.kalman.kalman_correct`), the SVSF with covariance and its variable
boundary layer (:mod:`chatterspec.filters.svsf_cov`), the second-order SVSF
(:mod:`chatterspec.filters.svsf2`). A filter gives its step and a parameter vector ``fp`` through
``_correction_step()`` (:class:`CorrectionStep`); the step returns 0, :data:`NOT_PD` (a matrix it
factors is not positive definite) or :data:`SINGULAR_PHI12` (the reduced-order form's ``Phi12``).
:func:`_cov_loop` runs runs (outer) and samples (inner) with the plant's ``predict`` and
``jacobian`` steps (:mod:`chatterspec.plants.steps`) bound the same way; for a correction that allows
it (``CorrectionStep.lanes``) on a constant Jacobian without the log-likelihood, blocks of
:data:`LANES` runs advance together, the same step in vector lanes (:func:`_lane_block`, same bits);
the IMM and SMM banks call :func:`sample_step` per mode. ``mapping`` of the SVSF-type corrections:
:data:`MAP_CONST` (``C^-1`` or ``C^+``), :data:`MAP_COV` (``P C^T (C P C^T)^-1``), :data:`MAP_LUEN`
(the reduced-order Luenberger form, in :mod:`chatterspec.filters.svsf_cov`).

**numpy.** :func:`cov_numpy` is the same step vectorized over realizations with a Python loop over
samples and the filter's numpy correction (``CorrectionStep.numpy``); it runs when
:func:`chatterspec._jit.enabled` is false, and for the ``luen`` mapping of a single filter. The
two agree to rounding (summation order, LAPACK vs the hand-written Cholesky). The prediction is
given as a function of the sample (:data:`Prediction`): a linear model's ``A x + B u``, a model's
Python ``transition``/``jacobian``, or one sample's prior computed by the caller.

For a model that measures through ``h`` (``NonlinearModel(..., h=..., h_jac=...)``; only the EKF
accepts one), the same step runs with ``C`` replaced by ``H = dh/dx`` at the prior::

    e = z(k+1) - h(x(k+1|k)),     H = dh/dx at x(k+1|k),         S = H P(k+1|k) H^T + R
    K = P(k+1|k) H^T S^-1,        x(k+1|k+1) = x(k+1|k) + K e
    P(k+1|k+1) = (I - K H) P(k+1|k) (I - K H)^T + K R K^T                    (Joseph form)
    e(k+1|k+1) = z(k+1) - h(x(k+1|k+1))

**Linear algebra.** The Cholesky factor, solves, products, prediction covariance and Joseph form
are small steps (``*_step``) inlined by the loops here, by the banks (:mod:`chatterspec.filters.imm`,
:mod:`chatterspec.filters.smm_svsf`) and by the reduced-order form. Every sum runs from its first
term (or 0.0) over q = 0, 1, ...: the same order as the loops these steps replaced, hence the same
bits.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from .. import _jit
from ..errors import ShapeError, SingularMatrixError
from ..plants.nonlinear import MeasurementSteps, Model, measure, measurement_jacobian
from ..plants.steps import PlantSteps
from .protocol import finite_sample, finite_state

__all__ = [
    "BAD_INPUT",
    "DIVERGED",
    "FIELDS",
    "MAP_CONST",
    "MAP_COV",
    "MAP_LUEN",
    "NOT_PD",
    "SINGULAR_PHI12",
    "CorrectionStep",
    "NumpyPrior",
    "chol_np",
    "chol_solve_step",
    "chol_step",
    "cov_loop",
    "cov_numpy",
    "gain_update_step",
    "given_prediction",
    "half_logdet_step",
    "innovation_step",
    "joseph_numpy",
    "joseph_step",
    "kalman_gain_numpy",
    "kernel_input",
    "linear_prediction",
    "loglik_given_step",
    "loglik_step",
    "map_numpy",
    "map_step",
    "map_update_step",
    "model_call_loop",
    "model_prediction",
    "one_offsets",
    "one_sample_constants",
    "one_sample_kernel",
    "predict_cov_step",
    "product_step",
    "residual_step",
    "sample_step",
    "svsf_offsets",
    "svsf_parameters",
    "take",
    "take2",
    "take3",
    "workspace",
]


KF, SVSF1, SVSF2, VBL = 0, 1, 2, 3
MAP_CONST, MAP_COV, MAP_LUEN = 0, 1, 2
#: Return codes of a correction step (0 = done).
NOT_PD, SINGULAR_PHI12 = 1, 2
#: Further return codes of the one-sample loop (:func:`_cov_one`): a non-finite input, a non-finite result.
BAD_INPUT, DIVERGED = 3, 4
LOG2PI = float(np.log(2.0 * np.pi))
FIELDS = ("x_prior", "x_post", "innovation", "S", "loglik", "e_post", "P_prior", "P_post")


class NumpyPrior(NamedTuple):
    """What a numpy correction (``CorrectionStep.numpy``) reads of one sample, arrays over realizations.

    ``e`` = z(k+1) - C x(k+1|k), ``ep`` = e(k|k), ``epp`` = e(k-1|k-1) (runs, m); ``xp`` =
    x(k+1|k) (runs, n); ``PCt`` = P(k+1|k) C^T (runs, n, m); ``D`` = C P(k+1|k) C^T and ``S`` = D + R
    (runs, m, m); ``C`` the measurement matrix (or ``dh/dx`` at the prior); ``F`` the transition's
    Jacobian at x(k|k).
    """

    e: np.ndarray
    ep: np.ndarray
    epp: np.ndarray
    xp: np.ndarray
    PCt: np.ndarray
    D: np.ndarray
    S: np.ndarray
    C: np.ndarray
    F: np.ndarray


@dataclass(frozen=True, eq=False)
class CorrectionStep:
    """A covariance filter's correction, as the loops take it.

    Attributes
    ----------
    name : str
        Short name (part of the compiled loops' names).
    step : callable
        The compiled correction step (signature in the module docstring).
    parameters : (L,) array
        ``fp`` of the step (its layout is the step's own).
    numpy : callable
        ``numpy(prior: NumpyPrior) -> (K (runs, n, m), x (runs, n))``: the same correction
        vectorized over realizations.
    mapping : int
        :data:`MAP_CONST`, :data:`MAP_COV` or :data:`MAP_LUEN` (error messages; ``luen`` single
        filters take the numpy path).
    lanes : bool
        Whether the compiled loop may advance :data:`LANES` runs at once (:func:`_lane_block`), compiled
        without numba's division-by-zero checks: every divisor of the step is guarded or checked
        (positive pivots, ``max(|e|, psi)`` with ``psi > 0``, ``e != 0``).
    """

    name: str
    step: Callable[..., int]
    parameters: np.ndarray
    numpy: Callable[..., tuple[np.ndarray, np.ndarray]]
    mapping: int = MAP_CONST
    lanes: bool = False


def svsf_parameters(
    mapping: int,
    n: int,
    m: int,
    gamma: np.ndarray,
    *,
    lam: np.ndarray | None = None,
    psi: np.ndarray | None = None,
    clip: tuple[float, float] = (0.0, 2.0),
    M: np.ndarray | None = None,
    luen: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """``fp`` of the SVSF-type corrections (layout of :func:`svsf_offsets`).

    ``[mapping, gamma (m), lam (m), psi (n), lo, hi, M (n m), T (n n), T^-1 (n n)]``: ``psi`` has
    m entries, or n with the ``luen`` mapping (measured coordinates first; padded with ones);
    ``lam`` and ``(lo, hi)`` are the second-order SVSF's; ``M`` the constant map (zeros unless
    :data:`MAP_CONST`); ``T``, ``T^-1`` the Luenberger transformation (zeros unless :data:`MAP_LUEN`).
    """
    psi_n = np.ones(n)
    if psi is not None:
        psi_n[: len(psi)] = psi
    parts = [
        np.array([float(mapping)]),
        np.broadcast_to(np.asarray(gamma, dtype=float), (m,)),
        np.zeros(m) if lam is None else np.broadcast_to(np.asarray(lam, dtype=float), (m,)),
        psi_n,
        np.array([float(clip[0]), float(clip[1])]),
        np.zeros(n * m) if M is None else np.ravel(M),
        np.zeros(n * n) if luen is None else np.ravel(luen[0]),
        np.zeros(n * n) if luen is None else np.ravel(luen[1]),
    ]
    return np.ascontiguousarray(np.concatenate(parts), dtype=float)


# ----------------------------------------------------------------------------- steps
@_jit.step
def svsf_offsets(n: int, m: int) -> tuple[int, int, int, int, int, int, int]:
    """Offsets in ``fp`` (:func:`svsf_parameters`) of gamma, lam, psi, lo (hi = lo + 1), M, T, T^-1."""
    o_psi = 1 + 2 * m
    o_lo = o_psi + n
    o_M = o_lo + 2
    o_T = o_M + n * m
    return 1, 1 + m, o_psi, o_lo, o_M, o_T, o_T + n * n


@_jit.step
def map_step(
    mapping: int,
    D: np.ndarray,
    L: np.ndarray,
    PCtT: np.ndarray,
    fp: np.ndarray,
    o_M: int,
    MpT: np.ndarray,
    n: int,
    m: int,
) -> bool:  # pragma: no cover - compiled
    """``MpT`` = M^T, the output-to-state map of the SVSF-type corrections; False if ``C P C^T`` is not PD.

    :data:`MAP_COV`: ``M^T = (C P C^T)^-1 (P C^T)^T`` (Cholesky of ``D`` into ``L``); otherwise
    the constant ``M`` stored row-major at ``fp[o_M:]``.
    """
    if mapping == MAP_COV:
        if not chol_step(D, L, m):
            return False
        chol_solve_step(L, PCtT, MpT, m, n)
    else:
        for i in range(m):
            for j in range(n):
                MpT[i, j] = fp[o_M + j * m + i]
    return True


@_jit.step
def map_update_step(
    xp: np.ndarray,
    MpT: np.ndarray,
    g: np.ndarray,
    dz: np.ndarray,
    x: np.ndarray,
    KgT: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """``K = M diag(g)`` (into ``KgT``) and ``x(k+1|k+1) = x(k+1|k) + M dz``."""
    for i in range(m):
        for j in range(n):
            KgT[i, j] = MpT[i, j] * g[i]
    gain_update_step(xp, MpT, dz, x, n, m)


def _sample(
    fp: np.ndarray,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    zk: np.ndarray,
    xp: np.ndarray,
    F: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    ws: tuple,
    n: int,
    m: int,
) -> int:  # pragma: no cover - compiled (a template: see sample_step)
    """The step of the module docstring for one realization, from ``xp`` = x(k+1|k) and ``F``.

    In place: ``x`` <- x(k+1|k+1), ``P`` <- P(k+1|k+1) (``P`` holds P(k|k) on entry), ``epp`` <-
    ``ep`` (e(k|k), which the correction reads), ``ep`` <- e(k+1|k+1). Scratch ``ws`` (see
    :func:`workspace`) keeps ``Pp`` = P(k+1|k), ``e``, ``S`` and, with ``WANT_LL``, ``ll[0]`` =
    log N(e; 0, S) for the caller. Returns 0 or the correction's / the Cholesky's code.
    """
    T1, Pp, PCt, PCtT, S, D, L, e, eb, wv, KgT, IKC, KR, ll = ws[0:14]
    predict_cov_step(F, P, Q, T1, Pp, n)
    if HX:  # a measurement z = h(x): H = dh/dx at the prior in place of C, e = z - h(x(k+1|k))
        Hm, zh = ws[26], ws[27]
        HJAC(xp, Hm)
        innovation_step(zk, xp, Pp, Hm, R, e, PCt, PCtT, D, S, n, m)
        HFUN(xp, zh)
        for i in range(m):
            e[i] = zk[i] - zh[i]
    else:
        innovation_step(zk, xp, Pp, C, R, e, PCt, PCtT, D, S, n, m)
    if not chol_step(S, L, m):
        return NOT_PD
    if WANT_LL:
        ll[0] = loglik_step(L, e, eb, wv, m)
    if HX:
        status = CORRECT(fp, e, ep, epp, xp, PCtT, D, L, Hm, F, x, KgT, ws, n, m)
        if status != 0:
            return status
        joseph_step(KgT, Hm, Pp, R, T1, IKC, KR, P, n, m)
        for i in range(m):
            epp[i] = ep[i]
        HFUN(x, zh)
        for i in range(m):
            ep[i] = zk[i] - zh[i]
        return 0
    status = CORRECT(fp, e, ep, epp, xp, PCtT, D, L, C, F, x, KgT, ws, n, m)
    if status != 0:
        return status
    joseph_step(KgT, C, Pp, R, T1, IKC, KR, P, n, m)
    for i in range(m):
        epp[i] = ep[i]
    residual_step(zk, C, x, ep, n, m)
    return 0


@_jit.step
def _no_correction(*args: object) -> int:  # (bound by sample_step before any compilation)
    """Placeholder binding of :func:`_sample` (never called)."""
    return NOT_PD


@_jit.step
def _no_measurement(x, out):  # type: ignore[no-untyped-def]
    """Placeholder binding of :func:`_sample`'s measurement function (never called)."""


#: Bindings of :func:`_sample`: the correction, whether to compute the log-likelihood, and a
#: measurement function ``h`` (``HX``; its steps ``HFUN(x, out)``, ``HJAC(x, out)``) in place of ``C``.
CORRECT = _no_correction
WANT_LL = True
HX = False
HFUN = HJAC = _no_measurement


def sample_step(
    correct: CorrectionStep, want_ll: bool = True, measurement: MeasurementSteps | None = None
) -> Callable[..., int]:
    """:func:`_sample` with ``correct``'s step bound: an inlined step for the loops.

    ``measurement``: the ``(h, h_jac)`` steps of a model measuring through ``h``
    (:func:`chatterspec.plants.steps.measurement_steps`), None for ``C``.
    """
    if measurement is None:
        return _jit.specialize_sizes(
            _sample,
            f"{correct.name}_ll{int(want_ll)}",
            {},
            inline=True,
            CORRECT=correct.step,
            WANT_LL=want_ll,
        )
    hfun, hjac = measurement
    return _jit.specialize_sizes(
        _sample, f"{correct.name}_ll{int(want_ll)}_hx", {}, inline=True,
        CORRECT=correct.step, WANT_LL=want_ll, HX=True, HFUN=hfun, HJAC=hjac,
    )  # fmt: skip


@_jit.step
def _no_sample(fp: np.ndarray, x: np.ndarray, P: np.ndarray, ep: np.ndarray, epp: np.ndarray, zk: np.ndarray,
    xp: np.ndarray, F: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, ws: tuple[np.ndarray, ...],
    n: int, m: int) -> int:  # fmt: skip
    """Placeholder binding of the loops (never called)."""
    return NOT_PD


@_jit.step
def workspace(n: int, m: int) -> tuple[np.ndarray, ...]:  # pragma: no cover - compiled (inlined in loops)
    """Scratch of :func:`_sample` and the correction steps: stack arrays of the loop.

    ``(T1, Pp, PCt, PCtT, S, D, L, e, eb, wv, KgT, IKC, KR, ll, MpT, g, dz, Phi, G12, P12i, Al,
    Ae, rr, dy, Ky, W, Hm, zh)``; ``Phi`` .. ``W`` are the reduced-order form's (n = 2m; ``W`` is
    (1, 2) otherwise), ``Hm`` (m, n) and ``zh`` (m) the measurement function's (``dh/dx`` and ``h``).
    Each is its own :func:`~chatterspec._jit.scratch` array, exactly sized when n and m are literal:
    no views of a shared block (their reshapes kept reference counting in the loops).
    """
    h = max(n - m, 1)
    hw = h if n == 2 * m else 1
    s1, s2 = _jit.scratch, _jit.scratch2
    return (
        s2(n, n),
        s2(n, n),
        s2(n, m),
        s2(m, n),
        s2(m, m),
        s2(m, m),
        s2(m, m),
        s1(m),
        s2(m, 1),
        s2(m, 1),
        s2(m, n),
        s2(n, n),
        s2(n, m),
        s1(1),
        s2(m, n),
        s1(m),
        s1(m),
        s2(n, n),
        s2(m, h),
        s2(h, m),
        s2(h, m),
        s1(h),
        s1(m),
        s1(n),
        s2(n, m),
        s2(hw, 2 * hw),
        s2(m, n),
        s1(m),
    )


@_jit.step
def store_step(flags: np.ndarray, outs: tuple[np.ndarray, ...], r: int, k: int, xp: np.ndarray, x: np.ndarray,
    e: np.ndarray, S: np.ndarray, ll: float, ep: np.ndarray, Pp: np.ndarray, P: np.ndarray, n: int,
    m: int) -> None:  # fmt: skip
    """Write sample k of run r into the outputs of :data:`FIELDS` whose ``flags`` entry is set.

    One test of each flag per call, outside the element loops (tested inside them, the flags were
    read again for every element: the shared-gain KF ran 3x slower).
    """
    o_xprior, o_xpost, o_e, o_S, o_ll, o_ep, o_Pprior, o_Ppost = outs
    if flags[0]:
        for i in range(n):
            o_xprior[r, k, i] = xp[i]
    if flags[1]:
        for i in range(n):
            o_xpost[r, k, i] = x[i]
    if flags[2]:
        for i in range(m):
            o_e[r, k, i] = e[i]
    if flags[5]:
        for i in range(m):
            o_ep[r, k, i] = ep[i]
    if flags[3]:
        for i in range(m):
            for j in range(m):
                o_S[r, k, i, j] = S[i, j]
    if flags[4]:
        o_ll[r, k] = ll
    if flags[6]:
        for i in range(n):
            for j in range(n):
                o_Pprior[r, k, i, j] = Pp[i, j]
    if flags[7]:
        for i in range(n):
            for j in range(n):
                o_Ppost[r, k, i, j] = P[i, j]


@_jit.step
def given_predict(prm: np.ndarray, x: np.ndarray, u: np.ndarray, xp: np.ndarray, n: int, p: int) -> None:
    """A prediction computed by the caller: ``xp = prm[:n]`` (the per-run row of :func:`cov_loop`)."""
    for i in range(n):
        xp[i] = prm[i]


@_jit.step
def given_jacobian(prm: np.ndarray, x: np.ndarray, u: np.ndarray, F: np.ndarray, n: int, p: int) -> None:
    """A Jacobian computed by the caller: ``F = prm[n:]`` row-major."""
    for i in range(n):
        for j in range(n):
            F[i, j] = prm[n + i * n + j]


@_jit.step
def _no_lane_block(*args: object) -> bool:
    """Placeholder binding of :func:`_cov_loop` (never called)."""
    return False


#: Bindings of :func:`_cov_loop`: the plant's steps, whether its Jacobian is constant, the sample
#: step (with the filter's correction), sizes (0: from the arrays), and the number of runs a block
#: advances together (:func:`_lane_block`, bound with the same steps as ``LANE_BLOCK``; 0: one at a time).
PREDICT = given_predict
JACOBIAN = given_jacobian
CONST_F = False
SAMPLE = _no_sample
NX = NZ = 0
LANE_BLOCK = _no_lane_block
LANE_WIDTH = 0


def _cov_loop(
    prm: np.ndarray,
    u: np.ndarray,
    z: np.ndarray,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    fp: np.ndarray,
    flags: np.ndarray,
    o_xprior: np.ndarray,
    o_xpost: np.ndarray,
    o_e: np.ndarray,
    o_S: np.ndarray,
    o_ll: np.ndarray,
    o_ep: np.ndarray,
    o_Pprior: np.ndarray,
    o_Ppost: np.ndarray,
) -> int:  # pragma: no cover - compiled (a template: see cov_loop)
    """The filter of ``SAMPLE`` on the plant of ``PREDICT``/``JACOBIAN``, runs outer, samples inner.

    ``prm`` (1 or runs, L): the plant's parameters (one row per run for :func:`given_predict`);
    ``u`` (1 or runs, K, p); ``z`` (runs, K, m); state ``x`` (runs, n), ``P`` (runs, n, n), ``ep``,
    ``epp`` (runs, m) updated in place; outputs as :data:`FIELDS`, each written when its ``flags``
    entry is set. Returns 0, ``1 + r`` (a matrix of run r not positive definite) or
    ``1 + runs + r`` (a singular ``Phi12`` in run r).
    """
    b = _jit.borrow
    flags = b(flags)
    prm, u, z, x, P, ep, epp, C, Q, R, fp = (
        b(prm),
        b(u),
        b(z),
        b(x),
        b(P),
        b(ep),
        b(epp),
        b(C),
        b(Q),
        b(R),
        b(fp),
    )
    o_xprior, o_xpost, o_e, o_S = b(o_xprior), b(o_xpost), b(o_e), b(o_S)
    o_ll, o_ep, o_Pprior, o_Ppost = b(o_ll), b(o_ep), b(o_Pprior), b(o_Ppost)
    runs, K, _ = z.shape
    n = NX if NX > 0 else x.shape[1]
    m = NZ if NZ > 0 else z.shape[2]
    p = u.shape[2]
    shared_prm = prm.shape[0] == 1
    shared_u = u.shape[0] == 1
    xp = _jit.scratch(n)
    F = _jit.scratch2(n, n)
    ws = workspace(n, m)
    Pp, S, e, ll = ws[1], ws[4], ws[7], ws[13]
    # the run's state in stack copies (no aliasing with the outputs: it stays in registers), written
    # back after the run or at a failed sample
    xr, Pr, epr, eppr = _jit.scratch(n), _jit.scratch2(n, n), _jit.scratch(m), _jit.scratch(m)
    if CONST_F:
        JACOBIAN(prm[0], x[0], u[0, 0], F, n, p)
    outs = (o_xprior, o_xpost, o_e, o_S, o_ll, o_ep, o_Pprior, o_Ppost)
    width = LANE_WIDTH if LANE_WIDTH > 0 else 1
    lw = lane_workspace(n, m, width)
    for r0 in range(0, runs, width):
        # LANE_WIDTH runs at once; a block where a matrix is not positive definite, and the last
        # runs, one at a time (the same bits; the error names the run the one-run loop names)
        if LANE_WIDTH > 0 and r0 + width <= runs and LANE_BLOCK(r0, prm, u, z, x, P, ep, epp, C, Q, R, fp, F,
                                                                  flags, outs, lw, ws, n, m, p):  # fmt: skip
            continue
        for r in range(r0, min(r0 + width, runs)):
            pr = 0 if shared_prm else r
            ur = 0 if shared_u else r
            state_copy(x[r], P[r], ep[r], epp[r], xr, Pr, epr, eppr, n, m)
            status = 0
            for k in range(K):
                PREDICT(prm[pr], xr, u[ur, k], xp, n, p)
                if not CONST_F:
                    JACOBIAN(prm[pr], xr, u[ur, k], F, n, p)
                status = SAMPLE(fp, xr, Pr, epr, eppr, z[r, k], xp, F, C, Q, R, ws, n, m)
                if status != 0:
                    break
                store_step(flags, outs, r, k, xp, xr, e, S, ll[0], epr, Pp, Pr, n, m)
            state_copy(xr, Pr, epr, eppr, x[r], P[r], ep[r], epp[r], n, m)
            if status == NOT_PD:
                return 1 + r
            if status == SINGULAR_PHI12:
                return 1 + runs + r
    return 0


def _lane_block(b: int, prm: np.ndarray, u: np.ndarray, z: np.ndarray, x: np.ndarray, P: np.ndarray,
    ep: np.ndarray, epp: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, fp: np.ndarray,
    F: np.ndarray, flags: np.ndarray, outs: tuple[np.ndarray, ...], lw: tuple[np.ndarray, ...],
    ws: tuple[np.ndarray, ...], n: int, m: int, p: int) -> bool:  # fmt: skip  # pragma: no cover - compiled
    """Runs ``b .. b + nl - 1`` over every sample together, lane ``l`` = run ``b + l`` (``F`` constant).

    Each sample is one loop over the lanes whose body is the one-run loop's (``PREDICT``, ``SAMPLE``)
    on that lane's state, read from and written back to ``lw`` (:func:`lane_workspace`, ``nl`` lanes
    innermost): LLVM vectorizes that loop, the lanes in vector registers, each lane with the
    operations of the one-run loop in their order (the same bits). The outputs are written after each
    sample; the state after the last. False, with the state untouched, when the step failed in some
    lane (the caller then runs the block one run at a time).
    """
    nl = LANE_WIDTH
    K = z.shape[1]
    shared_prm = prm.shape[0] == 1
    shared_u = u.shape[0] == 1
    X, Pl, EP, EPP, XP, Ppl, Sl, El, LLl, bad = lw
    Pp, S, e, ll = ws[1], ws[4], ws[7], ws[13]
    xr, Pr, epr, eppr, xp = (
        _jit.scratch(n),
        _jit.scratch2(n, n),
        _jit.scratch(m),
        _jit.scratch(m),
        _jit.scratch(n),
    )
    for l in range(nl):
        state_copy(x[b + l], P[b + l], ep[b + l], epp[b + l], xr, Pr, epr, eppr, n, m)
        lane_put_step(l, xr, Pr, epr, eppr, X, Pl, EP, EPP, n, m)
    for k in range(K):
        for l in range(nl):  # the prediction first (its sum over the inputs is a loop of run-time length)
            r = b + l
            for i in range(n):
                xr[i] = X[i, l]
            PREDICT(prm[0 if shared_prm else r], xr, u[0 if shared_u else r, k], xp, n, p)
            for i in range(n):
                XP[i, l] = xp[i]
        for l in range(nl):  # (vectorized: one lane per vector element)
            lane_get_step(l, X, Pl, EP, EPP, xr, Pr, epr, eppr, n, m)
            for i in range(n):
                xp[i] = XP[i, l]
            status = SAMPLE(fp, xr, Pr, epr, eppr, z[b + l, k], xp, F, C, Q, R, ws, n, m)
            bad[l] = 0.0 if status == 0 else 1.0
            lane_put_step(l, xr, Pr, epr, eppr, X, Pl, EP, EPP, n, m)
            lane_put_step(l, xp, Pp, e, ll, XP, Ppl, El, LLl, n, m)
            for i in range(m):
                for j in range(m):
                    Sl[i * m + j, l] = S[i, j]
        nbad = 0.0
        for l in range(nl):
            nbad += bad[l]
        if nbad != 0.0:
            return False
        lane_store_step(flags, outs, b, k, lw, n, m, nl)
    for l in range(nl):
        lane_get_step(l, X, Pl, EP, EPP, xr, Pr, epr, eppr, n, m)
        state_copy(xr, Pr, epr, eppr, x[b + l], P[b + l], ep[b + l], epp[b + l], n, m)
    return True


@_jit.step
def lane_put_step(l: int, x: np.ndarray, P: np.ndarray, ep: np.ndarray, epp: np.ndarray, X: np.ndarray,
    Pl: np.ndarray, EP: np.ndarray, EPP: np.ndarray, n: int, m: int) -> None:  # fmt: skip
    """Lane ``l`` of ``X`` (n, nl), ``Pl`` (n n, nl), ``EP``, ``EPP`` (m, nl) <- ``x``, ``P``, ``ep``, ``epp``
    (``ep``, ``epp`` as long as ``EP``, ``EPP`` have rows)."""
    for i in range(n):
        X[i, l] = x[i]
        for j in range(n):
            Pl[i * n + j, l] = P[i, j]
    for i in range(EP.shape[0]):
        EP[i, l] = ep[i]
    for i in range(EPP.shape[0]):
        EPP[i, l] = epp[i]


@_jit.step
def lane_get_step(l: int, X: np.ndarray, Pl: np.ndarray, EP: np.ndarray, EPP: np.ndarray, x: np.ndarray,
    P: np.ndarray, ep: np.ndarray, epp: np.ndarray, n: int, m: int) -> None:  # fmt: skip
    """``x``, ``P``, ``ep``, ``epp`` <- lane ``l`` of ``X``, ``Pl``, ``EP``, ``EPP`` (the inverse of
    :func:`lane_put_step`)."""
    for i in range(n):
        x[i] = X[i, l]
        for j in range(n):
            P[i, j] = Pl[i * n + j, l]
    for i in range(m):
        ep[i] = EP[i, l]
        epp[i] = EPP[i, l]


@_jit.step
def state_copy(x: np.ndarray, P: np.ndarray, ep: np.ndarray, epp: np.ndarray, x2: np.ndarray, P2: np.ndarray,
    ep2: np.ndarray, epp2: np.ndarray, n: int, m: int) -> None:  # fmt: skip
    """Copy a run's state ``x``, ``P``, ``e(k|k)``, ``e(k-1|k-1)`` into ``x2``, ``P2``, ``ep2``, ``epp2``."""
    for i in range(n):
        x2[i] = x[i]
        for j in range(n):
            P2[i, j] = P[i, j]
    for i in range(m):
        ep2[i] = ep[i]
        epp2[i] = epp[i]


@_jit.step
def take(cst: np.ndarray, o: int, a: int) -> tuple[np.ndarray, int]:
    """``cst[o : o + a]`` and the offset after it: the one-sample kernels read their packed constants so."""
    return cst[o : o + a], o + a


@_jit.step
def take2(cst: np.ndarray, o: int, a: int, b: int) -> tuple[np.ndarray, int]:
    """:func:`take` of an (a, b) C-order block."""
    return cst[o : o + a * b].reshape((a, b)), o + a * b


@_jit.step
def take3(cst: np.ndarray, o: int, a: int, b: int, c: int) -> tuple[np.ndarray, int]:
    """:func:`take` of an (a, b, c) C-order block."""
    return cst[o : o + a * b * c].reshape((a, b, c)), o + a * b * c


@_jit.step
def one_offsets(n: int, m: int) -> tuple[int, int, int, int, int, int, int, int, int]:
    """Offsets in the buffer of :func:`_cov_one` (``x`` at 0): ``P``, ``e(k|k)``, ``e(k-1|k-1)``, then
    the last sample's ``x(k|k-1)``, ``e(k|k-1)``, ``S``, ``loglik``, ``P(k|k-1)``, and the length."""
    o_P = n
    o_ep = o_P + n * n
    o_epp = o_ep + m
    o_xp = o_epp + m
    o_e = o_xp + n
    o_S = o_e + m
    o_ll = o_S + m * m
    o_Pp = o_ll + 1
    return o_P, o_ep, o_epp, o_xp, o_e, o_S, o_ll, o_Pp, o_Pp + n * n


def _cov_one(buf: np.ndarray, cst: np.ndarray, z: np.ndarray, u: np.ndarray) -> int:  # pragma: no cover
    """One sample of one realization: :func:`_cov_loop`'s body (the same steps) on packed arrays.

    ``buf`` (:func:`one_offsets`) holds the state ``x``, ``P``, ``e(k|k)``, ``e(k-1|k-1)`` and receives
    the sample's prior, innovation, ``S``, log-likelihood and prior covariance; ``cst`` is
    :func:`one_sample_constants` (sizes, the plant's parameters, ``C``, ``Q``, ``R``, the correction's
    ``fp``); ``z`` (m,), ``u`` (p,). The state is read into stack copies and written back only when
    the step succeeds and the new ``x``, ``P`` are finite, so a failed sample leaves it as it was.
    Returns 0, the step's :data:`NOT_PD` / :data:`SINGULAR_PHI12`, :data:`BAD_INPUT` (NaN/inf in
    ``z`` or ``u``) or :data:`DIVERGED`. A template like :func:`_cov_loop` (:func:`one_sample_kernel`).
    """
    b = _jit.borrow
    buf, cst, z, u = b(buf), b(cst), b(z), b(u)
    n = NX if NX > 0 else int(cst[0])
    m = NZ if NZ > 0 else int(cst[1])
    p = u.shape[0]
    if not finite_sample(z, m, u, p):
        return BAD_INPUT
    prm, o = take(cst, 4, int(cst[3]))
    C, o = take2(cst, o, m, n)
    Q, o = take2(cst, o, n, n)
    R, o = take2(cst, o, m, m)
    fp = cst[o:]
    o_P, o_ep, o_epp, o_xp, o_e, o_S, o_ll, o_Pp, _ = one_offsets(n, m)
    x = _jit.scratch(n)
    P = _jit.scratch2(n, n)
    ep = _jit.scratch(m)
    epp = _jit.scratch(m)
    for i in range(n):
        x[i] = buf[i]
        for j in range(n):
            P[i, j] = buf[o_P + i * n + j]
    for i in range(m):
        ep[i] = buf[o_ep + i]
        epp[i] = buf[o_epp + i]
    xp = _jit.scratch(n)
    F = _jit.scratch2(n, n)
    ws = workspace(n, m)
    PREDICT(prm, x, u, xp, n, p)
    JACOBIAN(prm, x, u, F, n, p)
    status = SAMPLE(fp, x, P, ep, epp, z, xp, F, C, Q, R, ws, n, m)
    if status != 0:  # a prediction that left the finite numbers: divergence, not a bad model
        return status if finite_state(xp, ws[1], n) else DIVERGED
    if not finite_state(x, P, n):
        return DIVERGED
    Pp, S, e, ll = ws[1], ws[4], ws[7], ws[13]
    for i in range(n):
        buf[i] = x[i]
        buf[o_xp + i] = xp[i]
        for j in range(n):
            buf[o_P + i * n + j] = P[i, j]
            buf[o_Pp + i * n + j] = Pp[i, j]
    for i in range(m):
        buf[o_ep + i] = ep[i]
        buf[o_epp + i] = epp[i]
        buf[o_e + i] = e[i]
        for j in range(m):
            buf[o_S + i * m + j] = S[i, j]
    buf[o_ll] = ll[0]
    return 0


def one_sample_constants(
    parameters: np.ndarray, C: np.ndarray, Q: np.ndarray, R: np.ndarray, fp: np.ndarray, p: int
) -> np.ndarray:
    """``cst`` of :func:`_cov_one`: ``[n, m, p, L, prm (L), C, Q, R (row-major), fp]`` as one float array."""
    m, n = np.shape(C)
    prm = np.ravel(np.asarray(parameters, dtype=float))
    head = np.array([n, m, p, prm.size], dtype=float)
    parts = [head, prm, np.ravel(C), np.ravel(Q), np.ravel(R), np.ravel(fp)]
    return np.ascontiguousarray(np.concatenate([np.asarray(a, dtype=float) for a in parts]))


def one_sample_kernel(
    correct: CorrectionStep,
    plant: object,
    n: int,
    m: int,
    measurement: MeasurementSteps | None = None,
) -> Callable[..., int]:
    """:func:`_cov_one` with the plant's steps and ``correct``'s sample step bound (sizes up to 4 literal).

    The same bindings as :func:`cov_loop`'s kernel, so one sample gives the bits of the batch loop;
    ``measurement`` as there.
    """
    bind = {
        "PREDICT": plant.predict,  # type: ignore[attr-defined]
        "JACOBIAN": plant.jacobian,  # type: ignore[attr-defined]
        "SAMPLE": sample_step(correct, measurement=measurement),
    }
    tag = f"one_{plant.name}_{correct.name}" + ("_hx" if measurement is not None else "")  # type: ignore[attr-defined]
    return _jit.specialize_sizes(_cov_one, tag, {"NX": n, "NZ": m}, **bind)


# ----------------------------------------------------------------------------- drivers
def kernel_input(a: npt.ArrayLike) -> np.ndarray:
    """``a`` as a read-only C-contiguous float array (a view when it is one already, else a copy).

    The compiled loops take every array they only read in this one form: numba compiles a kernel
    once per argument type, and a writable and a read-only array are two types (the model's
    matrices are read-only, a caller's own arrays usually not), so without it the same loop
    compiled twice.
    """
    v = np.ascontiguousarray(a, dtype=float).view()
    v.flags.writeable = False
    return v


def _alloc(
    keep: frozenset[str], shapes: dict[str, tuple[int, ...]]
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    flags = np.array([f in keep for f in FIELDS], dtype=np.bool_)
    arrays = {}
    for f in FIELDS:
        arrays[f] = np.empty(shapes[f] if f in keep else (0,) * len(shapes[f]))
    return flags, arrays


def _shapes(runs: int, K: int, n: int, m: int) -> dict[str, tuple[int, ...]]:
    return {
        "x_prior": (runs, K, n),
        "x_post": (runs, K, n),
        "innovation": (runs, K, m),
        "S": (runs, K, m, m),
        "loglik": (runs, K),
        "e_post": (runs, K, m),
        "P_prior": (runs, K, n, n),
        "P_post": (runs, K, n, n),
    }


def cov_loop(
    correct: CorrectionStep,
    plant: PlantSteps | None,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    keep: frozenset[str],
    *,
    xp_in: np.ndarray | None = None,
    F_in: np.ndarray | None = None,
    measurement: MeasurementSteps | None = None,
) -> dict[str, np.ndarray | None]:
    """Advance ``x, P, ep, epp`` (in place) over ``z`` (runs, K, m) with the compiled loop.

    Parameters
    ----------
    correct : CorrectionStep
        The filter's correction.
    plant : PlantSteps or None
        The model's steps (:func:`chatterspec.plants.steps.plant_steps`); None with ``xp_in`` and
        ``F_in`` (runs, n) / (runs, n, n), a prediction the caller computed (K = 1).
    x, P, ep, epp : arrays
        State (runs, n), (runs, n, n), (runs, m), (runs, m), C-contiguous float, updated in place.
    z : (runs, K, m) array
        Measurements.
    u : (1 | runs, K, p) array
        Inputs.
    C, Q, R : arrays
        The filter model's matrices.
    keep : frozenset of str
        Outputs to return (others None).
    measurement : (h, h_jac) steps, optional
        A model measuring through ``h`` (:func:`chatterspec.plants.steps.measurement_steps`): ``C``
        only gives the sizes.

    Returns
    -------
    dict of str to array or None
    """
    runs, K, m = z.shape
    n = x.shape[1]
    flags, out = _alloc(keep, _shapes(runs, K, n, m))
    c = kernel_input
    if plant is None:
        assert xp_in is not None and F_in is not None  # (no plant steps: the caller's prediction)
        prm = c(np.concatenate([xp_in, np.reshape(F_in, (runs, n * n))], axis=1))
        bind: dict[str, Any] = {"PREDICT": given_predict, "JACOBIAN": given_jacobian, "CONST_F": False}
        tag = f"given_{correct.name}"
    else:
        prm = c(plant.parameters)[None]
        bind = {
            "PREDICT": plant.predict,
            "JACOBIAN": plant.jacobian,
            "CONST_F": bool(plant.constant_jacobian),
        }
        tag = f"{plant.name}_{correct.name}"
    # the log-likelihood only when stored (its Cholesky solve and log are a third of a step)
    sample = sample_step(correct, want_ll="loglik" in keep, measurement=measurement)
    tag += ("_hx" if measurement is not None else "") + ("" if "loglik" in keep else "_noll")
    sizes = {"NX": n, "NZ": m}
    lanes_ok = correct.lanes and bind["CONST_F"] and measurement is None and "loglik" not in keep
    if lanes_ok and max(n, m) <= _jit.MAX_UNROLL:
        # LANES runs at a time in vector registers (not with the log-likelihood: LLVM does not vectorize
        # a loop that calls log, and the loop over lanes without vectors was 0.8x the one-run loop).
        # numba's division-by-zero branch would stop LLVM from vectorizing, and every divisor of these
        # steps is guarded (positive pivots, max(|e|, psi) with psi > 0, e != 0) or its lane checked (a
        # pivot that is not positive sends the block to the one-run loop), so the kernel divides as
        # IEEE 754 does: the same quotients, the same bits
        block = _jit.specialize_sizes(
            _lane_block, tag, {}, inline=True, SAMPLE=sample, LANE_WIDTH=LANES, **bind
        )
        bind |= {"LANE_BLOCK": block, "LANE_WIDTH": LANES}
        kernel = _jit.specialize_sizes(
            _cov_loop, f"{tag}_lanes{LANES}", sizes, error_model="numpy", SAMPLE=sample, **bind
        )
    else:
        kernel = _jit.specialize_sizes(_cov_loop, tag, sizes, SAMPLE=sample, **bind)
    status = kernel(
        prm, c(u), c(z), x, P, ep, epp, c(C), c(Q), c(R), c(correct.parameters), flags, out["x_prior"],
        out["x_post"], out["innovation"],
        out["S"], out["loglik"], out["e_post"], out["P_prior"], out["P_post"],
    )  # fmt: skip
    if status > runs:
        raise SingularMatrixError(_luen_message())
    if status:
        raise SingularMatrixError(_not_pd_message(correct.mapping, status - 1))
    return {f: (out[f] if f in keep else None) for f in FIELDS}


def _luen_message() -> str:
    return "the Luenberger form needs Phi12 = d(measured)/d(unmeasured) invertible at the estimate (eq 10)"


def _not_pd_message(mapping: int, run: int) -> str:
    what = "S = C P C^T + R" if mapping != MAP_COV else "S = C P C^T + R or C P C^T (the 'cov' mapping)"
    return (
        f"{what} is not positive definite in run {run}: check that R (and P0) are positive definite "
        "and that the model does not diverge"
    )


# ----------------------------------------------------------------------------- linear algebra
@_jit.step
def chol_step(A: np.ndarray, L: np.ndarray, m: int) -> bool:  # pragma: no cover - compiled
    """Lower Cholesky factor of the (m, m) matrix A into L; False if A is not positive definite."""
    for i in range(m):
        for j in range(i + 1):
            s = A[i, j]
            for q in range(j):
                s -= L[i, q] * L[j, q]
            if i == j:
                if not s > 0.0:
                    return False
                L[i, i] = np.sqrt(s)
            else:
                L[i, j] = s / L[j, j]
    return True


@_jit.step
def chol_solve_step(
    L: np.ndarray, B: np.ndarray, X: np.ndarray, m: int, ncol: int
) -> None:  # pragma: no cover
    """X = (L L^T)^-1 B for B of shape (m, ncol): forward then back substitution, column by column."""
    for c in range(ncol):
        for i in range(m):
            s = B[i, c]
            for q in range(i):
                s -= L[i, q] * X[q, c]
            X[i, c] = s / L[i, i]
        for i in range(m - 1, -1, -1):
            s = X[i, c]
            for q in range(i + 1, m):
                s -= L[q, i] * X[q, c]
            X[i, c] = s / L[i, i]


@_jit.step
def product_step(
    A: np.ndarray, B: np.ndarray, out: np.ndarray, ni: int, nj: int, nq: int, a_t: bool, b_t: bool
) -> None:  # pragma: no cover - compiled
    """``out[i, j] = sum_q A[i, q] B[q, j]`` from 0.0, q = 0, 1, ...; ``a_t``/``b_t``: read A^T / B^T."""
    for i in range(ni):
        for j in range(nj):
            s = 0.0
            for q in range(nq):
                s += (A[q, i] if a_t else A[i, q]) * (B[j, q] if b_t else B[q, j])
            out[i, j] = s


@_jit.step
def residual_step(zk: np.ndarray, C: np.ndarray, x: np.ndarray, out: np.ndarray, n: int, m: int) -> None:
    """``out = z - C x`` (the innovation of a prediction, or the a-posteriori residual)."""
    for i in range(m):
        s = zk[i]
        for j in range(n):
            s -= C[i, j] * x[j]
        out[i] = s


@_jit.step
def gain_update_step(xp: np.ndarray, KgT: np.ndarray, e: np.ndarray, x: np.ndarray, n: int, m: int) -> None:
    """``x = x(k+1|k) + K e`` with the gain given as ``K^T`` (m, n)."""
    for i in range(n):
        s = xp[i]
        for j in range(m):
            s += KgT[j, i] * e[j]
        x[i] = s


@_jit.step
def predict_cov_step(
    F: np.ndarray, P: np.ndarray, Q: np.ndarray, T1: np.ndarray, Pp: np.ndarray, n: int
) -> None:
    """``Pp = F P F^T + Q`` (``T1 = F P`` first; the upper triangle summed, then mirrored)."""
    product_step(F, P, T1, n, n, n, False, False)
    for i in range(n):  # symmetric: upper triangle, mirrored
        for j in range(i, n):
            s = Q[i, j]
            for q in range(n):
                s += T1[i, q] * F[j, q]
            Pp[i, j] = s
            Pp[j, i] = s


@_jit.step
def innovation_step(
    zk: np.ndarray,
    xp: np.ndarray,
    Pp: np.ndarray,
    C: np.ndarray,
    R: np.ndarray,
    e: np.ndarray,
    PCt: np.ndarray,
    PCtT: np.ndarray,
    D: np.ndarray,
    S: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """``e = z - C xp``, ``PCt = Pp C^T`` (and its transpose), ``D = C Pp C^T``, ``S = D + R``."""
    residual_step(zk, C, xp, e, n, m)
    product_step(Pp, C, PCt, n, m, n, False, True)
    for i in range(n):
        for j in range(m):
            PCtT[j, i] = PCt[i, j]
    product_step(C, PCt, D, m, m, n, False, False)
    for i in range(m):
        for j in range(m):
            S[i, j] = D[i, j] + R[i, j]


@_jit.step
def loglik_step(
    L: np.ndarray, e: np.ndarray, eb: np.ndarray, wv: np.ndarray, m: int
) -> float:  # pragma: no cover
    """``log N(e; 0, S)`` from the Cholesky factor ``L`` of ``S``: ``S^-1 e`` by :func:`chol_solve_step`
    (``e`` copied into the column ``eb`` (m, 1), solution in ``wv``), ``log det S = 2 sum log L_ii``
    (:func:`half_logdet_step`)."""
    return loglik_given_step(L, e, eb, wv, half_logdet_step(L, m), m)


@_jit.step
def half_logdet_step(L: np.ndarray, m: int) -> float:  # pragma: no cover - compiled
    """``sum_i log L_ii`` (half of ``log det S`` for the Cholesky factor ``L`` of ``S``), i = 0, 1, ..."""
    logdet = 0.0
    for i in range(m):
        logdet += np.log(L[i, i])
    return logdet


@_jit.step
def loglik_given_step(
    L: np.ndarray, e: np.ndarray, eb: np.ndarray, wv: np.ndarray, half_logdet: float, m: int
) -> float:  # pragma: no cover - compiled
    """:func:`loglik_step` with ``sum log L_ii`` given (the shared Kalman filter has it once per sample)."""
    for i in range(m):
        eb[i, 0] = e[i]
    chol_solve_step(L, eb, wv, m, 1)
    quad = 0.0
    for i in range(m):
        quad += e[i] * wv[i, 0]
    return -0.5 * (m * 1.8378770664093453 + 2.0 * half_logdet + quad)


@_jit.step
def joseph_step(
    KgT: np.ndarray,
    C: np.ndarray,
    Pp: np.ndarray,
    R: np.ndarray,
    T1: np.ndarray,
    IKC: np.ndarray,
    KR: np.ndarray,
    P: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """Joseph form ``P = (I - K C) Pp (I - K C)^T + K R K^T`` with the gain given as ``K^T`` (m, n).

    Scratch ``T1`` (n, n) = ``(I - K C) Pp``, ``IKC`` (n, n), ``KR`` (n, m); the upper triangle is
    summed, then mirrored.
    """
    for i in range(n):
        for j in range(n):
            s = 1.0 if i == j else 0.0
            for q in range(m):
                s -= KgT[q, i] * C[q, j]
            IKC[i, j] = s
    product_step(IKC, Pp, T1, n, n, n, False, False)
    product_step(KgT, R, KR, n, m, m, True, False)
    for i in range(n):  # symmetric: upper triangle, mirrored
        for j in range(i, n):
            s = 0.0
            for q in range(n):
                s += T1[i, q] * IKC[j, q]
            for q in range(m):
                s += KR[i, q] * KgT[q, j]
            P[i, j] = s
            P[j, i] = s


# ----------------------------------------------------------------------------- lanes
#: Runs a lane block of :func:`_cov_loop` advances together (:func:`_lane_block`).
LANES = 8


@_jit.step
def lane_workspace(n: int, m: int, nl: int) -> tuple[np.ndarray, ...]:  # pragma: no cover - compiled
    """The state and stored outputs of ``nl`` runs of :func:`_lane_block`, the lane (run) axis innermost.

    ``(X, P, EP, EPP, XP, Pp, S, E, LL, bad)``: a matrix ``A`` (a, c) of one run is ``A[i * c + j, l]``
    in lane ``l``; ``bad[l]`` is nonzero when the sample's step failed in lane ``l``; ``LL`` receives
    the step's log-likelihood slot (not computed: the lane loop runs without it).
    """
    s2 = _jit.scratch2
    return (
        s2(n, nl),
        s2(n * n, nl),
        s2(m, nl),
        s2(m, nl),
        s2(n, nl),
        s2(n * n, nl),
        s2(m * m, nl),
        s2(m, nl),
        s2(1, nl),
        _jit.scratch(nl),
    )


@_jit.step
def lane_store_step(flags: np.ndarray, outs: tuple[np.ndarray, ...], b: int, k: int,
    lw: tuple[np.ndarray, ...], n: int, m: int, nl: int) -> None:  # fmt: skip  # pragma: no cover - compiled
    """:func:`store_step` of a lane block: sample k of runs ``b .. b + nl - 1`` from ``lw``
    (:func:`lane_workspace`)."""
    o_xprior, o_xpost, o_e, o_S, _, o_ep, o_Pprior, o_Ppost = outs  # (no log-likelihood in lanes)
    X, Pl, EP, _, XP, Pp, S, E, _, _ = lw
    if flags[0]:
        lane_rows_step(o_xprior, XP, b, k, n, nl)
    if flags[1]:
        lane_rows_step(o_xpost, X, b, k, n, nl)
    if flags[2]:
        lane_rows_step(o_e, E, b, k, m, nl)
    if flags[5]:
        lane_rows_step(o_ep, EP, b, k, m, nl)
    if flags[3]:
        lane_rows_step(o_S.reshape((o_S.shape[0], o_S.shape[1], m * m)), S, b, k, m * m, nl)
    if flags[6]:
        lane_rows_step(o_Pprior.reshape((o_Pprior.shape[0], o_Pprior.shape[1], n * n)), Pp, b, k, n * n, nl)
    if flags[7]:
        lane_rows_step(o_Ppost.reshape((o_Ppost.shape[0], o_Ppost.shape[1], n * n)), Pl, b, k, n * n, nl)


@_jit.step
def lane_rows_step(out: np.ndarray, A: np.ndarray, b: int, k: int, c: int, nl: int) -> None:
    """``out[b + l, k, i] = A[i, l]`` for the ``nl`` lanes (``out`` (runs, K, c); a matrix field as
    (runs, K, a b), its row-major entries)."""
    for l in range(nl):
        for i in range(c):
            out[b + l, k, i] = A[i, l]


# ----------------------------------------------------------------------------- numpy path
#: ``predict(k, x) -> (x(k+1|k), F)``: the prediction of sample k from ``x(k|k)`` (runs, n), with
#: ``F`` (n, n) or (runs, n, n) the Jacobian of the transition.
Prediction = Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]


def chol_np(M: np.ndarray, mapping: int) -> np.ndarray:
    """numpy Cholesky of every block of ``M``; SingularMatrixError (naming the run) if one is not PD."""
    try:
        return np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        bad = np.flatnonzero(~np.all(np.linalg.eigvalsh(M) > 0, axis=-1))
        raise SingularMatrixError(_not_pd_message(mapping, int(bad[0]) if bad.size else 0)) from None


def joseph_numpy(Kg: np.ndarray, C: np.ndarray, Pp: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Joseph form ``(I - K C) Pp (I - K C)^T + K R K^T`` over leading axes: the numpy twin of
    :func:`joseph_step` (``Kg`` (..., n, m), ``C`` (..., m, n))."""
    IKC = np.eye(Pp.shape[-1]) - Kg @ C
    return IKC @ Pp @ np.swapaxes(IKC, -1, -2) + Kg @ R @ np.swapaxes(Kg, -1, -2)


def map_numpy(mapping: int, D: np.ndarray, PCt: np.ndarray, M: np.ndarray | None, runs: int) -> np.ndarray:
    """numpy twin of :func:`map_step`: ``M`` (runs, n, m)."""
    if mapping == MAP_COV:
        chol_np(D, mapping)
        return np.swapaxes(np.linalg.solve(D, np.swapaxes(PCt, -1, -2)), -1, -2)
    assert M is not None  # a fixed mapping matrix for every mapping but ``cov``
    return np.broadcast_to(M, (runs, *M.shape))


def kalman_gain_numpy(S: np.ndarray, PCt: np.ndarray) -> np.ndarray:
    """``K = P C^T S^-1`` for every run (numpy)."""
    return np.swapaxes(np.linalg.solve(S, np.swapaxes(PCt, -1, -2)), -1, -2)


def linear_prediction(A: np.ndarray, Bu: np.ndarray) -> Prediction:
    """The prediction of a linear model: ``x(k+1|k) = A x(k|k) + B u(k)``, ``F = A``.

    ``Bu`` (1|runs, K, n) holds ``B u(k)`` for every sample of the chunk.
    """
    return lambda k, x: (x @ A.T + Bu[:, k], A)


def given_prediction(xp_in: np.ndarray, F_in: np.ndarray) -> Prediction:
    """A prediction the caller computed for one sample: ``x(k+1|k) = xp_in`` (runs, n), ``F = F_in``."""
    return lambda k, x: (np.array(xp_in, dtype=float), F_in)


def model_prediction(model: Model, u: np.ndarray) -> Prediction:
    """The prediction from a model's Python ``transition`` and ``jacobian`` at ``x(k|k)``, ``u(k)``.

    ``u`` is (1|runs, K, p); one input for every run is passed as (p,), so a model's compiled
    batched kernel applies (eha4). The Jacobian may be (n, n) (shared) or (runs, n, n).

    Raises
    ------
    ShapeError
        ``transition`` or ``jacobian`` returned the wrong shape (when the prediction is called).
    """
    shared_u = u.shape[0] == 1

    def predict(k: int, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        uk = u[0, k] if shared_u else u[:, k]
        xp = np.asarray(model.transition(x, uk), dtype=float)
        F = np.asarray(model.jacobian(x, uk), dtype=float)
        want_F = (*x.shape, x.shape[1])
        if xp.shape != x.shape or F.shape not in (want_F, want_F[1:]):
            raise ShapeError(
                f"model.transition/jacobian must return {x.shape} and {want_F}; got {xp.shape} and {F.shape}"
            )
        return xp, np.broadcast_to(F, want_F)

    return predict


def cov_numpy(
    correct: CorrectionStep,
    predict: Prediction,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    keep: frozenset[str],
    *,
    h_model: Model | None = None,
) -> dict[str, np.ndarray | None]:
    """numpy twin of :func:`cov_loop`: vectorized over runs, a loop over samples; in place.

    ``predict(k, x)`` gives ``(x(k+1|k), F)`` (:func:`linear_prediction`, :func:`given_prediction`,
    :func:`model_prediction`). With ``h_model`` (a model measuring through ``h``, the EKF only),
    ``C`` is replaced by ``H = dh/dx`` at ``x(k+1|k)`` and ``C x`` by ``h(x)``, sample by sample.
    """
    runs, K, m = z.shape
    n = x.shape[1]
    flags, out = _alloc(keep, _shapes(runs, K, n, m))
    CT = C.T
    for k in range(K):
        xp, F = predict(k, x)
        Pp = F @ P @ np.swapaxes(F, -1, -2) + Q
        if h_model is None:
            Ck = C
            e = z[:, k] - xp @ CT
            PCt = Pp @ CT
        else:
            Ck = measurement_jacobian(h_model, xp)
            e = z[:, k] - measure(h_model, xp)
            PCt = Pp @ np.swapaxes(Ck, -1, -2)
        D = Ck @ PCt
        S = D + R
        L = chol_np(S, correct.mapping)
        w = np.linalg.solve(S, e[..., None])[..., 0]
        ll = -0.5 * (m * LOG2PI + 2.0 * np.sum(np.log(np.diagonal(L, axis1=-2, axis2=-1)), axis=-1))
        ll = ll - 0.5 * np.einsum("ri,ri->r", e, w)
        Kg, x_new = correct.numpy(NumpyPrior(e, ep, epp, xp, PCt, D, S, Ck, F))
        x[...] = x_new
        P[...] = joseph_numpy(Kg, Ck, Pp, R)
        epp[...] = ep
        ep[...] = z[:, k] - (x @ CT if h_model is None else measure(h_model, x))
        for f, flag, val in zip(FIELDS, flags, (xp, x, e, S, ll, ep, Pp, P), strict=True):
            if flag:
                out[f][:, k] = val
    return {f: (out[f] if f in keep else None) for f in FIELDS}


def model_call_loop(
    model: Model,
    corr: CorrectionStep,
    compiled: bool,
    x: np.ndarray,
    P: np.ndarray,
    ep: np.ndarray,
    epp: np.ndarray,
    z: np.ndarray,
    u: np.ndarray,
    C: np.ndarray,
    Q: np.ndarray,
    R: np.ndarray,
    keep: frozenset[str],
) -> dict[str, np.ndarray | None]:
    """The step for a model without compiled plant steps: its ``transition``/``jacobian`` per sample.

    Each sample's prediction comes from the model's Python methods (:func:`model_prediction`); the
    rest of the step is the compiled loop (``compiled``, one sample at a time, the outputs of every
    sample concatenated along axis 1) or :func:`cov_numpy`. ``x``, ``P``, ``ep``, ``epp`` are
    updated in place.

    Raises
    ------
    ShapeError
        ``transition`` or ``jacobian`` returned the wrong shape.
    """
    predict = model_prediction(model, u)
    if not compiled:
        return cov_numpy(corr, predict, x, P, ep, epp, z, C, Q, R, keep)
    steps = []
    for k in range(z.shape[1]):
        xp, F = predict(k, x)
        zk = z[:, k : k + 1]
        steps.append(
            cov_loop(corr, None, x, P, ep, epp, zk, u[:, k : k + 1], C, Q, R, keep, xp_in=xp, F_in=F)
        )
    res = {
        f: (None if steps[0][f] is None else np.concatenate([s[f] for s in steps], axis=1)) for f in steps[0]
    }
    return res
