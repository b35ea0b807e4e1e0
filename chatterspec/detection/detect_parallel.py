"""Detection of many realizations on worker processes or Dask, with the numbers of the serial path.

:func:`~chatterspec.detection._chunk_plan.detect_on_workers` (re-exported here) is
:func:`~chatterspec.detection.detect.detect_scenario` through
:func:`chatterspec.montecarlo.run_study` (``detect_scenario(..., workers=N)``): the thresholds and
run 0's STFT intervals come from a one-run record in the calling process
(:meth:`~chatterspec.detection._chunk_plan.ChunkPlan.build`), each chunk of ``chunk_runs``
realizations is simulated, filtered and tested on a worker
(:meth:`~chatterspec.detection._chunk_plan.ChunkPlan.test`), and the chunks are folded in chunk order.
Realization ``r`` does not depend on the chunking and the chunk boundaries are those of the serial
path, so the report is the same, bit for bit, whatever ``workers`` or ``scheduler``
(``chatterspec detect --workers N``). :func:`detect_parallel` is the former name of
``detect_scenario`` with workers, kept for its callers.
"""

from __future__ import annotations

from typing import Any

from ..plants.scenarios import Scenario
from ..rng import SeedLike
from ._chunk_plan import detect_on_workers
from .detect import DetectionReport, detect_scenario

__all__ = ["detect_on_workers", "detect_parallel"]


def detect_parallel(
    scenario: Scenario, runs: int = 1, seed: SeedLike = 0, *args: Any, **kwargs: Any
) -> DetectionReport:
    """:func:`~chatterspec.detection.detect.detect_scenario` with the seed 0 by default (its former name).

    Parameters
    ----------
    scenario, runs, seed
        As in :func:`~chatterspec.detection.detect.detect_scenario`; ``seed`` defaults to 0.
    *args, **kwargs
        ``alpha, threshold, correction`` and every keyword of
        :func:`~chatterspec.detection.detect.detect_scenario` (``workers``, ``scheduler``,
        ``progress``, ``identification``, ``frame_threshold``, ...).

    See Also
    --------
    chatterspec.detection.detect.detect_scenario : the entry point this name calls.
    """
    return detect_scenario(scenario, runs, seed, *args, **kwargs)
