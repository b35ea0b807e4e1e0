"""The one filter protocol: state, per-sample output and the ``initialize / update / run`` interface.

Every estimator of :mod:`chatterspec.filters` that carries a covariance (Kalman filter, EKF,
SVSF with covariance, dynamic second-order SVSF) follows the same contract, so a
multiple-model bank (SMM, IMM) can drive any of them through this interface alone:

* **Vectorized over realizations.** States are ``(runs, n)``; covariances are ``(runs, n, n)``,
  or one shared ``(n, n)`` matrix when they do not depend on the data (the linear Kalman
  filter started from a shared ``P0``).
* **One kernel for one sample or a chunk.** ``update(state, z, u)`` advances every realization
  over K samples; K = 1 is the online case, K = T the batch case. The per-sample arithmetic
  does not depend on K, so any chunking gives bit-identical numbers (tested).
* **Time convention.** A :class:`FilterState` holds the posterior after sample k:
  ``x(k|k)``, ``P(k|k)``, ``e(k|k)`` and ``e(k-1|k-1)``. ``update`` takes the measurements
  ``z(k+1) .. z(k+K)`` and the inputs ``u(k) .. u(k+K-1)`` (the input that drives
  ``x(k) -> x(k+1)``); sample j of the :class:`FilterOutput` belongs to time ``k+1+j``.
  ``run(z, u, x0=..., P0=...)`` is ``initialize`` followed by one ``update`` over the record.
* **Bank access.** A bank reads ``state.x`` and ``state.P`` (mode-conditioned estimate) and
  writes mixed values back with :meth:`FilterState.replace` between steps; a shared ``(n, n)``
  covariance may be replaced by a per-run ``(runs, n, n)`` one, and the filter then takes its
  per-run path. The per-sample innovation likelihood is ``FilterOutput.loglik``.

Notation of ``docs/design.md`` §7: e(k+1|k) = z(k+1) - C x(k+1|k) (innovation),
e(k|k) = z(k) - C x(k|k) (a-posteriori residual), S = C P(k+1|k) C^T + R.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Collection
from dataclasses import dataclass
from typing import Protocol, TypedDict, Unpack, runtime_checkable

import numpy as np
import numpy.typing as npt

from .._repr import short_repr
from .._validate import finite_array
from ..errors import ParameterError, ShapeError
from ..plants.nonlinear import Model

__all__ = ["DEFAULT_STORE", "STORABLE", "Filter", "FilterOutput", "FilterState"]

#: Output fields stored per sample when ``store`` is not given.
DEFAULT_STORE: frozenset[str] = frozenset({"x_prior", "x_post", "innovation", "S", "loglik", "e_post"})
#: Every field that ``store`` may name (covariances are stored only on request).
STORABLE: frozenset[str] = DEFAULT_STORE | {"P_prior", "P_post"}


class FilterStateFields(TypedDict, total=False):
    """Fields of :class:`FilterState`, as :meth:`FilterState.replace` takes them."""

    x: np.ndarray
    P: np.ndarray
    e_post: np.ndarray
    e_prev: np.ndarray
    k: int


@dataclass(frozen=True, eq=False)
class FilterState:
    """Posterior of every realization after sample ``k`` (what a bank reads and replaces).

    Attributes
    ----------
    x : (runs, n) array
        A-posteriori estimate ``x(k|k)``.
    P : (n, n) or (runs, n, n) array
        A-posteriori covariance ``P(k|k)``; ``(n, n)`` when shared by all realizations
        (data-independent, linear Kalman filter only).
    e_post : (runs, m) array
        A-posteriori residual ``e(k|k) = z(k) - C x(k|k)``.
    e_prev : (runs, m) array
        The residual one step earlier, ``e(k-1|k-1)`` (used by the second-order SVSF, eq 9).
    k : int
        Index of the last processed sample.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    x: np.ndarray
    P: np.ndarray
    e_post: np.ndarray
    e_prev: np.ndarray
    k: int

    @property
    def runs(self) -> int:
        """Number of realizations (leading axis of ``x``)."""
        return self.x.shape[0]

    @property
    def shared_covariance(self) -> bool:
        """True when ``P`` is one ``(n, n)`` matrix shared by every realization."""
        return self.P.ndim == 2

    def replace(self, **changes: Unpack[FilterStateFields]) -> FilterState:
        """Copy with fields replaced (e.g. a bank's mixed ``x`` and ``P``), shapes checked.

        Parameters
        ----------
        **changes
            New values for ``x``, ``P``, ``e_post``, ``e_prev`` or ``k``.

        Returns
        -------
        FilterState
        """
        unknown = set(changes) - {f.name for f in dataclasses.fields(self)}
        if unknown:
            raise TypeError(f"FilterState.replace() got unexpected keyword argument(s): {sorted(unknown)}")
        new = dataclasses.replace(self, **changes)
        runs, n = self.x.shape
        m = self.e_post.shape[1]
        x = finite_array("x", new.x, shape=(runs, n))
        P = finite_array("P", new.P, ndim=(2, 3))
        if P.shape[-2:] != (n, n) or (P.ndim == 3 and P.shape[0] != runs):
            raise ShapeError(f"P must have shape ({n}, {n}) or ({runs}, {n}, {n}); got {P.shape}")
        e_post = finite_array("e_post", new.e_post, shape=(runs, m))
        e_prev = finite_array("e_prev", new.e_prev, shape=(runs, m))
        return FilterState(x=x, P=P, e_post=e_post, e_prev=e_prev, k=int(new.k))


