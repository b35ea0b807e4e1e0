"""Rerun recordings and live streaming of the online monitor (headless)."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.detection.pipeline import chattering_record
from chatterspec.detection.spectral import spectrogram
from chatterspec.detection.thresholds import frame_threshold
from chatterspec.detection.verdicts import detect_frames
from chatterspec.errors import ParameterError
from chatterspec.plants.scenarios import Scenario, Segment

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from chatterspec.viewer import blueprint, recordings, rerun_log, spectrograms  # noqa: E402
from chatterspec.viewer import sinks as viewer  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture(autouse=True)
def _strict():
    rr.set_strict_mode(True)
    yield
    rr.set_strict_mode(False)


@pytest.fixture(scope="module")
def sim():
    nominal = cs.eha_linear()
    sc = Scenario(
        name="eha-leak-mid",
        nominal=nominal,
        input=cs.Chirp(10.0, 100.0, 5.0, 300.0),
        duration=5.0,
        windows=(Segment(2.5, 5.0, cs.eha_linear(leakage=9e-11), "leakage 9e-11"),),
        fault_channel="pressure",
    )
    return cs.simulate(sc, runs=1, seed=5)


@pytest.fixture(scope="module")
def batch(sim):
    rec = chattering_record(sim.scenario.nominal, sim.z, sim.u, scenario=sim.scenario)
    spec = spectrogram(rec.values[0], rec.dt, t0=rec.t[0])
    thr = frame_threshold(rec.model, spec.freqs_hz, spec.config, rec.dt)
    return rec, spec, detect_frames(spec, thr)


def _rows(reader: RrdReader, entity: str) -> list:
    chunks = reader.stream().filter(content=entity, is_static=False).to_chunks()
    return [c.to_record_batch() for c in chunks]


def _column(reader: RrdReader, entity: str, name: str) -> tuple[np.ndarray, list]:
    times, values = [], []
    for rb in _rows(reader, entity):
        times.extend(rb.column("time").cast("int64").to_pylist())
        values.extend(rb.column(name).to_pylist())
    order = np.argsort(times, kind="stable")
    return np.asarray(times)[order] * 1e-9, [values[i] for i in order]


def _images(reader: RrdReader, channel: str) -> tuple[np.ndarray, list[np.ndarray], list]:
    """(times s, dB images (bins, columns) with row 0 = the lowest frequency, depth ranges) of the
    spectrogram of ``channel`` (a ``DepthImage``, top row = highest frequency)."""
    t, buf = _column(reader, f"/spectrogram/{channel}/image", "DepthImage:buffer")
    _, fmt = _column(reader, f"/spectrogram/{channel}/image", "DepthImage:format")
    _, rng = _column(reader, f"/spectrogram/{channel}/image", "DepthImage:depth_range")
    imgs = []
    for b, f in zip(buf, fmt, strict=True):
        img = np.frombuffer(bytes(b[0]), dtype=np.float16).reshape(f[0]["height"], f[0]["width"])
        imgs.append(img[::-1].astype(float))
    return t, imgs, rng


def _column_static(reader: RrdReader, entity: str, name: str) -> tuple[None, list]:
    """The static rows of ``entity``'s column ``name``."""
    values = []
    for chunk in reader.stream().filter(content=entity, is_static=True).to_chunks():
        values.extend(chunk.to_record_batch().column(name).to_pylist())
    return None, values


