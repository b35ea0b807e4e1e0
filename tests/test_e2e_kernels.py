"""The end-to-end Monte Carlo kernels give the numbers of the code they replace, bit for bit.

* ``_chattering_rng_kernel`` draws the noise inside the compiled simulation + auxiliary-SVSF
  kernel, run by run, instead of drawing ``(BLOCK, T, n)`` arrays first: the same numbers
  only if numba's ``Generator.standard_normal`` is numpy's ziggurat on the same bit
  generator and the draws are consumed in the same order (including the runs skipped at
  the start of a block and the last step's unused process noise).
* ``verdict_kernel`` replaces the numpy passes of ``detect_spectrum``: the same ``argmax``
  semantics (first maximum, first NaN) and the same elementwise arithmetic.

Every comparison is exact (``assert_array_equal``): there is no rounding to tolerate.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from chatterspec import _jit
from chatterspec.detection import verdicts
from chatterspec.detection.pipeline import (
    _chattering_kernel,
    _chattering_rng_kernel,
    _rng_kernel,
    iter_chattering,
)
from chatterspec.detection.spectral import periodogram_freqs
from chatterspec.detection.thresholds import exact_threshold
from chatterspec.detection.verdicts import _VERDICT_FIELDS, detect_spectrum
from chatterspec.filters import svsf as svsf_mod
from chatterspec.filters.svsf import auxiliary_svsf
from chatterspec.montecarlo import BLOCK, block_generator, root_seed_sequence
from chatterspec.plants.scenarios import scenario
from chatterspec.plants.simulate import _noise_blocks, kernel_tables

needs_numba = pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed (pip install '.[fast]')")


@needs_numba
def test_numba_generator_draws_numpys_normals() -> None:
    """2 x 10^6 draws: about 1.4 % take the ziggurat's slow paths (wedges, tail), all covered."""
    import numba

    @numba.njit
    def fill(g: np.random.Generator, out: np.ndarray) -> None:
        for i in range(out.size):
            out[i] = g.standard_normal()

    root = root_seed_sequence(123)
    for stream in (0, 1):
        ref = block_generator(root, 3, stream).standard_normal(1_000_000)
        got = np.empty_like(ref)
        fill(block_generator(root, 3, stream), got)
        np.testing.assert_array_equal(got, ref)
    assert np.abs(ref).max() > 3.442619855899  # the tail beyond the ziggurat's last layer was drawn


def _rng_kernel_inputs(name: str, T: int):
    sc = scenario(name)
    t = sc.time[:T]
    u = sc.input.sample(t).reshape(len(t), -1)
    f = auxiliary_svsf(sc.nominal)
    Gu = np.ascontiguousarray(svsf_mod._rows_times(u[:-1], f._GT))
    tb = kernel_tables(sc, t, u)
    return (tb.seg_idx, tb.A, tb.C, tb.Lq, tb.Lr, tb.Bu, tb.x0, tb.diag, np.ascontiguousarray(f._PhiT), Gu)


