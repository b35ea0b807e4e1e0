"""Batched simulation of a plant under its position controller (``plants.closed_loop.ClosedLoop``).

At each sample ``k``, for every realization::

    z(k)   = C_s x(k) + Lr_s w(k)                         measurement (eq 2)
    u(k)   = pid_step(r(k), z_pos(k), d(k), controller state)   pump speed, rad/s
    x(k+1) = A_s x(k) + B_s u(k) + Lq_s v(k)              (eq 1; f_s(x, u) + v for a nonlinear plant)

with the segment ``s`` active at ``t_k``. The controller reads the same noisy measurement the filters
see, and ``u(k)`` is returned per realization (``Simulation.u`` of shape ``(runs, T, 1)``): the
filters run the open-loop nominal model with it. Seeding is that of the open-loop simulation
(:mod:`chatterspec.rng`: realization ``r`` draws block ``r // 64``, stream 0 = v, stream 1 = w), so
any chunking gives the same numbers, and a loop with zero gains whose input dither equals an
open-loop scenario's input reproduces that scenario's simulation bit for bit (tested).

The per-sample arithmetic is written once, as three steps with scalar arithmetic:
:func:`_measure` (eq 2), :func:`_advance` (eq 1, linear) and
:func:`chatterspec.plants.controllers.pid_step`. The compiled loop (:func:`_loop_kernel`, numba)
calls them on one realization at a time; the numpy path (:func:`_loop_numpy`) calls the same Python
functions on rows of realizations (channel-major ``(n, runs)`` state), doing the same correctly
rounded operations in the same order, so both paths give the same bits. The linear plant's
operations and their order are those of the open-loop ``plants.simulate._simulate_kernel``.
A nonlinear plant (the 4-state EHA) runs on the numpy path with its vectorized ``f``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from .. import _jit
from ..errors import NonFiniteError, ParameterError
from ..rng import SeedLike
from .closed_loop import ClosedLoop
from .controllers import pid_coefficients, pid_step
from .simulate import _is_diagonal, _noise_blocks, covariance_sqrt

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


def _initial_state(x0: np.ndarray, runs: int) -> LoopState:
    return LoopState(
        x=np.repeat(np.asarray(x0, dtype=float)[None], runs, axis=0),
        integ=np.zeros(runs),
        deriv=np.zeros(runs),
        y_prev=np.full(runs, np.nan),
    )


# --------------------------------------------------------------------------- the steps
@_jit.step
def _measure(
    C: np.ndarray, Lr: np.ndarray, diag_r: bool, x: np.ndarray, w: np.ndarray, z: np.ndarray
) -> None:  # pragma: no cover - compiled (its Python form runs on the numpy path)
    """``z = C x + Lr w`` (eq 2), sums over j = 0, 1, ... in order; only Lr's diagonal when ``diag_r``.

    ``x`` (n,), ``w`` (m,), ``z`` (m,) floats (compiled, one realization) or rows of realizations
    ``(n, runs)``, ``(m, runs)`` (numpy path).
    """
    m, n = C.shape
    for i in range(m):
        cx = 0.0
        for j in range(n):
            cx += C[i, j] * x[j]
        if diag_r:
            nz = Lr[i, i] * w[i]
        else:
            nz = 0.0
            for j in range(m):
                nz += Lr[i, j] * w[j]
        z[i] = cx + nz


@_jit.step
def _advance(
    A: np.ndarray,
    B: np.ndarray,
    Lq: np.ndarray,
    diag_q: bool,
    x: np.ndarray,
    u: float,
    v: np.ndarray,
    xn: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form runs on the numpy path)
    """``xn = (A x + B u) + Lq v`` (eq 1, one input), in the order of the open-loop simulation kernel."""
    n = A.shape[0]
    for i in range(n):
        ax = 0.0
        for j in range(n):
            ax += A[i, j] * x[j]
        if diag_q:
            nv = Lq[i, i] * v[i]
        else:
            nv = 0.0
            for j in range(n):
                nv += Lq[i, j] * v[j]
        xn[i] = (ax + B[i] * u) + nv


@_jit.njit
def _loop_kernel(
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    A: np.ndarray,
    B: np.ndarray,
    C: np.ndarray,
    Lq: np.ndarray,
    Lr: np.ndarray,
    diag: np.ndarray,
    ref: np.ndarray,
    dith: np.ndarray,
    coef: np.ndarray,
    out_idx: int,
    xs: np.ndarray,
    cs: np.ndarray,
    xt: np.ndarray,
    zt: np.ndarray,
    ut: np.ndarray,
    offset: int,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_closed_loop_sim.py)
    """The closed loop for the runs of one random block; states in ``xs`` (runs, n), ``cs`` (runs, 3) updated.

    Run r's samples go to ``xt[:, offset + r]``, ``zt[:, offset + r]``, ``ut[:, offset + r]`` (time-major);
    ``cs[r] = (I, D, y_prev)``, ``y_prev`` NaN before the first sample. After the last sample the
    plant is advanced once more, so ``xs`` holds ``x(K)`` for the next block.
    """
    runs, K, n = v.shape
    m = w.shape[2]
    x = np.empty(n)
    xn = np.empty(n)
    z = np.empty(m)
    kp, kpb, ki_dt, a_d, kd_f, u_max, k_t, clamp = (
        coef[0], coef[1], coef[2], coef[3], coef[4], coef[5], coef[6], coef[7]
    )  # fmt: skip
    for r in range(runs):
        for i in range(n):
            x[i] = xs[r, i]
        integ, deriv, y_prev = cs[r, 0], cs[r, 1], cs[r, 2]
        for k in range(K):
            s = seg_idx[k]
            _measure(C[s], Lr[s], diag[s, 1], x, w[r, k], z)
            y = z[out_idx]
            if y_prev != y_prev:  # NaN: no earlier measurement (no derivative kick at the start)
                y_prev = y
            u, integ, deriv = pid_step(
                kp, kpb, ki_dt, a_d, kd_f, u_max, k_t, clamp, integ, deriv, y_prev, ref[k], y, dith[k]
            )
            y_prev = y
            for i in range(m):
                zt[k, offset + r, i] = z[i]
            for i in range(n):
                xt[k, offset + r, i] = x[i]
            ut[k, offset + r] = u
            _advance(A[s], B[s], Lq[s], diag[s, 0], x, u, v[r, k], xn)
            for i in range(n):
                x[i] = xn[i]
        for i in range(n):
            xs[r, i] = x[i]
        cs[r, 0], cs[r, 1], cs[r, 2] = integ, deriv, y_prev


def _py(fn: object) -> object:
    """The Python function behind a compiled kernel (numpy path)."""
    return getattr(fn, "py_func", fn)


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
    """:func:`_loop_kernel` vectorized over realizations: the same steps on ``(channels, runs)`` rows."""
    measure, advance, step = _py(_measure), _py(_advance), _py(pid_step)
    runs, K, n = v.shape
    m = w.shape[2]
    vt = np.ascontiguousarray(v.transpose(1, 2, 0))  # (K, n, runs)
    wt = np.ascontiguousarray(w.transpose(1, 2, 0))
    x = np.ascontiguousarray(state.x.T)  # (n, runs)
    xn = np.empty_like(x)
    z = np.empty((m, runs))
    integ, deriv = state.integ.copy(), state.deriv.copy()
    y_prev = state.y_prev.copy()
    xt, zt, ut = np.empty((K, runs, n)), np.empty((K, runs, m)), np.empty((K, runs))
    for k in range(K):
        s = seg_idx[k]
        measure(tb.C[s], tb.Lr[s], tb.diag[s, 1], x, wt[k], z)
        y = z[out_idx].copy()
        first = np.isnan(y_prev)
        if first.any():
            y_prev[first] = y[first]
        u, integ, deriv = step(*coef, integ, deriv, y_prev, ref[k], y, dith[k])
        y_prev = y
        zt[k] = z.T
        xt[k] = x.T
        ut[k] = u
        advance(tb.A[s], tb.B[s], tb.Lq[s], tb.diag[s, 0], x, u, vt[k], xn)
        x, xn = xn, x
    return xt, zt, ut, LoopState(np.ascontiguousarray(x.T), integ, deriv, y_prev)


@dataclass(frozen=True, eq=False)
class _LinearTables:
    """Per-segment arrays of a linear closed-loop scenario (segment s active at sample k)."""

    A: np.ndarray  # (S, n, n)
    B: np.ndarray  # (S, n), the one input column
    C: np.ndarray  # (S, m, n)
    Lq: np.ndarray  # (S, n, n), Lq Lq^T = Q
    Lr: np.ndarray  # (S, m, m), Lr Lr^T = R
    diag: np.ndarray  # (S, 2) bool: Lq, Lr diagonal


def _linear_tables(scenario: object) -> _LinearTables:
    segs = scenario.segments  # type: ignore[attr-defined]
    c = np.ascontiguousarray
    return _LinearTables(
        A=c(np.stack([sg.model.A for sg in segs]), dtype=float),
        B=c(np.stack([sg.model.B[:, 0] for sg in segs]), dtype=float),
        C=c(np.stack([sg.model.C for sg in segs]), dtype=float),
        Lq=c(np.stack([covariance_sqrt(sg.model.Q) for sg in segs]), dtype=float),
        Lr=c(np.stack([covariance_sqrt(sg.model.R) for sg in segs]), dtype=float),
        diag=np.array([[_is_diagonal(sg.model.Q), _is_diagonal(sg.model.R)] for sg in segs], dtype=np.bool_),
    )


def _loop_of(scenario: object) -> ClosedLoop:
    loop = getattr(scenario, "input", None)
    if not isinstance(loop, ClosedLoop):
        raise ParameterError(f"scenario {getattr(scenario, 'name', '?')!r} is not a closed-loop scenario")
    return loop


def _step_linear(
    scenario: object,
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    ref: np.ndarray,
    dith: np.ndarray,
    state: LoopState,
    tb: _LinearTables,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    """K samples of the linear loop for ``runs`` realizations (noise ``v``, ``w``: ``(runs, K, n|m)``)."""
    loop = _loop_of(scenario)
    coef = np.asarray(pid_coefficients(loop.controller, scenario.dt), dtype=float)  # type: ignore[attr-defined]
    seg_idx = np.ascontiguousarray(seg_idx, dtype=np.int64)
    if not _jit.enabled():
        return _loop_numpy(v, w, seg_idx, tb, ref, dith, coef, loop.output, state)
    runs, K, n = v.shape
    m = w.shape[2]
    xs = np.array(state.x, dtype=float)
    cs = np.ascontiguousarray(np.stack([state.integ, state.deriv, state.y_prev], axis=1), dtype=float)
    xt, zt, ut = np.empty((K, runs, n)), np.empty((K, runs, m)), np.empty((K, runs))
    _loop_kernel(
        v,
        w,
        seg_idx,
        tb.A,
        tb.B,
        tb.C,
        tb.Lq,
        tb.Lr,
        tb.diag,
        ref,
        dith,
        coef,
        loop.output,
        xs,
        cs,
        xt,
        zt,
        ut,
        0,
    )
    return xt, zt, ut, LoopState(xs, cs[:, 0].copy(), cs[:, 1].copy(), cs[:, 2].copy())


def _step_nonlinear(
    scenario: object,
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    ref: np.ndarray,
    dith: np.ndarray,
    state: LoopState,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    """K samples of the loop around a nonlinear plant (numpy path, vectorized ``f``)."""
    loop = _loop_of(scenario)
    coef = pid_coefficients(loop.controller, scenario.dt)  # type: ignore[attr-defined]
    step = _py(pid_step)
    segs = scenario.segments  # type: ignore[attr-defined]
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
            first = np.isnan(y_prev)
            if first.any():
                y_prev[first] = y[first]
            u, integ, deriv = step(*coef, integ, deriv, y_prev, ref[k], y, dith[k])
            y_prev = y
            xt[k], zt[k], ut[k] = x, z, u
            x = f[s](x, u[:, None]) + _scale(v[:, k], Lq[s])
    bad = ~np.isfinite(xt)
    if bad.any():
        k, r, _ = np.argwhere(bad)[0]
        raise NonFiniteError(
            f"scenario {scenario.name!r}: the true state is not finite from sample {k} (realization {r} of "  # type: ignore[attr-defined]
            "this chunk): the closed loop diverged -- lower the controller gains or the saturation (EHA4: "
            "2 dt a1 |v| / M must stay below 1)"
        )
    return xt, zt, ut, LoopState(x, integ, deriv, y_prev)


def _scale(noise: np.ndarray, L: np.ndarray) -> np.ndarray:
    """``noise @ L.T``, element-wise when L is diagonal (as the open-loop nonlinear simulation)."""
    if _is_diagonal(L):
        return noise * np.diag(L)
    return noise @ L.T


def _run(
    scenario: object,
    v: np.ndarray,
    w: np.ndarray,
    seg_idx: np.ndarray,
    ref: np.ndarray,
    dith: np.ndarray,
    state: LoopState,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, LoopState]:
    if getattr(scenario, "is_linear", True):
        return _step_linear(scenario, v, w, seg_idx, ref, dith, state, _linear_tables(scenario))
    return _step_nonlinear(scenario, v, w, seg_idx, ref, dith, state)


def simulate_block_closed_loop(
    scenario: object, root: np.random.SeedSequence, lo: int, hi: int, t: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Simulate realizations ``lo .. hi - 1`` of a closed-loop scenario.

    Parameters
    ----------
    scenario : Scenario
        Its ``input`` is a :class:`~chatterspec.plants.closed_loop.ClosedLoop`.
    root : numpy.random.SeedSequence
        Root of the random streams (:mod:`chatterspec.rng`).
    lo, hi : int
        Global indices of the first and one-past-the-last realization.
    t : (T,) array
        Sample times in s.

    Returns
    -------
    x : (hi - lo, T, n) ndarray
        True states.
    z : (hi - lo, T, m) ndarray
        Measurements.
    u : (hi - lo, T, 1) ndarray
        Applied (saturated) pump speed in rad/s.
    """
    loop = _loop_of(scenario)
    T = len(t)
    nom = scenario.nominal  # type: ignore[attr-defined]
    n, m = nom.n_states, nom.n_outputs
    ref, dith = loop.signals(t)
    seg_idx = scenario.segment_index(t)  # type: ignore[attr-defined]
    xt, zt, ut = np.empty((T, hi - lo, n)), np.empty((T, hi - lo, m)), np.empty((T, hi - lo))
    for off, v, w in _noise_blocks(root, lo, hi, T, n, m):
        b = v.shape[0]
        state = _initial_state(scenario.x0, b)  # type: ignore[attr-defined]
        x, z, u, _ = _run(scenario, v, w, seg_idx, ref, dith, state)
        xt[:, off : off + b], zt[:, off : off + b], ut[:, off : off + b] = x, z, u
    return np.swapaxes(xt, 0, 1), np.swapaxes(zt, 0, 1), np.swapaxes(ut, 0, 1)[..., None]


