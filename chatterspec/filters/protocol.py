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

**Conventions every filter and bank shares** (documented for users in ``docs/filters.md``,
"Conventions"):

* **One storage option.** Every filter and bank takes ``store``: a collection of output field names
  (``FilterOutput`` fields for a filter; ``"P_post"`` and ``"mode_x_post"`` of
  :class:`~chatterspec.filters.bank.MultipleModelOutput` for SMM-SVSF and IMM, beside the
  fields they always return).
* **Optional input.** ``u=None`` means no input (zeros of the model's ``n_inputs`` channels), so an
  autonomous model needs no ``u`` (and a ``LinearModel`` no ``B``: ``B=None``).
* **Per-mode start of the IMM.** ``IMM.initialize(..., mode_x0=, mode_P0=)`` starts each mode-matched
  filter from its own estimate and covariance; the combined ``x(0|0)``, ``P(0|0)`` are their
  ``mu0``-weighted combination ([IMM] eq 31-33; :func:`chatterspec.filters.imm.mode_initial`).
* **Finite outputs.** The outputs of a filter chunk are finite, or :func:`require_finite` raises a
  :class:`~chatterspec.errors.DivergenceError` naming where they stopped being finite. A model that
  diverges (an unstable or badly mismatched ``A``, a nonlinear ``f`` that overflows or returns NaN
  mid-run) makes the estimate overflow; numpy's Cholesky of a NaN matrix returns NaN instead of
  raising, so without this check the filters would hand back NaN arrays with only numpy warnings. The
  check runs at the API boundary (after a chunk, on both the compiled and the numpy path), not inside
  the per-sample kernels: the final estimate and covariance are tested (cheap); only when they are not
  finite are the stored per-sample outputs searched for the first bad sample. The one-sample kernels
  test their input and state with the compiled steps :func:`finite_sample` and :func:`finite_state`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Protocol, TypedDict, Unpack, runtime_checkable

import numpy as np
import numpy.typing as npt

from .. import _jit
from .._repr import short_repr
from .._validate import finite_array
from ..errors import DivergenceError, ParameterError, ShapeError
from ..plants.nonlinear import Model

__all__ = ["DEFAULT_STORE", "STORABLE", "Filter", "FilterOutput", "FilterState"]


# ----------------------------------------------------------------------------- (from protocol)
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
    m, runs = model.n_outputs, state.runs
    z, u = check_update_data(z, u, runs, m, model.n_inputs, check)
    if state.e_post.shape != (runs, m) or state.e_prev.shape != (runs, m):
        raise ShapeError(f"state residuals must have shape ({runs}, {m})")
    return z, u


def check_update_data(
    z: npt.ArrayLike, u: npt.ArrayLike | None, runs: int, m: int, p: int, check: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """``z`` as (runs, K, m) and ``u`` as (1 | runs, K, p) float arrays of an update (None: no input).

    A 2-D ``z`` is one run; a 1-D ``u`` is one input channel when ``p == 1``, else one sample.

    Raises
    ------
    ShapeError
        Shapes that do not match the filter or bank.
    NonFiniteError
        NaN or inf (with ``check``).
    """
    z = finite_array("z", z, ndim=(2, 3)) if check else np.asarray(z, dtype=float)
    given = z.shape
    if z.ndim == 2:
        z = z[None]
    if z.shape[0] != runs or z.shape[2] != m:
        raise ShapeError(f"z must have shape ({runs}, K, {m}) (runs, samples, outputs); got {given}")
    K = z.shape[1]
    u = default_input(u, K, p)
    u = finite_array("u", u, ndim=(1, 2, 3)) if check else np.asarray(u, dtype=float)
    if u.ndim == 1:
        u = u[:, None] if p == 1 else u[None, :]
    if u.ndim == 2:
        u = u[None]
    if u.shape[1] != K or u.shape[2] != p or u.shape[0] not in (1, runs):
        raise ShapeError(
            f"u must have shape ({K}, {p}) or ({runs}, {K}, {p}) (samples like z); got {u.shape}"
        )
    return z, u


# ----------------------------------------------------------------------------- conventions
#: What ``store`` may name for SMM-SVSF and IMM (x_post, mu and loglik are always returned).
BANK_STORABLE = frozenset({"P_post", "mode_x_post"})
#: What ``store`` may name for the chattering SVSF (``e_prior``, the chattering, is always returned).
SVSF_STORABLE = frozenset({"x_post", "e_post", "e_lower"})


def store_flags(
    store: Collection[str] | None,
    fields: tuple[str, ...],
    allowed: frozenset[str],
    who: str,
    always: str,
) -> tuple[bool, ...]:
    """One flag per entry of ``fields``: is that output field named in ``store``.

    Parameters
    ----------
    store : collection of str or None
        Field names among ``allowed`` (None: none).
    fields : tuple of str
        The output fields, in the order of the returned flags.
    allowed : frozenset of str
        What ``store`` may name.
    who : str
        The filter's name, for messages.
    always : str
        What is always returned, for the error message.

    Returns
    -------
    tuple of bool
    """
    if store is None:
        return tuple(False for _ in fields)
    if isinstance(store, str):
        raise ParameterError(
            f"{who}: store is a collection of names, e.g. {{{store!r}}}; got the string {store!r}"
        )
    keep = frozenset(store)
    bad = keep - allowed
    if bad:
        raise ParameterError(f"{who}: store may name {sorted(allowed)} ({always}); got unknown {sorted(bad)}")
    return tuple(f in keep for f in fields)


def svsf_store(store: Collection[str] | None, who: str) -> tuple[bool, bool, bool]:
    """``(x_post, e_post, e_lower)`` flags of the chattering SVSF from ``store``.

    Parameters
    ----------
    store : collection of str or None
        Names among :data:`SVSF_STORABLE`.
    who : str
        The filter's name, for messages.

    Returns
    -------
    (bool, bool, bool)
    """
    fields = ("x_post", "e_post", "e_lower")
    states, post_error, lower = store_flags(store, fields, SVSF_STORABLE, who, "e_prior is always returned")
    return states, post_error, lower


def bank_store(store: Collection[str] | None, who: str) -> tuple[bool, bool]:
    """``(keep P_post, keep mode_x_post)`` from ``store``.

    Parameters
    ----------
    store : collection of str or None
        Names among :data:`BANK_STORABLE` (None: neither).
    who : str
        The bank's name, for messages.

    Returns
    -------
    (bool, bool)
    """
    always = "x_post, mu and loglik are always kept"
    covariance, modes = store_flags(store, ("P_post", "mode_x_post"), BANK_STORABLE, who, always)
    return covariance, modes


def default_input(u: npt.ArrayLike | None, K: int, p: int) -> npt.ArrayLike:
    """``u``, or zeros ``(K, p)`` when it is None (a model without input)."""
    return np.zeros((K, p)) if u is None else u


def check_svsf_chunk(
    z: np.ndarray, u: np.ndarray, runs: int, m: int, p: int, check: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Measurements ``z`` as (runs, K, m) and inputs ``u`` as (K, p) or (runs, K, p) of an SVSF update.

    Shared by the linear and the nonlinear chattering SVSF (their ``update`` takes the same chunk).

    Validates finiteness when ``check``; a 2-D ``z`` is one run, a 1-D ``u`` one input channel.

    Raises
    ------
    ShapeError
        Shapes that do not match the filter.
    NonFiniteError
        NaN or inf (with ``check``).
    """
    if check:
        z = finite_array("z", z, ndim=(2, 3))
        u = finite_array("u", u, ndim=(1, 2, 3))
    if z.ndim == 2:
        z = z[None]
    if z.shape[0] != runs or z.shape[2] != m:
        raise ShapeError(f"z must have shape ({runs}, K, {m}); got {z.shape}")
    K = z.shape[1]
    if u.ndim == 1:
        u = u[:, None]
    if u.shape[-2] != K or u.shape[-1] != p or (u.ndim == 3 and u.shape[0] not in (1, runs)):
        raise ShapeError(f"u must have shape ({K}, {p}) or ({runs}, {K}, {p}); got {u.shape}")
    return z, u


def check_initial_rows(x0: npt.ArrayLike, width: int, runs: int) -> np.ndarray:
    """An SVSF's ``x0``: (width,) or (runs | 1, width) float, finite (not yet broadcast).

    Raises
    ------
    ShapeError
        Another shape.
    NonFiniteError
        NaN or inf.
    """
    x0 = finite_array("x0", x0, ndim=(1, 2))
    if x0.shape[-1] != width or (x0.ndim == 2 and x0.shape[0] not in (1, runs)):
        raise ShapeError(f"x0 must have shape ({width},) or ({runs}, {width}); got {x0.shape}")
    return x0


def check_record(z: npt.ArrayLike, u: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray, bool]:
    """A whole record of an SVSF's ``run``: ``(z (runs, T, m), u (T | runs, T, p), single)``.

    ``single``: ``z`` was 2-D (one run, whose outputs are returned 2-D); a 1-D ``u`` is one input
    channel. Only the samples are checked here (``T`` >= 2, ``u`` like ``z``); the channels are
    checked by the filter's ``initialize``/``update``.

    Raises
    ------
    ShapeError
        ``u`` with another number of samples than ``z``, or fewer than 2 samples.
    NonFiniteError
        NaN or inf.
    """
    z = finite_array("z", z, ndim=(2, 3))
    single = z.ndim == 2
    if single:
        z = z[None]
    u = finite_array("u", u, ndim=(1, 2, 3))
    if u.ndim == 1:
        u = u[:, None]
    T = z.shape[1]
    if u.shape[-2] != T:
        raise ShapeError(f"u must have {T} samples (like z) along its time axis; got {u.shape}")
    if T < 2:
        raise ShapeError(f"z needs at least 2 samples; got {T}")
    return z, u, single


# ----------------------------------------------------------------------------- finite outputs
#: Per-sample outputs searched for the first non-finite sample, in order of preference.
_PER_SAMPLE = ("x_post", "x_prior", "innovation", "e_post", "e_prior", "loglik", "P_post", "P_prior")


@_jit.step
def finite_sample(z: np.ndarray, m: int, u: np.ndarray, p: int) -> bool:
    """Are ``z[:m]`` and ``u[:p]`` finite: the input check of every one-sample kernel, which refuses a
    NaN/inf sample before it touches the state (compiled loops inline it)."""
    for i in range(m):
        if not np.isfinite(z[i]):
            return False
    for i in range(p):
        if not np.isfinite(u[i]):
            return False
    return True


@_jit.step
def finite_state(x: np.ndarray, P: np.ndarray, n: int) -> bool:
    """Are ``x[:n]`` and ``P[:n, :n]`` finite: the output check of every one-sample kernel, which writes
    its state back only when it holds (compiled loops inline it)."""
    for i in range(n):
        if not np.isfinite(x[i]):
            return False
        for j in range(n):
            if not np.isfinite(P[i, j]):
                return False
    return True


def first_nonfinite(values: np.ndarray) -> tuple[int, int] | None:
    """``(sample, realization)`` of the first non-finite entry of a ``(runs, K, ...)`` array, or None.

    Parameters
    ----------
    values : (runs, K, ...) array
        Per-sample outputs (a ``(K, ...)`` array without a runs axis is not accepted here).
    """
    if values.ndim < 2:
        return None
    bad = ~np.isfinite(values.reshape(values.shape[0], values.shape[1], -1)).all(axis=2)  # (runs, K)
    if not bad.any():
        return None
    per_sample = bad.any(axis=0)
    k = int(np.argmax(per_sample))
    return k, int(np.argmax(bad[:, k]))


def require_finite(
    who: str,
    final: tuple[np.ndarray | None, ...],
    outputs: Mapping[str, np.ndarray | None],
    k0: int,
    K: int,
) -> None:
    """Raise :class:`~chatterspec.errors.DivergenceError` unless the chunk's results are finite.

    Parameters
    ----------
    who : str
        The filter, for the message (e.g. ``"KalmanFilter"``).
    final : tuple of arrays
        The state after the chunk (estimate, covariance); None entries are skipped. Only these are
        tested: a non-finite value inside the chunk propagates into them.
    outputs : mapping of str to array or None
        The chunk's stored per-sample outputs, ``(runs, K, ...)`` (covariances may be ``(K, n, n)``
        when shared by every realization).
    k0 : int
        Index of the last sample processed before the chunk (the chunk holds samples ``k0 + 1 ..
        k0 + K``).
    K : int
        Samples in the chunk.

    Raises
    ------
    DivergenceError
        With the first non-finite sample ``k`` (and realization) when the stored outputs locate it,
        otherwise the sample range of the chunk.
    """
    arrays = [a for a in final if a is not None]
    # a NaN or inf anywhere in the chunk propagates into the final estimate or covariance: testing
    # them is enough, and one sum per array is the cheapest test (called once per sample by the banks)
    with np.errstate(over="ignore", invalid="ignore"):
        if all(math.isfinite(float(a.sum())) for a in arrays):
            return
    if all(np.isfinite(a).all() for a in arrays):  # a finite sum overflowed: finite after all
        return
    where = None
    for name in _PER_SAMPLE:
        v = outputs.get(name)
        if v is None:
            continue
        v = np.asarray(v)
        if name.startswith("P_") and v.ndim == 3:  # shared covariance (K, n, n): one realization axis
            v = v[None]
        hit = first_nonfinite(v)
        if hit is not None and (where is None or hit[0] < where[0]):
            where = hit
    if where is not None:
        k, r = where
        at = f"from sample k = {k0 + k + 1} (output index {k}, realization {r})"
    else:
        at = f"within samples k = {k0 + 1} .. {k0 + K}"
    raise DivergenceError(
        f"{who}: the estimate is not finite {at}: the filter diverged. Check the model: an unstable "
        "or mismatched A (or f) makes the estimate overflow, and a transition f(x, u) or Jacobian that "
        "returns NaN/inf does the same; the outputs would be NaN from there on"
    )
