"""The compiled-kernel switch: a kernel that calls another kernel compiles (numba types only dispatchers);
numba's inliner, with the one-memo copy, compiles the same code."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

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


# A loop of steps that inline steps (branches and loops: several blocks and variables in each), the
# shape of the package's loops; the child compiles it cold and prints the inliner's copy, how many
# numba variables the copies made, and digests of the loop's LLVM IR and assembly.
_INLINING_CHILD = """
import hashlib, json, sys
import numpy as np
from numba.core import ir
from chatterspec import _jit

copies = [0]
var_copy = ir.Var.__deepcopy__
def counted(self, memo):
    copies[0] += 1
    return var_copy(self, memo)
ir.Var.__deepcopy__ = counted

@_jit.step
def leaf(x, i):
    if x[i] > 0.0:
        return 0.5 * x[i]
    s = 0.0
    for j in range(x.shape[0]):
        s += x[j] * x[j]
    return s

@_jit.step
def middle(x, y):
    t = 0.0
    for i in range(x.shape[0]):
        y[i] = leaf(x, i) - leaf(x, 0)
        t += y[i]
    return t

@_jit.njit
def loop(x, y):
    acc = 0.0
    for k in range(3):
        acc += middle(x, y) * middle(y, x)
    return acc

x, y = np.array([1.0, -2.0, 3.0]), np.zeros(3)
value = loop(x, y)
(cres,) = loop.dispatcher().overloads.values()
digest = lambda s: hashlib.sha256(s.encode()).hexdigest()
print(json.dumps({"copy": _jit.inline_copy(), "var_copies": copies[0], "value": value,
                  "ir": digest(cres.library.get_llvm_str()), "asm": digest(cres.library.get_asm_str())}))
"""


def _compile_cold(tmp_path: Path, copy: str) -> dict[str, Any]:
    """The child's report, compiled with an empty numba cache, ``copy`` in ``CHATTERSPEC_INLINE_COPY``
    (empty: the default)."""
    script = tmp_path / "inlining.py"
    script.write_text(_INLINING_CHILD)
    cache = tmp_path / f"numba-{copy or 'default'}"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), CHATTERSPEC_INLINE_COPY=copy)
    env.pop("CHATTERSPEC_JIT", None)
    out = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, env=env, check=True)
    report: dict[str, Any] = json.loads(out.stdout.splitlines()[-1])
    return report


def test_one_memo_inline_copy_gives_numbas_machine_code_in_fewer_copies(tmp_path: Path) -> None:
    """The inliner's one-memo copy (``_jit.inline_copy``) changes how numba copies a step's IR, not
    what it compiles: the same LLVM IR and assembly as numba's own per-block copy, from a fraction of
    the variable copies (numba's copies every variable once per block of the step)."""
    numba_copy = _compile_cold(tmp_path, "numba")
    one_memo = _compile_cold(tmp_path, "")
    assert numba_copy["copy"] == "numba"
    assert one_memo["copy"] == "one memo", "numba's inline_ir no longer has the lines the fix replaces"
    assert one_memo["value"] == numba_copy["value"]
    assert one_memo["ir"] == numba_copy["ir"]
    assert one_memo["asm"] == numba_copy["asm"]
    assert 0 < 3 * one_memo["var_copies"] < numba_copy["var_copies"]
