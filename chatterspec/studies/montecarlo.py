"""Old home of the Monte Carlo runner, :mod:`chatterspec.montecarlo` (every name re-exported)."""

from __future__ import annotations

from ..montecarlo import (
    DASK_CONNECT_TIMEOUT_S,
    DEFAULT_CHUNK_RUNS,
    Chunk,
    Study,
    plan_chunks,
    run_chunk,
    run_study,
)

__all__ = [
    "DASK_CONNECT_TIMEOUT_S",
    "DEFAULT_CHUNK_RUNS",
    "Chunk",
    "Study",
    "plan_chunks",
    "run_chunk",
    "run_study",
]
