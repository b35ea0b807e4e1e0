"""Multiple-model filters: SMM-SVSF ([SMM] eq 3.1-3.5, Table 1) and IMM ([IMM] eq 15-33, corrected).

Notation and corrections of ``docs/design.md`` §7.5-§7.6. Everything is batched over a
leading realization axis ``runs``; the only Python loop is over time (the recursions are sequential).

**SMM-SVSF, Table 1 reading** (default, :class:`SMMSVSF` with ``reading="table1"``): one SVSF whose
prediction is the mode-weighted prediction. Per sample, from the common posterior ``x(k|k), P(k|k)``::

    x_j = f_j(x(k|k), u(k)),  P_j = F_j P(k|k) F_j^T + Q_j,  S_j = C P_j C^T + R       (Table 1 steps 1-2)
    log p_j = log N(z(k+1) - C x_j; 0, S_j)                                           (eq 3.2-3.3, vector)
    mu_j(k+1) ∝ p_j mu_j(k)  (log domain), then mu_j >= floor and renormalize          (eq 3.1, step 3)
    x(k+1|k) = sum_j mu_j x_j,  P(k+1|k) = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]      (steps 4a-5)
    SVSF gain and update (eq 2.5-2.10) on x(k+1|k), P(k+1|k)                           (steps 6-7b)

**SMM bank reading** (``reading="bank"``): eq (3.4)-(3.5) taken literally, r independent SVSFs
(:class:`~chatterspec.filters.svsf_cov.SVSFCov`, one per mode) each weighted by its own innovation
likelihood; the output is the mu-weighted posterior.

**IMM** (:class:`IMM`), per sample with the transition matrix ``pi[i, j] = P(j at k | i at k-1)``::

    (19) c_j = sum_i pi_ij mu_i(k-1)          (18) mu_{i|j} = pi_ij mu_i(k-1) / c_j  (printed 1/mu_j)
    (20) x_0j = sum_i mu_{i|j} x_i            (21) P_0j = sum_i mu_{i|j} [P_i + (x_i - x_0j)(.)^T]
    (22)-(28) mode-matched filter j (any :class:`~chatterspec.filters.protocol.Filter`) from (x_0j, P_0j)
    (29) Lambda_j = N(e_j; 0, S_j)            (30) mu_j(k) ∝ c_j Lambda_j   (log domain)
    (31) x = sum_j mu_j x_j                   (32)-(33) P = sum_j mu_j [P_j + (x_j - x)(x_j - x)^T]

The printed (32)-(33) sum ``mu_i mu_j (x_i - x_j)(x_i - x_j)^T`` over all ``i, j``; that is exactly twice
the spread of (33) here (:func:`pairwise_spread`, tested), so it is read with a factor 1/2. For the
SVSF-type mode filters, ``e(k|k)`` of mode j is the residual of its mixed estimate ``z(k) - C x_0j``
(``docs/design.md`` I4); ``e(k-1|k-1)`` stays the value that mode stored.

Likelihoods (:func:`log_gaussian`) use the correlation-scaled ``S`` with eigenvalues floored at
1e-12 (the EHA states span about 20 decades, ``docs/design.md`` S3), so a near-singular ``S`` gives a finite,
conservative likelihood instead of NaN.

**Compiled IMM step.** When :func:`chatterspec._jit.enabled` and every mode is supported (EKF/KF,
SVSF-cov without ``vbl``, second-order SVSF, on nonlinear-EHA or linear models; see
:mod:`chatterspec.filters._imm_kernel`), :meth:`IMM.update` runs the whole recursion above in one
compiled loop over runs and samples; otherwise it drives the mode filters through the protocol,
one sample at a time. The two agree to rounding (summation order; tolerances in
``tests/test_imm_kernel.py``), and each is chunk-invariant bit for bit.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array, nonnegative
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.measurement import require_linear_measurement
from . import _imm_kernel, _smm_kernel
from ._base import check_model
from ._conventions import bank_store, default_input, mode_initial
from .mixture import combine
from .protocol import FilterState, check_spd
from .svsf_cov import SVSFCov, check_gamma, default_mapping, mapping_matrix, per_channel

__all__ = [
    "IMM",
    "SMMSVSF",
    "MultipleModelOutput",
    "MultipleModelState",
    "check_mode_probabilities",
    "check_transition_matrix",
    "check_weight_floor",
    "combine",
    "log_gaussian",
    "normalize_log_weights",
    "pairwise_spread",
]

LOG2PI = float(np.log(2.0 * np.pi))
#: Eigenvalue floor of the correlation-scaled innovation covariance (``docs/design.md`` S3).
EIG_FLOOR = 1e-12
#: Default SMM weight floor ([SMM] Table 1 step 3 as resolved in ``docs/design.md`` S4).
DEFAULT_WEIGHT_FLOOR = 1e-3


# ----------------------------------------------------------------------------------- validation
def check_mode_probabilities(name: str, mu: object, r: int) -> np.ndarray:
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


def check_transition_matrix(pi: object, r: int) -> np.ndarray:
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


def check_weight_floor(floor: object, r: int) -> float:
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
    value = nonnegative("weight_floor", floor)  # type: ignore[arg-type]
    if not value < 1.0 / r:
        raise ParameterError(
            f"weight_floor must lie in [0, 1/{r}) = [0, {1.0 / r:.4g}) for {r} modes (at 1/r every "
            f"weight is pinned to uniform); got {value}"
        )
    return value


def _check_bank_models(models: Sequence[object]) -> tuple[int, int]:
    if len(models) < 1:
        raise ParameterError("a multiple-model filter needs at least one mode")
    for mdl in models:
        check_model(mdl)
    dims = [(int(mdl.n_states), int(mdl.n_outputs), int(mdl.n_inputs)) for mdl in models]  # type: ignore[attr-defined]
    if len(set(dims)) != 1:
        raise ShapeError(
            "every mode must have the same numbers of states, measurements and inputs (they filter the "
            f"same data); got (n, m, p) = {dims}"
        )
    return dims[0][0], dims[0][1]


# ------------------------------------------------------------------------------------ math pieces
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


def pairwise_spread(mu: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """The spread term as printed in [IMM] eq (32)-(33): ``sum_i sum_j mu_i mu_j (x_i - x_j)(x_i - x_j)^T``.

    Exactly twice the standard spread ``sum_j mu_j (x_j - x)(x_j - x)^T`` (tested); kept only to
    document the correction. :func:`combine` uses the standard form.

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


