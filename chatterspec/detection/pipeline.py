"""Scenario -> simulation -> auxiliary SVSF -> chattering record, in constant-memory chunks.

The chattering record drops sample 0 (there is no prediction of z(0)), so a
4 s record at 1 ms gives N = 4000 chattering samples ``e(k|k-1)``, k = 1..N,
exactly the sequence of eq (49).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import positive_int
from ..filters.svsf import auxiliary_svsf, nonlinear_chattering
from ..filters.svsf_recursion import closed_form_step
from ..filters.svsf_recursion import rows_times as _rows_times
from ..montecarlo import BLOCK, SeedLike, block_generator, root_seed_sequence
from ..plants.nonlinear import Model, is_linear, require_linear
from ..plants.scenarios import Scenario
from ..plants.simulate import (
    NO_CTRL,
    Simulation,
    chunk_runs_of,
    iter_simulations,
    kernel_tables,
    plant_loop,
    same_shapes,
    scenario_input,
)

__all__ = ["ChatteringRecord", "chattering_record", "iter_chattering", "scenario_chattering"]


@dataclass(frozen=True, eq=False)
class ChatteringRecord:
    """Chattering of the auxiliary (sgn) SVSF for one or many realizations.

    Attributes
    ----------
    t : (N,) array
        Times in seconds of the chattering samples (``t[j] = (j + 1) dt``).
    values : (runs, N, m) array
        ``e(k|k-1)`` per realization, sample and measured channel.
    model : LinearModel
        Nominal model of the filter (defines the expected healthy spectrum).
    scenario : Scenario or None
        The scenario simulated, if any.
    first_run : int
        Global index of the first realization (chunks of a larger study).
    z : (runs, N + 1, m) array or None
        The measurements z(0) .. z(N) the chattering came from, when kept (fault
        identification, :mod:`chatterspec.detection.identification`, regresses on them).
    u : (N + 1, p) or (runs, N + 1, p) array or None
        The inputs u(0) .. u(N), when kept.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    t: np.ndarray
    values: np.ndarray
    model: Model
    scenario: Scenario | None = None
    first_run: int = 0
    z: np.ndarray | None = None
    u: np.ndarray | None = None

    @property
    def dt(self) -> float:
        """Sampling time (s)."""
        return self.model.dt

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.values.shape[0]

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return self.values.shape[1]

    @property
    def channels(self) -> tuple[str, ...]:
        """Output channel names."""
        return self.model.output_names


def chattering_record(
    model: Model,
    z: np.ndarray,
    u: np.ndarray | None = None,
    *,
    t0: float = 0.0,
    gamma: float = 0.1,
    x0: np.ndarray | None = None,
    scenario: Scenario | None = None,
    first_run: int = 0,
) -> ChatteringRecord:
    """Run the auxiliary SVSF on measurements ``z`` (runs, T, m) and keep samples 1..T-1.

    The chattering is the a priori error ``e(k|k-1)`` of the sgn-switching SVSF,
    eq (17); sample 0 (no prediction of z(0)) is dropped, leaving N = T - 1 samples.

    Parameters
    ----------
    model : LinearModel
        Nominal model of the filter (A-hat, B-hat, C-hat of eq 4-5); its
        ``dt`` (s) sets the time axis.
    z : (runs, T, m) or (T, m) array
        Measurements z(0) .. z(T-1); a 2-D array is treated as one realization.
    u : (T, p), (runs, T, p) or (T,) array, optional
        Inputs u(0) .. u(T-1); None: no input (zeros).
    t0 : float
        Time of ``z[..., 0, :]`` in seconds; the record's times are
        ``t0 + k dt`` for k = 1..T-1.
    gamma : float
        SVSF convergence rate in (0, 1) (eq 8-10).
    x0 : array, optional
        Initial estimate x(0|0); default ``C^-1 z(0)``.
    scenario : Scenario, optional
        Scenario that produced ``z``, stored in the record as metadata.
    first_run : int
        Global index of the first realization in ``z`` (for chunks of a larger study).

    Returns
    -------
    ChatteringRecord
        ``values`` of shape (runs, T - 1, m).
    """
    if u is None:  # no input (docs/filters.md)
        u = np.zeros((np.shape(z)[-2], model.n_inputs))
    if not is_linear(model):  # nonlinear nominal model: filters/svsf (full measurement)
        e = nonlinear_chattering(model, z, u, gamma=gamma, x0=x0)
    else:
        require_linear(model, "the chattering pipeline (auxiliary sgn-SVSF of eq 8-11)")
        e = auxiliary_svsf(model, gamma).run(z, u, x0=x0).e_prior
    if e.ndim == 2:
        e = e[None]
    T = e.shape[1]
    t = t0 + np.arange(1, T) * model.dt
    z = np.asarray(z, dtype=float)
    return ChatteringRecord(
        t=t,
        values=e[:, 1:],
        model=model,
        scenario=scenario,
        first_run=first_run,
        z=z[None] if z.ndim == 2 else z,
        u=np.asarray(u, dtype=float),
    )


