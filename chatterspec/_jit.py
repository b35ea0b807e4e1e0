"""The compiled-kernel switch for per-sample recursions.

Every recursion that cannot be vectorized in time (the smoothing SVSF, the
Kalman family, the second-order SVSF, multiple-model banks) is written once as
a plain function over explicit scalar loops and decorated with :func:`njit`.
With numba installed, :func:`njit` compiles it on first call
(``cache=True``: the machine code is stored beside the source, in
``__pycache__/*.nbi|*.nbc``, so a second process loads it instead of
recompiling); without numba, or with ``CHATTERSPEC_JIT=0`` in the environment,
the caller takes its numpy path instead (see :func:`enabled`). numba is
imported lazily, by the first :func:`enabled` call, so commands that never reach
a kernel do not pay its import time; a numba that is installed but fails to
import means the numpy path, with a warning.

How to add a compiled kernel
----------------------------
1. **Signature.** A module-level function ``_<name>_kernel(...)`` of numpy
   arrays and scalars only (no dataclasses, no ``None``: pass an empty array,
   e.g. ``np.empty((0, 0, 0))``, for an output that is not wanted, and test
   ``out.shape[0] > 0`` inside). Inputs first, then the state arrays it updates
   in place, then the preallocated outputs; it returns nothing. Arrays keep the
   package layout ``(runs, K, channels)``; strided views are fine (numba
   compiles one specialization per layout, and all of them are cached).
2. **Body.** ``for r in range(runs):`` outermost, then ``for k in range(K):``,
   with the per-run state in small local arrays allocated once before the loops
   and explicit scalar loops over channels (no array expressions, which would
   allocate a temporary per sample). Use only ``+ - * /``, ``abs``, ``min``,
   ``max``, ``np.sign``, ``np.sqrt``: each is correctly rounded and numba does
   not fuse or reorder them (no ``fastmath``), so the kernel's bits depend only
   on the order in which you write the sums. Runs are independent, so a chunk
   of runs or of samples gives the same bits as the whole record.
3. **Dispatch.** Decorate with :func:`njit`; in the public method, after
   validating the input in Python, branch on :func:`enabled`: compiled kernel
   if true, the existing numpy loop otherwise (keep it: it is the fallback
   without numba and the baseline of the benchmarks). Both branches must give
   the same results for every chunking, since online and batch use the same
   method.
4. **Equality test.** In ``tests/test_kernels.py``, run the same input through
   both branches (``monkeypatch.setenv("CHATTERSPEC_JIT", "0")`` selects the
   numpy one) and compare: bit-identical where both evaluate sums in the same
   order, otherwise to a stated tolerance with its reason (BLAS sums matrix
   products in a different order than the kernel's loop: a few ulps per step,
   which a stable filter does not amplify). Also run the kernel's Python
   function (``kernel.py_func``) on a tiny input, so the test does not depend
   on the compiler for its meaning. The tests skip the compiled side when
   numba is not installed; the ``test`` extra installs it so CI covers both.
"""

from __future__ import annotations

import importlib.util
import os
import threading
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

__all__ = ["HAVE_NUMBA", "enabled", "njit", "numpy_path"]

F = TypeVar("F", bound=Callable[..., Any])

#: Whether numba is installed (checked without importing it).
HAVE_NUMBA = importlib.util.find_spec("numba") is not None


_IMPORTABLE: list[bool] = []  # memo of the one import attempt


def _numba_importable() -> bool:
    """Import numba once; an installed but broken numba (e.g. built for another numpy) means no."""
    if not _IMPORTABLE:
        try:
            import numba  # noqa: F401

            _IMPORTABLE.append(True)
        except Exception as exc:  # pragma: no cover - depends on the environment
            warnings.warn(
                f"numba is installed but cannot be imported ({type(exc).__name__}: {exc}); "
                "chatterspec uses its numpy path",
                RuntimeWarning,
                stacklevel=3,
            )
            _IMPORTABLE.append(False)
    return _IMPORTABLE[0]


def enabled() -> bool:
    """True when compiled kernels are used (numba importable and ``CHATTERSPEC_JIT`` is not ``0``).

    The environment is read at every call, so a test can switch paths with
    ``monkeypatch.setenv``; numba itself is imported on the first call that needs it.
    """
    return (
        HAVE_NUMBA
        and not getattr(_FORCED, "numpy", False)
        and os.environ.get("CHATTERSPEC_JIT", "1") != "0"
        and _numba_importable()
    )


_FORCED = threading.local()


@contextmanager
def numpy_path() -> Iterator[None]:
    """Within the block (this thread only), :func:`enabled` is False: the numpy path runs.

    Used to re-run a chunk whose compiled kernel stopped on a non-finite covariance, so that the
    numpy path (same numbers) can locate the first non-finite sample.
    """
    before = getattr(_FORCED, "numpy", False)
    _FORCED.numpy = True
    try:
        yield
    finally:
        _FORCED.numpy = before


class _LazyKernel:
    """A kernel compiled by ``numba.njit(cache=True, nogil=True)`` on its first call."""

    __slots__ = ("__name__", "_compiled", "py_func")

    def __init__(self, func: Callable[..., Any]) -> None:
        self.py_func = func
        self.__name__ = func.__name__
        self._compiled: Callable[..., Any] | None = None

    def _compile(self) -> Callable[..., Any]:
        import numba

        # A kernel may call other kernels: numba can only type their compiled dispatchers, so
        # compile those first and put the dispatchers in the module's globals (they keep
        # ``py_func`` and are callable from Python like the wrapper they replace).
        env = self.py_func.__globals__
        for name in self.py_func.__code__.co_names:
            dep = env.get(name)
            if isinstance(dep, _LazyKernel):
                env[name] = dep._compiled if dep._compiled is not None else dep._compile()
        self._compiled = numba.njit(cache=True, nogil=True)(self.py_func)
        return self._compiled

    def __call__(self, *args: Any) -> Any:
        compiled = self._compiled
        if compiled is None:
            compiled = self._compile()
        return compiled(*args)


def njit(func: F) -> F:
    """Mark ``func`` as a compiled kernel (lazily ``numba.njit(cache=True, nogil=True)``).

    Parameters
    ----------
    func : callable
        A module-level function of scalars and numpy arrays written with explicit loops.

    Returns
    -------
    callable
        A wrapper compiling ``func`` on first call (its ``py_func`` attribute is
        ``func``), or ``func`` itself when numba is not installed.
    """
    if not HAVE_NUMBA:
        return func
    return _LazyKernel(func)  # type: ignore[return-value]