# ------------------------------------------------------------------------------------ containers
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


def _mode_names(modes: Sequence[str] | None, r: int) -> tuple[str, ...]:
    if modes is None:
        return tuple(f"mode{j}" for j in range(r))
    names = tuple(str(s) for s in modes)
    if len(names) != r:
        raise ShapeError(f"modes must name each of the {r} modes; got {len(names)} names")
    return names


def _init_common(n: int, m: int, r: int, x0: object, P0: object, runs: int | None, mu0: np.ndarray):
    x0a = finite_array("x0", x0, ndim=(1, 2))
    if x0a.shape[-1] != n:
        raise ShapeError(f"x0 must have {n} entries per run; got shape {x0a.shape}")
    if runs is None:
        runs = x0a.shape[0] if x0a.ndim == 2 else 1
    if isinstance(runs, bool) or not isinstance(runs, int | np.integer) or runs < 1:
        raise ParameterError(f"runs must be an integer >= 1; got {runs!r}")
    runs = int(runs)
    x = np.array(np.broadcast_to(x0a, (runs, n)), dtype=float)
    P0a = finite_array("P0", P0, ndim=(2, 3))
    if P0a.shape[-2:] != (n, n) or (P0a.ndim == 3 and P0a.shape[0] not in (1, runs)):
        raise ShapeError(f"P0 must have shape ({n}, {n}) or ({runs}, {n}, {n}); got {P0a.shape}")
    check_spd("P0", P0a)
    P = np.array(np.broadcast_to(P0a, (runs, n, n)), dtype=float)
    mu = np.array(np.broadcast_to(mu0, (runs, r)), dtype=float)
    return runs, x, P, mu


def _check_data(z: object, u: object, runs: int, m: int, p: int) -> tuple[np.ndarray, np.ndarray]:
    z = finite_array("z", z, ndim=(2, 3))
    if z.ndim == 2:
        z = z[None]
    if z.shape[0] != runs or z.shape[2] != m:
        raise ShapeError(f"z must have shape ({runs}, K, {m}) (runs, samples, outputs); got {z.shape}")
    K = z.shape[1]
    u = finite_array("u", default_input(u, K, p), ndim=(1, 2, 3))
    if u.ndim == 1:
        u = u[:, None] if p == 1 else u[None, :]
    if u.ndim == 2:
        u = u[None]
    if u.shape[1] != K or u.shape[2] != p or u.shape[0] not in (1, runs):
        raise ShapeError(
            f"u must have shape ({K}, {p}) or ({runs}, {K}, {p}) (samples like z); got {u.shape}"
        )
    return z, u


