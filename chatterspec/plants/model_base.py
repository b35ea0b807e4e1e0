"""What :class:`~chatterspec.plants.linear_model.LinearModel` and
:class:`~chatterspec.plants.nonlinear.NonlinearModel` share: the checks of their common fields and
the interface the filters use.

Both models describe ``x(k+1) = f(x(k), u(k)) + v(k)``, ``z(k) = C x(k) + w(k)`` (eq 1-2 of the
chattering paper, ``f(x, u) = A x + B u`` for the linear model). The filters only need
``transition``, ``jacobian``, ``C``, ``Q``, ``R``, ``dt`` and the sizes; :class:`ModelBase` documents
that interface once and holds what both models compute the same way (outputs, the oscillatory mode's
frequency and damping, the array part of the fingerprint). The ``check_*`` functions validate the
fields both dataclasses carry, with the same messages for both.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from .._validate import finite_array, readonly
from ..errors import ParameterError, ShapeError, SingularMatrixError

if TYPE_CHECKING:  # pragma: no cover
    from .linear_model import OscillatoryMode
    from .nonlinear import Model

__all__ = [
    "ModelBase",
    "check_covariance",
    "check_labels",
    "check_measurement_matrix",
    "check_noise",
    "frozen",
    "hash_arrays",
    "set_channel_labels",
    "state_units",
]

#: Time derivatives named after a measured state: their units follow from its unit (``m`` -> ``m/s``).
_DERIVATIVES = {"velocity": ("position", "/s"), "acceleration": ("position", "/s^2")}


def state_units(model: Model) -> tuple[str, ...]:
    """Units of a model's states: its ``state_units`` where it declares them (nonlinear models), else the
    unit of the output of the same name (a measured state), else for ``velocity`` / ``acceleration`` the
    unit of the ``position`` per second / per second squared; ``""`` where none of these says.

    Parameters
    ----------
    model : LinearModel or NonlinearModel

    Returns
    -------
    tuple of str
        One unit per state.
    """
    declared = tuple(getattr(model, "state_units", ()) or ())
    if any(declared):
        return declared
    by_name = dict(zip(model.output_names, model.output_units, strict=True))
    out = []
    for s in model.state_names:
        unit = by_name.get(s, "")
        if not unit and s in _DERIVATIVES:
            base, per = _DERIVATIVES[s]
            unit = f"{by_name[base]}{per}" if by_name.get(base) else ""
        out.append(unit)
    return tuple(out)


def check_covariance(name: str, M: np.ndarray) -> None:
    """Raise :class:`ParameterError` unless ``M`` is symmetric positive semi-definite.

    Parameters
    ----------
    name : str
        The covariance's name, for the message (``"Q"``, ``"R"``).
    M : (k, k) ndarray
        A finite square matrix.
    """
    d = np.diag(M)
    if np.any(d < 0):  # a variance: never negative (the relative eigenvalue tolerance would let it pass)
        i = int(np.flatnonzero(d < 0)[0])
        raise ParameterError(f"{name} must be positive semi-definite: diagonal entry {i} is {d[i]:g} < 0")
    if not np.allclose(M, M.T, rtol=1e-10, atol=0.0):
        raise ParameterError(f"{name} must be symmetric")
    eig = np.linalg.eigvalsh(M)
    if eig.min() < -1e-12 * max(1.0, abs(eig.max())):
        raise ParameterError(f"{name} must be positive semi-definite; smallest eigenvalue {eig.min():g}")


def check_measurement_matrix(C: npt.ArrayLike, n: int | None = None, *, full_rank: bool = True) -> np.ndarray:
    """``C`` as a finite (m, n) array with ``m <= n`` (a 1-D array is one measured channel).

    Parameters
    ----------
    C : array_like
        The measurement matrix.
    n : int, optional
        The number of states ``C`` must have as columns (None: any).
    full_rank : bool
        Require full row rank (independent measured channels).

    Raises
    ------
    ShapeError, NonFiniteError, SingularMatrixError
    """
    C = finite_array("C", C, ndim=(1, 2))
    if C.ndim == 1:
        C = C[None, :]
    if n is not None and C.shape[1] != n:
        raise ShapeError(f"C must have {n} columns (one per state); got shape {C.shape}")
    m, n = C.shape
    if m > n:
        raise ShapeError(f"C has more rows ({m}) than states ({n})")
    if full_rank and np.linalg.matrix_rank(C) < m:
        raise SingularMatrixError(f"C must have full row rank {m}; its rows are dependent")
    return C


def check_noise(Q: npt.ArrayLike, R: npt.ArrayLike, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The process- and measurement-noise covariances ``Q`` (n, n) and ``R`` (m, m), checked.

    Raises
    ------
    ShapeError, NonFiniteError, ParameterError
        On a wrong shape, a non-finite entry or a matrix that is not symmetric PSD.
    """
    Q = finite_array("Q", Q, shape=(n, n))
    R = finite_array("R", R, shape=(m, m))
    check_covariance("Q", Q)
    check_covariance("R", R)
    return Q, R


