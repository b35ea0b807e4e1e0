"""Batched Monte Carlo simulation of a scenario's true plant (eq 1-2): open loop, nonlinear, closed loop.

All realizations advance together: the only Python loop is over time steps
(and over fixed blocks of realizations when drawing random numbers, see
:mod:`chatterspec.montecarlo`). Arrays follow the package convention
``(runs, T, channels)``.

Batched simulation of scenarios whose true plant is nonlinear (``x(k+1) = f(x(k), u(k)) + v(k)``).

:func:`simulate` and :func:`iter_simulations` dispatch to :func:`simulate_block_nonlinear` when any model
of the scenario (nominal, plant or a fault window) is a
:class:`~chatterspec.plants.nonlinear.NonlinearModel`; callers never call it directly.

Seeding is *exactly* that of the linear simulation (:mod:`chatterspec.montecarlo`): realization ``r``
draws its process noise from ``block_generator(root, r // 64, 0).standard_normal((64, T, n))`` and
its measurement noise from stream 1 with shape ``(64, T, m)``, each scaled by the Cholesky-like
square root of the active segment's ``Q`` and ``R``. A nonlinear model that happens to be linear
therefore gives the same numbers as the equivalent ``LinearModel`` scenario, and any chunking of
the realizations (``chunk_runs``, ``first_run``, workers) gives bit-identical results: every
operation of a step is element-wise per realization (no BLAS kernel whose rounding depends on the
number of rows).

The true plant is time-segmented like the linear one: the segment active at ``t_k`` advances
``x(k) -> x(k+1)``, and ``z(k) = C x(k) + w(k)`` uses the ``C``/``R`` of the segment active at ``t_k``.

Batched simulation of a plant under its position controller (``plants.closed_loop.ClosedLoop``).

At each sample ``k``, for every realization::

    z(k)   = C_s x(k) + Lr_s w(k)                         measurement (eq 2)
    u(k)   = pid_step(r(k), z_pos(k), d(k), controller state)   pump speed, rad/s
    x(k+1) = A_s x(k) + B_s u(k) + Lq_s v(k)              (eq 1; f_s(x, u) + v for a nonlinear plant)

with the segment ``s`` active at ``t_k``. The controller reads the same noisy measurement the filters
see, and ``u(k)`` is returned per realization (``Simulation.u`` of shape ``(runs, T, 1)``): the
filters run the open-loop nominal model with it. Seeding is that of the open-loop simulation
(:mod:`chatterspec.montecarlo`: realization ``r`` draws block ``r // 64``, stream 0 = v, stream 1 = w), so
any chunking gives the same numbers, and a loop with zero gains whose input dither equals an
open-loop scenario's input reproduces that scenario's simulation bit for bit (tested).

The per-sample arithmetic is written once, as steps: the linear plant's
:func:`~chatterspec.plants.steps.measure_step` (eq 2) and
:func:`~chatterspec.plants.steps.advance_step` (eq 1), and the controller's
:func:`~chatterspec.plants.closed_loop.pid_step`. The compiled path is the open-loop simulation's
loop (:func:`plant_loop`) with :func:`controller_input` as its input step, in place
of the input table; the numpy path (:func:`_loop_numpy`) calls the same steps' Python functions on
rows of realizations (channel-major ``(n, runs)`` state), doing the same correctly rounded
operations in the same order, so both paths give the same bits. A nonlinear plant (the 4-state
EHA) runs on the numpy path with its vectorized ``f``. The streaming generator
:func:`closed_loop_blocks` (one realization, state carried between blocks) runs each block of a
linear plant in one compiled call (:func:`_stream_kernel`, the same steps), else the numpy path.

The compiled plant loop of the batched simulation and the tables and noise it reads (eq 1-2).

:func:`plant_loop` is the one per-sample loop of a linear plant; :func:`chatterspec._jit.specialize`
binds its input step and its sink: the open-loop simulation,
the closed loop (:func:`controller_input`) and the fused simulate-and-filter
chattering loop (:mod:`chatterspec.detection.pipeline`). :func:`kernel_tables` stacks a scenario's
segment models for it; :func:`scaled_noise` and :func:`segment_ranges` are the numpy path's pieces.

Overshoot and settling time of a closed-loop scenario's moves (noise-free response).

For each move of a :class:`~chatterspec.plants.closed_loop.StepSequence` or
:class:`~chatterspec.plants.closed_loop.SCurve` reference, from the level ``r0`` to ``r1``:

* **overshoot**: the largest excursion of the position beyond ``r1`` after the reference has
  arrived (the move's end), in % of the step ``|r1 - r0|``;
* **settling time**: from the reference's arrival to the last time the position is outside
  ``r1 +- band |r1 - r0|`` before the next move starts (0 if it never leaves the band; ``inf`` if
  it has not settled when the next move starts).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import positive_int
from ..errors import NonFiniteError, ParameterError
from ..montecarlo import BLOCK, SeedLike, block_generator, root_seed_sequence
from .closed_loop import ClosedLoop, SCurve, StepSequence, pid_coefficients, pid_step
from .models import LinearModel
from .nonlinear import measure
from .scenarios import Scenario
from .steps import advance_step, measure_step

if TYPE_CHECKING:
    from .nonlinear import Model

__all__ = [
    "NO_ARRAY",
    "NO_CTRL",
    "LoopState",
    "MoveMetrics",
    "Simulation",
    "as_scenario",
    "closed_loop_blocks",
    "covariance_sqrt",
    "is_closed_loop",
    "iter_simulations",
    "kernel_tables",
    "loop_response",
    "model_scenario",
    "move_metrics",
    "same_shapes",
    "scaled_noise",
    "segment_ranges",
    "simulate",
    "simulate_block_closed_loop",
    "simulate_block_nonlinear",
]


# The compiled plant loop and the tables and noise it reads.


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
    (:func:`chatterspec.plants.simulate.controller_input`).
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
    :func:`~chatterspec.plants.steps.measure_step`, then ``SINK(offset + r, k, x, z, zp,
    out_a, out_b, PhiT, Gu, n, m)`` (``zp`` is the sink's own per-run memory), then ``INPUT(offset + r,
    s, k, z, Bu, ctrl, bu, n)`` gives ``B_s u(k)`` (a table lookup, or a controller's output from
    ``z(k)``) and, before the last sample, :func:`~chatterspec.plants.steps.advance_step`
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
        vr = v[r]  # (T, n) and (T, m) views indexed from 0: no negative-index test per sample
        wr = w[r]
        for i in range(n):
            x[i] = x0[i]
        for k in range(T):
            s = seg_idx[k]
            measure_step(s, x, wr[k], C, Lr, diag, z, n, m)
            SINK(offset + r, k, x, z, zp, out_a, out_b, PhiT, Gu, n, m)
            INPUT(offset + r, s, k, z, Bu, ctrl, bu, n)
            if k + 1 < T:
                advance_step(s, x, bu, vr[k], A, Lq, diag, xn, n)
                for i in range(n):
                    x[i] = xn[i]


#: The simulation kernel: ``_simulate_kernel(v, w, seg_idx, A, C, Lq, Lr, Bu, x0, diag, ctrl, xt, zt,
#: PhiT, Gu, offset)`` writes run r to ``xt[:, offset + r]``, ``zt[:, offset + r]`` (time-major;
#: ``ctrl``, ``PhiT``, ``Gu`` unused).
_simulate_kernel = _jit.specialize(plant_loop, "store")

#: Empty float arrays for the unused arguments of :func:`plant_loop`.
NO_ARRAY = np.empty((0, 0))
NO_CTRL = np.empty(0)


# Nonlinear true plants.


def _scale(noise: np.ndarray, L: np.ndarray) -> np.ndarray:
    """``noise @ L.T`` computed element-wise when L is diagonal (the same bits as the matmul)."""
    if np.count_nonzero(L - np.diag(np.diag(L))) == 0:
        return noise * np.diag(L)
    return noise @ L.T


def simulate_block_nonlinear(
    scenario: Scenario, root: np.random.SeedSequence, lo: int, hi: int, t: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Simulate realizations ``lo .. hi - 1`` of a scenario with a nonlinear true plant.

    Parameters
    ----------
    scenario : Scenario
        The scenario (its ``segments`` give the true model per time window, ``x0`` the start).
    root : numpy.random.SeedSequence
        Root of the random streams (see :mod:`chatterspec.montecarlo`).
    lo, hi : int
        Global indices of the first and one-past-the-last realization.
    t : (T,) array
        Sample times in seconds.
    u : (T, p) array
        Input, shared by all realizations.

    Returns
    -------
    x : (hi - lo, T, n) ndarray
        True states.
    z : (hi - lo, T, m) ndarray
        Measurements.

    Raises
    ------
    NonFiniteError
        If the state leaves the finite numbers (e.g. explicit Euler beyond its stability limit);
        the message gives the first time and realization.
    """

    T = len(t)
    runs = hi - lo
    n = scenario.nominal.n_states
    seg_idx = scenario.segment_index(t)
    segments = scenario.segments
    ranges = segment_ranges(scenario, t)
    vt, zt = scaled_noise(scenario, root, lo, hi, t, lambda noise, M: _scale(noise, covariance_sqrt(M)))
    xt = np.empty((T, runs, n))
    xt[0] = scenario.x0
    # NonlinearModel.f was shape-checked when the model was built: call it directly in the loop
    step = [getattr(seg.model, "f", seg.model.transition) for seg in segments]
    for s in set(seg_idx[:-1].tolist()):
        segments[s].model.transition(xt[0], u[0])  # shape check once per model (raises ShapeError)
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(T - 1):
            nxt = step[seg_idx[k]](xt[k], u[k])
            np.add(nxt, vt[k], out=xt[k + 1])
    del vt
    bad = ~np.isfinite(xt)
    if bad.any():
        k, r, _ = np.argwhere(bad)[0]
        raise NonFiniteError(
            f"scenario {scenario.name!r}: the true state is not finite from t = {t[k]:.6g} s "
            f"(realization {lo + r}); the plant diverged -- for an explicit Euler model reduce dt "
            "or the input amplitude (EHA4: 2 dt a1 |v| / M must stay below 1)"
        )
    for k0, k1, model in ranges:
        C = model.C
        if getattr(model, "h", None) is not None:  # a nonlinear measurement h(x)
            zt[k0:k1] += measure(model, xt[k0:k1])
        elif C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(C.shape[0])):
            zt[k0:k1] += xt[k0:k1]
        else:
            zt[k0:k1] += xt[k0:k1] @ C.T
    return np.swapaxes(xt, 0, 1), np.swapaxes(zt, 0, 1)


