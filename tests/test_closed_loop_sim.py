"""The batched closed-loop simulation: both paths, chunking, open-loop equivalence, healthy chattering law."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.detection.pipeline import scenario_chattering
from chatterspec.montecarlo import root_seed_sequence
from chatterspec.plants import simulate as scl
from chatterspec.plants.closed_loop import (
    ClosedLoop,
    Hold,
    Multisine,
    PIDController,
    StepSequence,
    pid_coefficients,
)
from chatterspec.plants.models import eha_linear, second_order
from chatterspec.plants.scenarios import EHA_CL_CONTROLLER, EHA_CL_REFERENCE, Scenario, Segment, scenario
from chatterspec.plants.signals import Sine
from chatterspec.plants.simulate import simulate
from chatterspec.studies.detection_rates import false_alarm_study

needs_numba = pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")


def _saturating() -> Scenario:
    """Steps the controller cannot follow without saturating, a dither, a fault window, a derivative."""
    ctrl = PIDController(kp=1.5e5, ki=8e5, kd=40.0, saturation=250.0, anti_windup="clamping")
    loop = ClosedLoop(ctrl, StepSequence((0.05, 0.2), (0.02, -0.01)), dither=Multisine(8.0))
    return Scenario(
        "sat",
        eha_linear(),
        loop,
        0.4,
        windows=(Segment(0.25, 0.4, eha_linear(leakage=9e-11), "leak"),),
    )


@needs_numba
@pytest.mark.parametrize("name", ["eha-cl-leak-medium", "saturating"])
def test_compiled_closed_loop_equals_numpy_path_bitwise(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Both paths run the same steps (plant, controller) in the same order: the same bits."""
    sc = _saturating() if name == "saturating" else scenario(name)
    out = {}
    for jit in ("1", "0"):
        monkeypatch.setenv("CHATTERSPEC_JIT", jit)
        out[jit] = simulate(sc, 70, 5)  # two random blocks
    if name == "saturating":
        assert np.abs(out["1"].u).max() == 250.0  # the limit is reached: the clamping branch runs
    for f in ("x", "z", "u"):
        np.testing.assert_array_equal(getattr(out["1"], f), getattr(out["0"], f))
    assert out["1"].u.shape == (70, sc.n_samples, 1)


