"""Compiled kernels (chatterspec._jit) against the numpy path they replace.

Both paths evaluate the same per-element arithmetic; the only difference is the
order of the terms in the small matrix-vector products (BLAS in the numpy loop,
j = 0..n-1 in the kernel), i.e. a few ulps per step. The SVSF recursion is
stable (|1 - sat'| <= 1 and Phi is stable), so these differences do not grow:
1e-12 of each channel's scale (~1e4 ulps) bounds them with a wide margin, the
same tolerance as the closed-form/recursion test of tests/test_svsf.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.detection.pipeline import (
    _chattering_kernel,
    chattering_record,
    iter_chattering,
    scenario_chattering,
)
from chatterspec.detection.spectral import periodogram
from chatterspec.filters import svsf as svsf_mod
from chatterspec.filters import svsf_recursion
from chatterspec.filters.svsf import SVSF, auxiliary_svsf
from chatterspec.plants.scenarios import scenario
from chatterspec.plants.simulate import _simulate_kernel, kernel_tables, simulate

needs_numba = pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed (pip install '.[fast]')")

REL_TOL = 1e-12  # see the module docstring


def _filters() -> dict[str, tuple[str, SVSF, np.ndarray | None]]:
    eha = scenario("eha-healthy").nominal
    so = scenario("so-boundary-layer").nominal
    return {
        "sat-full": ("eha-healthy", SVSF(eha, psi=3 * np.sqrt(np.diag(eha.R))), None),
        "sat-reduced": ("so-boundary-layer", SVSF(so, psi=8e-4, psi_lower=0.8), None),
        "sgn-reduced": ("so-boundary-layer", SVSF(so, switching="sgn"), None),
        # non-zero initial error: the sgn filter leaves the closed form and runs the recursion
        "sgn-full-x0": ("eha-healthy", auxiliary_svsf(eha, gamma=0.5), np.array([0.01, -0.02, 0.5])),
    }


def _run(f: SVSF, z: np.ndarray, u: np.ndarray, x0: np.ndarray | None):
    return f.run(z, u, x0=x0, store={"x_post", "e_post", "e_lower"})


@needs_numba
@pytest.mark.parametrize("case", list(_filters()))
def test_compiled_svsf_equals_numpy_path(case: str, monkeypatch: pytest.MonkeyPatch) -> None:
    name, f, x0 = _filters()[case]
    sim = simulate(scenario(name), runs=3, seed=11)
    z, u = sim.z[:, :1500], sim.u[:1500]
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    fast = _run(f, z, u, x0)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    ref = _run(f, z, u, x0)
    # The output errors are differences of measurement-sized numbers (e = z - z_pred, e(k|k) =
    # z - y_u), so their rounding is counted in ulps of z, not of the (much smaller) errors;
    # e_lower = Phi22 Phi12^-1 e scales that by the row sums of |Phi22 Phi12^-1|.
    z_scale = np.abs(z).max()
    scales = {
        "e_prior": z_scale,
        "e_post": z_scale,
        "x_post": np.abs(ref.x_post).max(axis=(0, 1)),
        "e_lower": None if f._L is None else z_scale * np.abs(f._L).sum(axis=1),
    }
    for attr, scale in scales.items():
        a, b = getattr(fast, attr), getattr(ref, attr)
        if b is None:
            assert a is None, attr
            continue
        err = np.abs(a - b).max(axis=(0, 1))
        assert np.all(err <= REL_TOL * scale), (attr, err / scale)


@needs_numba
def test_compiled_kernel_equals_its_python_form_bitwise() -> None:
    """numba compiles the kernel without fastmath: same operations, same order, same bits."""
    sc = scenario("so-boundary-layer")
    sim = simulate(sc, runs=2, seed=4)
    f = SVSF(sc.nominal, psi=8e-4, psi_lower=0.8)
    z = np.ascontiguousarray(sim.z[:, 1:60])
    Gu = np.ascontiguousarray(svsf_mod._rows_times(sim.u[:59], f._GT)[None])
    state = f.initialize(sim.z[:, 0], x0=np.array([0.001, -0.01]))
    K, n, m = z.shape[1], 2, 1

    def call(kernel):
        y, ep = state.y.copy(), state.e_post.copy()
        # NaN-filled, so that an output the kernel leaves unwritten fails instead of comparing garbage
        outs = [np.full((2, K, k), np.nan) for k in (m, n, m, n - m)]
        kernel(z, Gu, f._PhiT, f._L, f._P, f._inv_psi, f.gamma, f._S_inv, y, ep, *outs)
        assert all(np.isfinite(o).all() for o in outs)
        return [y, ep, *outs]

    for a, b in zip(
        call(svsf_recursion._svsf_kernel), call(svsf_recursion._svsf_kernel.py_func), strict=True
    ):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("jit", ["0", "1"])
def test_online_single_samples_equal_batch_on_both_paths(jit: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The monitor's use: 1-sample updates give the batch bits, whichever path is active."""
    if jit == "1" and not _jit.HAVE_NUMBA:
        pytest.skip("numba not installed")
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    sc = scenario("eha-healthy")
    sim = simulate(sc, runs=1, seed=2)
    z, u = sim.z[0, :400], sim.u[:400]
    f = SVSF(sc.nominal, psi=3 * np.sqrt(np.diag(sc.nominal.R)))
    batch = f.run(z, u, store={"x_post"})
    state = f.initialize(z[0])
    e, x = [], []
    for k in range(1, len(z)):
        state, out = f.update(state, z[k : k + 1], u[k - 1 : k], store={"x_post"}, check=False)
        e.append(out.e_prior[0, 0])
        x.append(out.x_post[0, 0])
    np.testing.assert_array_equal(np.array(e), batch.e_prior[1:])
    np.testing.assert_array_equal(np.array(x), batch.x_post[1:])