def _check_recording(path: Path, rec, spec, flags, summary) -> None:
    reader = RrdReader(path)
    summary_text = reader.store().summary()  # needs the footer: the file was closed properly
    assert "/spectrum/pressure" in summary_text
    for c, name in enumerate(rec.channels):
        t, cols = _column(reader, f"/spectrum/{name}", "Tensor:data")
        assert len(cols) == spec.n_frames
        np.testing.assert_allclose(t, spec.times_s, atol=1e-9)
        buf = np.asarray(cols[-1][0]["buffer"])  # the union holds the F32 payload (spectrum_dtype default)
        np.testing.assert_array_equal(buf, spec.power[-1, :, c].astype(np.float32))
        # one row per frame / per sample for all channels: series c is channel c
        t, verdict = _column(reader, blueprint.VERDICT, "Scalars:scalars")
        np.testing.assert_array_equal(np.asarray(verdict)[:, c] > 0.5, flags[:, c])
        t_e, e = _column(reader, blueprint.CHATTERING, "Scalars:scalars")
        m = len(rec.channels)  # the m chattering series first, then the raw ones (raw data only)
        assert t_e.size == rec.n_samples and np.asarray(e).shape[1] in (m, 2 * m, 3 * m)
        np.testing.assert_array_equal(np.asarray(e)[:, :m], rec.values[0])
    t_ev, texts = _column(reader, "/events", "TextLog:text")
    alarms = [k for k, s in enumerate(texts) if "ALARM" in s[0] or "cleared" in s[0]]
    assert len(alarms) == len(summary.events) > 0
    half_win = (spec.config.n_window(rec.dt) - 1) * rec.dt / 2.0  # logged when the detector knew
    for ev in summary.events:
        word = "ALARM" if ev.kind == "fault-start" else "cleared"
        assert ev.alarm_time_s == pytest.approx(ev.time_s + half_win, abs=1e-12)
        hit = [k for k in alarms if f" s {ev.channel} " in texts[k][0] and word in texts[k][0]]
        assert any(abs(t_ev[k] - ev.alarm_time_s) < 1e-9 for k in hit), ev
        assert any(texts[k][0].startswith(f"{ev.alarm_time_s:.2f} s ") for k in hit), ev  # the same time
        assert flags[ev.frame, ev.channel_index] == (ev.kind == "fault-start")
    _, truth = _column(reader, blueprint.TRUTH_LANE, "StateChange:state")
    assert [s[0] for s in truth] == ["healthy", "leakage 9e-11"]


def test_record_simulation_reads_back(tmp_path: Path, sim, batch) -> None:
    rec, spec, flags = batch
    path = tmp_path / "sub" / "run.rrd"
    summary = recordings.record_detection(sim, path=path, chunk_samples=137)
    assert summary.path == path and summary.n_frames == spec.n_frames
    _check_recording(path, rec, spec, flags, summary)


def test_record_chattering_record(tmp_path: Path, batch) -> None:
    rec, spec, flags = batch
    summary = recordings.record_detection(rec, path=tmp_path / "c.rrd", chunk_samples=1000)
    _check_recording(tmp_path / "c.rrd", rec, spec, flags, summary)
    # the file gets ONE spectrogram tensor per channel for the whole record: band rows x one column
    # per frame, padded by pad_columns blank (DB_RANGE[0]) columns on each side so that the image covers
    # the whole record (the span of every time view), 10 log10(S / threshold) clipped to DB_RANGE,
    # logged at the record start
    reader = RrdReader(tmp_path / "c.rrd")
    t, blocks, rng = _images(reader, "pressure")
    assert len(blocks) == 1 and t[0] <= rec.t[0] + 1e-12
    lo, hi = spectrograms.default_band_hz(_monitor(rec))
    assert (lo, hi) == (1.0, 150.0)  # EHA: tested band from 1 Hz, capped at 3 x 41.8 Hz -> 150 Hz
    band = (spec.freqs_hz >= lo) & (spec.freqs_hz <= hi)
    p = spectrograms.pad_columns(_monitor(rec))
    assert p == 2  # 1 s window, 0.2 s hop: the first window starts 0.4 s before the first column's edge
    img = blocks[0]
    assert img.shape == (int(band.sum()), spec.n_frames + 2 * p)
    assert np.all(img[:, :p] == spectrograms.DB_RANGE[0]) and np.all(img[:, -p:] == spectrograms.DB_RANGE[0])
    img = img[:, p:-p]
    thr = frame_threshold(rec.model, spec.freqs_hz, spec.config, rec.dt)
    db = np.clip(10 * np.log10(spec.power[:, band, 2] / thr.values[band, 2]), *spectrograms.DB_RANGE)
    np.testing.assert_allclose(img, db.T, atol=0.02)  # float16 dB (resolution 0.016 dB at 30 dB)
    np.testing.assert_array_equal(np.asarray(rng[0]).ravel(), spectrograms.DB_RANGE)  # fixed colour range
    # the scale: frequency labels inside the band and a colour key with the dB range
    _, labels = _column_static(reader, "/spectrogram/pressure/freq_ticks", "Points2D:labels")
    assert labels[0][0] == "50 Hz" and labels[0][-1] == "150 Hz"
    _, key = _column_static(reader, "/spectrogram/pressure/key_ticks", "Points2D:labels")
    # short key labels (the view's title says dB): they fit the key, clear of the frequency labels
    assert key[0] == [f"{spectrograms.DB_RANGE[1]:g}", "12", f"{spectrograms.DB_RANGE[0]:g}"]


