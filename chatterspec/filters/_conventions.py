"""The conventions every filter and bank shares (private): what to store, inputs, per-mode starts.

Documented for users in ``docs/filters.md`` ("Conventions"). In short:

* **One storage option.** Every filter and bank takes ``store``: a collection of output field names
  (``FilterOutput`` fields for a filter; ``"P_post"`` and ``"mode_x_post"`` of
  :class:`~chatterspec.filters.bank.MultipleModelOutput` for SMM-SVSF and IMM, beside the
  fields they always return).
* **Optional input.** ``u=None`` means no input (zeros of the model's ``n_inputs`` channels), so an
  autonomous model needs no ``u`` (and a ``LinearModel`` no ``B``: ``B=None``).
* **Per-mode start of the IMM.** ``IMM.initialize(..., mode_x0=, mode_P0=)`` starts each mode-matched
  filter from its own estimate and covariance; the combined ``x(0|0)``, ``P(0|0)`` are their
  ``mu0``-weighted combination ([IMM] eq 31-33; :func:`chatterspec.filters.imm.mode_initial`).
"""

from __future__ import annotations

from collections.abc import Collection

import numpy as np
import numpy.typing as npt

from .._validate import finite_array
from ..errors import ParameterError, ShapeError

__all__ = [
    "BANK_STORABLE",
    "SVSF_STORABLE",
    "bank_store",
    "check_chunk",
    "check_initial_rows",
    "check_record",
    "default_input",
    "store_flags",
    "svsf_store",
]

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


def check_chunk(
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
