"""Batched simulation of a plant under its position controller (``plants.closed_loop.ClosedLoop``).

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
:func:`~chatterspec.plants.linear_steps.measure_step` (eq 2) and
:func:`~chatterspec.plants.linear_steps.advance_step` (eq 1), and the controller's
:func:`~chatterspec.plants.controllers.pid_step`. The compiled path is the open-loop simulation's
loop (``plants.simulate_kernel.plant_loop``) with :func:`controller_input` as its input step, in place
of the input table; the numpy path (:func:`_loop_numpy`) calls the same steps' Python functions on
rows of realizations (channel-major ``(n, runs)`` state), doing the same correctly rounded
operations in the same order, so both paths give the same bits. A nonlinear plant (the 4-state
EHA) runs on the numpy path with its vectorized ``f``. The streaming generator
:func:`closed_loop_blocks` (one realization, state carried between blocks) runs each block of a
linear plant in one compiled call (:func:`_stream_kernel`, the same steps), else the numpy path.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple, cast

import numpy as np

from .. import _jit
from ..errors import NonFiniteError, ParameterError
from .closed_loop import ClosedLoop
from .controllers import pid_coefficients, pid_step
from .linear_steps import advance_step, measure_step
from .simulate_kernel import NO_ARRAY, _noise_blocks, covariance_sqrt
from .simulate_kernel import kernel_tables as _tables
from .simulate_kernel import plant_loop as _plant_loop
from .simulate_kernel import same_shapes as _same_shapes
from .simulate_nonlinear import _scale

if TYPE_CHECKING:  # pragma: no cover
    from .linear_model import LinearModel
    from .scenario_types import Scenario

__all__ = ["LoopState", "closed_loop_blocks", "is_closed_loop", "loop_response", "simulate_block_closed_loop"]


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
#: :class:`~chatterspec.plants.controllers.PIDCoefficients`, then the record length T, the number of
#: segments S, the position output index, the running state (I, D, y_prev) of the current run,
#: then B_s (S x n, row-major), the reference r (T), the input dither d (T) and the output u (rows x T).
_T, _S, _OUT, _STATE, _B = 8, 9, 10, 11, 14


@_jit.step
def controller_input(
    row: int, s: int, k: int, z: np.ndarray, Bu: np.ndarray, ctrl: np.ndarray, bu: np.ndarray, n: int
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_closed_loop_sim.py)
    """The simulation loop's input step in closed loop: ``u(k)`` from ``z(k)``, then ``bu = B_s u(k)``.

    Reads the position ``z[out]``, runs :func:`~chatterspec.plants.controllers.pid_step` on the
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
_closed_loop_kernel = _jit.specialize(_plant_loop, "closed_loop", INPUT=controller_input)


def _closed_loop_sized(n: int, m: int) -> Callable[..., Any]:
    """:data:`_closed_loop_kernel` with the model's sizes as constants when small (as the open loop's)."""
    return _jit.specialize_sizes(_plant_loop, "closed_loop", {"NX": n, "NZ": m}, INPUT=controller_input)


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
    """The open-loop per-segment tables (``plants.simulate_kernel.kernel_tables``) and each segment's B."""
    tb = _tables(scenario, np.zeros(1), np.zeros((1, 1)))  # no input table needed
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
        As in :func:`~chatterspec.plants.simulate_nonlinear.simulate_block_nonlinear`.

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
    compiled = _jit.enabled() and getattr(scenario, "is_linear", True) and _same_shapes(scenario)
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
