"""Reproducible random streams that do not depend on how the work is chunked.

Realizations are grouped in fixed blocks of :data:`BLOCK` realizations; block
``b`` draws from its own generator, built from the root
:class:`numpy.random.SeedSequence` with ``spawn_key = root.spawn_key + (b,)``.
Any chunking of the realization axis (in-process chunks, local worker
processes, a Dask cluster) therefore produces the same numbers for the same
seed, and no global random state is ever touched.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BLOCK", "SeedLike", "block_generator", "root_seed_sequence", "seed_label"]

#: Realizations per random block (the unit of chunk-invariant seeding).
BLOCK = 64

SeedLike = int | np.random.SeedSequence | np.random.Generator | None


def root_seed_sequence(seed: SeedLike) -> np.random.SeedSequence:
    """Turn an int, SeedSequence, Generator or None into a root SeedSequence.

    A :class:`numpy.random.Generator` is consumed once (four 64-bit draws) to
    derive the root entropy, so passing the same generator state twice gives
    the same results.

    Parameters
    ----------
    seed : int, SeedSequence, Generator or None
        A non-negative integer (used as the SeedSequence entropy); a
        SeedSequence (returned unchanged); a Generator (advanced by one draw); or
        None (fresh OS entropy, not reproducible). Booleans, negative integers
        and other types raise :class:`~chatterspec.errors.ParameterError`.

    Returns
    -------
    numpy.random.SeedSequence
        Root from which :func:`block_generator` derives one stream per block
        of :data:`BLOCK` realizations.
    """
    if isinstance(seed, np.random.SeedSequence):
        return seed
    if isinstance(seed, np.random.Generator):
        return np.random.SeedSequence(seed.integers(0, 2**63, size=4, dtype=np.uint64).tolist())
    if seed is None:
        return np.random.SeedSequence()
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        from .errors import ParameterError

        raise ParameterError(f"seed must be a non-negative integer, SeedSequence or Generator; got {seed!r}")
    return np.random.SeedSequence(int(seed))


def seed_label(seed: SeedLike) -> int | None:
    """The JSON-ready label of a study's root seed: the integer for an int or numpy integer seed.

    Results record it in their ``seed`` field; a SeedSequence, Generator or None has no short
    reproducible label and gives None.

    Parameters
    ----------
    seed : int, SeedSequence, Generator or None
        The seed the study was given (validated by :func:`root_seed_sequence`).

    Returns
    -------
    int or None
        ``int(seed)`` for a Python or numpy integer, otherwise None.

    See Also
    --------
    root_seed_sequence : the root of the random streams built from the same seed.
    """
    return int(seed) if isinstance(seed, int | np.integer) else None


def block_generator(root: np.random.SeedSequence, block: int, stream: int = 0) -> np.random.Generator:
    """Generator of realization block ``block`` (and sub-stream ``stream``) under ``root``."""
    ss = np.random.SeedSequence(root.entropy, spawn_key=(*root.spawn_key, int(block), int(stream)))
    return np.random.Generator(np.random.PCG64(ss))