# A plant under its position controller.


class LoopState(NamedTuple):
    """Plant and controller state of a batch of realizations between two calls.

    Attributes
    ----------
    x : (runs, n) array
        True state ``x(k)``.
    integ : (runs,) array
        Integrator ``I(k)`` (rad/s).
    deriv : (runs,) array
        Filtered derivative ``D(k-1)`` (rad/s).
    y_prev : (runs,) array
        Last measured position ``y(k-1)`` (m); NaN before the first sample.
    """

    x: np.ndarray
    integ: np.ndarray
    deriv: np.ndarray
    y_prev: np.ndarray


class _Block(NamedTuple):
    """The exogenous signals of ``K`` samples of the loop: noise, plant segment, reference, dither."""

    v: np.ndarray  # (runs, K, n) standard normals of the process noise
    w: np.ndarray  # (runs, K, m) standard normals of the measurement noise
    seg_idx: np.ndarray  # (K,) index of the segment active at each sample
    ref: np.ndarray  # (K,) reference (m)
    dith: np.ndarray  # (K,) dither added to the pump speed (rad/s)


def _initial_state(x0: np.ndarray, runs: int) -> LoopState:
    return LoopState(
        x=np.repeat(np.asarray(x0, dtype=float)[None], runs, axis=0),
        integ=np.zeros(runs),
        deriv=np.zeros(runs),
        y_prev=np.full(runs, np.nan),
    )


