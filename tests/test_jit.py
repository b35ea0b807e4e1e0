"""The compiled-kernel switch: a kernel that calls another kernel compiles (numba types only dispatchers)."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit

pytestmark = pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")


@_jit.njit
def _inner(a: np.ndarray) -> float:
    s = 0.0
    for v in a:
        s += v * v
    return s


@_jit.njit
def _outer(a: np.ndarray) -> float:
    return 2.0 * _inner(a)


def test_nested_kernels_compile_and_match_python() -> None:
    a = np.arange(5.0)
    assert _outer(a) == 2.0 * float(np.sum(a * a)) == _outer.py_func(a)
    assert hasattr(globals()["_inner"], "py_func")  # the dispatcher that replaced the wrapper