def check_labels(attr: str, given: Iterable[object], size: int, prefix: str | None) -> tuple[str, ...]:
    """Channel names or units: ``given`` as strings, ``size`` entries; defaults when ``given`` is empty.

    Parameters
    ----------
    attr : str
        The field's name, for the message (``"state_names"``, ``"output_units"``).
    given : iterable
        The labels given (empty: the defaults).
    size : int
        How many channels there are.
    prefix : str or None
        Prefix of the default names ``prefix1..prefixN`` (``"x"``, ``"z"``, ``"u"``); None for units,
        whose default is the empty string.

    Raises
    ------
    ShapeError
        If ``given`` has another number of entries.
    """
    labels = tuple(str(s) for s in given)
    if not labels:
        labels = ("",) * size if prefix is None else tuple(f"{prefix}{i + 1}" for i in range(size))
    if len(labels) != size:
        raise ShapeError(f"{attr} must have {size} entries; got {len(labels)}")
    return labels


def set_channel_labels(model: ModelBase, n: int, m: int, p: int) -> None:
    """Set the checked channel names and units of a frozen model in place.

    ``state_names``, ``output_names``, ``input_names`` (default ``x1..xn``, ``z1..zm``, ``u1..up``),
    then ``state_units`` (if the model has that field) and ``output_units`` (default empty).

    Parameters
    ----------
    model : frozen dataclass
        The model being built (its ``__post_init__``).
    n, m, p : int
        Numbers of states, outputs and inputs.
    """
    names = (("state_names", n, "x"), ("output_names", m, "z"), ("input_names", p, "u"))
    units = (("state_units", n, None), ("output_units", m, None))
    for attr, size, prefix in (*names, *units):
        if hasattr(model, attr):
            object.__setattr__(model, attr, check_labels(attr, getattr(model, attr), size, prefix))


def frozen(value: npt.ArrayLike) -> np.ndarray:
    """A read-only float copy of ``value`` (what the model dataclasses store)."""
    return readonly(np.array(value, dtype=float))


def hash_arrays(h: hashlib._Hash, arrays: Iterable[np.ndarray]) -> None:
    """Feed arrays to a hash as little-endian float64 bytes, each followed by its shape.

    Parameters
    ----------
    h : hashlib hash object
        Updated in place (e.g. ``hashlib.sha256()``).
    arrays : iterable of ndarray
        The arrays, in a fixed order.
    """
    for arr in arrays:
        h.update(np.ascontiguousarray(arr, dtype="<f8").tobytes())
        h.update(str(arr.shape).encode())


class ModelBase:
    """The plant interface the filters use, and what the linear and nonlinear models share.

    A subclass is a frozen dataclass with the fields ``C`` (m, n), ``Q``, ``R``, ``dt`` (s) and the
    sizes ``n_states``/``n_inputs``, and defines :meth:`transition`, :meth:`jacobian` and ``mode``.
    """

    C: np.ndarray

    if TYPE_CHECKING:  # each model defines it (a property)

        @property
        def mode(self) -> OscillatoryMode | None: ...

    @property
    def n_outputs(self) -> int:
        """Number of outputs."""
        return self.C.shape[0]

    @property
    def natural_frequency_hz(self) -> float | None:
        """Natural frequency (Hz) of the oscillatory mode, or None (see ``mode``)."""
        mode = self.mode
        return None if mode is None else mode.natural_frequency_hz

    @property
    def damping_ratio(self) -> float | None:
        """Damping ratio of the oscillatory mode, or None (see ``mode``)."""
        mode = self.mode
        return None if mode is None else mode.damping_ratio

    def transition(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """One step of the noise-free dynamics ``f(x, u)``, batched.

        Parameters
        ----------
        x : (..., n) array
            States.
        u : (..., p) or (p,) array
            Inputs (broadcast against ``x``'s leading axes).

        Returns
        -------
        (..., n) array
        """
        raise NotImplementedError

    def jacobian(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Jacobian ``F = df/dx`` of :meth:`transition` at ``(x, u)``, batched.

        Parameters
        ----------
        x, u : arrays
            As in :meth:`transition`.

        Returns
        -------
        (..., n, n) array
        """
        raise NotImplementedError
