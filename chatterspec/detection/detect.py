"""Detection verdicts, severity scores and onset/offset localization (``docs/design.md`` §6).

This module runs a record or a study (:func:`detect_record`, :func:`detect_chunks`,
:func:`detect_scenario`); the verdicts live in :mod:`~chatterspec.detection.spectrum_verdicts`
(whole records), :mod:`~chatterspec.detection.frames` (STFT frames) and the report in
:mod:`~chatterspec.detection.report`.

A channel is flagged when its spectrum exceeds the threshold at any **tested** bin; where the fault
is (``peak_hz``, ``most_significant_hz``) and how large (``peak_ratio``, ``excess_power``) are defined
in :mod:`~chatterspec.detection.spectrum_verdicts`. The default detector is the ``exact`` threshold
with Bonferroni correction at family-wise alpha = 0.1 %.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Unpack

from .._validate import positive_int
from ..errors import ParameterError
from ..montecarlo import Execution, SeedLike
from ..plants.scenarios import Scenario
from ._chunk_plan import ChunkPlan, DetectorKeywords, DetectorOptions, detect_on_workers
from .pipeline import ChatteringRecord, iter_chattering
from .report import DetectionReport
from .thresholds import Correction, Threshold

if TYPE_CHECKING:  # pragma: no cover
    from .identification import IdentificationStream

__all__ = [
    "DETECT_CHUNK_RUNS",
    "DetectionReport",
    "DetectorKeywords",
    "DetectorOptions",
    "detect_chunks",
    "detect_record",
    "detect_scenario",
]


#: Realizations per chunk of :func:`detect_scenario` (EHA: ~100 MB of working arrays per chunk).
DETECT_CHUNK_RUNS = 256


def detect_record(
    record: ChatteringRecord,
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    **detector: Unpack[DetectorKeywords],
) -> DetectionReport:
    """Detect model mismatch in a chattering record (default: exact + Bonferroni, family-wise 0.1 %).

    Parameters
    ----------
    record : ChatteringRecord
        ``values`` (runs, N, m) and the nominal model.
    alpha, threshold, correction
        False-alarm probability in (0, 1), threshold kind (``"exact"``, ``"paper"`` or a ready
        :class:`~chatterspec.detection.thresholds.Threshold`) and multiple-test correction
        (``"bonferroni"``, ``"sidak"``, ``"none"``), as documented in :class:`DetectorOptions`.
    **detector
        ``stft``, ``config``, ``band``, ``frame_threshold``: the STFT intervals on run 0 (by default
        when the record's scenario has more than one segment), their settings, the band in Hz of the
        tested bins and a per-frame threshold (:class:`DetectorOptions`).

    Notes
    -----
    With ``runs > 1`` the report holds every run's verdict (detection rate per
    channel, single-record threshold) and the verdict of the averaged spectrum
    against the averaged ``exact`` threshold with K = runs at ``alpha`` with
    ``correction`` (family-wise by default) **whatever the single-record rule**:
    the paper's per-bin rule applied to ~2000 averaged bins would flag most
    healthy averages. Runs are assumed independent realizations. Identical to
    :func:`detect_chunks` on the record split in chunks.
    """
    if not isinstance(record, ChatteringRecord):
        raise ParameterError(f"record must be a ChatteringRecord; got {type(record).__name__}")
    return _detect([record], DetectorOptions(alpha, threshold, correction, **detector))


def detect_chunks(
    chunks: Iterable[ChatteringRecord],
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    **detector: Unpack[DetectorKeywords],
) -> DetectionReport:
    """:func:`detect_record` over a stream of chunks of realizations, in memory bounded by one chunk.

    Each chunk's periodograms are tested and dropped: only the per-run verdict
    scalars (``(runs, m)``, 48 bytes per run and channel), the running sum of the
    spectra (for the averaged verdict) and run 0's STFT are kept.

    Parameters
    ----------
    chunks : iterable of ChatteringRecord
        Chunks of one study (same model, length and scenario), e.g.
        :func:`chatterspec.detection.pipeline.iter_chattering`.
    alpha, threshold, correction, **detector
        As in :func:`detect_record` (:class:`DetectorOptions`).

    Raises
    ------
    ParameterError
        If ``chunks`` is empty or its records do not belong to one study.

    See Also
    --------
    detect_scenario : the chunks of a scenario, simulated here or on worker processes.
    """
    return _detect(chunks, DetectorOptions(alpha, threshold, correction, **detector))


def _detect(chunks: Iterable[ChatteringRecord], options: DetectorOptions) -> DetectionReport:
    """:func:`detect_chunks` with its settings in one object."""
    it = iter(chunks)
    first = next(it, None)
    if first is None:
        raise ParameterError("no chattering record to detect (empty chunk stream)")
    plan = ChunkPlan.build(first, options)
    acc = None
    record: ChatteringRecord | None = first
    while record is not None:
        if record is not first and record.model is not plan.model:
            if record.model.fingerprint() != plan.model.fingerprint():
                raise ParameterError("all chunks must share the nominal model of the first chunk")
        acc = plan.reduce(acc, plan.test(record.values))
        record = next(it, None)
    assert acc is not None  # (the first chunk was folded)
    return plan.report(acc)


def detect_scenario(
    scenario: Scenario,
    runs: int = 1,
    seed: SeedLike = None,
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    *,
    chunk_runs: int | None = DETECT_CHUNK_RUNS,
    gamma: float = 0.1,
    identification: IdentificationStream | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool | None = None,
    **detector: Unpack[DetectorKeywords],
) -> DetectionReport:
    """Simulate, filter and detect ``runs`` realizations of ``scenario`` chunk by chunk (bounded memory).

    Same numbers as ``detect_record(scenario_chattering(scenario, runs, seed), ...)``
    (verdicts identical; the averaged spectrum summed chunk by chunk, equal to
    rounding), with peak memory set by ``chunk_runs``, not by ``runs``; the same report, bit for
    bit, whatever ``workers`` or ``scheduler`` (``chatterspec detect --workers N``).

    Parameters
    ----------
    scenario : Scenario
        Catalogue or user scenario.
    runs : int
        Monte Carlo realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams (realization r is the same whatever the chunking).
    alpha, threshold, correction, **detector
        As in :func:`detect_record` (:class:`DetectorOptions`).
    chunk_runs : int, optional
        Realizations per chunk (default 256; None: the simulator's memory-sized default in this
        process, :data:`~chatterspec.montecarlo.DEFAULT_CHUNK_RUNS` on workers).
    gamma : float
        SVSF convergence rate in (0, 1) (eq 8-10).
    identification : IdentificationStream, optional
        Fault identification of every chunk too, added to this stream in chunk order (the
        serial ``IdentificationStream.tap`` numbers); the chunks then run through
        :func:`~chatterspec.montecarlo.run_study` even with one worker.
    workers, scheduler, progress
        Local worker processes, Dask scheduler and progress bar of
        :class:`~chatterspec.montecarlo.Execution`. With one worker, no scheduler and no
        ``identification`` the chunks stream through this process (no progress bar); otherwise
        the thresholds and run 0's STFT intervals come from a one-run record here and every chunk
        is simulated, filtered and tested by :func:`~chatterspec.montecarlo.run_study`.
    """
    runs = positive_int("runs", runs)
    options = DetectorOptions(alpha, threshold, correction, **detector)
    if workers == 1 and scheduler is None and identification is None:
        chunks = iter_chattering(scenario, runs, seed, chunk_runs=chunk_runs, gamma=gamma)
        return _detect(chunks, options)
    ex = Execution(workers=workers, scheduler=scheduler, chunk_runs=chunk_runs, progress=progress)
    return detect_on_workers(scenario, runs, seed, options, ex, gamma=gamma, identification=identification)
