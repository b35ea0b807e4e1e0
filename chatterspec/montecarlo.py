"""Monte Carlo realizations: reproducible random streams that do not depend on how the work is
chunked, and chunked execution (serial, local processes or Dask) with identical results.

In the package base so that the simulations, detection
(:func:`chatterspec.detection.detect.detect_scenario` with ``workers``) and the studies all use it.

Realizations are grouped in fixed blocks of :data:`BLOCK` realizations; block ``b`` draws from its
own generator (:func:`block_generator`), built from the root :class:`numpy.random.SeedSequence`
(:func:`root_seed_sequence`) with ``spawn_key = root.spawn_key + (b,)``. Any chunking of the
realization axis (in-process chunks, local worker processes, a Dask cluster) therefore produces the
same numbers for the same seed, and no global random state is ever touched.

A *study* is a picklable object with two methods:

``run_chunk(first_run, runs, seed) -> summary``
    A pure function of the realizations ``first_run .. first_run + runs - 1``
    and the root :class:`numpy.random.SeedSequence`; it returns small summary
    arrays (sums, counts, histograms, per-run scalars), never per-run spectra.
``reduce(acc, part) -> summary``
    Folds one chunk's summary into the accumulator (``acc`` is ``None`` for
    the first chunk).

The realization axis is cut into chunks whose boundaries are multiples of
:data:`BLOCK` and do not depend on the executor or on the
number of workers; realization ``r`` always draws from random block
``r // BLOCK``, and chunk summaries are folded in
chunk order whatever order they complete in. The same seed therefore gives
bit-identical results with 1 worker, N local processes or a Dask cluster.
Memory stays constant: at most ``2 * workers`` chunks are in flight and
out-of-order results wait in a buffer of the same bound; :func:`fix_mmap_threshold` (called by the
command line and the worker processes) keeps the peak resident memory independent of ``--runs``.

Examples
--------
>>> from chatterspec.montecarlo import run_study
>>> class Count:
...     def run_chunk(self, first_run, runs, seed):
...         return runs
...     def reduce(self, acc, part):
...         return part if acc is None else acc + part
>>> run_study(Count(), runs=1000, seed=0)
1000
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypedDict, runtime_checkable

import numpy as np

from ._validate import positive_int
from .errors import ChatterspecError, ParameterError
from .progress import Progress

if TYPE_CHECKING:  # pragma: no cover
    from concurrent.futures import Future

__all__ = [
    "BLOCK",
    "DEFAULT_CHUNK_RUNS",
    "Chunk",
    "Execution",
    "ExecutionOptions",
    "SeedLike",
    "Study",
    "block_generator",
    "plan_chunks",
    "root_seed_sequence",
    "run_chunk",
    "run_study",
    "seed_label",
]


# --- random streams per block of realizations ----------------------------------------------------------
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


# --- chunked execution ---------------------------------------------------------------------------------
#: Default realizations per chunk (a multiple of :data:`BLOCK`).
DEFAULT_CHUNK_RUNS = 2 * BLOCK

#: Seconds allowed to connect to a Dask scheduler before giving up.
DASK_CONNECT_TIMEOUT_S = 5.0


@runtime_checkable
class Study(Protocol):
    """What :func:`run_study` needs from a study (see the module docstring)."""

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> Any:
        """The small summary of realizations ``first_run .. first_run + runs - 1`` drawn from ``seed``."""
        ...

    def reduce(self, acc: Any, part: Any) -> Any:
        """``acc`` with one chunk's summary ``part`` folded in (``acc`` is None for the first chunk)."""
        ...


@dataclass(frozen=True)
class Chunk:
    """Realizations ``[first_run, first_run + runs)``, the ``index``-th chunk of a study."""

    index: int
    first_run: int
    runs: int


def plan_chunks(runs: int, chunk_runs: int | None = None) -> tuple[Chunk, ...]:
    """Cut ``runs`` realizations into chunks aligned to :data:`BLOCK`.

    Parameters
    ----------
    runs : int
        Total realizations (>= 1).
    chunk_runs : int, optional
        Realizations per chunk, rounded up to a multiple of ``BLOCK``
        (default :data:`DEFAULT_CHUNK_RUNS`). Only the last chunk may be shorter.

    Returns
    -------
    tuple of Chunk
    """
    return _chunks(positive_int("runs", runs), Execution(chunk_runs=chunk_runs).chunk_runs)