# ------------------------------------------------------------------------------------------ SMM
class _RecordRunner:
    """``run`` shared by the banks: :meth:`initialize` then one :meth:`update` over whole records."""

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray,
        P0: np.ndarray,
        store: Collection[str] | None = None,
        store_covariance: bool | None = None,
        store_modes: bool | None = None,
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
        store_covariance, store_modes : bool, optional
            Deprecated; see :meth:`update`.
        **initial
            IMM: ``mode_x0``, ``mode_P0`` (per-mode starts, see :meth:`IMM.initialize`).

        Returns
        -------
        MultipleModelOutput
        """
        zz = finite_array("z", z, ndim=(2, 3))
        runs = 1 if zz.ndim == 2 else zz.shape[0]
        state = self.initialize(x0, P0, runs=runs, **initial)  # type: ignore[attr-defined]
        keep = bank_store(store, store_covariance, store_modes, type(self).__name__)
        store = {n for n, k in zip(("P_post", "mode_x_post"), keep, strict=True) if k}
        return self.update(state, zz, u, store=store)[1]  # type: ignore[attr-defined]


@dataclass(frozen=True, eq=False)
class SMMSVSF(_RecordRunner):
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

    models: Sequence[object]
    psi: float | np.ndarray
    gamma: float | np.ndarray = 0.1
    mapping: Literal["full", "pinv", "cov"] | None = None
    weight_floor: float = DEFAULT_WEIGHT_FLOOR
    mu0: np.ndarray | None = None
    reading: Literal["table1", "bank"] = "table1"
    modes: Sequence[str] | None = None
    _svsf: SVSFCov | None = field(init=False, repr=False, default=None)
    _bank: tuple[SVSFCov, ...] = field(init=False, repr=False, default=())
    _compiled: dict[str, object] | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        models = tuple(self.models)
        _n, m = _check_bank_models(models)
        for mdl in models:
            require_linear_measurement(mdl, "SMM-SVSF")
        r = len(models)
        C = np.asarray(models[0].C, dtype=float)  # type: ignore[attr-defined]
        R = np.asarray(models[0].R, dtype=float)  # type: ignore[attr-defined]
        for j, mdl in enumerate(models[1:], start=1):
            if not (np.array_equal(mdl.C, C) and np.array_equal(mdl.R, R)):  # type: ignore[attr-defined]
                raise ParameterError(
                    f"SMM-SVSF modes share one sensor: mode {j} has a different C or R from mode 0"
                )
        object.__setattr__(self, "models", models)
        if self.reading not in ("table1", "bank"):
            raise ParameterError(f"reading must be 'table1' or 'bank'; got {self.reading!r}")
        mapping = default_mapping(C) if self.mapping is None else self.mapping
        mapping_matrix(C, mapping)  # named error for an unusable mapping
        object.__setattr__(self, "mapping", mapping)
        psi = per_channel("psi", self.psi, m, rule="the boundary layer")
        if np.any(psi <= 0):
            raise ParameterError(
                f"psi must be > 0 (smoothing boundary layer, output units); got {psi.tolist()}"
            )
        object.__setattr__(self, "psi", psi)
        object.__setattr__(self, "gamma", check_gamma(self.gamma, m))
        object.__setattr__(self, "weight_floor", check_weight_floor(self.weight_floor, r))
        mu0 = np.full(r, 1.0 / r) if self.mu0 is None else check_mode_probabilities("mu0", self.mu0, r)
        if mu0.ndim != 1:
            raise ShapeError(f"mu0 must have shape ({r},); got {mu0.shape}")
        object.__setattr__(self, "mu0", mu0)
        object.__setattr__(self, "modes", _mode_names(self.modes, r))
        # Table 1 steps 6-7b: one SVSF-cov (the modes share C and R) corrects the mixed prediction
        object.__setattr__(self, "_svsf", SVSFCov(models[0], psi=psi, gamma=self.gamma, mapping=mapping))
        if self.reading == "bank":
            bank = tuple(SVSFCov(mdl, psi=psi, gamma=self.gamma, mapping=mapping) for mdl in models)
            object.__setattr__(self, "_bank", bank)
        else:  # the compiled Table 1 loop when every mode has compiled plant steps (else numpy)
            object.__setattr__(self, "_compiled", _smm_kernel.smm_spec(models, self._svsf._correction_step()))

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
        mdl = self.models[0]
        n, m = int(mdl.n_states), int(mdl.n_outputs)  # type: ignore[attr-defined]
        runs, x, P, mu = _init_common(n, m, self.n_modes, x0, P0, runs, self.mu0)  # type: ignore[arg-type]
        states: tuple[FilterState, ...] = ()
        if self.reading == "bank":
            states = tuple(f.initialize(x, P, runs=runs) for f in self._bank)
        zero = np.zeros((runs, m))
        return MultipleModelState(x=x, P=P, mu=mu, e_post=zero, z_last=zero.copy(), mode_states=states, k=0)

    def update(
        self,
        state: MultipleModelState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
        store_covariance: bool | None = None,
        store_modes: bool | None = None,
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
            ``"mode_x_post"``: the mode-conditioned posteriors (bank reading; Table 1 keeps the mode
            predictions).
        store_covariance, store_modes : bool, optional
            Deprecated spellings of ``store={"P_post"}`` / ``store={"mode_x_post"}``
            (``DeprecationWarning``).

        Returns
        -------
        (MultipleModelState, MultipleModelOutput)
        """
        if not isinstance(state, MultipleModelState):
            raise TypeError(f"state must be a MultipleModelState; got {type(state).__name__}")
        mdl0 = self.models[0]
        m, p = int(mdl0.n_outputs), int(mdl0.n_inputs)  # type: ignore[attr-defined]
        store_covariance, store_modes = bank_store(store, store_covariance, store_modes, "SMMSVSF")
        z, u = _check_data(z, u, state.x.shape[0], m, p)
        if self.reading == "bank":
            return self._update_bank(state, z, u, store_covariance, store_modes)
        return self._update_table1(state, z, u, store_covariance, store_modes)

    def _update_table1(self, state, z, u, store_cov, store_modes):  # type: ignore[no-untyped-def]
        if self._compiled is not None and _jit.enabled() and z.shape[1]:
            return self._update_table1_compiled(state, z, u, store_cov, store_modes)
        models = self.models
        r = len(models)
        runs, K, _m = z.shape
        n = state.x.shape[1]
        C = np.asarray(models[0].C, dtype=float)  # type: ignore[attr-defined]
        R = np.asarray(models[0].R, dtype=float)  # type: ignore[attr-defined]
        Qs = np.stack([np.asarray(mdl.Q, dtype=float) for mdl in models])  # type: ignore[attr-defined]
        floor = self.weight_floor
        svsf = self._svsf
        x, P, mu, ep = state.x.copy(), state.P.copy(), state.mu.copy(), state.e_post.copy()
        epp = np.zeros_like(ep) if state.e_prev is None else state.e_prev.copy()
        o_x = np.empty((runs, K, n))
        o_mu = np.empty((runs, K, r))
        o_ll = np.empty((runs, K, r))
        o_P = np.empty((runs, K, n, n)) if store_cov else None
        o_mx = np.empty((runs, K, r, n)) if store_modes else None
        shared_u = u.shape[0] == 1
        xs = np.empty((runs, r, n))
        Fs = np.empty((runs, r, n, n))
        for k in range(K):
            uk = u[0, k] if shared_u else u[:, k]
            zk = z[:, k]
            for j, mdl in enumerate(models):  # Table 1 steps 1-2: every mode from the common posterior
                xs[:, j] = mdl.transition(x, uk)  # type: ignore[attr-defined]
                Fs[:, j] = mdl.jacobian(x, uk)  # type: ignore[attr-defined]
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
            o_x[:, k], o_mu[:, k], o_ll[:, k] = x, mu, ll
            if o_P is not None:
                o_P[:, k] = P
            if o_mx is not None:
                o_mx[:, k] = xs
        new = MultipleModelState(
            x=x,
            P=P,
            mu=mu,
            e_post=ep,
            z_last=z[:, -1].copy() if K else state.z_last,
            k=state.k + K,
            e_prev=epp,
        )
        return new, MultipleModelOutput(o_x, o_mu, o_ll, tuple(self.modes), o_P, o_mx)  # type: ignore[arg-type]

    def _update_table1_compiled(self, state, z, u, store_cov, store_modes):  # type: ignore[no-untyped-def]
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
        o = _smm_kernel.run_smm(
            self._compiled, self.weight_floor, x, P, mu, ep, epp, z, u, store_cov, store_modes
        )
        K = z.shape[1]
        new = MultipleModelState(
            x=x, P=P, mu=mu, e_post=ep, z_last=z[:, -1].copy(), k=state.k + K, e_prev=epp
        )
        out = MultipleModelOutput(o["x"], o["mu"], o["ll"], tuple(self.modes), o["P"], o["mx"])  # type: ignore[arg-type]
        return new, out

    def _update_bank(self, state, z, u, store_cov, store_modes):  # type: ignore[no-untyped-def]
        runs, K, _m = z.shape
        keep = {"x_post", "innovation", "S"} | ({"P_post"} if store_cov else set())
        new_states, outs = [], []
        for f, s in zip(self._bank, state.mode_states, strict=True):  # independent filters, eq 3.4
            s2, out = f.update(s, z, u, store=keep)
            new_states.append(s2)
            outs.append(out)
        ll = np.stack([log_gaussian(o.innovation, o.S) for o in outs], axis=-1)  # (runs, K, r)
        xs = np.stack([o.x_post for o in outs], axis=2)  # (runs, K, r, n)
        mu = state.mu.copy()
        o_mu = np.empty((runs, K, self.n_modes))
        logmu = np.log(np.maximum(mu, 1e-300))
        for k in range(K):  # eq 3.1 with the floor: sequential in time, vectorized over runs
            mu = normalize_log_weights(logmu + ll[:, k], self.weight_floor)
            logmu = np.log(mu)
            o_mu[:, k] = mu
        Ps = np.stack([o.P_post for o in outs], axis=2) if store_cov else None
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
        return new, MultipleModelOutput(x, o_mu, ll, tuple(self.modes), P, xs if store_modes else None)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------ IMM
