"""Old home of the Monte Carlo runner, :mod:`chatterspec.montecarlo` (every name re-exported)."""

from __future__ import annotations

from .. import montecarlo as _runner

DASK_CONNECT_TIMEOUT_S = _runner.DASK_CONNECT_TIMEOUT_S
DEFAULT_CHUNK_RUNS = _runner.DEFAULT_CHUNK_RUNS
Chunk, Execution, ExecutionOptions, Study, plan_chunks, run_chunk, run_study = (
    _runner.Chunk,
    _runner.Execution,
    _runner.ExecutionOptions,
    _runner.Study,
    _runner.plan_chunks,
    _runner.run_chunk,
    _runner.run_study,
)

__all__ = ["DASK_CONNECT_TIMEOUT_S", *_runner.__all__]
