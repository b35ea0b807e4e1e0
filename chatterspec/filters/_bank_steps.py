"""Compiled steps shared by the multiple-model banks (IMM, SMM-SVSF): likelihood, probabilities, combination.

:func:`log_gaussian_step` is :func:`chatterspec.filters.bank_math.log_gaussian` for one
innovation; :func:`mode_probabilities_step` is ``normalize_log_weights`` for one realization;
:func:`combine_step` is ``combine`` for one realization. Each does its numpy twin's arithmetic in
loop order, so the banks' compiled loops agree with their numpy paths to a few ulps per sample
(summation order; tolerances in tests/test_imm_kernel.py and tests/test_smm_kernel.py).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TypedDict

import numpy as np

from .. import _jit
from ..errors import SingularMatrixError
from ..plants.steps import PlantSteps
from ._engine import (
    LOG2PI,
    _luen_message,
    _not_pd_message,
    chol_solve_step,
    chol_step,
    given_jacobian,
    given_predict,
)
from .bank_math import EIG_FLOOR

#: Lower bound of the smallest eigenvalue of Sc above which the Cholesky likelihood is used.
CHOL_SAFE = 1e-10
_TINY = float(np.finfo(float).tiny)


@_jit.step
def _solve_col(L: np.ndarray, b: np.ndarray, out: np.ndarray, m: int) -> None:  # pragma: no cover
    """out = (L L^T)^-1 b for a vector b (the one-column case of ``chol_solve_step``)."""
    chol_solve_step(L, b.reshape((m, 1)), out.reshape((m, 1)), m, 1)


def _log_gaussian(
    e: np.ndarray,
    S: np.ndarray,
    m: int,
    Sc: np.ndarray,
    L: np.ndarray,
    ec: np.ndarray,
    col: np.ndarray,
    tmp: np.ndarray,
) -> float:  # pragma: no cover
    """``log N(e; 0, S)`` of one innovation, as :func:`~chatterspec.filters.bank_math.log_gaussian`.

    ``S`` is scaled to its correlation matrix ``Sc`` (``D = sqrt(diag S)``); with the Cholesky
    factor of ``Sc`` when ``1 / trace(Sc^-1)`` -- a lower bound of its smallest eigenvalue, with
    ``trace(Sc^-1) = ||L^-1||_F^2`` by forward substitution --
    exceeds :data:`CHOL_SAFE`, so the numpy function's eigenvalue floor (1e-12) cannot be active
    and ``quad = ec^T Sc^-1 ec``, ``log det Sc = 2 sum log L_ii`` are the same numbers up to
    rounding; otherwise ``np.linalg.eigh`` and the floor, as the numpy function. Scratch: ``Sc``,
    ``L`` (m, m), ``ec``, ``col`` (m), ``tmp`` (2m). Two forms of this one template:
    :data:`log_gaussian_step`, a compiled function of its own (LAPACK's ``eigh`` is slow to
    compile; the IMM calls it once per mode and sample), and :data:`log_gaussian_inline`, inlined
    (the SMM loop, whose literal sizes then unroll it).
    """
    logd = 0.0
    for i in range(m):
        di = S[i, i]
        if not di > _TINY:
            di = _TINY
        d = np.sqrt(di)
        tmp[i] = d
        ec[i] = e[i] / d
        logd += np.log(d)
    for i in range(m):
        for j in range(m):
            Sc[i, j] = S[i, j] / (tmp[i] * tmp[j])
    ok = chol_step(Sc, L, m)
    if ok:
        # trace(Sc^-1) = ||L^-1||_F^2: column i of L^-1 by forward substitution (from row i on)
        tr = 0.0
        for i in range(m):
            for r in range(i, m):
                s = 1.0 if r == i else 0.0
                for q in range(i, r):
                    s -= L[r, q] * col[q]
                col[r] = s / L[r, r]
                tr += col[r] * col[r]
        ok = tr > 0.0 and 1.0 / tr > CHOL_SAFE
    if ok:
        _solve_col(L, ec, col, m)
        quad = 0.0
        logdet = 0.0
        for i in range(m):
            quad += ec[i] * col[i]
            logdet += np.log(L[i, i])
        logdet = 2.0 * logdet
    else:  # the eigenvalue floor may be active: the numpy function's own arithmetic
        w, V = np.linalg.eigh(Sc)
        quad = 0.0
        logdet = 0.0
        for j in range(m):
            wj = w[j] if w[j] > EIG_FLOOR else EIG_FLOOR
            p = 0.0
            for i in range(m):
                p += V[i, j] * ec[i]
            quad += p * p / wj
            logdet += np.log(wj)
    return -0.5 * (quad + logdet + 2.0 * logd + m * LOG2PI)


#: :func:`_log_gaussian` as a compiled function (not inlined).
log_gaussian_step = _jit.specialize(_log_gaussian, "call")
#: :func:`_log_gaussian` as a step (inlined).
log_gaussian_inline = _jit.specialize(_log_gaussian, "inline", inline=True)


@_jit.step
def mode_probabilities_step(
    lw: np.ndarray, mu: np.ndarray, floor: float, nm: int
) -> bool:  # pragma: no cover
    """``mu = exp(lw - max lw) / sum`` (log weights ``lw`` (nm,), overwritten), then the optional floor.

    False when every log weight is ``-inf`` or the largest is not finite (the numpy function raises).
    """
    top = -np.inf
    for j in range(nm):
        if lw[j] > top:
            top = lw[j]
    if not np.isfinite(top):
        return False
    s = 0.0
    for j in range(nm):
        lw[j] = np.exp(lw[j] - top)
        s += lw[j]
    for j in range(nm):
        mu[j] = lw[j] / s
    if floor > 0.0:
        s = 0.0
        for j in range(nm):
            if mu[j] < floor:
                mu[j] = floor
            s += mu[j]
        for j in range(nm):
            mu[j] = mu[j] / s
    return True


@_jit.step
def combine_step(
    mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray, x: np.ndarray, P: np.ndarray, nm: int, n: int
) -> None:  # pragma: no cover
    """``x = sum_j mu_j x_j``, ``P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]`` for one realization."""
    for a in range(n):
        s = 0.0
        for j in range(nm):
            s += mu[j] * xs[j, a]
        x[a] = s
    for a in range(n):
        for b in range(n):
            s = 0.0
            for j in range(nm):
                da = xs[j, a] - x[a]
                s += mu[j] * (Ps[j, a, b] + da * (xs[j, b] - x[b]))
            P[a, b] = s


@_jit.step
def bank_store_step(
    r: int,
    k: int,
    x: np.ndarray,
    mu: np.ndarray,
    ll: np.ndarray,
    P: np.ndarray,
    xs: np.ndarray,
    o_x: np.ndarray,
    o_mu: np.ndarray,
    o_ll: np.ndarray,
    o_P: np.ndarray,
    o_mx: np.ndarray,
    nm: int,
    n: int,
) -> None:
    """Write sample k of run r of a bank: ``x``, ``mu``, ``ll``; ``P`` and the modes' ``xs`` if wanted."""
    for a in range(n):
        o_x[r, k, a] = x[a]
    for j in range(nm):
        o_mu[r, k, j] = mu[j]
        o_ll[r, k, j] = ll[j]
    if o_P.shape[0] > 0:
        for a in range(n):
            for c in range(n):
                o_P[r, k, a, c] = P[a, c]
    if o_mx.shape[0] > 0:
        for j in range(nm):
            for a in range(n):
                o_mx[r, k, j, a] = xs[j, a]