def _chunks(runs: int, chunk_runs: int | None) -> tuple[Chunk, ...]:
    """:func:`plan_chunks` of checked values."""
    size = DEFAULT_CHUNK_RUNS if chunk_runs is None else chunk_runs
    size = -(-size // BLOCK) * BLOCK
    return tuple(Chunk(i, lo, min(size, runs - lo)) for i, lo in enumerate(range(0, runs, size)))


def run_chunk(study: Study, chunk: Chunk, seed: np.random.SeedSequence) -> tuple[int, int, Any]:
    """Worker entry point: ``(chunk.index, chunk.runs, study.run_chunk(...))`` (module level, picklable).

    :func:`run_study` submits this function to the serial loop, the process pool
    or the Dask client alike, and reorders the returned tuples by ``chunk.index``.

    Parameters
    ----------
    study : Study
        Object whose ``run_chunk(first_run, runs, seed)`` computes the chunk's summary.
    chunk : Chunk
        The realizations ``[chunk.first_run, chunk.first_run + chunk.runs)`` to run.
    seed : numpy.random.SeedSequence
        The study's root seed sequence (the same for every chunk); realization r
        draws from block ``r // BLOCK`` under it, so results do not depend on chunking.

    Returns
    -------
    tuple of (int, int, Any)
        ``(chunk.index, chunk.runs, summary)``.
    """
    return chunk.index, chunk.runs, study.run_chunk(chunk.first_run, chunk.runs, seed)


def run_study(
    study: Study,
    runs: int,
    seed: SeedLike = 0,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    chunk_runs: int | None = None,
    progress: bool | None = None,
    label: str = "monte carlo",
) -> Any:
    """Run ``study`` over ``runs`` realizations and return the reduced summary.

    Parameters
    ----------
    study : Study
        Picklable object with ``run_chunk`` and ``reduce``.
    runs : int
        Number of realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams; the result depends on it and on ``runs``
        (and on ``chunk_runs`` only through floating-point summation order),
        never on ``workers`` or ``scheduler``.
    workers, scheduler, chunk_runs, progress
        Where and in what chunks the study runs, and whether a progress bar shows: see
        :class:`Execution` (whose :meth:`~Execution.run` calls this function with them).
    label : str
        Progress bar label.

    Returns
    -------
    object
        ``study.reduce`` folded over the chunk summaries in chunk order.

    Raises
    ------
    ParameterError
        ``runs`` or ``workers`` < 1.
    ChatterspecError
        The Dask scheduler does not answer within a few seconds, or
        ``dask.distributed`` is not installed.
    """
    return Execution(workers, scheduler, chunk_runs, progress).run(study, runs, seed, label)


class ExecutionOptions(TypedDict, total=False):
    """The keywords ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` of a study function.

    Every Monte Carlo study (``calibrate``, ``false_alarm_study``, ``power_study``, ...) takes them as
    ``**execution`` and runs with ``Execution(**execution)``; :class:`Execution` documents them.
    """

    workers: int
    scheduler: str | None
    chunk_runs: int | None
    progress: bool | None


@dataclass(frozen=True)
class Execution:
    """How a Monte Carlo study runs: where, in what chunks, with or without a progress bar.

    The settings never change a study's numbers (chunk boundaries aside, which move only the
    floating-point summation order of some sums); they are what every study function accepts as its
    ``workers``, ``scheduler``, ``chunk_runs`` and ``progress`` keywords.

    Parameters
    ----------
    workers : int
        Local worker processes (1 = in-process, serial). With a Dask ``scheduler`` it is the number
        of workers of ``local-dask``.
    scheduler : str, optional
        ``None`` (local processes), ``"local-dask"`` (a Dask ``LocalCluster`` on loopback, started
        and closed per run) or the address of a running Dask scheduler (``tcp://host:8786``).
        Needs the ``chatterspec[distributed]`` extra.
    chunk_runs : int, optional
        Realizations per chunk, rounded up to a multiple of :data:`BLOCK`
        (default :data:`DEFAULT_CHUNK_RUNS`; see :func:`plan_chunks`).
    progress : bool, optional
        Show a progress bar on stderr (default: only when stderr is a terminal).

    Raises
    ------
    ParameterError
        ``workers`` or ``chunk_runs`` not an integer >= 1, or an empty ``scheduler``.

    See Also
    --------
    run_study : the runner these settings are passed to.
    ExecutionOptions : the same settings as the ``**execution`` keywords of the study functions.

    Examples
    --------
    >>> from chatterspec.montecarlo import Execution
    >>> Execution(workers=2).chunk_runs is None
    True
    """

    workers: int = 1
    scheduler: str | None = None
    chunk_runs: int | None = None
    progress: bool | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "workers", positive_int("workers", self.workers))
        if self.chunk_runs is not None:
            object.__setattr__(self, "chunk_runs", positive_int("chunk_runs", self.chunk_runs))
        if self.scheduler is not None and not (isinstance(self.scheduler, str) and self.scheduler.strip()):
            raise ParameterError(f"scheduler must be 'local-dask' or an address; got {self.scheduler!r}")

    def run(self, study: Study, runs: int, seed: SeedLike, label: str = "monte carlo") -> Any:
        """Run ``study`` over ``runs`` realizations with these settings (:func:`run_study`).

        Parameters
        ----------
        study, runs, seed, label
            As in :func:`run_study`.

        Returns
        -------
        object
            ``study.reduce`` folded over the chunk summaries in chunk order.
        """
        runs = positive_int("runs", runs)
        if not (callable(getattr(study, "run_chunk", None)) and callable(getattr(study, "reduce", None))):
            raise ParameterError(f"study must define run_chunk() and reduce(); got {type(study).__name__}")
        root = root_seed_sequence(seed)
        chunks = _chunks(runs, self.chunk_runs)
        with Progress(runs, label, enabled=self.progress) as bar:
            if self.scheduler is not None:
                results = _dask_results(study, chunks, root, self.scheduler, self.workers)
            elif self.workers == 1 or len(chunks) == 1:
                results = (run_chunk(study, c, root) for c in chunks)
            else:
                results = _process_results(study, chunks, root, self.workers)
            return _fold_in_order(study, results, len(chunks), bar)