@dataclass(frozen=True, eq=False)
class FilterOutput:
    """Per-sample outputs of one ``update`` (shapes ``(runs, K, .)``; fields not stored are None).

    Attributes
    ----------
    x_prior : (runs, K, n) array or None
        Prior ``x(k+1|k)``.
    x_post : (runs, K, n) array or None
        Posterior ``x(k+1|k+1)``.
    innovation : (runs, K, m) array or None
        ``e(k+1|k) = z(k+1) - C x(k+1|k)``.
    S : (runs, K, m, m) array or None
        Innovation covariance ``C P(k+1|k) C^T + R`` (a read-only broadcast view when shared by all runs).
    loglik : (runs, K) array or None
        ``log N(e(k+1|k); 0, S)`` (natural log), the likelihood a multiple-model bank weighs.
    e_post : (runs, K, m) array or None
        A-posteriori residual ``e(k+1|k+1)``.
    P_prior : (runs, K, n, n) array or None
        ``P(k+1|k)`` (stored only when requested; a broadcast view when shared).
    P_post : (runs, K, n, n) array or None
        ``P(k+1|k+1)`` (stored only when requested; a broadcast view when shared).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    x_prior: np.ndarray | None = None
    x_post: np.ndarray | None = None
    innovation: np.ndarray | None = None
    S: np.ndarray | None = None
    loglik: np.ndarray | None = None
    e_post: np.ndarray | None = None
    P_prior: np.ndarray | None = None
    P_post: np.ndarray | None = None


@runtime_checkable
class Filter(Protocol):
    """What every covariance-carrying filter provides (see the module docstring).

    ``initialize(x0, P0, *, runs=None, e0=None, e_prev0=None) -> FilterState``;
    ``update(state, z, u=None, *, store=None, check=True) -> (FilterState, FilterOutput)`` with
    ``z`` of shape ``(runs, K, m)`` and ``u`` of shape ``(K, p)`` or ``(runs, K, p)`` (None: no input);
    ``run(z, u=None, *, x0, P0, store=None) -> FilterOutput``;
    ``correct(state, x_prior, P_prior, z, *, store=None) -> (FilterState, FilterOutput)``, the
    measurement update from a caller's prior (banks that mix predictions, [SMM] Table 1).
    ``model`` is the filter's model
    (``transition``, ``jacobian``, ``C``, ``Q``, ``R``, ``dt``, ``n_states``, ``n_outputs``,
    ``n_inputs``).
    """

    @property
    def model(self) -> Model:
        """The filter's model (read-only)."""
        ...

    def initialize(
        self,
        x0: np.ndarray,
        P0: np.ndarray,
        *,
        runs: int | None = None,
        e0: np.ndarray | None = None,
        e_prev0: np.ndarray | None = None,
    ) -> FilterState:
        """State at k = 0: ``x(0|0) = x0``, ``P(0|0) = P0`` (SPD), residuals ``e0``, ``e_prev0`` (default 0).

        ``x0`` is (n,) or (runs, n), ``P0`` (n, n) or (runs, n, n); ``runs`` gives the number of
        realizations when ``x0`` is shared.
        """
        ...

    def update(
        self,
        state: FilterState,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        store: Collection[str] | None = None,
        check: bool = True,
    ) -> tuple[FilterState, FilterOutput]:
        """Advance every realization over K samples: ``z`` (runs, K, m) = ``z(k+1) .. z(k+K)``.

        ``state`` is the posterior after sample k; ``u`` (K, p) or (runs, K, p) drives
        ``x(k) -> x(k+1)`` (None: no input); ``store`` names the output fields to keep; ``check``
        validates finiteness. K = 1 (online) and K = T (batch) give the same numbers.
        """
        ...

    def run(
        self,
        z: np.ndarray,
        u: np.ndarray | None = None,
        *,
        x0: np.ndarray,
        P0: np.ndarray,
        store: Collection[str] | None = None,
    ) -> FilterOutput:
        """Filter whole records: :meth:`initialize` at ``(x0, P0)`` then one :meth:`update` over ``z``, ``u``.

        ``store`` as in :meth:`update`; sample j of the output belongs to time j + 1.
        """
        ...

    def correct(
        self,
        state: FilterState,
        x_prior: np.ndarray,
        P_prior: np.ndarray,
        z: np.ndarray,
        *,
        store: Collection[str] | None = None,
    ) -> tuple[FilterState, FilterOutput]:
        """Measurement update only, from the caller's prior ``x_prior`` (runs, n), ``P_prior`` and ``z(k+1)``.

        The residual memory and ``k`` come from ``state``; ``store`` as in :meth:`update`. For
        banks that mix predictions ([SMM] Table 1).
        """
        ...


