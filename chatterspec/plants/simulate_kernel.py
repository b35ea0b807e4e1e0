"""The compiled plant loop of the batched simulation and the tables and noise it reads (eq 1-2).

:func:`plant_loop` is the one per-sample loop of a linear plant; :func:`chatterspec._jit.specialize`
binds its input step and its sink: the open-loop simulation (:mod:`chatterspec.plants.simulate`),
the closed loop (:mod:`chatterspec.plants.simulate_closed_loop`) and the fused simulate-and-filter
chattering loop (:mod:`chatterspec.detection.pipeline`). :func:`kernel_tables` stacks a scenario's
segment models for it; :func:`scaled_noise` and :func:`segment_ranges` are the numpy path's pieces.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import numpy as np

from .. import _jit
from ..montecarlo import BLOCK, block_generator
from .linear_steps import advance_step, measure_step
from .scenario_types import Scenario

if TYPE_CHECKING:  # pragma: no cover
    from .nonlinear import LinearModel, Model

__all__ = [
    "NO_ARRAY",
    "NO_CTRL",
    "covariance_sqrt",
    "kernel_tables",
    "same_shapes",
    "scaled_noise",
    "segment_ranges",
]


def covariance_sqrt(M: np.ndarray) -> np.ndarray:
    """A matrix L with L L^T = M for a symmetric PSD M (diagonal fast path, else eigh)."""
    if np.count_nonzero(M - np.diag(np.diag(M))) == 0:
        return np.diag(np.sqrt(np.clip(np.diag(M), 0.0, None)))
    w, V = np.linalg.eigh(M)
    return V * np.sqrt(np.clip(w, 0.0, None))


def segment_ranges(scenario: Scenario, t: np.ndarray) -> list[tuple[int, int, Model]]:
    """``(k0, k1, model)`` per active segment of ``scenario`` at times ``t`` (s): the true model of
    samples ``k0 .. k1 - 1``."""
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
    """Process and measurement noise of runs ``lo .. hi - 1`` of ``scenario``, time-major ``(T, runs, n|m)``.

    Drawn from the root seed ``root`` at the times ``t`` (s).

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
            vt[k0:k1, rows] = np.swapaxes(scale(v[:, k0:k1], model.Q), 0, 1)
            zt[k0:k1, rows] = np.swapaxes(scale(w[:, k0:k1], model.R), 0, 1)
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
        A=c(np.stack([cast("LinearModel", sg.model).A for sg in segs]), dtype=float),  # a linear scenario
        C=c(np.stack([sg.model.C for sg in segs]), dtype=float),
        Lq=c(np.stack([covariance_sqrt(sg.model.Q) for sg in segs]), dtype=float),
        Lr=c(np.stack([covariance_sqrt(sg.model.R) for sg in segs]), dtype=float),
        Bu=c(np.stack([u @ cast("LinearModel", sg.model).B.T for sg in segs]), dtype=float),
        x0=c(scenario.x0, dtype=float),
        diag=np.array([[_is_diagonal(sg.model.Q), _is_diagonal(sg.model.R)] for sg in segs], dtype=np.bool_),
    )


def same_shapes(scenario: Scenario) -> bool:
    """Whether every segment's model of ``scenario`` has the nominal's dimensions (the kernels stack them)."""
    nom = scenario.nominal
    dims = (nom.n_states, nom.n_outputs, nom.n_inputs)
    return all((sg.model.n_states, sg.model.n_outputs, sg.model.n_inputs) == dims for sg in scenario.segments)


def _is_diagonal(M: np.ndarray) -> bool:
    return bool(np.count_nonzero(M - np.diag(np.diag(M))) == 0)


def _noise_blocks(
    root: np.random.SeedSequence, lo: int, hi: int, T: int, n: int, m: int
) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """``(offset, v, w)`` per random block overlapping ``[lo, hi)``: raw normals ``(b, T, n|m)``.

    Exactly the numbers of :func:`chatterspec.montecarlo.block_generator` streams 0 (process) and
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


def plant_loop(
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    A: np.ndarray,
    C: np.ndarray,
    Lq: np.ndarray,
    Lr: np.ndarray,
    Bu: np.ndarray,
    x0: np.ndarray,
    diag: np.ndarray,
    ctrl: np.ndarray,
    out_a: np.ndarray,
    out_b: np.ndarray,
    PhiT: np.ndarray,
    Gu: np.ndarray,
    offset: int,
) -> None:  # pragma: no cover - compiled (Python form tested in tests/test_kernels.py)
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