# --------------------------------------------------------------------------- the controller as input step
#: Layout of the ``ctrl`` vector of :func:`controller_input` (float slots): the eight
#: :class:`~chatterspec.plants.closed_loop.PIDCoefficients`, then the record length T, the number of
#: segments S, the position output index, the running state (I, D, y_prev) of the current run,
#: then B_s (S x n, row-major), the reference r (T), the input dither d (T) and the output u (rows x T).
_T, _S, _OUT, _STATE, _B = 8, 9, 10, 11, 14


@_jit.step
def controller_input(
    row: int, s: int, k: int, z: np.ndarray, Bu: np.ndarray, ctrl: np.ndarray, bu: np.ndarray, n: int
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_closed_loop_sim.py)
    """The simulation loop's input step in closed loop: ``u(k)`` from ``z(k)``, then ``bu = B_s u(k)``.

    Reads the position ``z[out]``, runs :func:`~chatterspec.plants.closed_loop.pid_step` on the
    state kept in ``ctrl`` (reset at ``k = 0``: I = 0, D = 0, y_prev = y(0), so every run is
    independent of the others), writes u(k) of run ``row`` into ``ctrl``'s output slots; ``Bu``
    (the open-loop input table) is unused. Layout: :data:`_T` and following (see :func:`_pack`).
    """
    T = int(ctrl[_T])
    rb = _B + int(ctrl[_S]) * n
    db = rb + T
    ub = db + T
    y = z[int(ctrl[_OUT])]
    if k == 0:
        ctrl[_STATE] = 0.0
        ctrl[_STATE + 1] = 0.0
        ctrl[_STATE + 2] = y
    u, integ, deriv = pid_step(
        ctrl[0], ctrl[1], ctrl[2], ctrl[3], ctrl[4], ctrl[5], ctrl[6], ctrl[7],
        ctrl[_STATE], ctrl[_STATE + 1], ctrl[_STATE + 2], ctrl[rb + k], y, ctrl[db + k],
    )  # fmt: skip
    ctrl[_STATE] = integ
    ctrl[_STATE + 1] = deriv
    ctrl[_STATE + 2] = y
    ctrl[ub + row * T + k] = u
    for i in range(n):
        bu[i] = ctrl[_B + s * n + i] * u


def _pack(
    coef: np.ndarray, out: int, B: np.ndarray, ref: np.ndarray, dith: np.ndarray, rows: int
) -> np.ndarray:
    """The ``ctrl`` vector of :func:`controller_input` for ``rows`` runs (u slots uninitialized)."""
    T = ref.shape[0]
    head = np.array([*coef, T, B.shape[0], out, 0.0, 0.0, 0.0], dtype=float)
    return np.concatenate([head, B.ravel(), ref, dith, np.empty(rows * T)])


def _unpack_u(ctrl: np.ndarray, B: np.ndarray, T: int, rows: int) -> np.ndarray:
    """The controller outputs ``(T, rows)`` (time-major) from a ``ctrl`` vector after the loop."""
    ub = _B + B.size + 2 * T
    return ctrl[ub : ub + rows * T].reshape(rows, T).T


#: The closed-loop simulation kernel: the open-loop simulation's loop with the controller as input step.
_closed_loop_kernel = _jit.specialize(plant_loop, "closed_loop", INPUT=controller_input)


def _closed_loop_sized(n: int, m: int) -> Callable[..., Any]:
    """:data:`_closed_loop_kernel` with the model's sizes as constants when small (as the open loop's)."""
    return _jit.specialize_sizes(plant_loop, "closed_loop", {"NX": n, "NZ": m}, INPUT=controller_input)


def _py(fn: Callable[..., Any]) -> Callable[..., Any]:
    """The Python form of a compiled kernel or step, its steps included (numpy path on rows)."""
    return _jit.python_form(fn)


@dataclass(frozen=True, eq=False)
class _LinearTables:
    """Per-segment arrays of a linear closed-loop scenario (segment s active at sample k)."""

    A: np.ndarray  # (S, n, n)
    B: np.ndarray  # (S, n), the one input column
    C: np.ndarray  # (S, m, n)
    Lq: np.ndarray  # (S, n, n), Lq Lq^T = Q
    Lr: np.ndarray  # (S, m, m), Lr Lr^T = R
    diag: np.ndarray  # (S, 2) bool: Lq, Lr diagonal