def _monitor(rec):
    from chatterspec.online.monitor import ChatteringMonitor

    return ChatteringMonitor(rec.model)


def test_bulk_tensor_columns_match_rerun_encoding() -> None:
    cols = rerun_log._Columns(rr, spectrograms.DB_RANGE)
    assert cols.tensors_ok  # else every tensor falls back to one rr.log call (slow)
    x = np.random.default_rng(0).random((7, 11))
    ref = rr.Tensor(x[3], dim_names=["freq"]).data.as_arrow_array()
    assert cols._tensor_array(x, ("freq",))[3:4].equals(ref)
    # the layout parts are cached per process: a second batch (other values) and another logger's
    # columns reuse them and still encode exactly like rr.Tensor
    y = x[::-1].copy()
    again = rerun_log._Columns(rr, spectrograms.DB_RANGE)._tensor_array(y, ("freq",))
    assert again[3:4].equals(rr.Tensor(y[3], dim_names=["freq"]).data.as_arrow_array())
    assert again.equals(cols._tensor_array(y, ("freq",), cache=False))
    # the live spectrogram's layout (float16, dims freq and time) and the static spectra, which the
    # logger builds without rr.Tensor (its encoder imports pyarrow.compute)
    z = np.arange(6, dtype=np.float16).reshape(1, 3, 2)
    ref = rr.Tensor(z[0], dim_names=["freq", "time"]).data.as_arrow_array()
    assert cols._tensor_array(z, ("freq", "time")).equals(ref)
    (static,) = cols.static_tensor(x[3], ("freq",))
    expected = rr.Tensor(x[3], dim_names=["freq"]).as_component_batches()[0]
    assert static.component_descriptor() == expected.component_descriptor()
    assert static.as_arrow_array().equals(expected.as_arrow_array())
    assert cols.value_range_row.equals(
        rr.Tensor(np.zeros((1, 1)), value_range=list(spectrograms.DB_RANGE)).value_range.as_arrow_array()
    )


def test_fallback_without_bulk_tensors(tmp_path: Path, sim, batch, monkeypatch) -> None:
    monkeypatch.setattr(rerun_log, "_TENSOR_DTYPES", {})  # the layout probe fails -> rr.log per tensor
    rec, spec, flags = batch
    summary = recordings.record_detection(sim, path=tmp_path / "f.rrd", chunk_samples=450)
    _check_recording(tmp_path / "f.rrd", rec, spec, flags, summary)


