"""What the multiple-model banks share: checks, state and outputs, the mixture's arithmetic, ``update``.

SMM-SVSF (:mod:`chatterspec.filters.smm_svsf`) and IMM (:mod:`chatterspec.filters.imm`) take the
same data, keep the same state (:class:`MultipleModelState`) and return the same outputs
(:class:`MultipleModelOutput`); :class:`BankFilter` checks an update's data once for both and hands
:class:`~chatterspec.filters.one_sample.OnlineBank` the bank's one-sample kernel.

The arithmetic both banks do per sample, each formula in its numpy form (over realizations) and its
compiled form (one realization, inlined by the banks' loops), side by side:

* the mode likelihood ``log N(e; 0, S)`` ([SMM] eq 3.2-3.3, [IMM] eq 29): :func:`log_gaussian` /
  :func:`_log_gaussian`, with ``S`` scaled to its correlation matrix and its eigenvalues floored at
  :data:`EIG_FLOOR` (the EHA states span about 20 decades, ``docs/design.md`` S3), so that a
  near-singular ``S`` gives a finite, conservative likelihood instead of NaN;
* the normalized mode probabilities with an optional floor ([SMM] eq 3.1, [IMM] eq 30):
  :func:`normalize_log_weights` / :func:`mode_probabilities_step`;
* the mixture's mean and covariance ([SMM] steps 4a-5, [IMM] eq 31-33 with the factor 1/2):
  :func:`combine` / :func:`combine_step`.

Each compiled form does its numpy twin's arithmetic in loop order, so the banks' compiled loops agree
with their numpy paths to a few ulps per sample (summation order; tolerances in
tests/test_imm_kernel.py and tests/test_smm_kernel.py). The plumbing of those loops (the modes' plant
steps, the per-sample outputs, the status codes) is here too.

See Also
--------
chatterspec.filters.smm_svsf : SMM-SVSF, its equations and readings.
chatterspec.filters.imm : IMM, its cycle and the corrections to the printed equations.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, TypedDict, cast, overload

import numpy as np
import numpy.typing as npt

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array, names_of, nonnegative
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.nonlinear import Model
from ..plants.steps import PlantSteps
from ._base import check_model
from ._engine import (
    LOG2PI,
    _luen_message,
    _not_pd_message,
    chol_solve_step,
    chol_step,
    given_jacobian,
    given_predict,
)
from .one_sample import OnlineBank
from .protocol import FilterState, bank_store, check_update_data, initial_estimate

__all__ = [
    "EIG_FLOOR",
    "BankFilter",
    "MultipleModelOutput",
    "MultipleModelState",
    "OnePacked",
    "bank_outputs",
    "bank_plants",
    "bank_results",
    "bank_store_numpy",
    "bank_store_step",
    "check_bank_models",
    "check_mode_probabilities",
    "check_transition_matrix",
    "check_weight_floor",
    "combine",
    "combine_step",
    "initial_bank_state",
    "initial_mode_probabilities",
    "log_gaussian",
    "log_gaussian_inline",
    "log_gaussian_step",
    "mode_probabilities_step",
    "normalize_log_weights",
    "one_constants",
    "one_sample_io",
    "run_bank_loop",
]

#: What a bank's ``_one_pack`` gives :class:`~chatterspec.filters.one_sample.OnlineBank`: the compiled
#: one-sample call, its state buffer, packed constants, int slots, and the offsets of the combined
#: ``x``, ``P``, the probabilities ``mu`` and the last log-likelihoods in the buffer.
OnePacked = tuple[Callable[..., int], np.ndarray, np.ndarray, np.ndarray, tuple[int, int, int, int]]


def check_mode_probabilities(name: str, mu: npt.ArrayLike, r: int) -> np.ndarray:
    """Mode probabilities: ``r`` non-negative entries summing to 1 (within 1e-9).

    Parameters
    ----------
    name : str
        Name used in error messages.
    mu : (r,) or (runs, r) array_like
        Probabilities.
    r : int
        Number of modes.

    Returns
    -------
    ndarray of float

    Raises
    ------
    ShapeError
        Wrong number of entries.
    ParameterError
        A negative entry or a sum other than 1.
    """
    arr = finite_array(name, mu, ndim=(1, 2))
    if arr.shape[-1] != r:
        raise ShapeError(f"{name} must have one entry per mode ({r}); got shape {arr.shape}")
    if np.any(arr < 0):
        raise ParameterError(f"{name} must be non-negative (probabilities); got min {arr.min():.3g}")
    if not np.allclose(arr.sum(axis=-1), 1.0, rtol=0, atol=1e-9):
        raise ParameterError(f"{name} must sum to 1 over the modes; got sum {arr.sum(axis=-1)}")
    return np.array(arr, dtype=float)


def initial_mode_probabilities(mu0: npt.ArrayLike | None, r: int) -> np.ndarray:
    """A bank's ``mu0``: ``r`` probabilities (:func:`check_mode_probabilities`), uniform when None.

    Raises
    ------
    ShapeError
        Not of shape (r,) (one set for every realization).
    """
    mu = np.full(r, 1.0 / r) if mu0 is None else check_mode_probabilities("mu0", mu0, r)
    if mu.ndim != 1:
        raise ShapeError(f"mu0 must have shape ({r},); got {mu.shape}")
    return mu


def check_transition_matrix(pi: npt.ArrayLike, r: int) -> np.ndarray:
    """Mode transition matrix per step, ``pi[i, j] = P(mode j at k | mode i at k-1)``.

    Parameters
    ----------
    pi : (r, r) array_like
        Non-negative, rows summing to 1 (within 1e-9).
    r : int
        Number of modes.

    Returns
    -------
    (r, r) ndarray

    Raises
    ------
    ShapeError
        Not (r, r).
    ParameterError
        A negative entry or a row not summing to 1 (the message names the rows).
    """
    arr = finite_array("transition_matrix", pi, ndim=2)
    if arr.shape != (r, r):
        raise ShapeError(f"transition_matrix must be ({r}, {r}) (one row per mode); got {arr.shape}")
    if np.any(arr < 0):
        raise ParameterError(
            f"transition_matrix must be non-negative (probabilities); min entry {arr.min():.3g}"
        )
    sums = arr.sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > 1e-9)
    if bad.size:
        raise ParameterError(
            f"every row of transition_matrix must sum to 1 (row i = P(next mode | mode i)); rows "
            f"{bad.tolist()} sum to {sums[bad].tolist()}"
        )
    return np.array(arr, dtype=float)


def check_weight_floor(floor: float, r: int) -> float:
    """SMM weight floor in ``[0, 1/r)`` ([SMM] Table 1 step 3, ``docs/design.md`` S4).

    Parameters
    ----------
    floor : float
        Lower bound of every mode weight.
    r : int
        Number of modes.

    Returns
    -------
    float

    Raises
    ------
    ParameterError
        Outside ``[0, 1/r)`` (at ``1/r`` every weight would be pinned to uniform).
    """
    value = nonnegative("weight_floor", floor)
    if not value < 1.0 / r:
        raise ParameterError(
            f"weight_floor must lie in [0, 1/{r}) = [0, {1.0 / r:.4g}) for {r} modes (at 1/r every "
            f"weight is pinned to uniform); got {value}"
        )
    return value


def check_bank_models(models: Sequence[Model]) -> tuple[int, int]:
    """``(n, m)`` of a bank's mode models, which must all have the same state, output and input sizes.

    Parameters
    ----------
    models : sequence of models
        One per mode, at least one.

    Returns
    -------
    (int, int)
        States ``n`` and outputs ``m``.

    Raises
    ------
    ParameterError
        No mode.
    ShapeError
        Modes of different sizes (they filter the same data).
    """
    if len(models) < 1:
        raise ParameterError("a multiple-model filter needs at least one mode")
    for mdl in models:
        check_model(mdl)
    dims = [(int(mdl.n_states), int(mdl.n_outputs), int(mdl.n_inputs)) for mdl in models]
    if len(set(dims)) != 1:
        raise ShapeError(
            "every mode must have the same numbers of states, measurements and inputs (they filter the "
            f"same data); got (n, m, p) = {dims}"
        )
    return dims[0][0], dims[0][1]


@dataclass(frozen=True, eq=False)
class MultipleModelState:
    """State of a multiple-model filter after sample ``k`` (every realization).

    Attributes
    ----------
    x : (runs, n) array
        Combined posterior ``x(k|k)`` (SMM Table 1: the one SVSF's posterior).
    P : (runs, n, n) array
        Combined posterior covariance.
    mu : (runs, r) array
        Mode probabilities / weights after sample ``k``.
    e_post : (runs, m) array
        Posterior residual ``z(k) - C x(k|k)`` of the combined estimate.
    z_last : (runs, m) array
        Last measurement ``z(k)`` (IMM: residual of each mixed estimate, ``docs/design.md`` I4).
    mode_states : tuple of FilterState
        Mode-matched filter states (IMM and the SMM bank reading; empty for Table 1).
    k : int
        Index of the last processed sample.
    e_prev : (runs, m) array or None
        Residual one step earlier, ``e(k-1|k-1)`` (SMM Table 1; None = zeros).
    """

    x: np.ndarray
    P: np.ndarray
    mu: np.ndarray
    e_post: np.ndarray
    z_last: np.ndarray
    mode_states: tuple[FilterState, ...] = ()
    k: int = 0
    e_prev: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class MultipleModelOutput:
    """Per-sample outputs of a multiple-model filter (sample j belongs to time ``k + 1 + j``).

    Attributes
    ----------
    x_post : (runs, K, n) array
        Combined posterior estimate.
    mu : (runs, K, r) array
        Mode probabilities after each sample.
    loglik : (runs, K, r) array
        Log-likelihood of each mode's innovation (natural log).
    modes : tuple of str
        Mode names in bank order.
    P_post : (runs, K, n, n) array or None
        Combined posterior covariance (only with ``store={"P_post"}``).
    mode_x_post : (runs, K, r, n) array or None
        Mode-conditioned posteriors (IMM / bank; only with ``store={"mode_x_post"}``).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    x_post: np.ndarray
    mu: np.ndarray
    loglik: np.ndarray
    modes: tuple[str, ...]
    P_post: np.ndarray | None = None
    mode_x_post: np.ndarray | None = None

    @property
    def argmax_mode(self) -> np.ndarray:
        """Index of the most probable mode per run and sample, ``(runs, K)``."""
        return np.argmax(self.mu, axis=-1)


def initial_bank_state(
    n: int, r: int, x0: npt.ArrayLike, P0: npt.ArrayLike, runs: int | None, mu0: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """``(runs, x, P, mu)`` at k = 0 from a bank's ``initialize`` arguments (checked as any filter's).

    Parameters
    ----------
    n, r : int
        States and modes.
    x0, P0, runs
        As :meth:`chatterspec.filters.protocol.Filter.initialize`.
    mu0 : (r,) array
        Initial mode probabilities.

    Returns
    -------
    (int, (runs, n), (runs, n, n), (runs, r))
    """
    runs, x, P0a = initial_estimate(n, x0, P0, runs)
    P = np.array(np.broadcast_to(P0a, (runs, n, n)), dtype=float)
    mu = np.array(np.broadcast_to(mu0, (runs, r)), dtype=float)
    return runs, x, P, mu


# ----------------------------------------------------------------------------- the mixture (numpy)
@overload
def combine(mu: np.ndarray, xs: np.ndarray, Ps: None = None) -> tuple[np.ndarray, None]: ...
@overload
def combine(mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray) -> tuple[np.ndarray, np.ndarray]: ...
@overload
def combine(
    mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray | None]: ...


def combine(
    mu: np.ndarray, xs: np.ndarray, Ps: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Mode-weighted estimate and covariance ([SMM] eq 3.4-3.5, [IMM] eq 31-33 with the factor 1/2).

    ``x = sum_j mu_j x_j``, ``P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]``.

    Parameters
    ----------
    mu : (..., r) array
        Mode probabilities.
    xs : (..., r, n) array
        Mode-conditioned estimates.
    Ps : (..., r, n, n) array, optional
        Mode-conditioned covariances (None: return ``P = None``).

    Returns
    -------
    (x (..., n), P (..., n, n) or None)
    """
    x = np.einsum("...j,...jn->...n", mu, xs)
    if Ps is None:
        return x, None
    d = xs - x[..., None, :]
    P = np.einsum("...j,...jab->...ab", mu, Ps + d[..., :, None] * d[..., None, :])
    return x, P


#: Eigenvalue floor of the correlation-scaled innovation covariance (``docs/design.md`` S3).
EIG_FLOOR = 1e-12


def log_gaussian(e: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``log N(e; 0, S)`` over leading axes, robust to badly scaled ``S`` ([SMM] eq 3.2-3.3 vector form).

    ``S`` is scaled to its correlation matrix ``D^-1 S D^-1`` (``D = sqrt(diag S)``), whose eigenvalues
    are floored at 1e-12 ([IMM] eq 29 with ``sqrt(det(2 pi S))``, ``docs/design.md`` I3).

    Parameters
    ----------
    e : (..., m) array
        Innovations (output units).
    S : (..., m, m) array
        Innovation covariances (broadcast against ``e``), positive diagonal.

    Returns
    -------
    (...) ndarray
        Natural-log densities.
    """
    e = np.asarray(e, dtype=float)
    S = np.asarray(S, dtype=float)
    m = e.shape[-1]
    d = np.sqrt(np.maximum(np.diagonal(S, axis1=-2, axis2=-1), np.finfo(float).tiny))
    Sc = S / (d[..., :, None] * d[..., None, :])
    ec = e / d
    w, V = np.linalg.eigh(Sc)
    w = np.maximum(w, EIG_FLOOR)
    proj = np.einsum("...ij,...i->...j", V, ec)
    quad = np.sum(proj * proj / w, axis=-1)
    logdet = np.sum(np.log(w), axis=-1) + 2.0 * np.sum(np.log(d), axis=-1)
    return -0.5 * (quad + logdet + m * LOG2PI)


def normalize_log_weights(logw: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """Probabilities from unnormalized log weights over the last axis, with an optional floor.

    ``mu = exp(logw - logsumexp(logw))`` ([SMM] eq 3.1 / [IMM] eq 30 in the log domain); then, if
    ``floor > 0``, ``mu = max(mu, floor)`` and renormalize ([SMM] Table 1 step 3). After the
    renormalization a floored weight is ``floor / (1 + excess)``, still above ``floor / 2``.

    Parameters
    ----------
    logw : (..., r) array
        Log weights; ``-inf`` allowed (not all of them).
    floor : float
        Weight floor in ``[0, 1/r)`` (not re-checked here).

    Returns
    -------
    (..., r) ndarray
    """
    top = np.max(logw, axis=-1, keepdims=True)
    if not np.all(np.isfinite(top)):
        raise SingularMatrixError(
            "every mode likelihood is zero or non-finite in some realization; check R and Q of the mode "
            "models (the innovation covariance) and the measurement units"
        )
    mu = np.exp(logw - top)
    mu /= mu.sum(axis=-1, keepdims=True)
    if floor > 0:
        mu = np.maximum(mu, floor)
        mu /= mu.sum(axis=-1, keepdims=True)
    return mu


# ------------------------------------------------------------- compiled twins, the loops' plumbing
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
    """``log N(e; 0, S)`` of one innovation, as :func:`~chatterspec.filters.bank.log_gaussian`.

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


@_jit.step
def one_sample_io(buf: np.ndarray, size: int, z: np.ndarray, u: np.ndarray, n: int, m: int, p: int,
    nm: int) -> tuple:  # fmt: skip  # pragma: no cover - compiled
    """The arrays a bank's one-sample kernel hands its batch loop (a step: the scratch is the kernel's).

    ``work``: a copy of the state buffer's first ``size`` floats (written back by the kernel only when
    the sample succeeds); ``z`` (m,) and ``u`` (p,) as one run's one sample, (1, 1, m) and (1, 1, p);
    the loop's outputs ``x`` (1, 1, n) and ``mu`` (1, 1, nm), and an empty (0, 0, 0, 0) array for the
    outputs not kept.
    """
    work = _jit.scratch_block(size)
    for i in range(size):
        work[i] = buf[i]
    zu = _jit.scratch(m + p)
    for i in range(m):
        zu[i] = z[i]
    for i in range(p):
        zu[m + i] = u[i]
    o_x, o_mu, none = _jit.scratch(n), _jit.scratch(nm), _jit.scratch(0).reshape((0, 0, 0, 0))
    z1, u1 = zu[:m].reshape((1, 1, m)), zu[m:].reshape((1, 1, p))
    return work, z1, u1, o_x.reshape((1, 1, n)), o_mu.reshape((1, 1, nm)), none


def bank_store_numpy(
    out: dict[str, np.ndarray],
    k: int,
    x: np.ndarray,
    mu: np.ndarray,
    ll: np.ndarray,
    P: np.ndarray | None,
    xs: np.ndarray,
) -> None:
    """:func:`bank_store_step` for every run at once (the banks' numpy paths): sample ``k`` into ``out``.

    ``x`` (runs, n), ``mu`` and ``ll`` (runs, r), ``P`` (runs, n, n) (stored when ``out`` keeps it)
    and ``xs`` (runs, r, n) (likewise).
    """
    out["x"][:, k], out["mu"][:, k], out["ll"][:, k] = x, mu, ll
    if out["P"].shape[0] > 0:
        out["P"][:, k] = P
    if out["mx"].shape[0] > 0:
        out["mx"][:, k] = xs


@_jit.step
def _no_plant(prm, x, u, out, n, p):  # type: ignore[no-untyped-def]  # pragma: no cover
    """Placeholder of :func:`_bank_plant`'s second plant kind in a one-kind bank (never called)."""


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
    # one kind: every slot is 0, so the second kind is the placeholder (the plant is compiled once)
    pb, jb = (b.predict, b.jacobian) if b is not a else (_no_plant, _no_plant)
    step = _jit.specialize_sizes(
        _bank_plant, "_".join(kinds), {}, inline=True,
        PREDICT_A=a.predict, JACOBIAN_A=a.jacobian, PREDICT_B=pb, JACOBIAN_B=jb,
    )  # fmt: skip
    prm = np.zeros((len(plants), max(len(pl.parameters) for pl in plants)))
    for j, pl in enumerate(plants):
        prm[j, : len(pl.parameters)] = pl.parameters
    return step, np.array([kinds.index(pl.name) for pl in plants], dtype=np.int64), prm


def bank_outputs(runs: int, K: int, n: int, r: int, store_covariance: bool, store_modes: bool) -> dict:
    """The per-sample output arrays of a bank (empty 4-D arrays for the ones not stored).

    ``x`` (runs, K, n), ``mu`` and ``ll`` (runs, K, r), ``P`` (runs, K, n, n) when
    ``store_covariance``, ``mx`` (runs, K, r, n) when ``store_modes``: what :func:`bank_store_step`
    writes and :func:`bank_results` returns.
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
    """The outputs ``out`` of :func:`bank_outputs` as a bank returns them: None for the ones not stored
    (``P`` without ``store_covariance``, ``mx`` without ``store_modes``)."""
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
    ``python`` runs the loop's Python form, every step it calls in Python too (tests: the meaning does
    not depend on the compiler; nothing is compiled).

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
        kernel = _jit.python_form(kernel)
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


def one_constants(nm: int, n: int, m: int, floor: float, parts: Sequence[np.ndarray]) -> np.ndarray:
    """``cst`` of a bank's one-sample kernel: the header ``[nm, n, m, L_prm, L_fp, floor]``, then ``parts``.

    ``parts`` start with the plant parameters ``prm`` and the correction parameters ``fp`` (one row
    per mode or one shared row), whose row lengths the header records; every part is stored row-major.
    """
    L_prm, L_fp = np.atleast_2d(parts[0]).shape[1], np.atleast_2d(parts[1]).shape[1]
    head = np.array([nm, n, m, L_prm, L_fp, float(floor)], dtype=float)
    vals = [head] + [np.ravel(np.asarray(a, dtype=float)) for a in parts]
    return np.ascontiguousarray(np.concatenate(vals))


# ----------------------------------------------------------------------------- update and run
class BankFilter:
    """What SMM-SVSF and IMM share: their options, start, outputs and the checks of :meth:`update`.

    A subclass provides ``initialize``, ``_sensor_model()`` (the model whose sizes the data must
    match), ``_advance(state, z, u, store_covariance, store_modes)`` (the recursion on checked data),
    ``_one_pack(state)`` (its compiled one-sample kernel and packed arrays, :data:`OnePacked`, or None)
    and ``_one_state(read, state, k)`` (the state back from that kernel's buffer, ``read(offset,
    shape)`` giving a copy), and has the fields ``mu0``, ``weight_floor`` and ``modes`` (checked by
    :meth:`_check_bank`).
    """

    if TYPE_CHECKING:  # what the subclasses define (fields, then methods)
        mu0: np.ndarray | None
        weight_floor: float
        modes: Sequence[str] | None

        def initialize(
            self, x0: np.ndarray, P0: np.ndarray, *, runs: int | None = None
        ) -> MultipleModelState: ...

        def _sensor_model(self) -> Model: ...

        def _advance(
            self,
            state: MultipleModelState,
            z: np.ndarray,
            u: np.ndarray,
            store_covariance: bool,
            store_modes: bool,
        ) -> tuple[MultipleModelState, MultipleModelOutput]: ...

        def _one_pack(self, state: MultipleModelState) -> OnePacked | None: ...

        def _one_state(
            self, read: Callable[[int, tuple[int, ...]], np.ndarray], state: MultipleModelState, k: int
        ) -> MultipleModelState: ...

    def _check_bank(self, models: Sequence[Model]) -> tuple[int, int]:
        """Check the mode models (:func:`check_bank_models`) and set ``mu0``, ``weight_floor``, ``modes``.

        Returns
        -------
        (int, int)
            States ``n`` and outputs ``m`` of every mode.
        """
        n, m = check_bank_models(models)
        r = len(models)
        object.__setattr__(self, "mu0", initial_mode_probabilities(self.mu0, r))
        object.__setattr__(self, "weight_floor", check_weight_floor(self.weight_floor, r))
        object.__setattr__(self, "modes", names_of("modes", self.modes, r, "mode", first=0))  # mode0, ...
        return n, m

    def _initial_estimate(
        self, x0: npt.ArrayLike, P0: npt.ArrayLike, runs: int | None
    ) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
        """``(runs, x, P, mu)`` at k = 0 (:func:`initial_bank_state` with the bank's sizes and ``mu0``)."""
        n = int(self._sensor_model().n_states)
        modes, mu0 = cast(tuple[str, ...], self.modes), cast(np.ndarray, self.mu0)  # set by _check_bank
        return initial_bank_state(n, len(modes), x0, P0, runs, mu0)

    def _initial_state(
        self, x: np.ndarray, P: np.ndarray, mu: np.ndarray, mode_states: tuple[FilterState, ...]
    ) -> MultipleModelState:
        """The state at k = 0: ``e(0|0) = 0`` and ``z(0) = 0`` (no measurement yet)."""
        zero = np.zeros((x.shape[0], int(self._sensor_model().n_outputs)))
        return MultipleModelState(
            x=x, P=P, mu=mu, e_post=zero, z_last=zero.copy(), mode_states=mode_states, k=0
        )

    def _output(self, res: dict[str, np.ndarray | None]) -> MultipleModelOutput:
        """The bank's output from the per-sample arrays ``x, mu, ll, P, mx`` (None: not kept)."""
        x, mu, ll = res["x"], res["mu"], res["ll"]
        assert x is not None and mu is not None and ll is not None  # always kept
        return MultipleModelOutput(x, mu, ll, tuple(cast(tuple[str, ...], self.modes)), res["P"], res["mx"])

    def online(self, x0: np.ndarray, P0: np.ndarray, **initial: object) -> OnlineBank:
        """One realization advanced one sample per call: ``f = bank.online(x0, P0)``, ``x = f.step(z, u)``.

        Parameters
        ----------
        x0 : (n,) array
            ``x(0|0)``.
        P0 : (n, n) array
            ``P(0|0)``.
        **initial
            IMM: ``mode_x0``, ``mode_P0`` (see :meth:`IMM.initialize`).

        Returns
        -------
        OnlineBank
            Each step gives the numbers of :meth:`update` on that sample (``docs/filters.md``).
        """
        return OnlineBank(self, self.initialize(x0, P0, runs=1, **initial))

    def update(
        self,
        state: MultipleModelState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        """Advance every realization over K samples (``z(k+1..k+K)``, ``u(k..k+K-1)``).

        Parameters
        ----------
        state : MultipleModelState
            From :meth:`initialize` or a previous update.
        z : (runs, K, m) array
            Measurements.
        u : (K, p) or (runs, K, p) array, optional
            Inputs (``u(k)`` drives ``x(k) -> x(k+1)``); None: no input (zeros).
        store : collection of str, optional
            ``"P_post"``: keep the combined posterior covariance per sample (memory ``runs K n^2``);
            ``"mode_x_post"``: the mode-conditioned posteriors per sample (IMM and the SMM bank
            reading; SMM's Table 1 reading keeps the mode predictions).

        Returns
        -------
        (MultipleModelState, MultipleModelOutput)
        """
        if not isinstance(state, MultipleModelState):
            raise TypeError(f"state must be a MultipleModelState; got {type(state).__name__}")
        mdl0 = self._sensor_model()
        m, p = int(mdl0.n_outputs), int(mdl0.n_inputs)
        store_covariance, store_modes = bank_store(store, type(self).__name__)
        z, u = check_update_data(z, u, state.x.shape[0], m, p)
        return self._advance(state, z, u, store_covariance, store_modes)

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray,
        P0: np.ndarray,
        store: Collection[str] | None = None,
        **initial: object,
    ) -> MultipleModelOutput:
        """Filter whole records: :meth:`initialize` then one :meth:`update`.

        Parameters
        ----------
        z : (runs, T, m) array
            Measurements ``z(1) .. z(T)``.
        u : (T, p) or (runs, T, p) array, optional
            Inputs ``u(0) .. u(T-1)``; None: no input (zeros).
        x0 : (n,) or (runs, n) array
            ``x(0|0)``.
        P0 : (n, n) or (runs, n, n) array
            ``P(0|0)``.
        store : collection of str, optional
            See :meth:`update`.
        **initial
            IMM: ``mode_x0``, ``mode_P0`` (per-mode starts, see :meth:`IMM.initialize`).

        Returns
        -------
        MultipleModelOutput
        """
        zz = finite_array("z", z, ndim=(2, 3))
        runs = 1 if zz.ndim == 2 else zz.shape[0]
        state = self.initialize(x0, P0, runs=runs, **initial)
        keep = bank_store(store, type(self).__name__)
        store = {n for n, k in zip(("P_post", "mode_x_post"), keep, strict=True) if k}
        return self.update(state, zz, u, store=store)[1]
