"""Batched Monte Carlo simulation of a scenario's true plant (eq 1-2).

All realizations advance together: the only Python loop is over time steps
(and over fixed blocks of realizations when drawing random numbers, see
:mod:`chatterspec.montecarlo`). Arrays follow the package convention
``(runs, T, channels)``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import cast

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import positive_int
from ..errors import ParameterError
from ..montecarlo import SeedLike, root_seed_sequence
from .linear_model import LinearModel
from .scenarios import Scenario
from .simulate_kernel import (
    NO_ARRAY,
    NO_CTRL,
    _linear_scale,
    _noise_blocks,
    covariance_sqrt,
    kernel_tables,
    plant_loop,
    same_shapes,
    scaled_noise,
    segment_ranges,
)

__all__ = ["Simulation", "as_scenario", "covariance_sqrt", "iter_simulations", "simulate"]

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


def default_chunk_runs(scenario: Scenario) -> int:
    """Realizations per chunk for ``scenario``: a multiple of 64 whose arrays fit :data:`CHUNK_BYTES`."""
    T = scenario.n_samples
    per_run = 8 * T * 2 * (scenario.nominal.n_states + scenario.nominal.n_outputs)
    return max(64, int(CHUNK_BYTES // per_run) // 64 * 64)


def as_scenario(scenario: Scenario | str | os.PathLike[str]) -> Scenario:
    """``scenario`` itself, the catalogue scenario of that name, or the scenario of a model file.

    Parameters
    ----------
    scenario : Scenario, str or path
        A scenario; a name of :func:`~chatterspec.plants.scenarios.scenario_names`; or a model file
        ``NAME.toml`` (linear or nonlinear), whose scenario is its ``[simulation]`` table (input,
        initial state, duration; zero input and 4 s by default) with the file's model as nominal
        model and true plant, named after the file stem.

    Returns
    -------
    Scenario

    Raises
    ------
    UnknownScenarioError
        For a name that is not in the catalogue (the message lists the names).
    ParameterError
        For anything else.
    """
    if isinstance(scenario, str | os.PathLike) and str(scenario).endswith(".toml"):
        from .modelfile import load_model
        from .modelfile_nonlinear import file_scenario

        return file_scenario(load_model(scenario), name=Path(scenario).stem)
    if isinstance(scenario, str):
        from .scenarios import scenario as by_name

        return by_name(scenario)
    if not hasattr(scenario, "nominal"):  # a Scenario (duck-typed, as the studies pass them)
        raise ParameterError(
            f"scenario must be a Scenario or a catalogue name (str); got {type(scenario).__name__}"
        )
    return cast(Scenario, scenario)  # a Scenario (or a duck-typed one), by the check above


def simulate(
    scenario: Scenario | str,
    runs: int = 1,
    seed: SeedLike = None,
    *,
    chunk_runs: int | None = None,
) -> Simulation:
    """Simulate ``runs`` independent realizations of ``scenario``'s true plant.

    Parameters
    ----------
    scenario : Scenario or str
        Nominal model, time-segmented true plant, input and duration; or a catalogue name
        (``"eha-healthy"``) or a model file (``"my_model.toml"``, see :func:`as_scenario`).
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
    scenario: Scenario | str,
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
    scenario : Scenario or str
        Nominal model, time-segmented true plant, input and duration (seconds); or a catalogue name
        or model file (:func:`as_scenario`).
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
        :mod:`chatterspec.plants.simulate_closed_loop`) and ``t`` (T,) in seconds, and
        ``first_run`` set to its first realization index.

    Raises
    ------
    ShapeError
        If the scenario's input has a different number of channels than the model.
    """
    runs = positive_int("runs", runs)
    scenario = as_scenario(scenario)
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
