"""A catalogue scenario (or a model file's plant) simulated block by block in time, as CSV text.

The source of ``chatterspec simulate``: :func:`simulate_blocks` carries the state from block to block
(bounded memory whatever the duration) and draws the noise from one generator sample by sample, so the
rows for a seed do not depend on the block length (the ``--rate`` pacing); :func:`csv_header` /
:func:`csv_lines` write them in the columns ``chatterspec monitor`` reads.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from .._jit import enabled as _jit_enabled
from .._jit import njit
from ..errors import NonFiniteError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model
from ..plants.scenarios import Scenario
from ..plants.simulate import covariance_sqrt, stream_geometry

__all__ = ["csv_header", "csv_lines", "simulate_blocks"]


@njit
def _propagate(A: np.ndarray, x0: np.ndarray, f: np.ndarray, x: np.ndarray) -> None:  # pragma: no cover
    """``x[0] = x0``, ``x[k+1] = A x[k] + f[k]`` (eq 1 with the input and noise folded into ``f``)."""
    n = x0.shape[0]
    for i in range(n):
        x[0, i] = x0[i]
    for k in range(x.shape[0] - 1):
        for i in range(n):
            acc = f[k, i]
            for j in range(n):
                acc += A[i, j] * x[k, j]
            x[k + 1, i] = acc


def _propagate_numpy(A: np.ndarray, x0: np.ndarray, f: np.ndarray, x: np.ndarray) -> None:
    x[0] = x0
    AT = A.T.copy()
    for k in range(x.shape[0] - 1):
        np.dot(x[k], AT, out=x[k + 1])
        x[k + 1] += f[k]


def simulate_blocks(
    scenario: Scenario, seed: int, duration_s: float | None = None, *, block_s: float = 1.0
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Simulate one realization of ``scenario`` block by block in time (bounded memory).

    The true plant follows eq (1)-(2) as in :func:`chatterspec.plants.simulate.simulate`
    (same segments, input, ``Q`` and ``R``; a nonlinear plant steps its ``f``), with the
    state carried from block to block, so any duration runs in constant memory. Beyond the
    scenario's own duration ``D`` the scenario repeats: input and true-plant timeline are
    evaluated at ``t mod D`` while the state runs on (a 4 s chirp, say, restarts every 4 s).
    The numbers are not those of ``simulate(scenario, seed=seed)``; the distribution is.

    **The same seed gives the same numbers whatever ``block_s``** (so ``chatterspec simulate
    --seed S`` does not depend on ``--rate``): the noise comes from one generator,
    ``default_rng(SeedSequence(seed))``, drawn sample by sample as ``n + m`` standard normals
    (process noise, then measurement noise) in time order, and every per-sample product is
    evaluated element-wise (no matrix kernel whose rounding depends on the block length).

    Parameters
    ----------
    scenario : Scenario
        A catalogue scenario (linear or nonlinear true plant).
    seed : int
        Root seed (>= 0).
    duration_s : float, optional
        Seconds of data (default: the scenario's duration); samples at
        ``0, dt, ..., duration_s``.
    block_s : float
        Seconds of data per yielded block.

    Yields
    ------
    (t, z, u)
        Times (K,) in s, measurements (K, m), inputs (K, p).

    Raises
    ------
    NonFiniteError
        The true state left the finite numbers (e.g. explicit Euler beyond its stability
        limit); the message gives the time.
    """
    if getattr(scenario, "closed_loop", None) is not None:  # the controller computes u from z
        from ..plants.simulate import closed_loop_blocks

        yield from closed_loop_blocks(scenario, seed, duration_s, block_s=block_s)
        return
    dt = scenario.dt
    total, period, K = stream_geometry(scenario, duration_s, block_s)
    segs = scenario.segments
    n, m = scenario.nominal.n_states, scenario.nominal.n_outputs
    LQ = [covariance_sqrt(s.model.Q) for s in segs]
    LR = [covariance_sqrt(s.model.R) for s in segs]
    x = np.array(scenario.x0, dtype=float)
    propagate = _propagate if _jit_enabled() else _propagate_numpy
    rng = np.random.default_rng(np.random.SeedSequence(int(seed)))
    for lo in range(0, total, K):
        hi = min(lo + K, total)
        k = np.arange(lo, hi)
        t = k * dt
        tp = (k % period) * dt  # time within the repeating scenario
        seg = scenario.segment_index(tp)
        u = scenario.input.sample(tp).reshape(hi - lo, -1)
        noise = rng.standard_normal((hi - lo, n + m))  # per sample: n process, m measurement normals
        xs = np.empty((hi - lo + 1, n))
        z = np.empty((hi - lo, m))
        xs[0] = x
        edges = np.flatnonzero(np.diff(seg)) + 1
        for a, e in zip(np.r_[0, edges], np.r_[edges, hi - lo], strict=True):
            s = int(seg[a])
            model = segs[s].model
            v = _times_transposed(noise[a:e, :n], LQ[s])
            if isinstance(model, LinearModel):
                f = _times_transposed(u[a:e], model.B) + v
                part = np.empty((e - a + 1, n))
                propagate(np.ascontiguousarray(model.A), xs[a].copy(), np.ascontiguousarray(f), part)
                xs[a : e + 1] = part
            else:
                _step_nonlinear(model, xs, u, v, a, e)
            z[a:e] = _times_transposed(xs[a:e], model.C) + _times_transposed(noise[a:e, n:], LR[s])
        if not np.isfinite(xs).all():
            i = int(np.argmax(~np.isfinite(xs).all(axis=1)))
            raise NonFiniteError(
                f"scenario {scenario.name!r}: the true state is not finite from t = {(lo + i) * dt:.6g} s; "
                "the plant diverged -- for an explicit Euler model reduce dt or the input amplitude"
            )
        x = xs[-1].copy()
        yield t, z, u


