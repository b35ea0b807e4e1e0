"""Batched Monte Carlo simulation of a scenario's true plant (eq 1-2).

All realizations advance together: the only Python loop is over time steps
(and over fixed blocks of realizations when drawing random numbers, see
:mod:`chatterspec.rng`). Arrays follow the package convention
``(runs, T, channels)``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from .. import _jit
from .._validate import positive_int
from ..rng import BLOCK, SeedLike, block_generator, root_seed_sequence
from .linear_steps import advance_step, measure_step
from .scenarios import Scenario

__all__ = ["Simulation", "covariance_sqrt", "iter_simulations", "simulate"]

#: Target size (bytes) of the arrays of one internal chunk of realizations.
CHUNK_BYTES = 192 * 2**20


@dataclass(frozen=True, eq=False)
class Simulation:
    """Result of :func:`simulate`.

    Attributes
    ----------
    t : (T,) array
        Sample times in seconds, ``t[k] = k * dt``.
    x : (runs, T, n) array
        True states.
    z : (runs, T, m) array
        Measurements ``z(k) = C x(k) + w(k)``.
    u : (T, p) or (runs, T, p) array
        Input: identical for all realizations (T, p), or per realization (runs, T, p) when a
        controller computes it (closed-loop scenarios, ``scenario.closed_loop``).
    scenario : Scenario
    first_run : int
        Global index of the first realization held here (non-zero for chunks).
    """

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    u: np.ndarray
    scenario: Scenario
    first_run: int = 0

    @property
    def runs(self) -> int:
        return self.z.shape[0]

    def take(self, runs: slice) -> Simulation:
        """The realizations ``runs`` (a slice of this chunk), as copies; a per-realization ``u`` follows."""
        u = self.u[runs].copy() if self.u.ndim == 3 else self.u
        first = self.first_run + (runs.indices(self.runs)[0])
        return Simulation(self.t, self.x[runs].copy(), self.z[runs].copy(), u, self.scenario, first)

    def input_of(self, run: int) -> np.ndarray:
        """The input ``(T, p)`` of realization ``run`` (index within this chunk)."""
        return self.u[run] if self.u.ndim == 3 else self.u


def covariance_sqrt(M: np.ndarray) -> np.ndarray:
    """A matrix L with L L^T = M for a symmetric PSD M (diagonal fast path, else eigh)."""
    if np.count_nonzero(M - np.diag(np.diag(M))) == 0:
        return np.diag(np.sqrt(np.clip(np.diag(M), 0.0, None)))
    w, V = np.linalg.eigh(M)
    return V * np.sqrt(np.clip(w, 0.0, None))


def default_chunk_runs(scenario: Scenario) -> int:
    T = scenario.n_samples
    per_run = 8 * T * 2 * (scenario.nominal.n_states + scenario.nominal.n_outputs)
    return max(64, int(CHUNK_BYTES // per_run) // 64 * 64)


def simulate(
    scenario: Scenario,
    runs: int = 1,
    seed: SeedLike = None,
    *,
    chunk_runs: int | None = None,
) -> Simulation:
    """Simulate ``runs`` independent realizations of ``scenario``'s true plant.

    Parameters
    ----------
    scenario : Scenario
        Nominal model, time-segmented true plant, input and duration.
    runs : int
        Number of Monte Carlo realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams. The same seed gives the same numbers
        whatever ``chunk_runs`` is (realization r always draws from random
        block r // 64).
    chunk_runs : int, optional
        Realizations simulated together internally (memory/speed trade-off).

    Returns
    -------
    Simulation
        ``x`` of shape (runs, T, n), ``z`` of shape (runs, T, m), ``u`` of
        shape (T, p) and ``t`` of shape (T,), with T = round(duration/dt) + 1.

    Examples
    --------
    >>> import chatterspec as cs
    >>> sim = cs.simulate(cs.scenario("eha-healthy"), runs=2, seed=1)
    >>> sim.z.shape
    (2, 4001, 3)
    """
    runs = positive_int("runs", runs)
    chunks = list(iter_simulations(scenario, runs, seed, chunk_runs=chunk_runs))
    if len(chunks) == 1:
        return chunks[0]
    return Simulation(
        t=chunks[0].t,
        x=np.concatenate([c.x for c in chunks]),
        z=np.concatenate([c.z for c in chunks]),
        u=np.concatenate([c.u for c in chunks]) if chunks[0].u.ndim == 3 else chunks[0].u,
        scenario=scenario,
    )


def iter_simulations(
    scenario: Scenario,
    runs: int,
    seed: SeedLike = None,
    *,
    chunk_runs: int | None = None,
    first_run: int = 0,
) -> Iterator[Simulation]:
    """Yield the realizations ``first_run .. first_run + runs - 1`` in chunks (constant memory).

    Realization r always draws its noise from random block ``r // BLOCK`` of
    ``seed``, so the concatenated chunks equal :func:`simulate` with the same seed
    whatever ``chunk_runs`` and however the runs are split between calls.

    Parameters
    ----------
    scenario : Scenario
        Nominal model, time-segmented true plant, input and duration (seconds).
    runs : int
        Number of realizations to yield in total (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams (see :func:`chatterspec.rng.root_seed_sequence`).
    chunk_runs : int, optional
        Realizations per yielded chunk; the default is a multiple of 64 (at
        least 64) sized so that one chunk's state and measurement arrays stay
        near ``CHUNK_BYTES`` (192 MiB).
    first_run : int
        Index of the first realization (default 0), for continuing or splitting a study.

    Yields
    ------
    Simulation
        One chunk with ``x`` (k, T, n), ``z`` (k, T, m), shared ``u`` (T, p) (closed loop: the
        controller's output per realization, (k, T, 1), see
        :mod:`chatterspec.plants.simulate_closed_loop`) and ``t`` (T,) in seconds, and
        ``first_run`` set to its first realization index.

    Raises
    ------
    ShapeError
        If the scenario's input has a different number of channels than the model.
    """
    runs = positive_int("runs", runs)
    chunk = default_chunk_runs(scenario) if chunk_runs is None else positive_int("chunk_runs", chunk_runs)
    root = root_seed_sequence(seed)
    if getattr(scenario, "closed_loop", None) is not None:
        from .simulate_closed_loop import simulate_block_closed_loop

        t = scenario.time
        for lo in range(first_run, first_run + runs, chunk):
            hi = min(lo + chunk, first_run + runs)
            x, z, u = simulate_block_closed_loop(scenario, root, lo, hi, t)
            yield Simulation(t=t, x=x, z=z, u=u, scenario=scenario, first_run=lo)
        return
    t, u = scenario_input(scenario)
    for lo in range(first_run, first_run + runs, chunk):
        hi = min(lo + chunk, first_run + runs)
        x, z = _simulate_block(scenario, root, lo, hi, t, u)
        yield Simulation(t=t, x=x, z=z, u=u, scenario=scenario, first_run=lo)


def scenario_input(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """The sample times ``t`` (T,) in seconds and the input ``u`` (T, p) of an open-loop scenario.

    Raises
    ------
    ShapeError
        If the input has a different number of channels than the nominal model.
    """
    t = scenario.time
    u = scenario.input.sample(t).reshape(len(t), -1)
    if u.shape[1] != scenario.nominal.n_inputs:
        from ..errors import ShapeError

        raise ShapeError(
            f"scenario input gives {u.shape[1]} channel(s); the model has {scenario.nominal.n_inputs}"
        )
    return t, u


def segment_ranges(scenario: Scenario, t: np.ndarray) -> list[tuple[int, int, object]]:
    """``(k0, k1, model)`` per active segment: the true model of samples ``k0 .. k1 - 1``."""
    seg_idx = scenario.segment_index(t)
    ranges = []
    for s, seg in enumerate(scenario.segments):
        sel = np.flatnonzero(seg_idx == s)
        if sel.size:
            ranges.append((int(sel[0]), int(sel[-1]) + 1, seg.model))
    return ranges


def scaled_noise(
    scenario: Scenario,
    root: np.random.SeedSequence,
    lo: int,
    hi: int,
    t: np.ndarray,
    scale: Callable[[np.ndarray, np.ndarray], np.ndarray],
) -> tuple[np.ndarray, np.ndarray]:
    """Process and measurement noise of runs ``lo .. hi - 1``, time-major ``(T, runs, n|m)``.

    The raw normals of :func:`_noise_blocks` scaled per segment by ``scale(noise, Q)`` and
    ``scale(noise, R)`` of the segment's true model (``noise @ L^T`` with ``L L^T`` the covariance).
    """
    T = len(t)
    n, m = scenario.nominal.n_states, scenario.nominal.n_outputs
    ranges = segment_ranges(scenario, t)
    vt = np.empty((T, hi - lo, n))
    zt = np.empty((T, hi - lo, m))
    for off, v, w in _noise_blocks(root, lo, hi, T, n, m):
        rows = slice(off, off + v.shape[0])
        for k0, k1, model in ranges:
            vt[k0:k1, rows] = np.swapaxes(scale(v[:, k0:k1], model.Q), 0, 1)  # type: ignore[attr-defined]
            zt[k0:k1, rows] = np.swapaxes(scale(w[:, k0:k1], model.R), 0, 1)  # type: ignore[attr-defined]
    return vt, zt


def _linear_scale(noise: np.ndarray, M: np.ndarray) -> np.ndarray:
    return noise @ covariance_sqrt(M).T


@dataclass(frozen=True, eq=False)
class KernelTables:
    """Per-segment arrays of a scenario for the compiled kernels (segment s active at sample k)."""

    seg_idx: np.ndarray  # (T,) int64
    A: np.ndarray  # (S, n, n)
    C: np.ndarray  # (S, m, n)
    Lq: np.ndarray  # (S, n, n), Lq Lq^T = Q
    Lr: np.ndarray  # (S, m, m), Lr Lr^T = R
    Bu: np.ndarray  # (S, T, n), B u(k)
    x0: np.ndarray  # (n,)
    diag: np.ndarray  # (S, 2) bool: Lq, Lr diagonal (then only the diagonal terms are summed)


def kernel_tables(scenario: Scenario, t: np.ndarray, u: np.ndarray) -> KernelTables:
    """The per-segment tables of ``scenario`` at times ``t`` (s) with inputs ``u`` ``(T, inputs)``.

    The compiled plant loop (:func:`plant_loop`) reads them; so does the fused simulate-and-filter
    loop of :mod:`chatterspec.detection.pipeline`.
    """
    segs = scenario.segments
    c = np.ascontiguousarray
    return KernelTables(
        seg_idx=c(scenario.segment_index(t), dtype=np.int64),
        A=c(np.stack([sg.model.A for sg in segs]), dtype=float),
        C=c(np.stack([sg.model.C for sg in segs]), dtype=float),
        Lq=c(np.stack([covariance_sqrt(sg.model.Q) for sg in segs]), dtype=float),
        Lr=c(np.stack([covariance_sqrt(sg.model.R) for sg in segs]), dtype=float),
        Bu=c(np.stack([u @ sg.model.B.T for sg in segs]), dtype=float),
        x0=c(scenario.x0, dtype=float),
        diag=np.array([[_is_diagonal(sg.model.Q), _is_diagonal(sg.model.R)] for sg in segs], dtype=np.bool_),
    )


def same_shapes(scenario: Scenario) -> bool:
    """Whether every segment's model has the nominal's dimensions (the kernels stack them)."""
    nom = scenario.nominal
    dims = (nom.n_states, nom.n_outputs, nom.n_inputs)
    return all((sg.model.n_states, sg.model.n_outputs, sg.model.n_inputs) == dims for sg in scenario.segments)


def _is_diagonal(M: np.ndarray) -> bool:
    return bool(np.count_nonzero(M - np.diag(np.diag(M))) == 0)


def _noise_blocks(
    root: np.random.SeedSequence, lo: int, hi: int, T: int, n: int, m: int
) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """``(offset, v, w)`` per random block overlapping ``[lo, hi)``: raw normals ``(b, T, n|m)``.

    Exactly the numbers of :func:`chatterspec.rng.block_generator` streams 0 (process) and
    1 (measurement) of each block, realization-major; ``offset`` is the first run's index
    relative to ``lo``.
    """
    for b in range(lo // BLOCK, (hi - 1) // BLOCK + 1):
        b_lo, b_hi = b * BLOCK, (b + 1) * BLOCK
        s0, s1 = max(b_lo, lo), min(b_hi, hi)
        v = block_generator(root, b, 0).standard_normal((BLOCK, T, n))[s0 - b_lo : s1 - b_lo]
        w = block_generator(root, b, 1).standard_normal((BLOCK, T, m))[s0 - b_lo : s1 - b_lo]
        yield s0 - lo, v, w


@_jit.step
def open_loop_input(
    row: int, s: int, k: int, z: np.ndarray, Bu: np.ndarray, ctrl: np.ndarray, bu: np.ndarray, n: int
) -> None:
    """The input step of an open-loop scenario: ``bu = B_s u(k)`` from the table (``row``, ``ctrl`` unused).

    The simulation loop asks this step for the input's effect at every sample, after the sink and
    before it advances the plant; a controller step with the same signature (reading ``z(k)``,
    its gains, reference and per-run state in ``ctrl``, writing u(k) of run ``row`` there) closes
    the loop without another copy of the loop
    (:func:`chatterspec.plants.simulate_closed_loop.controller_input`).
    """
    for i in range(n):
        bu[i] = Bu[s, k, i]


@_jit.step
def store_sink(
    row: int,
    k: int,
    x: np.ndarray,
    z: np.ndarray,
    zp: np.ndarray,
    out_a: np.ndarray,
    out_b: np.ndarray,
    PhiT: np.ndarray,
    Gu: np.ndarray,
    n: int,
    m: int,
) -> None:  # pragma: no cover - compiled
    """The sink of :func:`simulate`: ``x(k)`` into ``out_a[k, row]``, ``z(k)`` into ``out_b[k, row]``."""
    for i in range(m):
        out_b[k, row, i] = z[i]
    for i in range(n):
        out_a[k, row, i] = x[i]


#: Bindings of :func:`plant_loop` (see :func:`chatterspec._jit.specialize`): sizes (0: from the arrays),
#: what consumes each sample, and the input step.
NX = NZ = 0
SINK = store_sink
INPUT = open_loop_input


def plant_loop(v, w, seg_idx, A, C, Lq, Lr, Bu, x0, diag, ctrl, out_a, out_b, PhiT, Gu, offset):  # type: ignore[no-untyped-def]  # pragma: no cover - compiled (Python form tested in tests/test_kernels.py)
    """Eq (1)-(2) for the runs of one random block, each sample handed to ``SINK`` (a template).

    Per run r and sample k, with the segment s active at k: ``z(k)`` by
    :func:`~chatterspec.plants.linear_steps.measure_step`, then ``SINK(offset + r, k, x, z, zp,
    out_a, out_b, PhiT, Gu, n, m)`` (``zp`` is the sink's own per-run memory), then ``INPUT(offset + r,
    s, k, z, Bu, ctrl, bu, n)`` gives ``B_s u(k)`` (a table lookup, or a controller's output from
    ``z(k)``) and, before the last sample, :func:`~chatterspec.plants.linear_steps.advance_step`
    ``x(k+1)``. ``v``, ``w`` are raw standard normals ``(runs, T, n|m)``; tables from
    :func:`kernel_tables`. Sinks: :func:`store_sink` (:data:`_simulate_kernel`) and the auxiliary
    SVSF's chattering (:mod:`chatterspec.detection.pipeline`). Every run starts from ``x0``
    and is independent of the others, so any chunking gives the same bits.
    """
    b = _jit.borrow
    v, w, seg_idx, A, C, Lq, Lr, Bu, x0 = b(v), b(w), b(seg_idx), b(A), b(C), b(Lq), b(Lr), b(Bu), b(x0)
    diag, ctrl, out_a, out_b, PhiT, Gu = b(diag), b(ctrl), b(out_a), b(out_b), b(PhiT), b(Gu)
    runs, T, _ = v.shape
    n = NX if NX > 0 else v.shape[2]
    m = NZ if NZ > 0 else w.shape[2]
    x = _jit.scratch(n)
    xn = _jit.scratch(n)
    bu = _jit.scratch(n)
    z = _jit.scratch(m)
    zp = _jit.scratch(m)
    for r in range(runs):
        for i in range(n):
            x[i] = x0[i]
        for k in range(T):
            s = seg_idx[k]
            measure_step(s, x, w[r, k], C, Lr, diag, z, n, m)
            SINK(offset + r, k, x, z, zp, out_a, out_b, PhiT, Gu, n, m)
            INPUT(offset + r, s, k, z, Bu, ctrl, bu, n)
            if k + 1 < T:
                advance_step(s, x, bu, v[r, k], A, Lq, diag, xn, n)
                for i in range(n):
                    x[i] = xn[i]


#: The simulation kernel: ``_simulate_kernel(v, w, seg_idx, A, C, Lq, Lr, Bu, x0, diag, ctrl, xt, zt,
#: PhiT, Gu, offset)`` writes run r to ``xt[:, offset + r]``, ``zt[:, offset + r]`` (time-major;
#: ``ctrl``, ``PhiT``, ``Gu`` unused).
_simulate_kernel = _jit.specialize(plant_loop, "store")

#: Empty float arrays for the unused arguments of :func:`plant_loop`.
NO_ARRAY = np.empty((0, 0))
NO_CTRL = np.empty(0)


def _simulate_block(
    scenario: Scenario, root: np.random.SeedSequence, lo: int, hi: int, t: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    if not getattr(scenario, "is_linear", True) and hi - lo > 1:
        # nonlinear true plant: same seeding scheme, f(x, u) stepping (plants/simulate_nonlinear.py)
        from .simulate_nonlinear import simulate_block_nonlinear

        return simulate_block_nonlinear(scenario, root, lo, hi, t, u)
    n, m = scenario.nominal.n_states, scenario.nominal.n_outputs
    compiled = _jit.enabled() and _jit.fits(n, m, vectors_only=True)
    if compiled and getattr(scenario, "is_linear", True) and same_shapes(scenario):
        # compiled path: per-run scalar arithmetic, so any chunking gives the same bits
        T = len(t)
        n, m = scenario.nominal.n_states, scenario.nominal.n_outputs
        tb = kernel_tables(scenario, t, u)
        xt = np.empty((T, hi - lo, n))
        zt = np.empty((T, hi - lo, m))
        kernel = _jit.specialize_sizes(plant_loop, "store", {"NX": n, "NZ": m})
        for off, v, w in _noise_blocks(root, lo, hi, T, n, m):
            kernel(
                v, w, tb.seg_idx, tb.A, tb.C, tb.Lq, tb.Lr, tb.Bu, tb.x0, tb.diag, NO_CTRL, xt, zt, NO_ARRAY,
                NO_ARRAY, off,
            )  # fmt: skip
        return np.swapaxes(xt, 0, 1), np.swapaxes(zt, 0, 1)
    if hi - lo == 1:
        # BLAS evaluates a one-row product by another kernel (gemv) whose rounding differs
        # in the last bit; simulate two realizations so that realization ``lo`` is
        # bit-identical whatever the chunking (realization lo + 1 is simply discarded)
        x, z = _simulate_block(scenario, root, lo, lo + 2, t, u)
        return x[:1], z[:1]
    T = len(t)
    n = scenario.nominal.n_states
    seg_idx = scenario.segment_index(t)
    segments = scenario.segments
    ranges = segment_ranges(scenario, t)
    # Noise is stored time-major (T, runs, channels) for the recursion; each
    # random block is drawn realization-major so the numbers do not depend on
    # the chunking (see chatterspec.rng).
    vt, zt = scaled_noise(scenario, root, lo, hi, t, _linear_scale)
    xt = np.empty((T, hi - lo, n))
    xt[0] = scenario.x0
    # x_aug = [x, 1] and W = [[A^T], [(B u(k))^T]] fold the input into one matmul
    x_aug = np.ones((hi - lo, n + 1))
    x_aug[:, :n] = scenario.x0
    W = [np.vstack([seg.model.A.T, np.zeros((1, n))]) for seg in segments]
    Bu = [u @ seg.model.B.T for seg in segments]
    for k in range(T - 1):
        s = seg_idx[k]
        Ws = W[s]
        Ws[n] = Bu[s][k]
        nxt = xt[k + 1]
        np.matmul(x_aug, Ws, out=nxt)  # eq (1)
        nxt += vt[k]
        x_aug[:, :n] = nxt
    del vt
    # measurements z(k) = C x(k) + w(k), with the C of the segment active at k
    for k0, k1, model in ranges:
        zt[k0:k1] += xt[k0:k1] @ model.C.T
    # (runs, T, channels) views of the time-major buffers (no copy)
    return np.swapaxes(xt, 0, 1), np.swapaxes(zt, 0, 1)


# The old private names of the kernel interface (plant_loop, kernel_tables, same_shapes).
_plant_loop, _tables, _Tables, _same_shapes = plant_loop, kernel_tables, KernelTables, same_shapes