@dataclass(frozen=True, eq=False)
class IMM(_RecordRunner):
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

    filters: Sequence[object]
    transition_matrix: np.ndarray
    mu0: np.ndarray | None = None
    weight_floor: float = 0.0
    modes: Sequence[str] | None = None
    _fused: dict[str, np.ndarray] | None = field(init=False, repr=False, default=None)

    def __post_init__(self) -> None:
        filters = tuple(self.filters)
        for j, f in enumerate(filters):
            if not all(hasattr(f, a) for a in ("initialize", "update", "model")):
                raise TypeError(
                    f"IMM filter {j} ({type(f).__name__}) does not satisfy the Filter protocol "
                    "(initialize, update, model)"
                )
        models = [f.model for f in filters]  # type: ignore[attr-defined]
        _check_bank_models(models)
        r = len(filters)
        object.__setattr__(self, "filters", filters)
        object.__setattr__(self, "transition_matrix", check_transition_matrix(self.transition_matrix, r))
        mu0 = np.full(r, 1.0 / r) if self.mu0 is None else check_mode_probabilities("mu0", self.mu0, r)
        if mu0.ndim != 1:
            raise ShapeError(f"mu0 must have shape ({r},); got {mu0.shape}")
        object.__setattr__(self, "mu0", mu0)
        object.__setattr__(self, "weight_floor", check_weight_floor(self.weight_floor, r))
        object.__setattr__(self, "modes", _mode_names(self.modes, r))
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
        mdl = self.filters[0].model  # type: ignore[attr-defined]
        n, m = int(mdl.n_states), int(mdl.n_outputs)
        runs, x, P, mu = _init_common(n, m, self.n_modes, x0, P0, runs, self.mu0)  # type: ignore[arg-type]
        xs, Ps, x, P = mode_initial(x, P, mu, mode_x0, mode_P0, self.n_modes)
        states = tuple(f.initialize(xs[:, j], Ps[:, j], runs=runs) for j, f in enumerate(self.filters))  # type: ignore[attr-defined]
        zero = np.zeros((runs, m))
        return MultipleModelState(x=x, P=P, mu=mu, e_post=zero, z_last=zero.copy(), mode_states=states, k=0)

    def update(
        self,
        state: MultipleModelState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
        store_covariance: bool | None = None,
        store_modes: bool | None = None,
    ) -> tuple[MultipleModelState, MultipleModelOutput]:
        """Advance every realization over K samples (``z(k+1..k+K)``, ``u(k..k+K-1)``).

        Parameters
        ----------
        state : MultipleModelState
            From :meth:`initialize` or a previous update.
        z : (runs, K, m) array
            Measurements.
        u : (K, p) or (runs, K, p) array, optional
            Inputs; None: no input (zeros).
        store : collection of str, optional
            ``"P_post"``: keep the combined posterior covariance per sample; ``"mode_x_post"``: the
            mode-matched posteriors per sample.
        store_covariance, store_modes : bool, optional
            Deprecated spellings of ``store={"P_post"}`` / ``store={"mode_x_post"}``
            (``DeprecationWarning``).

        Returns
        -------
        (MultipleModelState, MultipleModelOutput)
        """
        if not isinstance(state, MultipleModelState):
            raise TypeError(f"state must be a MultipleModelState; got {type(state).__name__}")
        mdl0 = self.filters[0].model  # type: ignore[attr-defined]
        m, p = int(mdl0.n_outputs), int(mdl0.n_inputs)
        runs = state.x.shape[0]
        store_covariance, store_modes = bank_store(store, store_covariance, store_modes, "IMM")
        z, u = _check_data(z, u, runs, m, p)
        K = z.shape[1]
        if K and self._fused is not None and len(state.mode_states) == self.n_modes and _jit.enabled():
            return self._update_fused(state, z, u, store_covariance, store_modes)
        n = state.x.shape[1]
        r = self.n_modes
        C = np.asarray(mdl0.C, dtype=float)
        pi = self.transition_matrix
        keep = ("x_post", "innovation", "S")
        mu = state.mu.copy()
        sts = list(state.mode_states)
        zl = state.z_last
        o_x = np.empty((runs, K, n))
        o_mu = np.empty((runs, K, r))
        o_ll = np.empty((runs, K, r))
        o_P = np.empty((runs, K, n, n)) if store_covariance else None
        o_mx = np.empty((runs, K, r, n)) if store_modes else None
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
                s, out = f.update(s, zk, uk, store=keep, check=False)  # type: ignore[attr-defined]
                sts[j] = s
                es[:, j] = out.innovation[:, 0]
                Ss[:, j] = out.S[:, 0] if out.S.ndim == 4 else out.S[0]
            ll = log_gaussian(es, Ss)  # (29), all modes at once
            mu = normalize_log_weights(np.log(c) + ll, self.weight_floor)  # (30)
            xs = np.stack([s.x for s in sts], axis=1)
            if o_P is not None or k == K - 1:
                Ps = np.stack([np.broadcast_to(s.P, (runs, n, n)) for s in sts], axis=1)
                x, P = combine(mu, xs, Ps)  # (31)-(33) with the factor 1/2
            else:
                x, _ = combine(mu, xs)
            o_x[:, k], o_mu[:, k], o_ll[:, k] = x, mu, ll
            if o_P is not None:
                o_P[:, k] = P
            if o_mx is not None:
                o_mx[:, k] = xs
            zl = z[:, k]
            first = False
        if K == 0:
            return state, MultipleModelOutput(o_x, o_mu, o_ll, tuple(self.modes), o_P, o_mx)  # type: ignore[arg-type]
        new = MultipleModelState(
            x=x,
            P=np.broadcast_to(P, (runs, n, n)).copy(),
            mu=mu,
            e_post=zl - x @ C.T,
            z_last=zl.copy(),
            mode_states=tuple(sts),
            k=state.k + K,
        )
        return new, MultipleModelOutput(o_x, o_mu, o_ll, tuple(self.modes), o_P, o_mx)  # type: ignore[arg-type]

    def _update_fused(self, state, z, u, store_cov, store_modes):  # type: ignore[no-untyped-def]
        # the same recursion as update()'s loop, compiled (chatterspec.filters._imm_kernel)
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
        C = np.asarray(self.filters[0].model.C, dtype=float)  # type: ignore[attr-defined]
        new = MultipleModelState(
            x=st["x"],
            P=st["P"],
            mu=st["mu"],
            e_post=st["zl"] - st["x"] @ C.T,
            z_last=st["zl"],
            mode_states=sts,
            k=state.k + K,
        )
        out = MultipleModelOutput(o["x"], o["mu"], o["ll"], tuple(self.modes), o["P"], o["mx"])  # type: ignore[arg-type]
        return new, out