def _from_simulation(sim: Simulation, gamma: float) -> ChatteringRecord:
    sc = sim.scenario
    return chattering_record(sc.nominal, sim.z, sim.u, gamma=gamma, scenario=sc, first_run=sim.first_run)


@_jit.step
def chattering_sink(
    row: int,
    k: int,
    x: np.ndarray,
    z: np.ndarray,
    zp: np.ndarray,
    e_out: np.ndarray,
    z_out: np.ndarray,
    PhiT: np.ndarray,
    Gu: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """The auxiliary SVSF's chattering of each simulated sample: the sink of the fused loop.

    ``e_out[row, i, k - 1] = e_i(k|k-1)`` by :func:`~chatterspec.filters.svsf_recursion.closed_form_step`
    (eq 23) from ``z(k)``, ``zp = z(k-1)`` and ``Gu[k - 1]`` = G u(k-1), for k >= 1; then ``zp = z(k)``.
    Channel-major output, so that each channel's record is contiguous for the periodogram's FFT.
    With a non-empty ``z_out`` (``(runs * m, T)``: the ``(runs, m, T)`` channel-major measurements)
    ``z(k)`` is kept too (fault identification regresses on it).
    """
    if k > 0:
        for i in range(m):
            e_out[row, i, k - 1] = closed_form_step(i, z[i], Gu[k - 1, i], PhiT, zp, m)
    for i in range(m):
        zp[i] = z[i]
    if z_out.shape[0] > 0:
        for i in range(m):
            z_out[row * m + i, k] = z[i]


#: Simulation (eq 1-2) and the auxiliary SVSF's chattering (eq 23) fused, one block of runs:
#: ``_chattering_kernel(v, w, seg_idx, A, C, Lq, Lr, Bu, x0, diag, ctrl, e_out, NO_ARRAY, PhiT, Gu,
#: offset)``. The plant steps of :func:`chatterspec.plants.simulate.simulate` and the closed-form
#: step of ``SVSF.update``, so the result is bit-identical to filtering the simulation; only x(k),
#: z(k), z(k-1) of the current run are held (no ``(runs, T, n)`` arrays).
_chattering_kernel = _jit.specialize(plant_loop, "chattering", SINK=chattering_sink)

#: The plant loop :func:`_rng_loop` calls for each run (bound per size, see :func:`_rng_kernel`).
RUN = _chattering_kernel


def _rng_loop(
    g0: np.random.Generator,
    g1: np.random.Generator,
    skip: int,
    runs: int,
    seg_idx: np.ndarray,
    A: np.ndarray,
    C: np.ndarray,
    Lq: np.ndarray,
    Lr: np.ndarray,
    Bu: np.ndarray,
    x0: np.ndarray,
    diag: np.ndarray,
    ctrl: np.ndarray,
    PhiT: np.ndarray,
    Gu: np.ndarray,
    e_out: np.ndarray,
    offset: int,
    z_out: np.ndarray | None = None,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_e2e_kernels.py)
    """``RUN`` (the fused loop) on runs ``skip .. skip + runs - 1`` of one random block, drawing as it goes.

    ``g0`` and ``g1`` are the block's generators (streams 0 and 1 of
    :func:`chatterspec.montecarlo.block_generator`). ``standard_normal((BLOCK, T, n))`` fills its
    array in C order, one number after the other from the same stream, so drawing run r's
    ``(T, n)`` numbers when run r starts (after discarding the ``skip`` runs before it) gives
    the same numbers; numba's ``Generator.standard_normal`` is numpy's ziggurat on the same
    bit generator (tests/test_e2e_kernels.py compares them). Only one run's noise is held (2 x 96
    kB for the EHA's 4001 x 3, in the core's L2 cache), not ``(BLOCK, T, n)`` arrays. ``z_out``
    (``(runs * m, T)``, optional) receives the measurements (see :func:`chattering_sink`).
    """
    T = seg_idx.shape[0]
    n = A.shape[1]
    m = C.shape[1]
    for _ in range(skip * T * n):
        g0.standard_normal()
    for _ in range(skip * T * m):
        g1.standard_normal()
    v = np.empty((1, T, n))
    w = np.empty((1, T, m))
    keep = np.empty((0, 0)) if z_out is None else z_out
    for r in range(runs):
        for k in range(T):
            for i in range(n):
                v[0, k, i] = g0.standard_normal()
        for k in range(T):
            for i in range(m):
                w[0, k, i] = g1.standard_normal()
        RUN(v, w, seg_idx, A, C, Lq, Lr, Bu, x0, diag, ctrl, e_out, keep, PhiT, Gu, offset + r)


#: :func:`_rng_loop` for any size (the per-size kernels of :func:`_rng_kernel` give the same bits).
_chattering_rng_kernel = _jit.specialize(_rng_loop, "any")


def _rng_kernel(n: int, m: int) -> Callable[..., None]:
    """The drawing loop whose fused loop has this model's sizes as constants when small (unrolled).

    For the EHA's 3 x 3 this runs the arithmetic at the speed of the loop written out by hand
    (119 against 39 M steps/s for the loops over 3-element vectors), with the same steps.
    """
    run = _jit.specialize_sizes(plant_loop, "chattering", {"NX": n, "NZ": m}, SINK=chattering_sink)
    return _jit.specialize_sizes(_rng_loop, "rng", {"NX": n, "NZ": m}, RUN=run)


def _fused_chattering(
    scenario: Scenario,
    runs: int,
    seed: SeedLike,
    chunk_runs: int | None,
    first_run: int,
    gamma: float,
    measurements: bool = False,
    reuse: bool = False,
) -> Iterator[ChatteringRecord]:
    """:func:`iter_chattering` through :func:`_chattering_kernel` (same numbers, no x arrays; z only
    with ``measurements``)."""
    model = scenario.nominal
    f = auxiliary_svsf(model, gamma)
    root = root_seed_sequence(seed)
    t, u = scenario_input(scenario)
    T, m = len(t), model.n_outputs
    tb = kernel_tables(scenario, t, u)
    Gu = np.ascontiguousarray(_rows_times(u[:-1], f._GT), dtype=float)  # as SVSF.update computes it
    PhiT = np.ascontiguousarray(f._PhiT, dtype=float)
    times = np.arange(1, T) * model.dt
    chunk = chunk_runs_of(scenario, chunk_runs)
    kernel = _rng_kernel(model.n_states, m)
    z_buf = None
    for lo in range(first_run, first_run + runs, chunk):
        hi = min(lo + chunk, first_run + runs)
        e = np.empty((hi - lo, m, T - 1))  # channel-major storage (contiguous FFT lines)
        if not measurements:
            z = None
        elif not reuse or z_buf is None or z_buf.shape[0] < hi - lo:
            z = z_buf = np.empty((hi - lo, m, T))
        else:  # the previous record's buffer: no fresh pages to fault in per chunk
            z = z_buf[: hi - lo]
        for b in range(lo // BLOCK, (hi - 1) // BLOCK + 1):  # the random blocks overlapping [lo, hi)
            s0, s1 = max(b * BLOCK, lo), min((b + 1) * BLOCK, hi)
            g0, g1 = block_generator(root, b, 0), block_generator(root, b, 1)
            args = (
                tb.seg_idx,
                tb.A,
                tb.C,
                tb.Lq,
                tb.Lr,
                tb.Bu,
                tb.x0,
                tb.diag,
                NO_CTRL,
                PhiT,
                Gu,
                e,
                s0 - lo,
            )
            if z is None:
                kernel(g0, g1, s0 - b * BLOCK, s1 - s0, *args)
            else:
                kernel(g0, g1, s0 - b * BLOCK, s1 - s0, *args, z.reshape(-1, T))
        values = e.transpose(0, 2, 1)  # the (runs, N, m) view of the package convention
        yield ChatteringRecord(
            t=times,
            values=values,
            model=model,
            scenario=scenario,
            first_run=lo,
            z=None if z is None else z.transpose(0, 2, 1),
            u=u if measurements else None,
        )


def can_fuse(scenario: Scenario) -> bool:
    """Whether the fused simulate-and-filter kernel covers ``scenario``.

    It covers the closed-form case: compiled kernels, full measurement, T >= 2, open loop, every
    segment with the nominal's dimensions. The command line uses it to choose its progress display.
    """
    model = scenario.nominal
    return (
        _jit.enabled()
        and _jit.fits(model.n_states, model.n_outputs, vectors_only=True)
        and getattr(scenario, "closed_loop", None) is None
        and getattr(scenario, "is_linear", True)
        and model.full_measurement
        and scenario.n_samples >= 2
        and same_shapes(scenario)
    )


def iter_chattering(
    scenario: Scenario,
    runs: int,
    seed: SeedLike = None,
    *,
    chunk_runs: int | None = None,
    first_run: int = 0,
    gamma: float = 0.1,
    measurements: bool = False,
    reuse_measurements: bool = False,
) -> Iterator[ChatteringRecord]:
    """Simulate and filter ``runs`` realizations chunk by chunk (constant memory).

    Realization ``r`` gets the same noise whatever the chunking (see :mod:`chatterspec.montecarlo`).
    Each chunk of :func:`~chatterspec.plants.simulate.iter_simulations` is filtered by the
    auxiliary SVSF built on ``scenario.nominal``.

    Parameters
    ----------
    scenario : Scenario
        Nominal model, true plant, input and duration (seconds) to simulate.
    runs : int
        Total number of realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams (see :func:`chatterspec.montecarlo.root_seed_sequence`).
    chunk_runs : int, optional
        Realizations per yielded record (default: memory-sized, see
        :func:`~chatterspec.plants.simulate.iter_simulations`).
    first_run : int
        Index of the first realization (default 0).
    gamma : float
        SVSF convergence rate in (0, 1) (eq 8-10).
    measurements : bool
        Keep the measurements and inputs in the records (``record.z``, ``record.u``), for
        fault identification; the fused compiled path then also writes z (8 bytes per
        sample and channel). The simulated path always keeps them.
    reuse_measurements : bool
        With ``measurements`` on the fused path: every record's ``z`` is a view of one buffer,
        overwritten by the next record (for a consumer that is done with a record before it asks
        for the next, like :class:`~chatterspec.detection.identification.IdentificationStream`:
        no fresh memory to fault in per chunk).

    Yields
    ------
    ChatteringRecord
        One record per chunk, each with ``first_run`` set to its first realization.
    """
    if can_fuse(scenario):
        runs = positive_int("runs", runs)
        yield from _fused_chattering(
            scenario, runs, seed, chunk_runs, first_run, gamma, measurements, reuse_measurements
        )
        return
    for sim in iter_simulations(scenario, runs, seed, chunk_runs=chunk_runs, first_run=first_run):
        yield _from_simulation(sim, gamma)


def scenario_chattering(
    scenario: Scenario, runs: int = 1, seed: SeedLike = None, *, gamma: float = 0.1
) -> ChatteringRecord:
    """All ``runs`` realizations of ``scenario``'s chattering in one record.

    Concatenates the chunks of :func:`iter_chattering`; the result is identical
    to filtering ``simulate(scenario, runs, seed)``.

    Parameters
    ----------
    scenario : Scenario
        Nominal model, true plant, input and duration (seconds) to simulate.
    runs : int
        Number of realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams (see :func:`chatterspec.montecarlo.root_seed_sequence`).
    gamma : float
        SVSF convergence rate in (0, 1) (eq 8-10).

    Returns
    -------
    ChatteringRecord
        ``values`` of shape (runs, N, m) with N = T - 1 chattering samples.
    """
    runs = positive_int("runs", runs)
    chunks = list(iter_chattering(scenario, runs, seed, gamma=gamma))
    if len(chunks) == 1:
        return chunks[0]
    return ChatteringRecord(
        t=chunks[0].t,
        values=np.concatenate([c.values for c in chunks]),
        model=scenario.nominal,
        scenario=scenario,
    )
