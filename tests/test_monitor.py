"""Online chattering monitor: chunk invariance, equality with the batch path, events, bounded memory."""

from __future__ import annotations

import itertools
import subprocess
import sys

import numpy as np
import pytest

import chatterspec as cs
from chatterspec import _jit
from chatterspec.detection.pipeline import chattering_record
from chatterspec.detection.spectral import spectrogram
from chatterspec.detection.thresholds import frame_threshold
from chatterspec.detection.verdicts import detect_frames, frame_intervals
from chatterspec.errors import NonFiniteError, ParameterError, ShapeError
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.plants.scenarios import Scenario, Segment


def _scenario() -> Scenario:
    nominal = cs.eha_linear()
    return Scenario(
        name="eha-leak-mid",
        nominal=nominal,
        input=cs.Chirp(10.0, 100.0, 6.0, 300.0),
        duration=6.0,
        windows=(Segment(3.0, 6.0, cs.eha_linear(leakage=9e-11), "leakage"),),
    )


@pytest.fixture(scope="module")
def sim():
    return cs.simulate(_scenario(), runs=1, seed=11)


@pytest.fixture(scope="module")
def batch(sim):
    rec = chattering_record(sim.scenario.nominal, sim.z, sim.u)
    spec = spectrogram(rec.values[0], rec.dt, t0=rec.t[0])
    thr = frame_threshold(rec.model, spec.freqs_hz, spec.config, rec.dt)
    return rec, spec, detect_frames(spec, thr)