def test_unreachable_viewer_keeps_complete_file(tmp_path: Path, sim, batch, monkeypatch) -> None:
    """An unreachable viewer costs one short probe and nothing else: no gRPC stream is opened to it
    (whose flush at close would wait on a peer that never answers), and the file is complete."""
    rec, spec, flags = batch
    port = viewer._free_port()  # nothing listens there
    probes = []
    real_probe = viewer._reachable

    def probe(url: str, timeout: float = viewer.CONNECT_TIMEOUT_S) -> tuple[bool, str]:
        probes.append(timeout)
        return real_probe(url, timeout)

    def no_grpc(*args, **kwargs):
        pytest.fail("a gRPC sink was opened to an unreachable viewer")

    monkeypatch.setattr(viewer, "_reachable", probe)
    monkeypatch.setattr(rr, "GrpcSink", no_grpc)
    with pytest.warns(viewer.LiveViewerWarning, match="unreachable"):
        summary = recordings.record_detection(sim, path=tmp_path / "u.rrd", live=f"127.0.0.1:{port}")
    assert probes == [viewer.CONNECT_TIMEOUT_S] and viewer.CONNECT_TIMEOUT_S <= 5.0
    assert summary.live_url is None and summary.notes
    _check_recording(tmp_path / "u.rrd", rec, spec, flags, summary)