@needs_numba
@pytest.mark.parametrize(("lo", "hi"), [(0, 64), (5, 9), (70, 75), (60, 130)])
@pytest.mark.parametrize("dims", [3, 2])
@pytest.mark.parametrize("diag", [True, False])
def test_rng_kernel_equals_drawing_blocks_first(lo: int, hi: int, dims: int, diag: bool) -> None:
    """Runs [lo, hi) from the block streams: partial blocks at both ends, a block boundary crossed.

    3 x 3 (the EHA) and 2 x 2 (the EHA's matrices cut down: any numbers do for a bitwise
    comparison), through the loop for any size and the unrolled one for that size; both with
    the diagonal shortcut for Lq, Lr and without it (full sums, non-diagonal factors).
    """
    T, m = 50, dims
    seg_idx, A, C, Lq, Lr, Bu, x0, dg, PhiT, Gu = _rng_kernel_inputs("eha-leak-major", T)
    c = np.ascontiguousarray
    if not diag:  # non-diagonal noise factors: the full sums
        Lq, Lr, dg = Lq + 1e-3, Lr + 1e-4, np.zeros_like(dg)
    cut = (A[:, :m, :m], C[:, :m, :m], Lq[:, :m, :m], Lr[:, :m, :m], Bu[:, :, :m], x0[:m])
    args = (seg_idx, *map(c, cut), dg, np.empty(0), c(PhiT[:m, :m]), c(Gu[:, :m]))
    root = root_seed_sequence(9)
    ref = np.full((hi - lo, m, T - 1), np.nan)
    for off, v, w in _noise_blocks(root, lo, hi, T, m, m):
        _chattering_kernel(v, w, *args[:9], ref, np.empty((0, 0)), *args[9:], off)
    # the drawing loop for any size, its Python form, and its per-size form (unrolled for 2 and 3)
    for kernel in (_chattering_rng_kernel, _chattering_rng_kernel.py_func, _rng_kernel(m, m)):
        e = np.full((hi - lo, m, T - 1), np.nan)
        for b in range(lo // BLOCK, (hi - 1) // BLOCK + 1):
            s0, s1 = max(b * BLOCK, lo), min((b + 1) * BLOCK, hi)
            g0, g1 = block_generator(root, b, 0), block_generator(root, b, 1)
            kernel(g0, g1, s0 - b * BLOCK, s1 - s0, *args, e, s0 - lo)
        np.testing.assert_array_equal(e, ref)


@needs_numba
def test_fused_records_do_not_depend_on_the_chunking(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    sc = scenario("eha-healthy")
    whole = next(iter_chattering(sc, 140, seed=2, chunk_runs=140)).values
    parts = np.concatenate([r.values for r in iter_chattering(sc, 137, seed=2, chunk_runs=37, first_run=3)])
    np.testing.assert_array_equal(parts, whole[3:])


def _spectra(rng: np.random.Generator, shape: tuple[int, ...], threshold) -> np.ndarray:
    """Healthy-like spectra with some bins pushed over the threshold."""
    p = rng.exponential(size=shape) * threshold.expected
    hot = rng.random(shape) < 2e-3
    return np.where(hot, threshold.values * rng.uniform(0.5, 3.0, shape), p)


def _verdicts(power, threshold, monkeypatch: pytest.MonkeyPatch, jit: str) -> dict[str, np.ndarray]:
    monkeypatch.setenv("CHATTERSPEC_JIT", jit)
    d = detect_spectrum(power, threshold, threshold.expected)
    return {k: getattr(d, k) for k in _VERDICT_FIELDS}


@needs_numba
@pytest.mark.parametrize("band", [None, (5.0, 60.0)])
def test_compiled_verdict_equals_numpy_path(band, monkeypatch: pytest.MonkeyPatch) -> None:
    model = scenario("eha-healthy").nominal
    N = 400
    freqs = periodogram_freqs(N, model.dt)
    th = exact_threshold(model, freqs, N, 1e-2, band=band)
    rng = np.random.default_rng(4)
    base = _spectra(rng, (300, *th.values.shape), th)
    base[0, 7] = base[0, 9] = 10 * th.values[7]  # ties: the first bin wins
    base[1] = th.values * 2.0  # every bin over, equal ratios
    base[2, 11, 0] = np.nan  # NaN: argmax returns its bin
    base[3, 5, 1] = np.inf
    base[4] = th.expected  # no bin over, zero excess everywhere
    cases = {
        "runs": base,
        "one": base[5],
        "2-d lead": base[:12].reshape(3, 4, *th.values.shape),
        "strided": base[::-2],
        "channel-major": np.ascontiguousarray(base.transpose(0, 2, 1)).transpose(0, 2, 1),
        "empty": base[:0],
    }
    for name, power in cases.items():
        fast = _verdicts(power, th, monkeypatch, "1")
        ref = _verdicts(power, th, monkeypatch, "0")
        for k in _VERDICT_FIELDS:
            np.testing.assert_array_equal(fast[k], ref[k], err_msg=f"{name}: {k}")
    assert fast["detected"].shape == (0, 3)


@needs_numba
def test_verdict_kernel_equals_its_python_form_and_handles_scattered_bins(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Scattered tested bins (not one run of bins); one channel (numpy sums it pairwise) and two."""
    model = scenario("eha-healthy").nominal
    N = 64
    freqs = periodogram_freqs(N, model.dt)
    th = exact_threshold(model, freqs, N, 1e-2)
    rng = np.random.default_rng(5)
    power = _spectra(rng, (40, *th.values.shape), th)
    idx = np.array([1, 2, 5, 6, 7, 20, 31])
    outs = []
    for kernel in (verdicts.verdict_kernel, verdicts.verdict_kernel.py_func):
        k, ke = np.full((40, 3), -1, np.intp), np.full((40, 3), -1, np.intp)  # -1 / NaN: unwritten
        pr, ps = np.full((40, 3), np.nan), np.full((40, 3), np.nan)
        kernel(power, th.values, th.expected, idx, k, pr, ke, ps)
        assert (k >= 0).all() and (ke >= 0).all() and np.isfinite(pr).all() and np.isfinite(ps).all()
        outs.append((k, pr, ke, ps))
    for a, b in zip(*outs, strict=True):
        np.testing.assert_array_equal(a, b)
    ratio = power[:, idx] / th.values[idx]
    np.testing.assert_array_equal(outs[0][0], np.argmax(ratio, axis=1))
    np.testing.assert_array_equal(outs[0][3], power[:, idx].sum(axis=1))  # numpy adds bin after bin
    # a threshold testing scattered bins; one channel (numpy sums it pairwise: the sum stays numpy's)
    tested = np.zeros(th.tested.shape, bool)
    tested[idx] = True
    for thr in (replace(th, tested=tested), _channels(th, 1), _channels(th, 2)):
        p = power[..., : thr.values.shape[1]]
        fast = _verdicts(p, thr, monkeypatch, "1")
        ref = _verdicts(p, thr, monkeypatch, "0")
        for key in _VERDICT_FIELDS:
            np.testing.assert_array_equal(fast[key], ref[key], err_msg=key)


def _channels(th, m: int):
    return replace(th, values=th.values[:, :m], expected=th.expected[:, :m])


@needs_numba
def test_detect_cli_streams_the_fused_records(monkeypatch: pytest.MonkeyPatch) -> None:
    """``chatterspec detect`` (and demo) take the fused path: the records and run 0 of the old route."""
    from chatterspec.cli.detect import stream_chunks
    from chatterspec.detection.pipeline import chattering_record
    from chatterspec.plants import simulate as simulate_mod

    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    sc = scenario("eha-leak-minor")
    ref_sim = simulate_mod.simulate(sc, runs=70, seed=3)
    ref = chattering_record(sc.nominal, ref_sim.z, ref_sim.u)

    batch = simulate_mod.iter_simulations

    def run0_only(scenario, runs, *args, **kwargs):  # simulate(sc, 1, seed): run 0 for the recording
        assert runs == 1, "stream_chunks simulated (runs, T, n) arrays instead of the fused kernel"
        return batch(scenario, runs, *args, **kwargs)

    monkeypatch.setattr(simulate_mod, "iter_simulations", run0_only)
    first: list = []
    recs = list(stream_chunks(sc, 70, 3, first))
    np.testing.assert_array_equal(np.concatenate([r.values for r in recs]), ref.values)
    assert [r.first_run for r in recs] == [0]
    np.testing.assert_array_equal(first[0].x, ref_sim.x[:1])
    np.testing.assert_array_equal(first[0].z, ref_sim.z[:1])


def _captured_study(module, call, monkeypatch: pytest.MonkeyPatch):
    """The HealthyStudy a study function builds (its ``Execution.run`` is intercepted)."""
    seen = []

    def capture(self, study, *args, **kwargs):
        seen.append(study)
        return real(self, study, *args, **kwargs)

    real = module.Execution.run
    monkeypatch.setattr(module.Execution, "run", capture)
    call()
    return seen[0]


@needs_numba
@pytest.mark.parametrize("which", ["far", "far-no-frames", "calibrate"])
def test_healthy_study_counts_equal_numpy_path(which: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled exceedance counts (integers) give the numpy path's summary exactly, with its dtypes."""
    from chatterspec import montecarlo
    from chatterspec.studies import detection_rates
    from chatterspec.studies.calibration import healthy, thresholds

    sc = scenario("eha-healthy")
    if which == "calibrate":
        # calibrate runs its study through its exact tails at 64 runs: one study)
        study = _captured_study(
            montecarlo, lambda: thresholds.calibrate(sc, 1e-2, runs=64, seed=1), monkeypatch
        )
    else:
        frames = which == "far"
        study = _captured_study(
            montecarlo,
            lambda: detection_rates.false_alarm_study(sc, [1e-2, 0.2], runs=64, seed=1, frames=frames),
            monkeypatch,
        )
    x = next(iter_chattering(sc, 70, seed=8, chunk_runs=70)).values
    monkeypatch.setenv("CHATTERSPEC_JIT", "1")
    fast = study._summarize(x, sc.dt)
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    ref = study._summarize(x, sc.dt)
    assert list(fast) == list(ref)
    for key in ref:
        assert fast[key].dtype == ref[key].dtype, key
        np.testing.assert_array_equal(fast[key], ref[key], err_msg=key)
    assert ref["fw"].sum() > 0  # alpha = 0.2 (or the per-bin kinds): exceedances were counted
    # the kernel's Python form on a small input
    power, thr = x[:3, None, :40] ** 2, study.thr_values[:, :40]
    tested = study.thr_tested[:, :40]
    a = healthy.exceedance_counts(power, thr, tested)
    monkeypatch.setattr(healthy, "_exceedance_kernel", healthy._exceedance_kernel.py_func)
    b = healthy.exceedance_counts(power, thr, tested)
    for u, v in zip(a, b, strict=True):
        np.testing.assert_array_equal(u, v)


def test_detect_progress_bar_counts_every_realization(capsys: pytest.CaptureFixture[str]) -> None:
    """``detect --runs`` advances its progress bar by each chunk's realizations, to the total."""
    from chatterspec.cli.detect import stream_chunks, with_progress

    sc = scenario("eha-healthy")
    recs = list(with_progress(stream_chunks(sc, 300, 0, []), 300, "detect test", enabled=True))
    assert sum(r.values.shape[0] for r in recs) == 300
    err = capsys.readouterr().err
    assert "detect test" in err and "300/300" in err
    assert err.endswith("\n")  # the bar is closed once the chunks are exhausted