def bank_store_numpy(
    out: dict[str, np.ndarray],
    k: int,
    x: np.ndarray,
    mu: np.ndarray,
    ll: np.ndarray,
    P: np.ndarray | None,
    xs: np.ndarray,
) -> None:
    """:func:`bank_store_step` for every run at once (the banks' numpy paths): sample ``k`` into ``out``."""
    out["x"][:, k], out["mu"][:, k], out["ll"][:, k] = x, mu, ll
    if out["P"].shape[0] > 0:
        out["P"][:, k] = P
    if out["mx"].shape[0] > 0:
        out["mx"][:, k] = xs


#: Bindings of :func:`_bank_plant`: the two plant kinds a bank may mix.
PREDICT_A = PREDICT_B = given_predict
JACOBIAN_A = JACOBIAN_B = given_jacobian


def _bank_plant(
    slot: int, prm: np.ndarray, x: np.ndarray, u: np.ndarray, xp: np.ndarray, F: np.ndarray, n: int, p: int
) -> None:  # pragma: no cover - compiled
    """A mode's prediction and Jacobian by its plant kind: ``slot`` 0 = ``PREDICT_A``, 1 = ``PREDICT_B``."""
    if slot == 0:
        PREDICT_A(prm, x, u, xp, n, p)
        JACOBIAN_A(prm, x, u, F, n, p)
    else:
        PREDICT_B(prm, x, u, xp, n, p)
        JACOBIAN_B(prm, x, u, F, n, p)


