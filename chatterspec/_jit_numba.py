"""The compiled forms of :func:`chatterspec._jit.scratch`, ``scratch2``, ``scratch_block`` and ``borrow``.

numba intrinsics, imported only when numba compiles: :class:`chatterspec._jit._LazyKernel` gives a
kernel this module in place of :mod:`chatterspec._jit` (and these functions in place of the
Python ones it imported by name), so ``_jit.scratch(n)`` in a loop is a stack array. A literal size
gives an array of exactly that size (LLVM promotes it to registers once the loops over it are
unrolled); a run-time size gives the room of :data:`~chatterspec._jit.STACK_CAPACITY` floats
(``scratch_block``: :data:`~chatterspec._jit.BLOCK_CAPACITY`), of which the array uses the first
``n`` (``n m``): callers keep the sizes within it (``chatterspec._jit.fits``). The memory belongs
to the frame of the compiled function that calls the intrinsic (the loop, or the step inlined into
it) and is valid until that function returns: never return it.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

from ._jit_limits import BLOCK_CAPACITY, MAX_DIMENSION, STACK_CAPACITY

__all__ = [
    "BLOCK_CAPACITY",
    "MAX_DIMENSION",
    "STACK_CAPACITY",
    "borrow",
    "scratch",
    "scratch2",
    "scratch_block",
]

_F8 = types.float64


def _array(context, builder, ptr, shape, ndim):
    """A C-order float64 array of ``shape`` (intp values) at ``ptr``, without a meminfo."""
    arrty = types.Array(_F8, ndim, "C")
    ary = context.make_array(arrty)(context, builder)
    itemsize = context.get_constant(types.intp, 8)
    strides = [itemsize]
    for s in reversed(shape[1:]):
        strides.insert(0, builder.mul(strides[0], s))
    context.populate_array(
        ary,
        data=ptr,
        shape=cgutils.pack_array(builder, list(shape)),
        strides=cgutils.pack_array(builder, strides),
        itemsize=itemsize,
        meminfo=None,
    )
    return ary._getvalue()


def _stack(capacity: int, ndim: int) -> Callable[..., Any]:
    """Codegen of a stack array: ``capacity`` floats when a size is not literal, else their product."""

    def codegen(context, builder, signature, args):
        sizes = signature.args
        if all(isinstance(t, types.IntegerLiteral) for t in sizes):
            room = 1
            for t in sizes:
                room *= max(int(t.literal_value), 1)
        else:
            room = capacity
        ptr = cgutils.alloca_once(builder, context.get_value_type(_F8), size=room)
        shape = [context.cast(builder, v, t, types.intp) for v, t in zip(args, sizes, strict=True)]
        return _array(context, builder, ptr, shape, ndim)

    return codegen


@intrinsic
def scratch(typingctx, n):
    """Stack vector of ``n`` floats (see the module docstring)."""
    if not isinstance(n, types.Integer):
        return None
    return types.Array(_F8, 1, "C")(n), _stack(STACK_CAPACITY, 1)


@intrinsic
def scratch2(typingctx, n, m):
    """Stack ``(n, m)`` C-order matrix (see the module docstring)."""
    if not (isinstance(n, types.Integer) and isinstance(m, types.Integer)):
        return None
    return types.Array(_F8, 2, "C")(n, m), _stack(STACK_CAPACITY, 2)


@intrinsic
def scratch_block(typingctx, n):
    """Stack vector with the room of ``BLOCK_CAPACITY`` floats (a workspace carved into pieces)."""
    if not isinstance(n, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        ptr = cgutils.alloca_once(builder, context.get_value_type(_F8), size=BLOCK_CAPACITY)
        shape = [context.cast(builder, args[0], signature.args[0], types.intp)]
        return _array(context, builder, ptr, shape, 1)

    return types.Array(_F8, 1, "C")(n), codegen


@intrinsic
def borrow(typingctx, a):
    """The same array without its meminfo (no reference counting); anything else unchanged."""
    if not isinstance(a, types.Array):

        def identity(context, builder, signature, args):
            return args[0]

        return a(a), identity

    def codegen(context, builder, signature, args):
        src = context.make_array(a)(context, builder, value=args[0])
        dst = context.make_array(a)(context, builder)
        context.populate_array(
            dst, data=src.data, shape=src.shape, strides=src.strides, itemsize=src.itemsize, meminfo=None
        )
        return dst._getvalue()

    return a(a), codegen
