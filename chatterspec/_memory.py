"""Process memory: a fixed glibc mmap threshold, so that freed large arrays go back to the OS.

glibc's ``malloc`` raises its mmap threshold each time a large ``mmap``-ed block is freed (up to
32 MiB on 64-bit), after which arrays of a few MiB come from the heap instead; a chunked Monte
Carlo loop that allocates and frees such arrays in varying sizes then fragments the heap, and the
peak resident memory creeps up with the number of chunks, i.e. with ``--runs`` (measured:
``chatterspec detect eha-healthy`` 427 MB at 2 560 runs, 499 MB at 10 240 runs; tracemalloc's
peak of live Python/numpy memory stays at 186 MB in both). Setting ``M_MMAP_THRESHOLD`` once
disables that adaptation: every block of ``MMAP_THRESHOLD_BYTES`` or more is ``mmap``-ed and
returned to the OS when freed. Measured on ``detect eha-healthy`` at 2 560 / 10 240 runs (peak
RSS) and ``far eha-healthy --runs 3000`` (system CPU time of the page faults, default 0.6 s):
128 KiB 391 / 392 MB, 2.7 s; 1 MiB 391 / 392 MB, 2.7 s; **8 MiB 396 / 396 MB, 1.3 s**;
32 MiB 438 / 438 MB, 1.0 s. 8 MiB keeps the peak flat at ~10 % more CPU time on ``far``.

Only the command-line interface and the worker processes of
:func:`chatterspec.montecarlo.run_study` call :func:`fix_mmap_threshold`; importing
chatterspec as a library leaves the host process's allocator alone.
"""

from __future__ import annotations

import ctypes
import sys

__all__ = ["MMAP_THRESHOLD_BYTES", "fix_mmap_threshold"]

#: Blocks of at least this many bytes are mmap-ed (glibc starts at 128 KiB and adapts up to 32 MiB).
MMAP_THRESHOLD_BYTES = 8 * 2**20
_M_MMAP_THRESHOLD = -3  # <malloc.h>


def fix_mmap_threshold() -> bool:
    """Fix glibc's mmap threshold at :data:`MMAP_THRESHOLD_BYTES` (no-op elsewhere).

    Returns
    -------
    bool
        True if the C library accepted the setting (glibc on Linux), False otherwise.
    """
    if not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no C library symbols, or a libc without mallopt
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES))