def bank_plants(plants: list[PlantSteps]) -> tuple[Callable[..., None] | None, np.ndarray, np.ndarray]:
    """``(step, slot per mode, prm rows)`` for the modes' :class:`~chatterspec.plants.steps.PlantSteps`.

    ``step`` is :func:`_bank_plant` with the (at most two) plant kinds bound; None when there are more.
    """
    kinds = list(dict.fromkeys(pl.name for pl in plants))
    if len(kinds) > 2:
        return None, np.empty(0, dtype=np.int64), np.empty((0, 0))
    by_name = {pl.name: pl for pl in plants}
    a, b = by_name[kinds[0]], by_name[kinds[-1]]
    step = _jit.specialize_sizes(
        _bank_plant, f"{a.name}_{b.name}", {}, inline=True,
        PREDICT_A=a.predict, JACOBIAN_A=a.jacobian, PREDICT_B=b.predict, JACOBIAN_B=b.jacobian,
    )  # fmt: skip
    prm = np.zeros((len(plants), max(len(pl.parameters) for pl in plants)))
    for j, pl in enumerate(plants):
        prm[j, : len(pl.parameters)] = pl.parameters
    return step, np.array([kinds.index(pl.name) for pl in plants], dtype=np.int64), prm


def bank_outputs(runs: int, K: int, n: int, r: int, store_covariance: bool, store_modes: bool) -> dict:
    """The per-sample output arrays of a bank (empty 4-D arrays for the ones not stored).

    ``x`` (runs, K, n), ``mu`` and ``ll`` (runs, K, r), ``P`` (runs, K, n, n), ``mx`` (runs, K, r, n):
    what :func:`bank_store_step` writes and :func:`bank_results` returns.
    """
    none = np.empty((0, 0, 0, 0))
    return {
        "x": np.empty((runs, K, n)),
        "mu": np.empty((runs, K, r)),
        "ll": np.empty((runs, K, r)),
        "P": np.empty((runs, K, n, n)) if store_covariance else none,
        "mx": np.empty((runs, K, r, n)) if store_modes else none,
    }


class BankLoop(TypedDict):
    """What :func:`run_bank_loop` reads of a bank's compiled-loop specification."""

    kernel: Callable[..., int]  # the compiled loop; returns its status
    mapping: int  # the state-correction mapping of its corrections (for the error message)


def bank_results(
    out: dict[str, np.ndarray], store_covariance: bool, store_modes: bool
) -> dict[str, np.ndarray | None]:
    """The outputs of :func:`bank_outputs` as a bank returns them: None for the ones not stored."""
    return {
        "x": out["x"],
        "mu": out["mu"],
        "ll": out["ll"],
        "P": out["P"] if store_covariance else None,
        "mx": out["mx"] if store_modes else None,
    }


def run_bank_loop(
    spec: BankLoop,
    args: tuple[object, ...],
    out: dict[str, np.ndarray],
    *,
    python: bool = False,
) -> None:
    """Run a bank's compiled loop (IMM or SMM) into ``out`` (:func:`bank_outputs`); raise on its status.

    ``spec`` holds the loop (``kernel``) and the mapping of its corrections (``mapping``, for the
    message); ``args`` are the loop's arguments before its outputs ``o_x, o_mu, o_ll, o_P, o_mx``;
    ``python`` runs the loop's Python form (tests: the meaning does not depend on the compiler).

    Raises
    ------
    SingularMatrixError
        The loop returned ``1 + run`` (a matrix not positive definite), ``-(1 + run)`` (every mode
        likelihood zero or non-finite) or ``-(1 + runs + run)`` (the ``luen`` form's ``Phi12``
        singular).
    """
    runs = out["x"].shape[0]
    kernel = spec["kernel"]
    if python:
        kernel = getattr(kernel, "py_func", kernel)
    status = kernel(*args, out["x"], out["mu"], out["ll"], out["P"], out["mx"])
    if status > 0:
        raise SingularMatrixError(_not_pd_message(int(spec["mapping"]), status - 1))
    if status < -runs:
        raise SingularMatrixError(_luen_message())
    if status < 0:
        raise SingularMatrixError(
            "every mode likelihood is zero or non-finite in some realization; check R and Q of the mode "
            "models (the innovation covariance) and the measurement units"
        )