# ---------------------------------------------------------------------- shared validation helpers
def check_spd(name: str, M: np.ndarray) -> None:
    """Raise ParameterError unless every (n, n) block of ``M`` is symmetric positive definite."""
    sym_err = np.max(np.abs(M - np.swapaxes(M, -1, -2)), initial=0.0)
    scale = max(1.0, float(np.max(np.abs(M), initial=0.0)))
    if sym_err > 1e-10 * scale:
        raise ParameterError(f"{name} must be symmetric; max |{name} - {name}^T| = {sym_err:.3g}")
    try:
        np.linalg.cholesky(M)
    except np.linalg.LinAlgError:
        eig = np.min(np.linalg.eigvalsh(M))
        raise ParameterError(
            f"{name} must be positive definite (a covariance with every variance > 0); "
            f"smallest eigenvalue {eig:.3g}"
        ) from None


def channel_rows(
    name: str, value: npt.ArrayLike, m: int, *, label: str | None = None, channels: Collection[str] = ()
) -> np.ndarray:
    """``value`` as (K, m) float rows of the ``m`` output channels; a 1-D array is one row (sample).

    Parameters
    ----------
    name : str
        Name of the argument (in the NaN/inf message).
    value : (K, m) or (m,) array_like
        Samples of the m channels (e.g. ``z(0)`` of a filter, a monitor's measurements).
    m : int
        Number of channels.
    label : str, optional
        What the shape message calls it (default ``name``).
    channels : collection of str
        Channel names the shape message lists (default: none).

    Returns
    -------
    (K, m) ndarray of float

    Raises
    ------
    ShapeError
        Not m channels per row.
    NonFiniteError
        NaN or inf.
    """
    arr = finite_array(name, value, ndim=(1, 2))
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.shape[1] != m:
        names = f" {list(channels)}" if channels else ""
        raise ShapeError(f"{label or name} must have {m} channel(s){names}; got shape {arr.shape}")
    return arr


def sample_rows(name: str, value: object, size: int) -> np.ndarray:
    """``value`` as a C-contiguous float ``(size,)`` array (a number when ``size == 1``), else ShapeError.

    The one check of a one-sample call (finiteness is tested inside the compiled call).
    """
    try:
        arr = np.ascontiguousarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ShapeError(f"{name} must be numeric; got {type(value).__name__}") from exc
    if arr.shape != (size,):
        raise ShapeError(f"{name} must have shape ({size},) (one sample); got {arr.shape}")
    return arr


def resolve_store(store: Collection[str] | None) -> frozenset[str]:
    """The set of output fields to keep (``None`` = :data:`DEFAULT_STORE`)."""
    if store is None:
        return DEFAULT_STORE
    if isinstance(store, str):
        raise ParameterError(f"store is a collection of names, e.g. {{{store!r}}}; got the string {store!r}")
    keep = frozenset(store)
    bad = keep - STORABLE
    if bad:
        raise ParameterError(f"store may name only {sorted(STORABLE)}; got unknown {sorted(bad)}")
    return keep


