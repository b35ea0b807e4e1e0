"""The sizes of the compiled scratch memory, shared by :mod:`chatterspec._jit` (which re-exports
them) and its numba backend :mod:`chatterspec._jit_numba` (private module)."""

from __future__ import annotations

__all__ = ["BLOCK_CAPACITY", "MAX_DIMENSION", "STACK_CAPACITY"]

#: Room (floats) of a compiled :func:`scratch` / :func:`scratch2` whose size is known only at run time.
STACK_CAPACITY = 256
#: Largest number of states or outputs of a loop with matrix scratch (16 x 16 = STACK_CAPACITY).
MAX_DIMENSION = 16
#: Room (floats) of a compiled :func:`scratch_block` (a covariance filter's workspace up to MAX_DIMENSION).
BLOCK_CAPACITY = 8192