def _fold_in_order(
    study: Study, results: Iterator[tuple[int, int, Any]], n_chunks: int, bar: Progress
) -> Any:
    """Fold results arriving in any order into ``study.reduce`` in chunk-index order."""
    acc: Any = None
    pending: dict[int, Any] = {}
    nxt = 0
    for index, n, part in results:
        pending[index] = part
        bar.update(n)
        while nxt in pending:
            acc = study.reduce(acc, pending.pop(nxt))
            nxt += 1
    if nxt != n_chunks:  # pragma: no cover - executors always deliver every chunk
        raise ChatterspecError(f"Monte Carlo run lost chunks: got {nxt} of {n_chunks}")
    return acc


def _bounded_submit(
    submit: Callable[[Chunk], Any],
    chunks: tuple[Chunk, ...],
    in_flight: int,
    wait_some: Callable[[set], tuple[set, set]],
    result_of: Callable[[Any], tuple[int, int, Any]],
) -> Iterator[tuple[int, int, Any]]:
    todo = iter(chunks)
    running: set = set()
    for c in todo:
        running.add(submit(c))
        if len(running) >= in_flight:
            break
    while running:
        done, running = wait_some(running)
        for fut in done:
            yield result_of(fut)
            nxt = next(todo, None)
            if nxt is not None:
                running.add(submit(nxt))


def _process_results(
    study: Study, chunks: tuple[Chunk, ...], root: np.random.SeedSequence, workers: int
) -> Iterator[tuple[int, int, Any]]:
    # imported here: the seeding above is imported by every simulation, the process pool only here
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    ctx = multiprocessing.get_context("spawn")
    n = min(workers, len(chunks))
    # one BLAS thread per worker: the cores are shared out by processes
    env_keys = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
    saved = {k: os.environ.get(k) for k in env_keys}
    for k in env_keys:
        os.environ[k] = "1"
    try:
        with ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=fix_mmap_threshold) as pool:

            def wait_some(running: set[Future]) -> tuple[set, set]:
                done, rest = wait(running, return_when=FIRST_COMPLETED)
                return set(done), set(rest)

            yield from _bounded_submit(
                lambda c: pool.submit(run_chunk, study, c, root),
                chunks,
                2 * n,
                wait_some,
                lambda f: f.result(),
            )
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _import_dask() -> Any:
    try:
        import dask.distributed as dd
    except ImportError as exc:
        raise ChatterspecError(
            "--scheduler needs dask.distributed; install the extra: pip install 'chatterspec[distributed]'"
        ) from exc
    return dd