def initial_estimate(
    n: int, x0: npt.ArrayLike, P0: npt.ArrayLike, runs: int | None
) -> tuple[int, np.ndarray, np.ndarray]:
    """``(runs, x, P0)`` from a filter's or bank's ``initialize`` arguments, checked.

    Parameters
    ----------
    n : int
        Number of states.
    x0 : (n,) or (runs, n) array_like
        Initial estimate.
    P0 : (n, n) or (runs, n, n) array_like
        Initial covariance, symmetric positive definite.
    runs : int or None
        Number of realizations (None: rows of ``x0``, or 1).

    Returns
    -------
    (int, (runs, n) array, (n, n) or (runs, n, n) array)
        ``x`` broadcast to every run; ``P0`` as given (float), not yet broadcast.

    Raises
    ------
    ShapeError, ParameterError, NonFiniteError
        Wrong shapes, ``runs`` not an integer >= 1, ``P0`` not SPD, NaN or inf.
    """
    x0 = finite_array("x0", x0, ndim=(1, 2))
    if x0.shape[-1] != n:
        raise ShapeError(f"x0 must have {n} entries per run; got shape {x0.shape}")
    if runs is None:
        runs = x0.shape[0] if x0.ndim == 2 else 1
    if isinstance(runs, bool) or not isinstance(runs, int | np.integer) or runs < 1:
        raise ParameterError(f"runs must be an integer >= 1; got {runs!r}")
    runs = int(runs)
    if x0.ndim == 2 and x0.shape[0] not in (1, runs):
        raise ShapeError(f"x0 must have shape ({n},) or ({runs}, {n}); got {x0.shape}")
    x = np.array(np.broadcast_to(x0, (runs, n)), dtype=float)
    P0 = finite_array("P0", P0, ndim=(2, 3))
    if P0.shape[-2:] != (n, n) or (P0.ndim == 3 and P0.shape[0] not in (1, runs)):
        raise ShapeError(f"P0 must have shape ({n}, {n}) or ({runs}, {n}, {n}); got {P0.shape}")
    check_spd("P0", P0)
    return runs, x, P0


def initial_state(
    model: Model,
    x0: npt.ArrayLike,
    P0: npt.ArrayLike,
    *,
    runs: int | None,
    e0: npt.ArrayLike | None,
    e_prev0: npt.ArrayLike | None,
    shared_ok: bool,
) -> FilterState:
    """Validated :class:`FilterState` at k = 0 (initial residuals default to 0, ``docs/design.md`` §7.2)."""
    n, m = model.n_states, model.n_outputs
    runs, x, P0 = initial_estimate(n, x0, P0, runs)
    if P0.ndim == 2 and shared_ok:
        P = np.array(P0, dtype=float)
    else:
        P = np.array(np.broadcast_to(P0, (runs, n, n)), dtype=float)

    def residual(name: str, val: npt.ArrayLike | None) -> np.ndarray:
        if val is None:
            return np.zeros((runs, m))
        arr = finite_array(name, val, ndim=(1, 2))
        if arr.shape[-1] != m or (arr.ndim == 2 and arr.shape[0] not in (1, runs)):
            raise ShapeError(f"{name} must have shape ({m},) or ({runs}, {m}); got {arr.shape}")
        return np.array(np.broadcast_to(arr, (runs, m)), dtype=float)

    return FilterState(x=x, P=P, e_post=residual("e0", e0), e_prev=residual("e_prev0", e_prev0), k=0)


def check_chunk(
    model: Model, state: FilterState, z: npt.ArrayLike, u: npt.ArrayLike | None, check: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Validate ``z`` (runs, K, m) and ``u`` (K, p) / (runs, K, p) / None; returns ``(z, u)`` as float arrays.

    ``u`` comes back 3-D, ``(1, K, p)`` when shared by all runs.
    """
    m, p = model.n_outputs, model.n_inputs
    runs = state.runs
    if u is None:  # no input: zeros (an autonomous model needs no u)
        u = np.zeros((np.shape(z)[-2] if np.ndim(z) >= 2 else 0, p))
    if check:
        z = finite_array("z", z, ndim=(2, 3))
        u = finite_array("u", u, ndim=(1, 2, 3))
    else:
        z, u = np.asarray(z, dtype=float), np.asarray(u, dtype=float)
    if z.ndim == 2:
        if runs != 1:
            raise ShapeError(f"z must have shape ({runs}, K, {m}); got {z.shape}")
        z = z[None]
    if z.shape[0] != runs or z.shape[2] != m:
        raise ShapeError(f"z must have shape ({runs}, K, {m}) (runs, samples, outputs); got {z.shape}")
    K = z.shape[1]
    if u.ndim == 1:
        u = u[:, None] if p == 1 else u[None, :]
    if u.ndim == 2:
        u = u[None]
    if u.shape[1] != K or u.shape[2] != p or u.shape[0] not in (1, runs):
        raise ShapeError(
            f"u must have shape ({K}, {p}) or ({runs}, {K}, {p}) (samples like z); got {u.shape}"
        )
    if state.e_post.shape != (runs, m) or state.e_prev.shape != (runs, m):
        raise ShapeError(f"state residuals must have shape ({runs}, {m})")
    return z, u