def _linear_tables(scenario: Scenario) -> _LinearTables:
    """The open-loop per-segment tables (``plants.simulate.kernel_tables``) and each segment's B."""
    tb = kernel_tables(scenario, np.zeros(1), np.zeros((1, 1)))  # no input table needed
    segs = scenario.segments
    B = np.ascontiguousarray(np.stack([cast("LinearModel", sg.model).B[:, 0] for sg in segs]), dtype=float)
    return _LinearTables(A=tb.A, B=B, C=tb.C, Lq=tb.Lq, Lr=tb.Lr, diag=tb.diag)


def _control_rows(
    coef: np.ndarray,
    integ: np.ndarray,
    deriv: np.ndarray,
    y_prev: np.ndarray,
    r: float,
    y: np.ndarray,
    d: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``pid_step`` on rows of realizations; a NaN ``y_prev`` means no earlier sample (no derivative kick)."""
    first = np.isnan(y_prev)
    if first.any():  # as controller_input at k = 0
        y_prev = np.where(first, y, y_prev)
    return _py(pid_step)(*coef, integ, deriv, y_prev, r, y, d)


def _loop_numpy(
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    tb: _LinearTables,
    ref: np.ndarray,
    dith: np.ndarray,
    coef: np.ndarray,
    out_idx: int,
    state: LoopState,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    """The compiled closed loop vectorized over realizations: the same steps on ``(channels, runs)`` rows.

    Unlike the compiled loop it starts from ``state`` and returns the state after the last
    sample (the plant advanced once more), for :func:`closed_loop_blocks`.
    """
    measure, advance = _py(measure_step), _py(advance_step)
    runs, K, n = v.shape
    m = w.shape[2]
    vt = np.ascontiguousarray(v.transpose(1, 2, 0))  # (K, n, runs)
    wt = np.ascontiguousarray(w.transpose(1, 2, 0))
    x = np.ascontiguousarray(state.x.T)  # (n, runs)
    xn = np.empty_like(x)
    z = np.empty((m, runs))
    bu = np.empty((n, runs))
    integ, deriv = state.integ.copy(), state.deriv.copy()
    y_prev = state.y_prev.copy()
    xt, zt, ut = np.empty((K, runs, n)), np.empty((K, runs, m)), np.empty((K, runs))
    for k in range(K):
        s = seg_idx[k]
        measure(s, x, wt[k], tb.C, tb.Lr, tb.diag, z, n, m)
        y = z[out_idx].copy()
        u, integ, deriv = _control_rows(coef, integ, deriv, y_prev, ref[k], y, dith[k])
        y_prev = y
        zt[k] = z.T
        xt[k] = x.T
        ut[k] = u
        for i in range(n):
            bu[i] = tb.B[s, i] * u
        advance(s, x, bu, vt[k], tb.A, tb.Lq, tb.diag, xn, n)
        x, xn = xn, x
    return xt, zt, ut, LoopState(np.ascontiguousarray(x.T), integ, deriv, y_prev)


@_jit.njit
def _stream_kernel(
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    A: np.ndarray,
    C: np.ndarray,
    Lq: np.ndarray,
    Lr: np.ndarray,
    diag: np.ndarray,
    B: np.ndarray,
    coef: np.ndarray,
    out_idx: int,
    ref: np.ndarray,
    dith: np.ndarray,
    st: np.ndarray,
    zt: np.ndarray,
    ut: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_closed_loop_sim.py)
    """:func:`_loop_numpy` for one realization, compiled: the same steps, from and to a carried state.

    ``v`` (K, n), ``w`` (K, m) standard normals; ``st`` = ``[x (n), I, D, y_prev]`` (``y_prev`` NaN before
    the first sample), updated in place (the plant advanced past the last sample, as
    :func:`_loop_numpy`); outputs ``zt`` (K, m), ``ut`` (K,). Per sample: :func:`measure_step`, the
    controller's :func:`pid_step` on the position (its derivative without a kick at the first
    sample), ``B_s u`` and :func:`advance_step`: the operations of the numpy path, hence its bits.
    """
    K, n = v.shape
    m = w.shape[1]
    x = np.empty(n)
    xn = np.empty(n)
    bu = np.empty(n)
    z = np.empty(m)
    for i in range(n):
        x[i] = st[i]
    integ, deriv, y_prev = float(st[n]), float(st[n + 1]), float(st[n + 2])
    for k in range(K):
        s = seg_idx[k]
        measure_step(s, x, w[k], C, Lr, diag, z, n, m)
        y = float(z[out_idx])
        if y_prev != y_prev:  # no earlier sample: no derivative kick
            y_prev = y
        u, integ, deriv = pid_step(
            coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7],
            integ, deriv, y_prev, ref[k], y, dith[k],
        )  # fmt: skip
        y_prev = y
        for i in range(m):
            zt[k, i] = z[i]
        ut[k] = u
        for i in range(n):
            bu[i] = B[s, i] * u
        advance_step(s, x, bu, v[k], A, Lq, diag, xn, n)
        for i in range(n):
            x[i] = xn[i]
    for i in range(n):
        st[i] = x[i]
    st[n], st[n + 1], st[n + 2] = integ, deriv, y_prev


def _stream_linear(
    scenario: Scenario, block: _Block, state: LoopState, tb: _LinearTables
) -> tuple[np.ndarray, np.ndarray, LoopState]:
    """K samples of one realization of the linear loop from ``state`` in one compiled call: ``(z, u)``.

    ``z`` (K, m), ``u`` (K,) and the state after the block; the numbers of :func:`_step_linear`.
    """
    loop = _loop_of(scenario)
    coef = np.asarray(pid_coefficients(loop.controller, scenario.dt), dtype=float)
    v, w, seg_idx, ref, dith = block
    K, n = v.shape[1], v.shape[2]
    st = np.concatenate([state.x[0], [state.integ[0], state.deriv[0], state.y_prev[0]]])
    zt, ut = np.empty((K, w.shape[2])), np.empty(K)
    c = np.ascontiguousarray
    _stream_kernel(
        c(v[0]), c(w[0]), c(seg_idx, dtype=np.int64), tb.A, tb.C, tb.Lq, tb.Lr, tb.diag, tb.B, coef,
        int(loop.output), c(ref, dtype=float), c(dith, dtype=float), st, zt, ut,
    )  # fmt: skip
    new = LoopState(
        st[None, :n].copy(), st[n : n + 1].copy(), st[n + 1 : n + 2].copy(), st[n + 2 : n + 3].copy()
    )
    return zt, ut, new


def _loop_of(scenario: Scenario) -> ClosedLoop:
    loop = getattr(scenario, "input", None)
    if not isinstance(loop, ClosedLoop):
        raise ParameterError(f"scenario {getattr(scenario, 'name', '?')!r} is not a closed-loop scenario")
    return loop


def _step_linear(
    scenario: Scenario, block: _Block, state: LoopState, tb: _LinearTables
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    """K samples of the linear loop for ``runs`` realizations from ``state`` (numpy path)."""
    loop = _loop_of(scenario)
    coef = np.asarray(pid_coefficients(loop.controller, scenario.dt), dtype=float)
    v, w, seg_idx, ref, dith = block
    return _loop_numpy(v, w, np.asarray(seg_idx), tb, ref, dith, coef, loop.output, state)


def _block_linear_compiled(scenario: Scenario, block: _Block) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Runs of one random block from rest through the compiled loop: ``(x, z, u)`` time-major."""
    loop = _loop_of(scenario)
    v, w, seg_idx, ref, dith = block
    runs, T, n = v.shape
    m = w.shape[2]
    tb = _linear_tables(scenario)
    coef = np.asarray(pid_coefficients(loop.controller, scenario.dt), dtype=float)
    ctrl = _pack(coef, loop.output, tb.B, ref, dith, runs)
    xt, zt = np.empty((T, runs, n)), np.empty((T, runs, m))
    x0 = np.ascontiguousarray(scenario.x0, dtype=float)
    seg = np.ascontiguousarray(seg_idx, dtype=np.int64)
    no_table = np.empty((0, 0, 0))  # the open-loop input table: unused by the controller step
    _closed_loop_sized(n, m)(
        v, w, seg, tb.A, tb.C, tb.Lq, tb.Lr, no_table, x0, tb.diag, ctrl, xt, zt, NO_ARRAY, NO_ARRAY, 0
    )  # fmt: skip
    return xt, zt, _unpack_u(ctrl, tb.B, T, runs)