def _times_transposed(rows: np.ndarray, M: np.ndarray) -> np.ndarray:
    """``rows @ M.T`` evaluated column by column, element-wise (the same bits for any number of rows)."""
    out = np.zeros((rows.shape[0], M.shape[0]))
    for j in range(M.shape[1]):
        out += rows[:, j : j + 1] * M[:, j]
    return out


def _step_nonlinear(model: Model, xs: np.ndarray, u: np.ndarray, v: np.ndarray, a: int, e: int) -> None:
    """``xs[k + 1] = f(xs[k], u[k]) + v[k - a]`` for ``k = a .. e - 1`` (one realization, in place)."""
    f = getattr(model, "f", None) or model.transition
    model.transition(xs[a : a + 1], u[a])  # shape check once
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging state is reported by the caller
        for k in range(a, e):
            xs[k + 1] = np.asarray(f(xs[k : k + 1], u[k]))[0] + v[k - a]


def csv_header(model: Model) -> str:
    """The CSV header line (no newline) of a stream for ``model``: ``time``, outputs, inputs.

    Parameters
    ----------
    model : LinearModel
        Gives the column names.
    """
    return ",".join(["time", *model.output_names, *model.input_names])


def csv_lines(t: np.ndarray, z: np.ndarray, u: np.ndarray, *, digits: int = 9) -> str:
    """Rows ``time,z...,u...`` as CSV text, one line per sample, each ending in a newline.

    Parameters
    ----------
    t : (K,) array
        Times (s), written with microsecond resolution.
    z : (K, m) array
        Measurements.
    u : (K, p) array
        Inputs.
    digits : int
        Significant digits of ``z`` and ``u``.
    """
    K = t.shape[0]
    if K == 0:
        return ""
    vals = np.column_stack([t, z, u])
    row = "%.6f" + (",%." + str(int(digits)) + "g") * (vals.shape[1] - 1) + "\n"
    return (row * K) % tuple(vals.ravel().tolist())