def test_spawn_without_display_still_writes_file(tmp_path: Path, sim, monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    summary = recordings.record_detection(sim, live="spawn")
    assert summary.path is not None and summary.path.parent == Path("recordings")
    assert any("no display" in n for n in summary.notes)
    RrdReader(summary.path).store()


def test_ctrl_c_closes_recording(tmp_path: Path, sim) -> None:
    def interrupt(ev):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        recordings.record_detection(sim, path=tmp_path / "k.rrd", on_event=interrupt)
    summary = RrdReader(tmp_path / "k.rrd").store().summary()  # footer written
    assert "/spectrum/pressure" in summary


@pytest.mark.filterwarnings("ignore:RRD file has no footer")
def test_live_viewer_receives_data(tmp_path: Path, sim, batch) -> None:
    exe = viewer.find_viewer()
    if exe is None:
        pytest.skip("the rerun viewer executable is not installed")
    _, spec, _ = batch
    port = viewer._free_port()
    out = tmp_path / "server.rrd"
    proc = subprocess.Popen(
        [exe, "--bind", "127.0.0.1", "--port", str(port), "--save", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own process group: the receiver's children are stopped with it
    )
    try:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        deadline = time.monotonic() + 15.0
        while not viewer._reachable(url, 0.2)[0]:
            if time.monotonic() > deadline or proc.poll() is not None:
                pytest.skip("the headless rerun receiver did not start")
            time.sleep(0.1)
        summary = recordings.record_detection(sim, live=url, chunk_samples=500)
        assert summary.live_url == url and summary.path is None
        time.sleep(0.5)
    finally:
        with contextlib.suppress(ProcessLookupError):  # it may have exited already
            os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
        with contextlib.suppress(ProcessLookupError):  # a child that ignored SIGINT
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    reader = RrdReader(out)
    n = sum(
        c.num_rows for c in reader.stream().filter(content="/spectrum/pressure", is_static=False).to_chunks()
    )
    assert n == spec.n_frames
    n = sum(
        c.num_rows
        for c in reader.stream().filter(content="/spectrogram/pressure/image", is_static=False).to_chunks()
    )
    assert n == spec.n_frames  # the scrolling view goes to the live viewer at every hop
    _, views, rng = _images(reader, "pressure")
    # always 50 columns (a fixed scale in the view), blank before the 50th frame, newest on the right
    assert all(v.shape[1] == 50 for v in views)
    assert np.all(views[0][:, :49] == spectrograms.DB_RANGE[0])
    assert len(rng) == spec.n_frames and np.array_equal(np.asarray(rng[-1]).ravel(), spectrograms.DB_RANGE)


def _visible(view, entity: str) -> list[bool]:
    """The visible_series override of ``entity`` in ``view`` (SeriesLines or SeriesPoints)."""
    (batch,) = view.visualizer_overrides[entity].as_component_batches()
    return batch.as_arrow_array().to_pylist()


def test_blueprint_builds() -> None:
    channels = ("position", "velocity", "pressure")
    bp = blueprint.blueprint(channels, has_truth=True)
    assert bp is not None
    # one column of views per channel, in channel order; each time-series view shows only its own
    # channel's series of the shared entities (series j = channel j; psi: +psi_j, -psi_j)
    columns = bp.root_container.contents[0].contents
    assert len(columns) == len(channels)
    for c, (name, col) in enumerate(zip(channels, columns, strict=True)):
        chat, _, det, freq = col.contents
        assert all(v.name.startswith(f"{name}:") for v in col.contents)
        own = [j == c for j in range(len(channels))]
        # /chattering/e: the m chattering series, then up to 2 raw series per channel, all hidden
        hidden_raw = [False] * (blueprint.SAMPLE_SERIES_PER_CHANNEL - 1) * len(channels)
        assert _visible(chat, blueprint.CHATTERING) == own + hidden_raw
        assert _visible(chat, blueprint.PSI) == [j // 2 == c for j in range(2 * len(channels))]
        assert _visible(det, blueprint.STATISTIC) == own
        assert [e for e in det.contents if "/fault/" in e] == [f"+ {blueprint.fault_entity(name)}"]
        assert _visible(freq, blueprint.PEAK_HZ) == own
        assert _visible(freq, blueprint.MOST_SIGNIFICANT_HZ) == own
        # the peak frequency in red only at flagged frames (its own sparse entity)
        assert [e for e in freq.contents if "/fault/" in e] == [f"+ {blueprint.fault_hz_entity(name)}"]
    bp = blueprint.blueprint(("position",), band_hz=(1.0, 150.0), span_s=(0.4, 3.6))
    assert bp is not None
    # lanes sort in channel order below the truth lane (the viewer orders them by entity path)
    lanes = [blueprint.lane_entity(i, c) for i, c in enumerate(("position", "velocity", "pressure"))]
    assert sorted([blueprint.TRUTH_LANE, *lanes]) == [blueprint.TRUTH_LANE, *lanes]


def test_default_band_second_order() -> None:
    from chatterspec.online.monitor import ChatteringMonitor
    from chatterspec.plants.scenarios import scenario

    mon = ChatteringMonitor(scenario("so-timeline-constant").nominal)
    assert spectrograms.default_band_hz(mon) == (1.0, 15.0)  # 3 x 5 Hz natural frequency


def _cli(*argv: str) -> int:
    from chatterspec.cli import monitor, replay

    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers()
    monitor.register(sub)
    replay.register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


def test_monitor_command_on_example(tmp_path: Path, capsys) -> None:
    out = tmp_path / "m.rrd"
    rc = _cli(
        "monitor",
        str(EXAMPLES / "eha_model.toml"),
        "--data",
        str(EXAMPLES / "eha_data.csv"),
        "--record",
        str(out),
        "--json",
    )
    assert rc == 0
    import json

    doc = json.loads(capsys.readouterr().out)
    starts = [e for e in doc["events"] if e["kind"] == "fault-start" and e["channel"] == "pressure"]
    assert starts and 3.0 < starts[0]["time_s"] < 5.0  # leakage from t = 4 s
    assert "/spectrum/pressure" in RrdReader(out).store().summary()


def test_replay_without_display(tmp_path: Path, monkeypatch, capsys) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    f = tmp_path / "x.rrd"
    f.write_bytes(b"")
    from chatterspec.cli import main
    from chatterspec.errors import DataFileError

    assert main(["replay", str(f)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("chatterspec replay: error: no display") and err.count("\n") == 1

    with pytest.raises(DataFileError, match="no such file"):
        _cli("replay", str(tmp_path / "missing.rrd"))


def test_file_spectrogram_blocks_tile_long_records(tmp_path: Path, batch) -> None:
    """With file_block_frames, consecutive tensors tile the record: every frame in exactly one."""
    from chatterspec.online.monitor import ChatteringMonitor

    rec, spec, _ = batch
    mon = ChatteringMonitor(rec.model, t0=float(rec.t[0]))
    with viewer.open_sinks(record=tmp_path / "b.rrd") as sinks:
        logger = rerun_log.RerunLogger(sinks, mon, file_block_frames=7, send_blueprint=False)
        for lo in range(0, rec.n_samples, 333):
            logger.log_update(mon.push_chattering(rec.values[0, lo : lo + 333]))
        logger.close()
    t, blocks, _ = _images(RrdReader(tmp_path / "b.rrd"), "velocity")
    widths = [b.shape[1] for b in blocks]
    p = spectrograms.pad_columns(mon)  # blank columns before the first frame and after the last one
    want = [7] * (spec.n_frames // 7) + ([spec.n_frames % 7] if spec.n_frames % 7 else [])
    want[0] += p
    want[-1] += p
    assert widths == want
    # block k starts half a hop before its first frame (the first one at the record's start)
    np.testing.assert_allclose(t[1:], spec.times_s[7::7] - 0.1, atol=1e-9)
    assert t[0] <= rec.t[0] + 1e-12


def test_logger_construction_error_is_not_hidden(tmp_path: Path, sim, monkeypatch) -> None:
    """A RerunLogger that fails to build raises its own error (it used to surface as UnboundLocalError)."""
    from chatterspec.errors import ParameterError

    def broken(*args, **kwargs):
        raise ParameterError("band_hz holds no STFT bin")

    monkeypatch.setattr(recordings, "RerunLogger", broken)
    with pytest.raises(ParameterError, match="no STFT bin"):
        recordings.record_detection(sim, path=tmp_path / "b.rrd")


def test_sample_rows_and_float64_spectra(tmp_path: Path, sim) -> None:
    """/chattering/e holds one row per sample: the chattering value of each channel, then
    [measured, sat-SVSF estimate] of each channel in turn, equal to the monitor's values; the ±psi
    lines hold +psi_c, -psi_c per channel; spectrum_dtype="float64" logs the monitor's spectra
    bit-exactly."""
    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings

    mon = ChatteringMonitor(sim.scenario.nominal, MonitorSettings(psi=(4.2e-3, 4.8e-3, 4.3e3)))
    ups = []
    with viewer.open_sinks(record=tmp_path / "s.rrd") as sinks:
        logger = rerun_log.RerunLogger(sinks, mon, spectrum_dtype="float64", send_blueprint=False)
        for lo in range(0, sim.z.shape[1], 700):
            ups.append(mon.push(sim.z[0, lo : lo + 700], sim.u[lo : lo + 700]))
            logger.log_update(ups[-1])
        logger.close()
    reader = RrdReader(tmp_path / "s.rrd")
    est = np.concatenate([u.estimate for u in ups])
    meas = np.concatenate([u.measured for u in ups])
    chat = np.concatenate([u.chattering for u in ups])
    t_all = np.concatenate([u.t for u in ups])
    t, rows = _column(reader, blueprint.CHATTERING, "Scalars:scalars")
    np.testing.assert_allclose(t, t_all, atol=1e-9)
    m = len(mon.channels)
    rows = np.asarray(rows)
    assert rows.shape == (t_all.size, 3 * m)
    np.testing.assert_array_equal(rows[:, :m], chat)
    raw = rows[:, m:]
    _, psi = _column(reader, blueprint.PSI, "Scalars:scalars")
    np.testing.assert_array_equal(psi[0], [4.2e-3, -4.2e-3, 4.8e-3, -4.8e-3, 4.3e3, -4.3e3])
    for c, name in enumerate(mon.channels):
        np.testing.assert_array_equal(raw[:, 2 * c : 2 * c + 2], np.stack([meas[:, c], est[:, c]], axis=1))
        _, cols = _column(reader, f"/spectrum/{name}", "Tensor:data")
        last = [u.frames for u in ups if u.frames.n_frames][-1]
        np.testing.assert_array_equal(np.asarray(cols[-1][0]["buffer"]), last.power[-1, :, c])
    with pytest.raises(ParameterError, match="spectrum_dtype"):
        rerun_log.RerunLogger(viewer.Sinks(), mon, spectrum_dtype="float16")


def _temporal_rows(path: Path) -> dict[str, list]:
    """Every temporal row of a recording: entity -> rows sorted by time, each (time, component values)."""
    out: dict[str, list] = {}
    for chunk in RrdReader(path).stream().filter(is_static=False).to_chunks():
        rb = chunk.to_record_batch()
        entity = rb.schema.metadata[b"rerun:entity_path"].decode()
        names = [n for n in rb.schema.names if ":" in n]  # the components ("Archetype:field")
        times = rb.column("time").cast("int64").to_pylist()
        cols = [rb.column(n).to_pylist() for n in names]
        out.setdefault(entity, []).extend(
            (t, tuple(zip(names, (c[i] for c in cols), strict=True))) for i, t in enumerate(times)
        )
    return {k: sorted(v, key=lambda r: r[0]) for k, v in out.items()}


def test_file_batches_do_not_change_the_recording(tmp_path: Path, sim) -> None:
    """The per-sample and per-frame file batches are a transport detail: one batch per stream, the
    defaults and tiny batches (a few pushes of samples, 2 frames) record the same rows, except the
    two-row helper lines (±psi, 0 dB), which hold one row at each batch's first and last sample or
    frame and the same values."""
    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings

    mon = ChatteringMonitor(sim.scenario.nominal, MonitorSettings(psi=(4.2e-3, 4.8e-3, 4.3e3)))
    ups = [mon.push(sim.z[0, lo : lo + 700], sim.u[lo : lo + 700]) for lo in range(0, sim.z.shape[1], 700)]
    assert sum(u.frames.n_frames for u in ups) > 10 and sum(len(u.events) for u in ups) > 0
    rows = {}
    for name, kw in {
        "one": {"batch_samples": 10**9, "batch_frames": 10**9},
        "default": {},
        "tiny": {"batch_samples": 1000, "batch_frames": 2},
    }.items():
        path = tmp_path / f"{name}.rrd"
        with viewer.open_sinks(record=path) as sinks:
            logger = rerun_log.RerunLogger(sinks, mon, send_blueprint=False, **kw)
            for u in ups:
                logger.log_update(u)
            logger.close()
        rows[name] = _temporal_rows(path)
    helpers = {blueprint.PSI, blueprint.THRESHOLD}
    assert set(rows["one"]) >= {blueprint.CHATTERING, blueprint.STATISTIC, "/events", "/spectrum/pressure"}
    for name in ("default", "tiny"):
        assert set(rows[name]) == set(rows["one"])
        for entity, want in rows["one"].items():
            got = rows[name][entity]
            if entity in helpers:  # more rows with more batches, all with the same values
                assert len(got) >= len(want) == 2 and all(r[1] == want[0][1] for r in got)
                assert got[0][0] == want[0][0] and got[-1][0] == want[-1][0]
            else:
                assert got == want, entity
    assert len(rows["tiny"][blueprint.PSI]) > len(rows["default"][blueprint.PSI])
    with pytest.raises(ParameterError, match="batch_samples"):
        rerun_log.RerunLogger(viewer.Sinks(), mon, batch_samples=0)


def test_peak_hz_series_is_the_largest_excess_among_flagged_bins(tmp_path: Path) -> None:
    """The per-frame ``peak_hz`` series follows the batch report's rule, recomputed here from the batch
    spectrogram: the largest S - E among the bins over the threshold when a frame has any, else over
    all tested bins. On minor leakage (seed 0) the overall largest excess of flagged frames sits on
    healthy high-frequency noise (the old rule: up to ~400 Hz once the footprint fades)."""
    from chatterspec.detection.spectral import expected_frame_spectrum

    sim = cs.simulate(cs.scenario("eha-leak-minor"), runs=1, seed=0)
    rec = chattering_record(sim.scenario.nominal, sim.z, sim.u, scenario=sim.scenario)
    spec = spectrogram(rec.values[0], rec.dt, t0=rec.t[0])
    thr = frame_threshold(rec.model, spec.freqs_hz, spec.config, rec.dt)
    flags = detect_frames(spec, thr)
    expected = expected_frame_spectrum(rec.model, spec.freqs_hz, spec.config, rec.dt)
    path = tmp_path / "p.rrd"
    recordings.record_detection(sim, path=path, chunk_samples=1000)
    t = thr.tested
    f_t = spec.freqs_hz[t]
    reader = RrdReader(path)
    c = rec.channels.index("pressure")
    _, got = _column(reader, blueprint.PEAK_HZ, "Scalars:scalars")
    got = np.asarray(got)[:, c]
    want, overall = [], []
    for j in range(spec.n_frames):
        s = spec.power[j, t, c]
        excess = s - expected[t, c]
        over = s > thr.values[t, c]
        overall.append(f_t[np.argmax(excess)])
        want.append(f_t[np.argmax(np.where(over, excess, -np.inf))] if over.any() else overall[-1])
    np.testing.assert_array_equal(got, want)
    fl = flags[:, c]
    assert fl.any() and np.all((got[fl] >= 10.0) & (got[fl] <= 100.0))  # inside the chirp band
    assert np.any(np.asarray(overall)[fl] > 100.0)  # where the old rule left the footprint


@pytest.mark.parametrize("tested", ["contiguous", "sparse"])
def test_peak_bins_paths_agree(tested: str, monkeypatch) -> None:
    """The compiled and numpy paths of ``peak_bins`` pick the same bins (bit-identical: subtractions and
    comparisons only), equal to the rule written out with np.where/argmax on the frame-major array:
    frames with bins over the threshold (their largest excess among those), frames with none (the
    overall largest excess), exact ties (the first bin wins, as np.argmax)."""
    rng = np.random.default_rng(7)
    F, B, m = 40, 64, 3
    power = rng.exponential(size=(F, B, m))
    idx = np.arange(1, B - 1) if tested == "contiguous" else np.arange(1, B, 3)
    expected = rng.uniform(0.5, 1.5, size=(idx.size, m))
    thr = expected * 4.0
    thr[:, 1] = 1e9  # channel 1: never over the threshold
    power[5, idx[[2, 7]], 0] = power[5, idx[7], 0] + 10.0  # a tie in excess needs equal E as well
    expected[7, 0] = expected[2, 0]
    p_t = power[:, idx, :]
    excess = p_t - expected
    masked = np.where(p_t > thr, excess, -np.inf)
    want = np.where((p_t > thr).any(axis=1), masked.argmax(axis=1), excess.argmax(axis=1))
    assert (p_t > thr).any(axis=1)[:, 0].any() and not (p_t > thr).any(axis=1)[:, 1].any()
    assert want[5, 0] == 2  # the tie: the first of the two bins
    monkeypatch.setenv("CHATTERSPEC_JIT", "0")
    np.testing.assert_array_equal(spectrograms.peak_bins(power, idx, expected, thr), want)
    out = np.empty((F, m), dtype=np.int64)
    kernel = spectrograms._peak_bins_kernel
    getattr(kernel, "py_func", kernel)(power, idx, expected, thr, out)  # the kernel's Python source
    np.testing.assert_array_equal(out, want)
    # out=: rows of a batch array filled block by block (the logger's use), on both paths
    for jit in ("0", "1"):
        monkeypatch.setenv("CHATTERSPEC_JIT", jit)
        batch = np.full((F + 5, m), -1, dtype=np.int64)
        got = spectrograms.peak_bins(power, idx, expected, thr, out=batch[5:])
        assert np.shares_memory(got, batch) and (batch[:5] == -1).all()
        np.testing.assert_array_equal(batch[5:], want)
    monkeypatch.delenv("CHATTERSPEC_JIT")
    np.testing.assert_array_equal(spectrograms.peak_bins(power, idx, expected, thr), want)