def _step_nonlinear(
    scenario: Scenario, block: _Block, state: LoopState
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    """K samples of the loop around a nonlinear plant (numpy path, vectorized ``f``)."""
    loop = _loop_of(scenario)
    v, w, seg_idx, ref, dith = block
    coef = np.asarray(pid_coefficients(loop.controller, scenario.dt), dtype=float)
    segs = scenario.segments
    runs, K, n = v.shape
    m = w.shape[2]
    Lq = [covariance_sqrt(sg.model.Q) for sg in segs]
    Lr = [covariance_sqrt(sg.model.R) for sg in segs]
    f = [getattr(sg.model, "f", sg.model.transition) for sg in segs]
    x = np.array(state.x, dtype=float)
    integ, deriv, y_prev = state.integ.copy(), state.deriv.copy(), state.y_prev.copy()
    xt, zt, ut = np.empty((K, runs, n)), np.empty((K, runs, m)), np.empty((K, runs))
    out = loop.output
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(K):
            s = int(seg_idx[k])
            C = segs[s].model.C
            z = (x if np.array_equal(C, np.eye(n)) else x @ C.T) + _scale(w[:, k], Lr[s])
            y = z[:, out].copy()
            u, integ, deriv = _control_rows(coef, integ, deriv, y_prev, ref[k], y, dith[k])
            y_prev = y
            xt[k], zt[k], ut[k] = x, z, u
            x = f[s](x, u[:, None]) + _scale(v[:, k], Lq[s])
    bad = ~np.isfinite(xt)
    if bad.any():
        k, r, _ = np.argwhere(bad)[0]
        raise NonFiniteError(
            f"scenario {scenario.name!r}: the true state is not finite from sample {k} (realization {r} of "
            "this chunk): the closed loop diverged -- lower the controller gains or the saturation (EHA4: "
            "2 dt a1 |v| / M must stay below 1)"
        )
    return xt, zt, ut, LoopState(x, integ, deriv, y_prev)


def _run(
    scenario: Scenario, block: _Block, state: LoopState, tables: _LinearTables | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    """K samples of the loop on the numpy path, linear (``tables``: the scenario's, if at hand) or not."""
    if getattr(scenario, "is_linear", True):
        return _step_linear(scenario, block, state, _linear_tables(scenario) if tables is None else tables)
    return _step_nonlinear(scenario, block, state)


def simulate_block_closed_loop(
    scenario: Scenario, root: np.random.SeedSequence, lo: int, hi: int, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate realizations ``lo .. hi - 1`` of a closed-loop scenario.

    Parameters
    ----------
    scenario : Scenario
        Its ``input`` is a :class:`~chatterspec.plants.closed_loop.ClosedLoop`.
    root, lo, hi, t
        As in :func:`~chatterspec.plants.simulate.simulate_block_nonlinear`.

    Returns
    -------
    x, z : ndarrays
        True states and measurements, as in ``simulate_block_nonlinear``.
    u : (hi - lo, T, 1) ndarray
        Applied (saturated) pump speed in rad/s.
    """
    loop = _loop_of(scenario)
    T = len(t)
    nom = scenario.nominal
    n, m = nom.n_states, nom.n_outputs
    ref, dith = loop.signals(t)
    seg_idx = scenario.segment_index(t)
    xt, zt, ut = np.empty((T, hi - lo, n)), np.empty((T, hi - lo, m)), np.empty((T, hi - lo))
    compiled = _jit.enabled() and getattr(scenario, "is_linear", True) and same_shapes(scenario)
    for off, v, w in _noise_blocks(root, lo, hi, T, n, m):
        b = v.shape[0]
        block = _Block(v, w, seg_idx, ref, dith)
        if compiled:
            x, z, u = _block_linear_compiled(scenario, block)
        else:
            x, z, u, _ = _run(scenario, block, _initial_state(scenario.x0, b))
        xt[:, off : off + b], zt[:, off : off + b], ut[:, off : off + b] = x, z, u
    return np.swapaxes(xt, 0, 1), np.swapaxes(zt, 0, 1), np.swapaxes(ut, 0, 1)[..., None]


def stream_geometry(scenario: Scenario, duration_s: float | None, block_s: float) -> tuple[int, int, int]:
    """Sample counts of a stream of ``scenario`` block by block: ``(total, period, block)``.

    Parameters
    ----------
    scenario : Scenario
        Its ``dt`` and ``duration`` (s).
    duration_s : float or None
        Seconds of data (None: the scenario's duration); samples at ``0, dt, ..., duration_s``.
    block_s : float
        Seconds of data per block.

    Returns
    -------
    (int, int, int)
        Samples in the stream, samples of one scenario period (the timeline repeats beyond it),
        samples per block (at least 1).

    Raises
    ------
    ParameterError
        A duration that is not a positive finite number of seconds.
    """
    dt = scenario.dt
    D = scenario.duration
    duration = D if duration_s is None else float(duration_s)
    if not (np.isfinite(duration) and duration > 0):
        raise ParameterError(f"duration must be > 0 s; got {duration_s!r}")
    return round(duration / dt) + 1, round(D / dt), max(1, round(block_s / dt))


def closed_loop_blocks(
    scenario: Scenario, seed: int, duration_s: float | None = None, *, block_s: float = 1.0
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One realization of a closed-loop scenario block by block in time (bounded memory).

    The closed-loop counterpart of :func:`chatterspec.online.simulated_stream.simulate_blocks`: plant and
    controller state run on from block to block, the noise comes from one generator
    (``SeedSequence(seed)``, ``n + m`` normals per sample in time order, so the rows for a seed do not
    depend on ``block_s``), and beyond the scenario's duration ``D`` the reference,
    the dither and the true-plant timeline repeat (evaluated at ``t mod D``).

    Parameters
    ----------
    scenario : Scenario
        A closed-loop scenario.
    seed : int
        Root seed (>= 0).
    duration_s : float, optional
        Seconds of data (default: the scenario's duration); samples at ``0, dt, ..., duration_s``.
    block_s : float
        Seconds of data per yielded block.

    Yields
    ------
    (t, z, u)
        Times (K,) in s, measurements (K, m), applied pump speed (K, 1) in rad/s.
    """
    loop = _loop_of(scenario)
    dt = scenario.dt
    total, period, K = stream_geometry(scenario, duration_s, block_s)
    nom = scenario.nominal
    n, m = nom.n_states, nom.n_outputs
    state = _initial_state(scenario.x0, 1)
    tables = _linear_tables(scenario) if getattr(scenario, "is_linear", True) else None
    # one generator drawn sample by sample: the rows of a seed do not depend on block_s (the --rate pacing)
    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
    for lo in range(0, total, K):
        hi = min(lo + K, total)
        k = np.arange(lo, hi)
        tp = (k % period) * dt
        ref, dith = loop.signals(tp)
        noise = rng.standard_normal((hi - lo, n + m))  # per sample: n process, m measurement normals
        v, w = noise[None, :, :n], noise[None, :, n:]
        seg = scenario.segment_index(tp)
        if tables is not None and _jit.enabled():  # one compiled call per block (the same numbers)
            z1, u1, state = _stream_linear(scenario, _Block(v, w, seg, ref, dith), state, tables)
            yield k * dt, z1, u1[:, None]
            continue
        _, z, u, state = _run(scenario, _Block(v, w, seg, ref, dith), state, tables)
        yield k * dt, z[:, 0], u[:, 0, None]


def loop_response(
    scenario: Scenario, t: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The noise-free response of a closed-loop scenario (its plant segments, no v or w).

    Parameters
    ----------
    scenario : Scenario
        A closed-loop scenario.
    t : (T,) array, optional
        Sample times in s (default ``scenario.time``).

    Returns
    -------
    t : (T,) ndarray
    r : (T,) ndarray
        Reference (m), dither on the reference included.
    x : (T, n) ndarray
        True state.
    u : (T,) ndarray
        Applied pump speed (rad/s).
    """
    loop = _loop_of(scenario)
    t = scenario.time if t is None else np.asarray(t, dtype=float)
    nom = scenario.nominal
    ref, dith = loop.signals(t)
    zeros_v = np.zeros((1, len(t), nom.n_states))
    zeros_w = np.zeros((1, len(t), nom.n_outputs))
    state = _initial_state(scenario.x0, 1)
    block = _Block(zeros_v, zeros_w, scenario.segment_index(t), ref, dith)
    x, _, u, _ = _run(scenario, block, state)
    return t, ref, x[:, 0], u[:, 0]


def is_closed_loop(scenario: Scenario) -> bool:
    """Whether ``scenario``'s input is a :class:`~chatterspec.plants.closed_loop.ClosedLoop`."""
    return isinstance(getattr(scenario, "input", None), ClosedLoop)


# The public simulation.

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

    __repr__ = short_repr  # shapes and key figures, never whole arrays
    _repr_extra = ("runs",)

    t: np.ndarray
    x: np.ndarray
    z: np.ndarray
    u: np.ndarray
    scenario: Scenario
    first_run: int = 0

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.z.shape[0]

    def take(self, runs: slice) -> Simulation:
        """The realizations ``runs`` (a slice of this chunk), as copies; a per-realization ``u`` follows."""
        u = self.u[runs].copy() if self.u.ndim == 3 else self.u
        first = self.first_run + (runs.indices(self.runs)[0])
        return Simulation(self.t, self.x[runs].copy(), self.z[runs].copy(), u, self.scenario, first)

    def input_of(self, run: int) -> np.ndarray:
        """The input ``(T, p)`` of realization ``run`` (index within this chunk)."""
        return self.u[run] if self.u.ndim == 3 else self.u


def chunk_runs_of(scenario: Scenario, chunk_runs: int | None) -> int:
    """Realizations per chunk for ``scenario``: ``chunk_runs`` checked (an integer >= 1), or for None a
    multiple of 64 whose arrays fit :data:`CHUNK_BYTES`."""
    if chunk_runs is not None:
        return positive_int("chunk_runs", chunk_runs)
    T = scenario.n_samples
    per_run = 8 * T * 2 * (scenario.nominal.n_states + scenario.nominal.n_outputs)
    return max(64, int(CHUNK_BYTES // per_run) // 64 * 64)


def model_scenario(model: LinearModel, duration: float = 4.0, name: str | None = None) -> Scenario:
    """A healthy scenario for a user model: zero input, the model as nominal and true plant.

    The input is zero on every channel: the healthy chattering of a matched linear model does not
    depend on u.

    Parameters
    ----------
    model : LinearModel
        Nominal model, also used as the true plant (no fault windows).
    duration : float
        Record length in seconds (default 4 s, the paper's record).
    name : str, optional
        Scenario name; default ``model.name``, or ``"user-model"`` if that is empty.

    Returns
    -------
    Scenario
        Family ``"user"``, healthy.
    """
    from .signals import ZeroInput

    return Scenario(
        name=name or model.name or "user-model",
        nominal=model,
        input=ZeroInput(model.n_inputs),
        duration=duration,
        description="user model, healthy, zero input",
        family="user",
    )


def as_scenario(
    scenario: Scenario | LinearModel | str | os.PathLike[str], default_duration: float = 4.0
) -> Scenario:
    """``scenario`` itself, the catalogue scenario of that name, or the healthy scenario of a model.

    Parameters
    ----------
    scenario : Scenario, LinearModel, str or path
        A scenario; a :class:`~chatterspec.plants.models.LinearModel` (its healthy zero-input
        scenario, :func:`model_scenario`); a name of :func:`~chatterspec.plants.scenarios.scenario_names`;
        or a model file ``NAME.toml`` (linear or nonlinear), whose scenario is its ``[simulation]``
        table (input, initial state, duration; zero input and ``default_duration`` by default) with
        the file's model as nominal model and true plant, named after the file stem.
    default_duration : float
        Record length in seconds of a model, or of a model file without ``[simulation] duration_s``
        (default 4); catalogue scenarios and Scenario objects carry their own.

    Returns
    -------
    Scenario
        A Scenario argument itself (not a copy); otherwise a new one.

    Raises
    ------
    UnknownScenarioError
        For a name that is not in the catalogue (the message lists the names).
    ParameterError
        For anything else.
    """
    if isinstance(scenario, LinearModel):
        return model_scenario(scenario, default_duration)
    if isinstance(scenario, str | os.PathLike) and str(scenario).endswith(".toml"):
        from .modelfile import file_scenario, load_model

        return file_scenario(load_model(scenario), default_duration, name=Path(scenario).stem)
    if isinstance(scenario, str):
        from .scenarios import scenario as by_name

        return by_name(scenario)
    if not hasattr(scenario, "nominal"):  # a Scenario (duck-typed, as the studies pass them)
        raise ParameterError(
            "scenario must be a Scenario, a LinearModel, a model file (.toml) or a catalogue name (str); "
            f"got {type(scenario).__name__}"
        )
    return cast(Scenario, scenario)  # a Scenario (or a duck-typed one), by the check above


def simulate(
    scenario: Scenario | LinearModel | str,
    runs: int = 1,
    seed: SeedLike = None,
    *,
    chunk_runs: int | None = None,
) -> Simulation:
    """Simulate ``runs`` independent realizations of ``scenario``'s true plant.

    Parameters
    ----------
    scenario : Scenario, LinearModel or str
        Nominal model, time-segmented true plant, input and duration; or a catalogue name
        (``"eha-healthy"``), a model file (``"my_model.toml"``) or a model (its healthy 4 s
        scenario, zero input; see :func:`as_scenario`).
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
    scenario = as_scenario(scenario)
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
    scenario: Scenario | LinearModel | str,
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
    scenario : Scenario, LinearModel or str
        Nominal model, time-segmented true plant, input and duration (seconds); or a catalogue name,
        model file or model (:func:`as_scenario`).
    runs : int
        Number of realizations to yield in total (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams (see :func:`chatterspec.montecarlo.root_seed_sequence`).
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
        :mod:`chatterspec.plants.simulate`) and ``t`` (T,) in seconds, and
        ``first_run`` set to its first realization index.

    Raises
    ------
    ShapeError
        If the scenario's input has a different number of channels than the model.
    """
    runs = positive_int("runs", runs)
    scenario = as_scenario(scenario)
    chunk = chunk_runs_of(scenario, chunk_runs)
    root = root_seed_sequence(seed)
    if getattr(scenario, "closed_loop", None) is not None:
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


def _simulate_block(
    scenario: Scenario, root: np.random.SeedSequence, lo: int, hi: int, t: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    if not getattr(scenario, "is_linear", True) and hi - lo > 1:
        # nonlinear true plant: same seeding scheme, f(x, u) stepping (simulate_block_nonlinear)
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
    # the chunking (see chatterspec.montecarlo).
    vt, zt = scaled_noise(scenario, root, lo, hi, t, _linear_scale)
    xt = np.empty((T, hi - lo, n))
    xt[0] = scenario.x0
    # x_aug = [x, 1] and W = [[A^T], [(B u(k))^T]] fold the input into one matmul
    x_aug = np.ones((hi - lo, n + 1))
    x_aug[:, :n] = scenario.x0
    linear = [cast(LinearModel, seg.model) for seg in segments]  # (the caller took the linear path)
    W = [np.vstack([lm.A.T, np.zeros((1, n))]) for lm in linear]
    Bu = [u @ lm.B.T for lm in linear]
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


# Overshoot and settling time of a closed-loop scenario's moves.


@dataclass(frozen=True)
class MoveMetrics:
    """The response to one move of the reference.

    Attributes
    ----------
    start_s, end_s : float
        When the reference starts and stops moving (s; equal for a step).
    step_m : float
        ``r1 - r0`` in m.
    overshoot_pct : float
        Overshoot in % of ``|step_m|`` (0 when the position stays short of ``r1``).
    settling_s : float
        Settling time into the band after ``end_s`` (s).
    peak_u : float
        Largest ``|u|`` (rad/s) between this move's start and the next one's.
    saturated : bool
        Whether ``u`` reached the saturation during the move.
    """

    start_s: float
    end_s: float
    step_m: float
    overshoot_pct: float
    settling_s: float
    peak_u: float
    saturated: bool

    def to_dict(self) -> dict[str, float | bool]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {
            "start_s": self.start_s,
            "end_s": self.end_s,
            "step_mm": self.step_m * 1e3,
            "overshoot_pct": self.overshoot_pct,
            "settling_s": self.settling_s,
            "peak_u": self.peak_u,
            "saturated": self.saturated,
        }


def move_metrics(scenario: Scenario, band: float = 0.02) -> list[MoveMetrics]:
    """Overshoot and settling time of every move of a closed-loop scenario's reference (no noise).

    Parameters
    ----------
    scenario : Scenario
        A closed-loop scenario whose reference is a ``StepSequence`` or an ``SCurve`` (no dither
        on the reference).
    band : float
        Settling band as a fraction of the step (default 2 %).

    Returns
    -------
    list of MoveMetrics
        One per move that ends inside the record.
    """
    loop = getattr(scenario, "closed_loop", None)
    if loop is None:
        raise ParameterError(f"{getattr(scenario, 'name', '?')!r} is not a closed-loop scenario")
    ref = loop.reference
    if not isinstance(ref, StepSequence | SCurve):
        raise ParameterError(
            f"move metrics need a StepSequence or SCurve reference; got {type(ref).__name__}"
        )
    move_time = ref.move_time if isinstance(ref, SCurve) else 0.0
    t, _, x, u = loop_response(scenario)
    y = x[:, loop.output]
    levels = (ref.initial, *ref.levels)
    out = []
    for j, start in enumerate(ref.times):
        r0, r1 = levels[j], levels[j + 1]
        step = r1 - r0
        end = start + move_time
        nxt = ref.times[j + 1] if j + 1 < len(ref.times) else t[-1] + scenario.dt
        after = (t >= end - 1e-9) & (t < nxt - 1e-9)
        during = (t >= start - 1e-9) & (t < nxt - 1e-9)
        if step == 0 or not after.any():  # no move, or it ends after the record
            continue
        over = float(np.max((y[after] - r1) * np.sign(step)) / abs(step) * 100.0)
        outside = np.abs(y[after] - r1) > band * abs(step)
        if not outside.any():
            settle = 0.0
        elif outside[-1]:
            settle = float("inf")
        else:
            settle = float(t[after][np.flatnonzero(outside)[-1] + 1] - end)
        peak = float(np.abs(u[during]).max())
        out.append(
            MoveMetrics(
                start_s=float(start),
                end_s=float(end),
                step_m=float(step),
                overshoot_pct=max(over, 0.0),
                settling_s=settle,
                peak_u=peak,
                saturated=bool(peak >= loop.controller.saturation),
            )
        )
    return out
