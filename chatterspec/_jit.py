"""The compiled-kernel switch for per-sample recursions.

Every recursion that cannot be vectorized in time (the smoothing SVSF, the
Kalman family, the second-order SVSF, multiple-model banks) is written once as
a plain function over explicit scalar loops and decorated with :func:`njit`.
With numba installed, :func:`njit` compiles it (``cache=True``: the machine code
is stored beside the source, so a second process does not recompile); without
numba, or with ``CHATTERSPEC_JIT=0`` in the environment, the same Python
function is returned and the caller takes its numpy path instead (see
:func:`enabled`). Both paths are tested equal.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["HAVE_NUMBA", "enabled", "njit"]

F = TypeVar("F", bound=Callable[..., Any])

try:  # pragma: no cover - depends on the environment
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover
    _numba = None
    HAVE_NUMBA = False


def enabled() -> bool:
    """True when compiled kernels are used (numba importable and ``CHATTERSPEC_JIT`` is not ``0``)."""
    return HAVE_NUMBA and os.environ.get("CHATTERSPEC_JIT", "1") != "0"


def njit(func: F) -> F:
    """Compile ``func`` with ``numba.njit(cache=True, nogil=True)`` when numba is available.

    Parameters
    ----------
    func : callable
        A function of scalars and numpy arrays written with explicit loops.

    Returns
    -------
    callable
        The compiled dispatcher, or ``func`` itself without numba.
    """
    if _numba is None:
        return func
    return _numba.njit(cache=True, nogil=True)(func)  # type: ignore[return-value]