def dask_client(scheduler: str, workers: int = 2) -> tuple[Any, Any]:
    """Connect to ``scheduler`` (or start ``local-dask``); return ``(client, cluster_or_None)``.

    ``scheduler`` is checked by :class:`Execution`.

    An address that does not answer raises :class:`ChatterspecError` after
    :data:`DASK_CONNECT_TIMEOUT_S` seconds.
    """
    dd = _import_dask()
    if scheduler == "local-dask":
        cluster = dd.LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            host="127.0.0.1",
            dashboard_address=None,
        )
        try:
            return dd.Client(cluster, timeout=f"{DASK_CONNECT_TIMEOUT_S}s"), cluster
        except Exception:
            cluster.close()
            raise
    address = scheduler if "://" in scheduler else f"tcp://{scheduler}"
    try:
        client = dd.Client(address, timeout=f"{DASK_CONNECT_TIMEOUT_S}s")
    except Exception as exc:  # OSError, TimeoutError, or garbage from a non-Dask service
        raise ChatterspecError(
            f"cannot reach the Dask scheduler at {address!r} within {DASK_CONNECT_TIMEOUT_S:g} s "
            f"({type(exc).__name__}: {exc}); start one with `dask scheduler` or use --scheduler local-dask"
        ) from None
    return client, None


def _dask_results(
    study: Study, chunks: tuple[Chunk, ...], root: np.random.SeedSequence, scheduler: str, workers: int
) -> Iterator[tuple[int, int, Any]]:
    dd = _import_dask()
    client, cluster = dask_client(scheduler, workers)
    try:
        n_workers = max(1, len(client.scheduler_info(n_workers=-1).get("workers", {})) or workers)
        study_f = client.scatter(study, broadcast=True)

        def wait_some(running: set) -> tuple[set, set]:
            res = dd.wait(list(running), return_when="FIRST_COMPLETED")
            return set(res.done), set(res.not_done)

        def result_of(fut: Any) -> tuple[int, int, Any]:
            out = fut.result()
            fut.release()
            return out

        yield from _bounded_submit(
            lambda c: client.submit(run_chunk, study_f, c, root, pure=False),
            chunks,
            2 * n_workers,
            wait_some,
            result_of,
        )
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


# --- process memory: a fixed glibc mmap threshold, so that freed large arrays go back to the OS ---------
#
# glibc's ``malloc`` raises its mmap threshold each time a large ``mmap``-ed block is freed (up to
# 32 MiB on 64-bit), after which arrays of a few MiB come from the heap instead; a chunked Monte
# Carlo loop that allocates and frees such arrays in varying sizes then fragments the heap, and the
# peak resident memory creeps up with the number of chunks, i.e. with ``--runs`` (measured:
# ``chatterspec detect eha-healthy`` 427 MB at 2 560 runs, 499 MB at 10 240 runs; tracemalloc's
# peak of live Python/numpy memory stays at 186 MB in both). Setting ``M_MMAP_THRESHOLD`` once
# disables that adaptation: every block of ``MMAP_THRESHOLD_BYTES`` or more is ``mmap``-ed and
# returned to the OS when freed. Measured on ``detect eha-healthy`` at 2 560 / 10 240 runs (peak
# RSS) and ``far eha-healthy --runs 3000`` (system CPU time of the page faults, default 0.6 s):
# 128 KiB 391 / 392 MB, 2.7 s; 1 MiB 391 / 392 MB, 2.7 s; **8 MiB 396 / 396 MB, 1.3 s**;
# 32 MiB 438 / 438 MB, 1.0 s. 8 MiB keeps the peak flat at ~10 % more CPU time on ``far``.
#
# Only the command-line interface and the worker processes of :func:`run_study` call
# :func:`fix_mmap_threshold`; importing chatterspec as a library leaves the host process's allocator
# alone.

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