def closed_loop_blocks(
    scenario: object, seed: SeedLike, duration_s: float | None = None, *, block_s: float = 1.0
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """One realization of a closed-loop scenario block by block in time (bounded memory).

    The closed-loop counterpart of :func:`chatterspec.online.stream.simulate_blocks`: plant and
    controller state run on from block to block, the noise of block ``b`` comes from
    ``SeedSequence(seed, spawn_key=(b,))``, and beyond the scenario's duration ``D`` the reference,
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
    dt = scenario.dt  # type: ignore[attr-defined]
    D = scenario.duration  # type: ignore[attr-defined]
    duration = D if duration_s is None else float(duration_s)
    if not (np.isfinite(duration) and duration > 0):
        raise ParameterError(f"duration must be > 0 s; got {duration_s!r}")
    total = round(duration / dt) + 1
    period = round(D / dt)
    K = max(1, round(block_s / dt))
    nom = scenario.nominal  # type: ignore[attr-defined]
    n, m = nom.n_states, nom.n_outputs
    state = _initial_state(scenario.x0, 1)  # type: ignore[attr-defined]
    tables = _linear_tables(scenario) if getattr(scenario, "is_linear", True) else None
    for b, lo in enumerate(range(0, total, K)):
        hi = min(lo + K, total)
        k = np.arange(lo, hi)
        tp = (k % period) * dt
        ref, dith = loop.signals(tp)
        rng = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(b,)))  # type: ignore[arg-type]
        v = rng.standard_normal((1, hi - lo, n))
        w = rng.standard_normal((1, hi - lo, m))
        seg = scenario.segment_index(tp)  # type: ignore[attr-defined]
        if tables is not None:
            _, z, u, state = _step_linear(scenario, v, w, seg, ref, dith, state, tables)
        else:
            _, z, u, state = _step_nonlinear(scenario, v, w, seg, ref, dith, state)
        yield k * dt, z[:, 0], u[:, 0, None]


def loop_response(
    scenario: object, t: np.ndarray | None = None
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
    t = scenario.time if t is None else np.asarray(t, dtype=float)  # type: ignore[attr-defined]
    nom = scenario.nominal  # type: ignore[attr-defined]
    ref, dith = loop.signals(t)
    zeros_v = np.zeros((1, len(t), nom.n_states))
    zeros_w = np.zeros((1, len(t), nom.n_outputs))
    state = _initial_state(scenario.x0, 1)  # type: ignore[attr-defined]
    x, _, u, _ = _run(scenario, zeros_v, zeros_w, scenario.segment_index(t), ref, dith, state)  # type: ignore[attr-defined]
    return t, ref, x[:, 0], u[:, 0]


def is_closed_loop(scenario: object) -> bool:
    """Whether ``scenario``'s input is a :class:`~chatterspec.plants.closed_loop.ClosedLoop`."""
    return isinstance(getattr(scenario, "input", None), ClosedLoop)