def test_numeric_core_does_not_import_rerun() -> None:
    code = (
        "import sys, chatterspec, chatterspec.online.monitor, chatterspec.plants.modelfile; "
        "print('rerun' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_random_chunks_reproduce_batch_spectrogram(sim, batch, seed: int) -> None:
    rec, spec, flags = batch
    rng = np.random.default_rng(seed)
    sizes = rng.integers(1, 900, size=200)
    mon = ChatteringMonitor(sim.scenario.nominal)
    ups = list(mon.stream(sim.z[0], sim.u, sizes))
    e = np.concatenate([u.chattering for u in ups])
    np.testing.assert_array_equal(e, rec.values[0])  # same kernel: bit-identical chattering
    np.testing.assert_array_equal(np.concatenate([u.t for u in ups]), rec.t)
    power = np.concatenate([u.frames.power for u in ups])
    assert power.shape == spec.power.shape
    np.testing.assert_allclose(power, spec.power, rtol=1e-12, atol=0)
    np.testing.assert_allclose(
        np.concatenate([u.frames.times_s for u in ups]), spec.times_s, rtol=0, atol=1e-12
    )
    np.testing.assert_array_equal(np.concatenate([u.frames.flags for u in ups]), flags)
    np.testing.assert_array_equal(np.concatenate([u.frames.index for u in ups]), np.arange(spec.n_frames))
    assert mon.n_frames == spec.n_frames


def test_one_sample_at_a_time_and_bounded_buffer(sim, batch) -> None:
    _, spec, _ = batch
    mon = ChatteringMonitor(sim.scenario.nominal)
    n = 1500  # one window + a few hops, sample by sample
    cols = []
    for k in range(n):
        upd = mon.push(sim.z[0, k], sim.u[k])
        cols.append(upd.frames.power)
        assert mon.buffered_samples < mon.n_window
    power = np.concatenate(cols)
    np.testing.assert_allclose(power, spec.power[: power.shape[0]], rtol=1e-12, atol=0)
    assert power.shape[0] == (n - 1 - mon.n_window) // mon.n_hop + 1


def test_mixed_small_and_huge_pushes(sim, batch) -> None:
    rec, spec, flags = batch
    mon = ChatteringMonitor(rec.model, t0=rec.t[0])
    sizes = [1, 3, mon.n_window - 5, 1, 2 * mon.n_window + 7, 199, 200, 201, 1]
    sizes.append(rec.n_samples - sum(sizes))  # the rest in one push
    ups = [mon.push_chattering(part) for part in np.split(rec.values[0], np.cumsum(sizes)[:-1])]
    np.testing.assert_allclose(np.concatenate([u.frames.power for u in ups]), spec.power, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(np.concatenate([u.frames.flags for u in ups]), flags)
    assert mon.buffered_samples < mon.n_window


def test_events_match_batch_frame_intervals(sim, batch) -> None:
    rec, spec, flags = batch
    mon = ChatteringMonitor(sim.scenario.nominal)
    events = [ev for u in mon.stream(sim.z[0], sim.u, 333) for ev in u.events]
    assert any(ev.channel == "pressure" and ev.kind == "fault-start" for ev in events)
    for c, name in enumerate(rec.channels):
        intervals = frame_intervals(flags[:, c], spec.times_s, spec.config, rec.dt)
        starts = [ev for ev in events if ev.channel == name and ev.kind == "fault-start"]
        ends = [ev for ev in events if ev.channel == name and ev.kind == "fault-end"]
        assert len(starts) == len(intervals)
        for ev, (onset, _) in zip(starts, intervals, strict=True):
            assert ev.estimate_s == pytest.approx(onset, abs=1e-9)
            assert flags[ev.frame, c]
            assert ev.peak_ratio > 1.0
        closed = [iv for iv in intervals if not (mon.active[c] and iv is intervals[-1])]
        assert len(ends) == len(closed)
        for ev, (_, offset) in zip(ends, closed, strict=True):
            assert ev.estimate_s == pytest.approx(offset, abs=1e-9)
            assert not flags[ev.frame, c]


def test_pressure_fault_detected_after_onset(sim) -> None:
    mon = ChatteringMonitor(sim.scenario.nominal)
    events = [ev for u in mon.stream(sim.z[0], sim.u, 200) for ev in u.events if ev.channel == "pressure"]
    first = events[0]
    assert first.kind == "fault-start"
    assert 2.5 < first.time_s < 4.0  # fault at 3 s; a 1 s frame centred >= 2.5 s overlaps it
    assert 20.0 < first.peak_hz < 100.0


def test_push_chattering_equals_raw_push(sim, batch) -> None:
    rec, spec, _ = batch
    mon = ChatteringMonitor(rec.model, t0=rec.t[0])
    ups = [mon.push_chattering(rec.values[0, k : k + 777]) for k in range(0, rec.n_samples, 777)]
    np.testing.assert_allclose(np.concatenate([u.frames.power for u in ups]), spec.power, rtol=1e-12, atol=0)
    np.testing.assert_allclose(np.concatenate([u.frames.times_s for u in ups]), spec.times_s, atol=1e-12)
    with pytest.raises(ParameterError, match="one kind of input"):
        mon.push(sim.z[0, :5], sim.u[:5])


def test_sat_svsf_estimate_with_psi(sim) -> None:
    mon = ChatteringMonitor(sim.scenario.nominal, MonitorSettings(psi=(1e-2, 1e-2, 5e3)))
    upd = mon.push(sim.z[0, :500], sim.u[:500])
    assert upd.estimate is not None and upd.estimate.shape == (499, 3)
    assert np.all(np.isfinite(upd.estimate))


def test_bad_input(sim) -> None:
    mon = ChatteringMonitor(sim.scenario.nominal)
    z = sim.z[0, :10].copy()
    z[4, 1] = np.nan
    with pytest.raises(NonFiniteError):
        mon.push(z, sim.u[:10])
    assert mon.n_samples == 0  # nothing consumed
    with pytest.raises(ShapeError, match="3 channel"):
        mon.push(sim.z[0, :10, :2], sim.u[:10])
    with pytest.raises(ShapeError, match="u must have shape"):
        mon.push(sim.z[0, :10], sim.u[:9])
    with pytest.raises(ParameterError):
        MonitorSettings(alpha=2.0)
    with pytest.raises(ParameterError):
        MonitorSettings(psi=(1.0, -1.0, 1.0))


def test_frame_verdict_flags_equal_direct_comparison_at_ties() -> None:
    """The one-pass flags (from max S / threshold) equal detect_frames' any(S > threshold) also at
    exact ties: S == threshold (ratio 1, not flagged) and S one ulp above it (ratio may round to 1,
    flagged), placed on random tested bins of random frames and channels."""
    from chatterspec.detection.verdicts import frame_verdicts

    model = cs.eha_linear()
    cfg = MonitorSettings().stft
    freqs = cfg.freqs_hz(model.dt)
    thr = frame_threshold(model, freqs, cfg, model.dt)
    rng = np.random.default_rng(3)
    F, m = 400, model.n_outputs
    power = thr.values * rng.uniform(0.0, 0.999, size=(F, *thr.values.shape))
    tested = np.flatnonzero(thr.tested)
    f = rng.integers(0, F, 300)
    b = rng.choice(tested, 300)
    c = rng.integers(0, m, 300)
    v = thr.values[b, c]
    power[f[:150], b[:150], c[:150]] = v[:150]  # exactly at the threshold: not a fault
    power[f[150:], b[150:], c[150:]] = np.nextafter(v[150:], np.inf)  # one ulp above: a fault
    ratio = power[:, tested, :] / thr.values[tested]
    assert np.any(ratio.max(axis=1) == 1.0)  # the tie branch is exercised
    direct = (power[:, tested, :] > thr.values[tested]).any(axis=1)
    assert direct.any() and not direct.all()
    flags, _, peak_ratio = frame_verdicts(power, thr)
    np.testing.assert_array_equal(flags, direct)
    np.testing.assert_array_equal(peak_ratio, ratio.max(axis=1))
    # a NaN bin (no monitor makes one) does not hide a bin above the threshold: the direct rule
    power[0, tested[:2], 0] = [np.nan, 2.0 * thr.values[tested[1], 0]]
    assert frame_verdicts(power, thr)[0][0, 0]


@pytest.mark.parametrize("ties", [False, True])
def test_compiled_frame_verdicts_equal_the_numpy_ones(ties: bool) -> None:
    """The monitor's one-pass verdict kernel (numba) gives the numpy path's flags, peaks and ratios.

    Random spectra around the threshold, with repeated maxima (the first bin wins in both, as
    np.argmax) and, with ``ties``, bins exactly at the threshold and one ulp above it.
    """
    from chatterspec import _jit
    from chatterspec.detection.verdicts import FrameVerdicts, peak_kernel

    model = cs.eha_linear()
    cfg = MonitorSettings().stft
    thr = frame_threshold(model, cfg.freqs_hz(model.dt), cfg, model.dt)
    rng = np.random.default_rng(5)
    power = thr.values * rng.uniform(0.0, 0.99, size=(40, *thr.values.shape))
    hot = rng.random((40, 3)) < 0.5  # about half the frames and channels get one bin above the threshold
    f_hot, c_hot = np.nonzero(hot)
    b_hot = rng.choice(np.flatnonzero(thr.tested), f_hot.size)
    power[f_hot, b_hot, c_hot] = thr.values[b_hot, c_hot] * rng.uniform(1.01, 3.0, f_hot.size)
    power[3, 100:103, 1] = power[3, 100:103, 1].max() * 50  # three equal maxima: the first one is the peak
    if ties:
        tested = np.flatnonzero(thr.tested)
        b = rng.choice(tested, 40, replace=False)
        power[np.arange(40), b, 0] = thr.values[b, 0] * 2.0
        power[np.arange(20), b[:20], 2] = thr.values[b[:20], 2]
        power[np.arange(20, 40), b[20:], 2] = np.nextafter(thr.values[b[20:], 2], np.inf)
    ref = FrameVerdicts(thr)(power)
    fast = FrameVerdicts(thr, compiled=True)
    assert fast.compiled  # the EHA threshold: contiguous tested bins, finite normal values
    outs = [fast(power)]
    if _jit.HAVE_NUMBA:  # the kernel's Python form too
        k, ratio = np.empty((40, 3), dtype=np.int64), np.empty((40, 3))
        peak_kernel.py_func(
            power[:, fast.sel],
            fast.values,
            np.empty((0, 0)),
            np.arange(fast.values.shape[0]),
            k,
            ratio,
            k,
            ratio,
        )
        outs.append((ratio > 1.0, fast.freqs[k], ratio))
    for out in outs:
        for a, b in zip(out, ref, strict=True):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
    assert ref[0].any() and not ref[0].all()


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
@pytest.mark.parametrize("psi", [None, (4.2e-3, 4.8e-3, 4.3e3)])
def test_fused_filter_kernel_gives_the_bits_of_the_svsf_update_path(sim, psi) -> None:
    """One compiled call per push for both filters: the same kernels and sums as SVSF.update, same bits.

    Irregular chunks (1 sample to 1.7 s); chattering, sat estimate and frame spectra compared exactly
    with a monitor that goes through SVSF._advance (compiled kernels too); the kernel's Python form
    on a small push gives the same bits as well.
    """
    from chatterspec.online._push_kernels import _filters_kernel, filters_kernel

    model = sim.scenario.nominal
    fused = ChatteringMonitor(model, MonitorSettings(psi=psi))
    plain = ChatteringMonitor(model, MonitorSettings(psi=psi))
    ff = fused._filters  # both filters and the fused push of the monitor
    assert ff.fused and ff._kernel is filters_kernel(3, 3)  # the EHA: the unrolled 3-state loop
    plain._filters.fused = False
    z, u = sim.z[0, :4000], sim.u[:4000]
    bounds = [0, 1, 2, 3, 250, 251, 1950, 2000, 3700, 4000]
    for lo, hi in itertools.pairwise(bounds):
        a, b = fused.push(z[lo:hi], u[lo:hi]), plain.push(z[lo:hi], u[lo:hi])
        np.testing.assert_array_equal(a.chattering, b.chattering)
        if psi is not None:
            np.testing.assert_array_equal(a.estimate, b.estimate)
        np.testing.assert_array_equal(a.frames.power, b.frames.power)
    assert fused.n_frames == plain.n_frames > 10
    # the kernel's Python form (it calls the compiled SVSF kernels) on a 40-sample push
    if psi is not None:
        sat = ff._sat
        outs = []
        # samples 4000 .. 4039 of the stream (z above stops at 4000; an empty push would compare
        # the uninitialized outputs), with u(k) and y(k|k) = z(k) of the sample before each
        zk, uk, y_aux = sim.z[0, None, 4000:4040], sim.u[3999:4039], sim.z[0, 3999:4000]
        assert zk.shape == (1, 40, 3) and uk.shape[0] == 40
        for kernel in (_filters_kernel, _filters_kernel.py_func):
            y, ep = ff._sat_state.y.copy(), ff._sat_state.e_post.copy()
            e, Gu, x_out = (np.full((1, 40, 3), np.nan) for _ in range(3))
            PhiT, L, P, inv_psi, gamma, S_inv = sat._kernel_consts
            kernel(
                zk, uk, ff._GT, ff._aux_PhiT, y_aux, e, Gu, True,
                PhiT, L, P, inv_psi, gamma, S_inv, y, ep, np.empty((1, 40, 3)), x_out, ff._none3,
            )  # fmt: skip
            outs.append((e, x_out, y, ep))
        # the unrolled 3-state loop (the EHA's path in push), compiled and in its Python form
        run3 = filters_kernel(3, 3)
        for kernel in (run3, run3.py_func):
            y, ep = ff._sat_state.y.copy(), ff._sat_state.e_post.copy()
            e, x_out = np.full((1, 40, 3), np.nan), np.full((1, 40, 3), np.nan)
            kernel(
                zk, uk, ff._GT, ff._aux_PhiT, y_aux, e, ff._none3, True,
                PhiT, L, P, inv_psi, gamma, S_inv, y, ep, ff._none3, x_out, ff._none3,
            )  # fmt: skip
            outs.append((e, x_out, y, ep))
        assert all(np.isfinite(a).all() for out in outs for a in out)  # every output written
        for other in outs[1:]:
            for a, b in zip(outs[0], other, strict=True):
                np.testing.assert_array_equal(a, b)


FRAME_FIELDS = (
    "index",
    "times_s",
    "power",
    "flags",
    "peak_hz",
    "peak_ratio",
    "score",
    "alarm",
    "alarm_statistic",
)


@pytest.mark.skipif(not _jit.enabled(), reason="the fused hop is the compiled path")
@pytest.mark.parametrize(
    "rule", [None, cs.CusumRule(threshold=6.0, drift=3.0), cs.PersistenceRule(threshold=5.0, k=2, n=4)]
)
def test_fused_hop_gives_the_bits_of_the_separate_calls(sim, rule) -> None:
    """Power, verdicts, score and alarm rule of a block of frames in one compiled call: the same steps as
    FrameEngine, FrameVerdicts, FrameScore and AlarmStream one after the other, so every field and event
    is equal, whatever the pushes (one sample, a window, several blocks of frames)."""
    model = sim.scenario.nominal
    fused = ChatteringMonitor(model, MonitorSettings(rule=rule))
    plain = ChatteringMonitor(model, MonitorSettings(rule=rule))
    assert fused._frames._fused
    plain._frames._fused = False
    z, u = sim.z[0], sim.u
    events = 0
    for lo, hi in itertools.pairwise([0, 1, 250, 1251, 1252, 4600, z.shape[0]]):
        a, b = fused.push(z[lo:hi], u[lo:hi]), plain.push(z[lo:hi], u[lo:hi])
        for name in FRAME_FIELDS:
            x, y = getattr(a.frames, name), getattr(b.frames, name)
            assert (x is None) == (y is None), name
            if x is not None:
                np.testing.assert_array_equal(x, y, err_msg=name)
        assert a.events == b.events
        events += len(a.events)
    assert events >= 1 and fused.n_frames == plain.n_frames > 20


@pytest.mark.skipif(not _jit.enabled(), reason="the fused hop is the compiled path")
def test_fused_push_of_chattering_gives_the_bits_of_the_separate_calls(batch) -> None:
    """Chattering pushes on the fused path (the frame buffer's compiled copy, check and taper, then one
    compiled call per block of frames): the fields and events of the separate calls, for pushes of a
    few samples, of several blocks and longer than the buffer keeps between pushes; a NaN is refused
    before anything is consumed, on both paths."""
    from chatterspec.online.monitor import MAX_BUFFER_ROWS

    rec = batch[0]
    e = rec.values[0]
    reps = -(-(MAX_BUFFER_ROWS + 5000) // e.shape[0])
    e = np.concatenate([e] * reps)  # longer than the largest buffer kept between pushes
    rule = cs.CusumRule(threshold=6.0, drift=3.0)
    fused = ChatteringMonitor(rec.model, MonitorSettings(rule=rule))
    plain = ChatteringMonitor(rec.model, MonitorSettings(rule=rule))
    assert fused._frames._fused
    plain._frames._fused = False
    bad = e[:10].copy()
    bad[3, 2] = np.inf
    for mon in (fused, plain):
        with pytest.raises(NonFiniteError, match="1 NaN/inf"):
            mon.push_chattering(bad)
        assert mon.n_samples == 0 and mon.buffered_samples == 0
    bounds = [0, 3, 999, 1000, 1001, 4700, 4700 + MAX_BUFFER_ROWS + 1, e.shape[0]]
    events = 0
    for lo, hi in itertools.pairwise(bounds):
        a, b = fused.push_chattering(e[lo:hi]), plain.push_chattering(e[lo:hi])
        for name in FRAME_FIELDS:
            x, y = getattr(a.frames, name), getattr(b.frames, name)
            assert (x is None) == (y is None), name
            if x is not None:
                np.testing.assert_array_equal(x, y, err_msg=name)
        np.testing.assert_array_equal(a.t, b.t)
        assert a.events == b.events
        events += len(a.events)
        assert fused.buffered_samples == plain.buffered_samples < fused.n_window
    assert events >= 1 and fused.n_frames == plain.n_frames > 300


@pytest.mark.skipif(not _jit.enabled(), reason="the fused hop is the compiled path")
@pytest.mark.parametrize("rule", [None, cs.CusumRule(threshold=6.0, drift=3.0)])
def test_fused_push_keeps_the_fault_peaks_of_the_separate_calls(batch, rule) -> None:
    """The fused push's kernel keeps each active fault's largest peak over blocks where no alarm starts
    or ends; the fault-end events (which report that peak) equal those of the separate calls, through
    faults that last many pushes of one block each and pushes of several blocks."""
    e = batch[0].values[0]
    healthy, faulty = e[:3000], e[3000:] * np.linspace(1.0, 4.0, 3000)[:, None]  # a growing fault
    x = np.concatenate([healthy, faulty, healthy, faulty, healthy])  # two faults, each ending
    fused = ChatteringMonitor(batch[0].model, MonitorSettings(rule=rule))
    plain = ChatteringMonitor(batch[0].model, MonitorSettings(rule=rule))
    assert fused._frames._fused
    plain._frames._fused = False
    events = []
    for lo, hi in itertools.pairwise([*range(0, 8000, 1000), 11000, 11001, 12000, x.shape[0]]):
        a, b = fused.push_chattering(x[lo:hi]), plain.push_chattering(x[lo:hi])
        assert a.events == b.events
        events += a.events
    starts = {}
    grown = 0
    for ev in events:
        if ev.kind == "fault-start":
            starts[ev.channel] = ev.peak_ratio
        else:  # the peak of frames after the start, kept by the kernel between the pushes
            grown += ev.peak_ratio > starts[ev.channel]
    assert grown >= 2


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
def test_frame_buffer_kernel_python_form() -> None:
    """``frames_in`` compiled and as Python: the same buffer, tapered frames and kept samples as the
    direct formula (append, frame f of samples ``f H .. f H + W``, times the window, keep from frame F);
    a NaN or inf is refused whatever its place."""
    from chatterspec.online._push_kernels import frames_in

    rng = np.random.default_rng(3)
    W, H, m, nb, K = 8, 3, 2, 5, 12
    win = rng.random(W)
    e = rng.normal(size=(K, m))
    start = rng.normal(size=(m, nb))
    n = nb + K
    F = (n - W) // H + 1
    x = np.concatenate([start, e.T], axis=1)  # (m, n)
    want = np.stack([np.stack([x[c, f * H : f * H + W] * win for f in range(F)]) for c in range(m)])[None]
    for kernel in (frames_in, frames_in.py_func):
        buf = np.full((m, n), np.nan)
        buf[:, :nb] = start
        tapered = np.full((1, m, F, W), np.nan)
        kept = kernel(buf, nb, e, True, win, H, 0, F, F, tapered)
        assert kept == n - F * H
        np.testing.assert_array_equal(tapered, want)
        np.testing.assert_array_equal(buf[:, :kept], x[:, F * H :])
        for bad_value, place in ((np.nan, (1, 1)), (np.inf, (0, 0)), (-np.inf, (K - 1, m - 1))):
            bad = e.copy()
            bad[place] = bad_value
            with np.errstate(invalid="ignore"):  # the Python form's inf - inf (the check's NaN)
                assert kernel(buf, kept, bad, True, win, H, 0, 0, 0, tapered) == -1
        np.testing.assert_array_equal(buf[:, :kept], x[:, F * H :])  # the kept samples untouched


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
def test_sample_times_give_the_bits_of_the_numpy_formula() -> None:
    """The pushed samples' times, compiled and numpy (in place): the bits of ``t0 + arange * dt`` over
    random clocks (a product and sum fused into one rounding would differ in many of them)."""
    from chatterspec.online._push_kernels import sample_times, sample_times_numpy

    rng = np.random.default_rng(8)
    for _ in range(200):
        t0 = rng.normal() * 10.0 ** rng.integers(-3, 6)
        dt = rng.random() * 10.0 ** rng.integers(-6, 0)
        first, count = int(rng.integers(0, 2**40)), int(rng.integers(0, 600))
        want = t0 + np.arange(first, first + count, dtype=float) * dt
        for times in (sample_times, sample_times_numpy):
            np.testing.assert_array_equal(times(t0, first, count, dt), want)


def test_fast_result_builders_give_the_dataclasses() -> None:
    """The push's FrameBlock and MonitorUpdate, and the identification's WindowDecision, built with their
    instance dict set at once: the fields (every one, by name) and values of the dataclasses' constructors."""
    import dataclasses

    from chatterspec.online.identification_monitor import WindowDecision, _window_decision
    from chatterspec.online.monitor import FrameBlock, MonitorUpdate, _frame_block, _monitor_update

    vals = [np.arange(i, i + 2) for i in range(9)]
    window = (3, 1.5, (1.0, 2.0), 2.0, True, "leakage", ("healthy", "fault"), ("fault", "healthy", "healthy"))
    for cls, build, args in (
        (FrameBlock, _frame_block, vals),
        (MonitorUpdate, _monitor_update, [*vals[:4], FrameBlock(*vals), ()]),
        (WindowDecision, _window_decision, window),
    ):
        fast, slow = build(*args), cls(*args)
        assert type(fast) is cls
        assert list(vars(fast)) == [f.name for f in dataclasses.fields(cls)] == list(vars(slow))
        assert all(vars(fast)[k] is vars(slow)[k] for k in vars(slow))
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(fast, dataclasses.fields(cls)[0].name, None)


def test_frame_rfft_is_scipy_rfft() -> None:
    """The monitor's frame transform (pocketfft's r2c called directly) gives the bits of scipy.fft.rfft,
    on a contiguous block of frames and on the first frames of a larger one (a strided view)."""
    import scipy.fft

    from chatterspec.online._push_kernels import frame_rfft

    x = np.random.default_rng(5).normal(size=(1, 3, 10, 1000))
    for block in (x, x[:, :, :7]):
        np.testing.assert_array_equal(frame_rfft(block), scipy.fft.rfft(block, n=1000, axis=-1))


@pytest.mark.parametrize("psi", [None, (4.2e-3, 4.8e-3, 4.3e3)])
def test_one_sample_steps_give_the_numbers_of_pushes(sim, psi) -> None:
    """``step`` (one compiled call per sample with numba, a one-sample push without) mixed with pushes: the
    chattering, estimates, frames' alarms and events of chunked pushes."""
    model = sim.scenario.nominal
    rule = cs.CusumRule(threshold=6.0, drift=3.0)
    pushed = ChatteringMonitor(model, MonitorSettings(psi=psi, rule=rule))
    stepped = ChatteringMonitor(model, MonitorSettings(psi=psi, rule=rule))
    z, u = sim.z[0], sim.u
    ev_push, chat, est = [], [], []
    for lo in range(0, z.shape[0], 333):
        upd = pushed.push(z[lo : lo + 333], u[lo : lo + 333])
        ev_push += upd.events
        chat.append(upd.chattering)
        if psi is not None:
            est.append(upd.estimate)
    ev_step, chat_s, est_s = [], [], []
    for k in range(z.shape[0]):
        if k % 1000 == 500:  # a push in between: the same state
            ev_step += stepped.push(z[k : k + 1], u[k : k + 1]).events
        else:
            ev_step += stepped.step(z[k], u[k])
        if k:
            chat_s.append(stepped.last_chattering)
            est_s.append(stepped.last_estimate)
    np.testing.assert_array_equal(np.concatenate(chat), np.array(chat_s))
    if psi is not None:
        np.testing.assert_array_equal(np.concatenate(est), np.array(est_s))
    else:
        assert all(e is None for e in est_s)
    assert ev_step == ev_push and len(ev_push) >= 1
    assert stepped.n_frames == pushed.n_frames and stepped.n_samples == pushed.n_samples
    with pytest.raises(NonFiniteError):
        stepped.step(np.array([np.nan, 0.0, 0.0]), u[0])
    with pytest.raises(ShapeError):
        stepped.step(z[0, :2], u[0])
    assert stepped.n_samples == pushed.n_samples  # nothing consumed


def test_cli_monitor_set_up_without_the_collector_and_loop_with_it_frozen(monkeypatch, capsys) -> None:
    """``chatterspec monitor`` reads the model (its set-up) with the cyclic garbage collector off, runs the
    loop with it on and the set-up's objects frozen out of its collections, and leaves it as it found it:
    on, nothing frozen (an in-process caller keeps collecting its own garbage)."""
    import gc
    from pathlib import Path

    import chatterspec.plants.modelfile as modelfile
    import chatterspec.viewer.recordings as recordings
    from chatterspec.cli import main

    seen: dict[str, tuple[bool, int]] = {}
    load_model, run_monitor = modelfile.load_model, recordings.run_monitor

    def loading(*args: object, **kwargs: object) -> object:
        seen["set-up"] = (gc.isenabled(), gc.get_freeze_count())
        return load_model(*args, **kwargs)

    def looping(*args: object, **kwargs: object) -> object:
        seen["loop"] = (gc.isenabled(), gc.get_freeze_count())
        return run_monitor(*args, **kwargs)

    monkeypatch.setattr(modelfile, "load_model", loading)
    monkeypatch.setattr(recordings, "run_monitor", looping)
    examples = Path(__file__).resolve().parents[1] / "examples"
    assert gc.isenabled() and gc.get_freeze_count() == 0
    argv = ["monitor", str(examples / "eha_model.toml"), "--data", str(examples / "eha_data.csv"), "--json"]
    assert main([*argv, "--no-identify"]) == 0
    capsys.readouterr()
    assert seen["set-up"] == (False, 0)
    assert seen["loop"][0] and seen["loop"][1] > 0
    assert gc.isenabled() and gc.get_freeze_count() == 0


def test_monitor_threshold_is_computed_once_where_it_is_given(monkeypatch) -> None:
    """The per-frame threshold of a monitor (monitor_threshold: the exact one of its settings, or a given
    one restricted to the band; another STFT's is refused) is what ChatteringMonitor computes by default;
    a monitor and the alarm calibration given it use it and compute none (the CLI computes it once for
    both)."""
    import chatterspec.detection.thresholds as thresholds
    from chatterspec.detection.thresholds import monitor_threshold
    from chatterspec.studies.alarm_budget import calibrate_alarm

    model = cs.scenario("eha-healthy").nominal
    settings = MonitorSettings(band=(20.0, 200.0))
    th = monitor_threshold(model, settings)
    mon = ChatteringMonitor(model, settings)
    want = frame_threshold(model, mon.freqs_hz, settings.stft, model.dt, settings.alpha, band=settings.band)
    np.testing.assert_array_equal(th.values, want.values)
    np.testing.assert_array_equal(mon.threshold.values, want.values)
    given = MonitorSettings(
        threshold=frame_threshold(model, mon.freqs_hz, settings.stft, model.dt), band=(20.0, 200.0)
    )
    np.testing.assert_array_equal(
        monitor_threshold(model, given).values, given.threshold.restricted((20.0, 200.0)).values
    )
    other = MonitorSettings(stft=cs.STFTConfig(window_s=0.5, hop_s=0.1), threshold=given.threshold)
    with pytest.raises(ShapeError, match="another STFT window"):
        monitor_threshold(model, other)

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("the per-frame threshold was computed again")

    monkeypatch.setattr(thresholds, "frame_threshold", refuse)
    assert ChatteringMonitor(model, settings, threshold=th).threshold is th
    cal = calibrate_alarm(model, settings, "frame", 1.0, threshold=th)  # the exact law: no simulation
    assert cal.rule.name == "frame"
    with pytest.raises(AssertionError, match="computed again"):
        ChatteringMonitor(model, settings)


def test_settings_share_the_frame_threshold_only_with_the_same_frame_settings() -> None:
    """The threshold computed for the alarm calibration is passed on to the monitor (``monitor``, ``detect
    --record``) only when the alarm settings kept what it depends on: a rule changes nothing; the frame
    and persistence rules' drawn level (another alpha), another band or another given threshold does."""
    import dataclasses

    s = MonitorSettings()
    assert dataclasses.replace(s, rule=cs.CusumRule(threshold=6.0, drift=3.0)).same_frame_threshold(s)
    assert not dataclasses.replace(s, alpha=0.5 * s.alpha).same_frame_threshold(s)
    assert not dataclasses.replace(s, band=(10.0, 100.0)).same_frame_threshold(s)
    from chatterspec.detection.thresholds import monitor_threshold

    th = monitor_threshold(cs.scenario("eha-healthy").nominal, s)
    assert not dataclasses.replace(s, threshold=th).same_frame_threshold(s)
