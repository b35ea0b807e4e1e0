"""Detection of many realizations on worker processes or Dask, with the numbers of the serial path.

:func:`detect_parallel` is :func:`~chatterspec.detection.detect.detect_scenario` through
:func:`chatterspec.studies.montecarlo.run_study`: the thresholds and run 0's STFT intervals come
from a one-run record in the calling process (:meth:`~chatterspec.detection._chunk_plan.ChunkPlan.build`),
each chunk of :data:`~chatterspec.detection.detect.DETECT_CHUNK_RUNS` realizations is simulated,
filtered and tested on a worker (:meth:`~chatterspec.detection._chunk_plan.ChunkPlan.test`), and the
chunks are folded in chunk order. Realization ``r`` does not depend on the chunking and the chunk
boundaries are those of the serial path, so the report is the same, bit for bit, whatever
``workers`` or ``scheduler`` (``chatterspec detect --workers N``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._validate import positive_int
from ..plants.scenarios import Scenario
from ..rng import SeedLike
from ._chunk_plan import ChunkPlan, DetectorOptions
from .detect import DETECT_CHUNK_RUNS, DetectionReport
from .pipeline import iter_chattering
from .spectral import DEFAULT_STFT, STFTConfig
from .thresholds import Band, Correction, Threshold

__all__ = ["detect_parallel"]


@dataclass(frozen=True, eq=False)
class _DetectStudy:
    """A :class:`~chatterspec.studies.montecarlo.Study`: one chunk's verdicts and summed spectrum."""

    scenario: Scenario
    plan: ChunkPlan
    gamma: float
    identification: Any = None  # an IdentificationStream's (setup, alpha, confidence), or None

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> Any:
        acc, parts = None, []
        keep = self.identification is not None
        for rec in iter_chattering(
            self.scenario,
            runs,
            seed,
            chunk_runs=runs,
            first_run=first_run,
            gamma=self.gamma,
            measurements=keep,
            reuse_measurements=keep,
        ):
            acc = self.plan.reduce(acc, self.plan.test(rec.values))
            if keep:
                from .identification import identify_record

                setup, alpha, confidence = self.identification
                parts.append(identify_record(rec, alpha=alpha, confidence=confidence, setup=setup))
        return acc, parts

    def reduce(self, acc: Any, part: Any) -> Any:
        if acc is None:
            return part
        acc[0][0].extend(part[0][0])
        acc[0][1] += part[0][1]
        acc[0][2] += part[0][2]
        acc[1].extend(part[1])
        return acc


def detect_parallel(
    scenario: Scenario,
    runs: int = 1,
    seed: SeedLike = 0,
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    *,
    stft: bool | None = None,
    config: STFTConfig = DEFAULT_STFT,
    band: Band | None = None,
    frame_threshold: Threshold | None = None,
    gamma: float = 0.1,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool | None = None,
    identification: Any = None,
) -> DetectionReport:
    """:func:`~chatterspec.detection.detect.detect_scenario` on worker processes or Dask (same numbers).

    Parameters
    ----------
    scenario : Scenario
        Catalogue or user scenario.
    runs : int
        Monte Carlo realizations (>= 1).
    seed : int, SeedSequence or None
        Root of the random streams.
    alpha, threshold, correction, stft, config, band, frame_threshold
        As in :func:`~chatterspec.detection.detect.detect_chunks`.
    gamma : float
        SVSF convergence rate in (0, 1).
    workers : int
        Local worker processes (1: in this process).
    scheduler : str, optional
        ``"local-dask"`` or a Dask scheduler address (see :func:`~chatterspec.studies.montecarlo.run_study`).
    progress : bool, optional
        Progress bar on stderr (default: on a terminal).
    identification : IdentificationStream, optional
        Fault identification of every chunk on the workers too, added to this stream in chunk order
        (the serial ``IdentificationStream.tap`` numbers).

    Returns
    -------
    DetectionReport
        Equal to ``detect_chunks(iter_chattering(scenario, runs, seed, chunk_runs=DETECT_CHUNK_RUNS), ...)``.

    See Also
    --------
    chatterspec.detection.detect.detect_chunks : the serial path.
    """
    from ..montecarlo import run_study
    from ..rng import root_seed_sequence

    runs = positive_int("runs", runs)
    root = root_seed_sequence(seed)
    first = next(iter_chattering(scenario, 1, root, chunk_runs=1, gamma=gamma))  # realization 0
    options = DetectorOptions(alpha, threshold, correction, stft, config, band, frame_threshold)
    plan = ChunkPlan.build(first, options)
    ident = (
        None
        if identification is None
        else (identification.setup, identification.alpha, identification.confidence)
    )
    study = _DetectStudy(scenario, plan, gamma, ident)
    acc = run_study(
        study,
        runs,
        root,
        workers=workers,
        scheduler=scheduler,
        chunk_runs=min(runs, DETECT_CHUNK_RUNS),
        progress=progress,
        label=f"detect {scenario.name}",
    )
    acc, parts = acc
    for part in parts:
        identification.add(part)
    return plan.report(acc)