def test_enabled_follows_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    assert not _jit.enabled()
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    assert _jit.enabled() == _jit.HAVE_NUMBA


@needs_numba
@pytest.mark.parametrize("name", ["eha-healthy", "eha-leak-major", "so-boundary-layer"])
def test_compiled_simulation_equals_numpy_path(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Same random numbers (chatterspec.montecarlo blocks); only the order of the 3-term sums differs.

    BLAS may evaluate x_aug @ W with fused multiply-adds and in another order: about one ulp per
    step, not amplified by the stable plant, so 1e-12 of each channel's scale is a wide bound.
    """
    sc = scenario(name)
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    fast = simulate(sc, runs=70, seed=5, chunk_runs=64)  # crosses a random-block boundary
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    ref = simulate(sc, runs=70, seed=5, chunk_runs=64)
    for a, b in ((fast.x, ref.x), (fast.z, ref.z)):
        scale = np.abs(b).max(axis=(0, 1))
        assert np.all(np.abs(a - b).max(axis=(0, 1)) <= REL_TOL * scale)
    assert fast.z.strides[1] > fast.z.strides[0]  # time-major storage, as the numpy path returns


@needs_numba
@pytest.mark.parametrize("name", ["eha-healthy", "eha-leak-major", "so-f11-high"])
def test_fused_chattering_is_the_filtered_simulation(name: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fused kernel repeats the simulation's and the closed form's arithmetic: same bits, any chunking."""
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    sc = scenario(name)
    sim = simulate(sc, runs=70, seed=6)
    ref = chattering_record(sc.nominal, sim.z, sim.u, scenario=sc)
    recs = list(iter_chattering(sc, 60, seed=6, chunk_runs=64, first_run=10))
    assert [r.first_run for r in recs] == [10]
    np.testing.assert_array_equal(recs[0].values, ref.values[10:])
    np.testing.assert_array_equal(recs[0].t, ref.t)
    # channel-major storage behind the (runs, N, m) view: the periodogram does not see it
    np.testing.assert_array_equal(
        periodogram(recs[0].values, sc.dt).power, periodogram(ref.values[10:], sc.dt).power
    )
    whole = scenario_chattering(sc, runs=70, seed=6)
    np.testing.assert_array_equal(whole.values, ref.values)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")  # numpy path: same noise, rounding-level difference
    slow = scenario_chattering(sc, runs=70, seed=6)
    assert np.abs(slow.values - whole.values).max() <= REL_TOL * np.abs(sim.z).max()


@needs_numba
def test_simulation_kernels_equal_their_python_form_bitwise() -> None:
    sc = scenario("eha-leak-major")
    t = sc.time[:40]
    u = sc.input.sample(t).reshape(len(t), -1)
    tb = kernel_tables(sc, t, u)
    rng = np.random.default_rng(0)
    v, w = rng.standard_normal((2, 40, 3)), rng.standard_normal((2, 40, 3))
    f = auxiliary_svsf(sc.nominal)
    Gu = np.ascontiguousarray(svsf_mod._rows_times(u[:-1], f._GT))
    outs = []
    none, no_ctrl = np.empty((0, 0)), np.empty(0)
    for kernel in (_simulate_kernel, _simulate_kernel.py_func):
        xt, zt = np.full((40, 3, 3), np.nan), np.full((40, 3, 3), np.nan)  # run 1 of 3 is written
        kernel(
            v, w, tb.seg_idx, tb.A, tb.C, tb.Lq, tb.Lr, tb.Bu, tb.x0, tb.diag, no_ctrl, xt, zt, none, none, 1
        )
        assert np.isfinite(xt[:, 1:]).all() and np.isfinite(zt[:, 1:]).all()
        outs.append((xt[:, 1:], zt[:, 1:]))
    for kernel in (_chattering_kernel, _chattering_kernel.py_func):
        e = np.full((3, 3, 39), np.nan)  # (runs, m, N): channel-major; run 1 is written
        kernel(
            v,
            w,
            tb.seg_idx,
            tb.A,
            tb.C,
            tb.Lq,
            tb.Lr,
            tb.Bu,
            tb.x0,
            tb.diag,
            no_ctrl,
            e,
            none,
            f._PhiT,
            Gu,
            1,
        )
        assert np.isfinite(e[1:]).all()
        outs.append((e[1:].transpose(0, 2, 1),))
    np.testing.assert_array_equal(outs[0][0], outs[1][0])
    np.testing.assert_array_equal(outs[0][1], outs[1][1])
    np.testing.assert_array_equal(outs[2][0], outs[3][0])
    # the diagonal shortcut gives the bits of the full sums (the skipped terms are exact zeros)
    assert tb.diag.all()
    e_full = np.empty((3, 3, 39))
    no_diag = np.zeros_like(tb.diag)
    args = (tb.seg_idx, tb.A, tb.C, tb.Lq, tb.Lr, tb.Bu, tb.x0, no_diag)
    _chattering_kernel(v, w, *args, no_ctrl, e_full, none, f._PhiT, Gu, 1)
    np.testing.assert_array_equal(e_full[1:].transpose(0, 2, 1), outs[2][0])
    # and the fused chattering is the closed form applied to the simulated z
    z = np.swapaxes(outs[0][1], 0, 1)
    e_ref = f.run(z, np.broadcast_to(u, (2, 40, u.shape[1]))).e_prior[:, 1:]
    np.testing.assert_array_equal(outs[2][0], e_ref)


def _closed_form_inputs(runs: int, layout: str, K: int = 700, per_run_input: bool = False):
    """Random measurements of EHA scale in either memory layout, and inputs shared or per run."""
    rng = np.random.default_rng(100 + runs)
    scale = np.array([1e-3, 1e-2, 1e6])  # position (m), velocity (m/s), pressure (Pa): mixed magnitudes
    if layout == "time-major":
        z = np.swapaxes(rng.standard_normal((K + 1, runs, 3)), 0, 1) * scale
    else:
        z = rng.standard_normal((runs, K + 1, 3)) * scale
    u = rng.standard_normal((runs, K + 1, 1) if per_run_input else (K + 1, 1)) * 50.0
    return z, u


@needs_numba
@pytest.mark.parametrize("runs", [1, 64])
@pytest.mark.parametrize("layout", ["time-major", "realization-major"])
@pytest.mark.parametrize("per_run_input", [False, True])
def test_compiled_closed_form_is_bitwise_the_numpy_closed_form(
    runs: int, layout: str, per_run_input: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Eq (23) compiled: the same element-wise operations in the same order, so the same bits.

    (numba without fastmath does not contract a * b - c into an FMA; an FMA would change the
    last bit of some samples and this exact comparison would fail.) Chunked calls too, in both
    layouts, since the online monitor feeds the filter in pieces of any size.
    """
    f = auxiliary_svsf(scenario("eha-healthy").nominal)
    z, u = _closed_form_inputs(runs, layout, per_run_input=per_run_input)
    out = {}
    for jit in ("1", "0"):
        monkeypatch.setenv("CHATTERSPEC_JIT", jit)
        whole = f.run(z, u).e_prior
        state, pieces = f.initialize(z[:, 0]), []
        for lo, hi in [(1, 2), (2, 300), (300, 301), (301, 701)]:
            state, o = f.update(state, z[:, lo:hi], u[..., lo - 1 : hi - 1, :])
            pieces.append(o.e_prior)
        out[jit] = (whole, np.concatenate(pieces, axis=1))
        assert out[jit][0].strides == out["1"][0].strides  # the same memory layout on both paths
    np.testing.assert_array_equal(out["1"][0], out["0"][0])
    np.testing.assert_array_equal(out["1"][1], out["0"][1])
    np.testing.assert_array_equal(out["1"][1], out["1"][0][:, 1:])


@needs_numba
def test_closed_form_kernel_equals_its_python_form() -> None:
    f = auxiliary_svsf(scenario("eha-healthy").nominal)
    z, u = _closed_form_inputs(2, "realization-major", K=30)
    Gu = svsf_mod._rows_times(u[:-1], f._GT)[None]
    y0 = z[:, 0].copy()
    outs = []
    for kernel in (svsf_recursion._closed_form_kernel, svsf_recursion._closed_form_kernel.py_func):
        for time_major in (True, False):
            e = np.full((2, 30, 3), np.nan)
            kernel(z[:, 1:], Gu, f._PhiT, y0, e, time_major)
            assert np.isfinite(e).all()
            outs.append(e)
    for e in outs[1:]:
        np.testing.assert_array_equal(e, outs[0])
    # and the Python form is eq (23) written out: e(k+1|k) = z(k+1) - Phi z(k) - G u(k), up to the
    # rounding of the einsum's other summation order: a few ulps of the terms' magnitude, bounded
    # element-wise by REL_TOL (1e-12, ~1e4 ulps) times the sum of the terms' absolute values
    ref = z[:, 1:] - np.einsum("ij,rkj->rki", f._PhiT.T, z[:, :-1]) - Gu
    size = np.abs(z[:, 1:]) + np.einsum("ij,rkj->rki", np.abs(f._PhiT.T), np.abs(z[:, :-1])) + np.abs(Gu)
    assert np.all(np.abs(outs[1] - ref) <= REL_TOL * size)


def test_rows_times_channel_major_gives_the_same_bits() -> None:
    """The monitor's faster G u(k) layout: the same products summed in the same order (j = 0, 1, ...)."""
    rng = np.random.default_rng(8)
    MT = rng.standard_normal((2, 3)) * [1.0, 1e3, 1e-3]
    for shape in [(1000, 2), (4, 50, 2), (7, 1)]:
        a = rng.standard_normal(shape) * 300.0
        ref = svsf_mod._rows_times(a, MT[: shape[-1]])
        got = svsf_mod._rows_times(a, MT[: shape[-1]], channel_major=True)
        assert got.shape == ref.shape
        np.testing.assert_array_equal(got, ref)
