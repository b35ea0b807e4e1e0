"""Compiled forms of :func:`chatterspec._jit.scratch` / ``scratch2`` (imported only when numba compiles).

A literal size gives a stack array (``alloca`` in the kernel's entry block, no allocator call, no
reference count); LLVM promotes it to registers once the loops over it are unrolled. A run-time
size gives ``np.empty``. The stack array must not outlive the kernel that allocates it: kernels
use it for per-run state only and never return it.
"""

from __future__ import annotations

import numpy as np
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload

from ._jit import STACK_CAPACITY, borrow, scratch, scratch2

_F8 = types.float64


def _stack_array(context, builder, shape: tuple[int, ...]):  # type: ignore[no-untyped-def]
    arrty = types.Array(_F8, len(shape), "C")
    size = 1
    for s in shape:
        size *= s
    ptr = cgutils.alloca_once(builder, context.get_value_type(_F8), size=max(size, 1))
    ary = context.make_array(arrty)(context, builder)
    itemsize = context.get_constant(types.intp, 8)
    strides, acc = [], 8
    for s in reversed(shape):
        strides.append(acc)
        acc *= max(s, 1)
    strides.reverse()
    context.populate_array(
        ary,
        data=ptr,
        shape=cgutils.pack_array(builder, [context.get_constant(types.intp, s) for s in shape]),
        strides=cgutils.pack_array(builder, [context.get_constant(types.intp, s) for s in strides]),
        itemsize=itemsize,
        meminfo=None,
    )
    return ary._getvalue()


@intrinsic
def _stack1(typingctx, n):  # type: ignore[no-untyped-def]
    if not isinstance(n, types.IntegerLiteral):
        return None
    size = (n.literal_value,)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return _stack_array(context, builder, size)

    return types.Array(_F8, 1, "C")(n), codegen


@intrinsic
def _stack2(typingctx, n, m):  # type: ignore[no-untyped-def]
    if not (isinstance(n, types.IntegerLiteral) and isinstance(m, types.IntegerLiteral)):
        return None
    size = (n.literal_value, m.literal_value)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        return _stack_array(context, builder, size)

    return types.Array(_F8, 2, "C")(n, m), codegen


@intrinsic
def _borrow(typingctx, a):  # type: ignore[no-untyped-def]
    if not isinstance(a, types.Array):
        return None

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        src = context.make_array(a)(context, builder, value=args[0])
        dst = context.make_array(a)(context, builder)
        context.populate_array(
            dst, data=src.data, shape=src.shape, strides=src.strides, itemsize=src.itemsize, meminfo=None
        )
        return dst._getvalue()

    return a(a), codegen


@intrinsic
def _stack_dyn(typingctx, n, m):  # type: ignore[no-untyped-def]
    """A (n, m) C-order stack array of STACK_CAPACITY floats' room (the caller checks n m <= capacity)."""

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        arrty = types.Array(_F8, 2, "C")
        ptr = cgutils.alloca_once(builder, context.get_value_type(_F8), size=STACK_CAPACITY)
        ary = context.make_array(arrty)(context, builder)
        itemsize = context.get_constant(types.intp, 8)
        n_, m_ = (context.cast(builder, v, t, types.intp) for v, t in zip(args, signature.args, strict=True))
        context.populate_array(
            ary,
            data=ptr,
            shape=cgutils.pack_array(builder, [n_, m_]),
            strides=cgutils.pack_array(builder, [builder.mul(m_, itemsize), itemsize]),
            itemsize=itemsize,
            meminfo=None,
        )
        return ary._getvalue()

    return types.Array(_F8, 2, "C")(n, m), codegen


def _literal(t) -> bool:  # type: ignore[no-untyped-def]
    return isinstance(t, types.IntegerLiteral) and t.literal_value > 0


@overload(scratch, prefer_literal=True, inline="always")
def _scratch(n):  # type: ignore[no-untyped-def]
    if _literal(n):
        return lambda n: _stack1(n)

    def impl(n):  # type: ignore[no-untyped-def]
        if n <= STACK_CAPACITY:
            return _stack_dyn(1, n)[0]
        return np.empty(n)  # too large for the stack: a heap array, reference counted

    return impl


@overload(scratch2, prefer_literal=True, inline="always")
def _scratch2(n, m):  # type: ignore[no-untyped-def]
    if _literal(n) and _literal(m):
        return lambda n, m: _stack2(n, m)

    def impl(n, m):  # type: ignore[no-untyped-def]
        if n * m <= STACK_CAPACITY:
            return _stack_dyn(n, m)
        return np.empty((n, m))

    return impl


@overload(borrow, inline="always")
def _borrow_overload(a):  # type: ignore[no-untyped-def]
    if isinstance(a, types.Array):
        return lambda a: _borrow(a)
    return lambda a: a