@pytest.mark.parametrize("jit", ["1", "0"])
def test_closed_loop_is_chunk_invariant(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    sc = _saturating()
    whole = simulate(sc, 70, 9)
    parts = simulate(sc, 70, 9, chunk_runs=13)
    for f in ("x", "z", "u"):
        np.testing.assert_array_equal(getattr(whole, f), getattr(parts, f))
    one = simulate(sc, 1, 9)
    np.testing.assert_array_equal(one.u[0], whole.u[0])


def test_loop_kernel_python_form_equals_numpy_path() -> None:
    """The compiled loop's Python form (no compiler) on a tiny input gives the numpy path's bits.

    The Python form of ``_plant_loop`` with the controller as input step: the same loop as the
    open-loop simulation's, the steps' plain functions.
    """
    sc = _saturating()
    t = sc.time[:120]
    ref, dith = sc.input.signals(t)
    root = root_seed_sequence(2)
    _, v, w = next(scl._noise_blocks(root, 0, 3, len(t), 3, 3))
    tb = scl._linear_tables(sc)
    seg = np.ascontiguousarray(sc.segment_index(t), dtype=np.int64)
    coef = np.asarray(pid_coefficients(sc.input.controller, sc.dt))
    x_np, z_np, u_np, _ = scl._loop_numpy(v, w, seg, tb, ref, dith, coef, 0, scl._initial_state(sc.x0, 3))
    loop = dict(scl.plant_loop.__globals__)
    loop.update(
        INPUT=scl._py(scl.controller_input),
        SINK=scl._py(loop["store_sink"]),
        measure_step=scl._py(scl.measure_step),
        advance_step=scl._py(scl.advance_step),
    )
    import types

    py_loop = types.FunctionType(scl.plant_loop.__code__, loop)
    step_globals = scl._py(scl.controller_input).__globals__
    saved = step_globals["pid_step"]
    step_globals["pid_step"] = scl._py(saved)
    try:
        ctrl = scl._pack(coef, 0, tb.B, ref, dith, 3)
        xt, zt = np.empty((120, 3, 3)), np.empty((120, 3, 3))
        py_loop(v, w, seg, tb.A, tb.C, tb.Lq, tb.Lr, np.empty((0, 0, 0)), np.zeros(3), tb.diag, ctrl, xt, zt,
                scl.NO_ARRAY, scl.NO_ARRAY, 0)  # fmt: skip
    finally:
        step_globals["pid_step"] = saved
    np.testing.assert_array_equal(xt, x_np)
    np.testing.assert_array_equal(zt, z_np)
    np.testing.assert_array_equal(scl._unpack_u(ctrl, tb.B, 120, 3), u_np)


@pytest.mark.parametrize("jit", ["1", "0"])
def test_state_carries_across_calls(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """K1 + K2 samples in two calls (state carried) equal K1 + K2 in one: the streaming path's invariant."""
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    sc = scenario("eha-cl-healthy")
    t = sc.time[:400]
    ref, dith = sc.input.signals(t)
    rng = np.random.default_rng(4)
    v, w = rng.standard_normal((2, 400, 3)), rng.standard_normal((2, 400, 3))
    seg = sc.segment_index(t)
    tb = scl._linear_tables(sc)
    s0 = scl._initial_state(sc.x0, 2)
    _, z, u, end = scl._step_linear(sc, scl._Block(v, w, seg, ref, dith), s0, tb)
    first = scl._Block(v[:, :150], w[:, :150], seg[:150], ref[:150], dith[:150])
    _, z1, u1, mid = scl._step_linear(sc, first, s0, tb)
    second = scl._Block(v[:, 150:], w[:, 150:], seg[150:], ref[150:], dith[150:])
    _, z2, u2, end2 = scl._step_linear(sc, second, mid, tb)
    np.testing.assert_array_equal(np.concatenate([u1, u2]), u)
    np.testing.assert_array_equal(np.concatenate([z1, z2]), z)
    np.testing.assert_array_equal(end2.x, end.x)


@needs_numba
def test_zero_gain_loop_with_input_dither_is_the_open_loop_simulation(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """No feedback and ``d(t)`` = the open-loop input: the open-loop simulation, bit for bit (compiled).

    The plant step repeats the open-loop kernel's operations in its order; a stable plant (second
    order) so that a loop without gains is stable.
    """
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    Q, R = np.diag([1e-8, 1e-6]), np.diag([1e-8, 1e-6])
    plant = second_order(10.0, 0.1, Q=Q, R=R)
    sine = Sine(0.8, 3.0)
    open_loop = Scenario("o", plant, sine, 2.0)
    zero = PIDController(kp=0.0, ki=0.0, saturation=1.0)
    closed = Scenario("c", plant, ClosedLoop(zero, Hold(), dither=sine), 2.0)
    a, b = simulate(open_loop, 66, 3), simulate(closed, 66, 3)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(np.broadcast_to(a.u, b.u.shape), b.u)


def test_healthy_closed_loop_chattering_is_the_open_loop_noise_law() -> None:
    """With the exact model the chattering (eq 23) is v(k) + w(k+1) - C A C^-1 w(k): u drops out.

    The closed loop moves the plant differently from the open-loop chirp, but with the same
    seed the noises are the same, so the healthy chattering equals the open-loop one up to the
    rounding of the different state values (1e-9 of the chattering's standard deviation).
    """
    nominal = eha_linear()  # eq 66's noise, as eha-healthy
    closed = Scenario("c", nominal, ClosedLoop(EHA_CL_CONTROLLER, EHA_CL_REFERENCE), 4.0)
    e_cl = scenario_chattering(closed, 3, 11).values
    e_ol = scenario_chattering(scenario("eha-healthy"), 3, 11).values
    scale = e_ol.std(axis=(0, 1))
    assert np.abs(e_cl - e_ol).max(axis=(0, 1)) / scale == pytest.approx(0.0, abs=1e-9)


def test_closed_loop_family_wise_false_alarm_rate_is_nominal() -> None:
    """The analytic exact thresholds hold in closed loop: family-wise rate = alpha within its interval.

    alpha = 5 %, 600 healthy runs of eha-cl-healthy. Bonferroni over n = 1999 nearly independent
    bins gives a family-wise rate 1 - (1 - alpha/n)^n = 4.88 %; the 99 % Clopper-Pearson interval
    of each channel's rate must contain it (a true rate of 2 alpha, or of alpha / 4, is excluded
    with probability > 0.98 at 600 runs, exact binomial).
    """
    res = false_alarm_study("eha-cl-healthy", alpha=0.05, runs=600, seed=7, frames=False, progress=False)
    r = res.get("exact-bonferroni")
    expected = 1 - (1 - 0.05 / 1999) ** 1999
    for est in r.family_wise:
        assert est.ci_low <= expected <= est.ci_high, est
    assert r.verdict == "within"


def test_nonlinear_closed_loop_runs_chunked_and_streams() -> None:
    sc = scenario("eha4-cl-healthy")
    a = simulate(sc, 6, 2)
    b = simulate(sc, 6, 2, chunk_runs=4)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.u, b.u)
    assert np.abs(a.u).max() <= 120.0
    # the reference's first move (5 mm at 0.5-1.5 s) is followed within 2 mm on every run
    k = sc.time.searchsorted(1.9)
    assert np.abs(a.x[:, k, 0] - 0.005).max() < 2e-3
    blocks = list(scl.closed_loop_blocks(sc, 1, 0.5, block_s=0.2))
    assert [len(t) for t, _, _ in blocks] == [200, 200, 101]
    assert all(u.shape == (len(t), 1) for t, _, u in blocks)


def test_stream_repeats_the_reference_beyond_the_duration() -> None:
    sc = scenario("eha-cl-healthy")
    t, z, _ = zip(*scl.closed_loop_blocks(sc, 0, 6.0, block_s=1.0), strict=True)
    t, z = np.concatenate(t), np.concatenate(z)
    ref = EHA_CL_REFERENCE.sample(np.mod(t, 4.0))
    settled = (np.mod(t, 4.0) > 0.9) & (np.mod(t, 4.0) < 1.2)  # after the first move, both laps
    assert np.abs(z[settled, 0] - ref[settled]).max() < 0.5e-3
    assert (t > 4.0).sum() > 0 and np.abs(z[(np.mod(t, 4.0) > 0.9) & (t > 4.0), 0]).max() > 0.009


@needs_numba
@pytest.mark.parametrize("name", ["eha-cl-leak-major", "saturating"])
def test_compiled_stream_equals_the_numpy_stream_for_any_block(name: str) -> None:
    """The stream's compiled block (one call per block, state carried) gives the numpy path's bits, and the
    rows of a seed do not depend on the block length; the kernel's Python form does the same arithmetic."""
    sc = _saturating() if name == "saturating" else scenario(name)
    a = list(scl.closed_loop_blocks(sc, 3, 1.2, block_s=0.07))
    with _jit.numpy_path():
        b = list(scl.closed_loop_blocks(sc, 3, 1.2, block_s=0.3))
    for i in (1, 2):
        np.testing.assert_array_equal(np.concatenate([x[i] for x in a]), np.concatenate([x[i] for x in b]))
    # the Python form of the kernel on one block (its steps compiled, scalars in Python)
    tb = scl._linear_tables(sc)
    t = sc.time[:50]
    ref, dith = sc.input.signals(t)
    rng = np.random.default_rng(9)
    v, w = rng.standard_normal((1, 50, 3)), rng.standard_normal((1, 50, 3))
    block = scl._Block(v, w, sc.segment_index(t), ref, dith)
    z, u, end = scl._stream_linear(sc, block, scl._initial_state(sc.x0, 1), tb)
    st = np.concatenate([sc.x0, [0.0, 0.0, np.nan]])
    zt, ut = np.empty((50, 3)), np.empty(50)
    coef = np.asarray(pid_coefficients(sc.input.controller, sc.dt), dtype=float)
    scl._stream_kernel.py_func(
        v[0], w[0], np.asarray(block.seg_idx, dtype=np.int64), tb.A, tb.C, tb.Lq, tb.Lr, tb.diag, tb.B, coef,
        sc.input.output, ref, dith, st, zt, ut,
    )  # fmt: skip
    np.testing.assert_array_equal(zt, z)
    np.testing.assert_array_equal(ut, u)
    np.testing.assert_array_equal(st[:3], end.x[0])
