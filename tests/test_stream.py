"""Live sources: stdin and followed files, simulate, gaps, bad rows, signals, rotation, events."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli.scenarios import export_model_toml
from chatterspec.errors import DataFileError
from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
from chatterspec.online.simulated_stream import csv_header, csv_lines, simulate_blocks
from chatterspec.online.stream import (
    RESTART,
    BadRow,
    CsvRows,
    LatencyStats,
    Restart,
    RowBlock,
    follow_file,
)
from chatterspec.plants.datafile import load_data
from chatterspec.plants.modelfile import load_model
from chatterspec.viewer import live_stream  # the live stream monitor's rotation
from chatterspec.viewer import sinks as viewer
from chatterspec.viewer.live_stream import StreamMonitor

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_MODEL = ROOT / "examples" / "eha_model.toml"
EXAMPLE_DATA = ROOT / "examples" / "eha_data.csv"  # 8 s at 1 kHz, leakage from 4 s (fault start 3.7 s)
RERUN = Path(sys.executable).parent / "rerun"
ENV = {**os.environ, "PYTHONPATH": str(ROOT)}


def _cli(*argv: str) -> list[str]:
    return [sys.executable, "-m", "chatterspec", *argv]


def _main(
    argv: list[str], stdin_text: str | None, tmp_path: Path, capsys, monkeypatch
) -> tuple[int, str, str]:
    """Run the command line in this process (no interpreter start-up); stdin from a file."""
    from chatterspec.cli import main

    if stdin_text is not None:
        src = tmp_path / f"stdin-{time.perf_counter_ns()}.csv"
        src.write_text(stdin_text)
        fh = src.open()
        monkeypatch.setattr(sys, "stdin", fh)
    capsys.readouterr()
    try:
        rc = main(argv)
    finally:
        if stdin_text is not None:
            fh.close()
    out, err = capsys.readouterr()
    return rc, out, err


def _events(stdout: str) -> list[dict]:
    return [json.loads(line) for line in stdout.splitlines() if line.strip()]


def _comparable(ev: dict) -> tuple:
    """An event without its wall time (the only field that differs between two runs)."""
    return tuple((k, v) for k, v in sorted(ev.items()) if k != "wall_time")


def _no_traceback(stderr: str) -> None:
    assert "Traceback" not in stderr, stderr


def _verify(path: Path) -> None:
    cmd = [str(RERUN), "rrd", "verify", str(path)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, f"rerun rrd verify {path}: {out.stdout}\n{out.stderr}"


@pytest.fixture(scope="module")
def spec():
    return load_model(EXAMPLE_MODEL)


@pytest.fixture(scope="module")
def example_text() -> str:
    return EXAMPLE_DATA.read_text()


# --------------------------------------------------------------------------- parser
def test_rows_split_anywhere_equal_one_block(spec, example_text) -> None:
    """Bytes cut at arbitrary places (mid-line, mid-number) give the same rows and line numbers."""
    data = example_text.encode()
    whole = CsvRows(spec.model)
    ref = [b for b in whole.feed(data, 0.0) + whole.finish(0.0) if isinstance(b, RowBlock)]
    assert len(ref) == 1 and ref[0].n_rows == 8001
    assert ref[0].lines[0] == 3  # line 1: comment, line 2: header
    ds = load_data(EXAMPLE_DATA, spec.model)
    np.testing.assert_allclose(ref[0].z, ds.z, rtol=1e-15)
    np.testing.assert_allclose(ref[0].t, ds.t, rtol=1e-15)

    rng = np.random.default_rng(0)
    cuts = np.sort(rng.choice(len(data), size=400, replace=False))
    parser = CsvRows(spec.model)
    blocks = []
    for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(data)], strict=True):
        blocks += parser.feed(data[lo:hi], 0.0)
    blocks += parser.finish(0.0)
    assert all(isinstance(b, RowBlock) for b in blocks)
    np.testing.assert_array_equal(np.concatenate([b.z for b in blocks]), ref[0].z)
    np.testing.assert_array_equal(np.concatenate([b.u for b in blocks]), ref[0].u)
    np.testing.assert_array_equal(np.concatenate([b.lines for b in blocks]), ref[0].lines)


def test_bad_rows_nan_and_restart_are_named_by_line(spec) -> None:
    p = CsvRows(spec.model)
    text = (
        "# comment\n"
        "time,position,velocity,pressure,pump_speed,note\n"  # an extra column is ignored
        "0.000,1,2,3,4,a\n"
        "0.001,1,x,3,4,b\n"  # line 4: not a number
        "0.002,1,2,nan,4,c\n"  # line 5: NaN
        "0.003,1,2,,4,c\n"  # line 6: empty cell
        "0.004,1,2,3\n"  # line 7: too few fields
        "\n"
        "time,position,velocity,pressure,pump_speed\n"  # line 9: the producer started over
        "0.000,1,2,3,4\n"
    )
    out = p.feed(text.encode(), 1.0)
    kinds = [(type(o).__name__, getattr(o, "line", None)) for o in out]
    assert kinds == [
        ("RowBlock", None),
        ("BadRow", 4),
        ("BadRow", 5),
        ("BadRow", 6),
        ("BadRow", 7),
        ("Restart", 9),
        ("RowBlock", None),
    ]
    assert "column 'velocity'" in out[1].message and "'x'" in out[1].message
    assert "NaN" in out[2].message and "line 5" in out[2].message
    assert out[0].lines.tolist() == [3] and out[-1].lines.tolist() == [10]
    with pytest.raises(DataFileError, match="lacks column"):
        CsvRows(spec.model).feed(b"time,position\n", 0.0)


def test_follow_file_restarts_on_truncation_and_starts_from_end(tmp_path, spec) -> None:
    path = tmp_path / "f.csv"
    path.write_bytes(b"time,position,velocity,pressure,pump_speed\n0,1,2,3,4\n0.001,1,2,3,4\n0.002,1,")
    gen = follow_file(path, from_end=True, poll_s=0.01, idle_timeout_s=0.3)
    got = [next(gen)[0]]
    assert got == [b"time,position,velocity,pressure,pump_speed\n"]  # header, then the tail is skipped
    path.write_bytes(b"time,position,velocity,pressure,pump_speed\n")  # truncated: a new file
    with path.open("ab") as fh:
        fh.write(b"0,5,6,7,8\n")
    rest = [d for d, _ in gen]
    assert rest[0] == RESTART  # the file shrank below the read position
    p = CsvRows(spec.model)
    items = [i for d in got + rest[rest.index(RESTART) :] for i in p.feed(d, 0.0)]
    assert isinstance(items[-2], Restart) and isinstance(items[-1], RowBlock)
    assert items[-1].z.tolist() == [[5.0, 6.0, 7.0]]


def test_latency_stats_median_and_max() -> None:
    x = np.random.default_rng(1).lognormal(np.log(2e-3), 1.0, size=10_001)
    st = LatencyStats()
    for v in x:
        st.add(float(v))
    # bins are 0.5 % wide in log: the reported median is within half a bin (0.25 %) of a sample median
    assert st.median() == pytest.approx(np.median(x), rel=3e-3)
    assert st.max_s == x.max() and st.n == x.size
    assert st.counts.nbytes < 50_000  # fixed size whatever the run length


# --------------------------------------------------------------------------- gaps (in process)
def _blocks(t, z, u, lines=None):
    lines = np.arange(t.shape[0]) + 2 if lines is None else lines
    return RowBlock(t, z, u, lines, time.perf_counter())


def test_gap_resets_and_equals_two_fresh_monitors(spec) -> None:
    """A time jump = a gap event + a fresh monitor from the resuming sample: the events after the
    gap are exactly those of a new monitor started there (the filter and STFT buffer were reset)."""
    ds = load_data(EXAMPLE_DATA, spec.model)
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    cut, skip = 3000, 37  # drop 37 samples after 3 s: a 38 dt step
    a, b = slice(0, cut), slice(cut + skip, None)
    events = []
    sm = StreamMonitor(spec.model, settings, on_event=events.append)
    for sl in (a, b):
        for lo in range(sl.start, sl.stop or ds.n_samples, 777):  # chunks that straddle nothing special
            hi = min(lo + 777, sl.stop or ds.n_samples)
            sm.process(_blocks(ds.t[lo:hi], ds.z[lo:hi], ds.u[lo:hi], np.arange(lo, hi) + 3))
    summary = sm.close()
    gaps = [e for e in events if e.kind == "gap"]
    assert len(gaps) == 1 and summary.counts["gap"] == 1
    assert gaps[0].sample_time_s == pytest.approx(ds.t[cut + skip]) and gaps[0].line == cut + skip + 3
    assert "jumped" in gaps[0].reason

    ref = []
    for sl in (a, b):
        mon = ChatteringMonitor(spec.model, settings, t0=float(ds.t[sl][0]))
        evs = mon.push(ds.z[sl], ds.u[sl]).events
        ref += [(e.kind, e.channel, e.alarm_time_s, e.peak_ratio) for e in evs]
        ref_frames = mon.n_frames
    got = [(e.kind, e.channel, e.sample_time_s, e.ratio) for e in events if e.kind != "gap"]
    assert ref and [g[:3] for g in got] == [r[:3] for r in ref]  # the leak (from 4 s) is seen after the gap
    # chunked vs whole pushes: spectra agree to rounding (test_monitor), so do the ratios
    np.testing.assert_allclose([g[3] for g in got], [r[3] for r in ref], rtol=1e-9)
    assert summary.n_rows == ds.n_samples - skip
    assert summary.n_frames > ref_frames


def test_backwards_time_and_skipped_row_are_gaps(spec) -> None:
    ds = load_data(EXAMPLE_DATA, spec.model)
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    events = []
    sm = StreamMonitor(spec.model, settings, on_event=events.append, skip_bad_rows=True)
    t = ds.t[:1500].copy()
    t[1000:] -= 0.5  # time goes back at row 1000
    sm.process(_blocks(t, ds.z[:1500], ds.u[:1500]))
    sm.process(BadRow(1600, "standard input, line 1600: column 'pressure': 'x' is not a number"))
    sm.process(_blocks(ds.t[1501:2000] - 0.5, ds.z[1501:2000], ds.u[1501:2000], np.arange(1501, 2000) + 2))
    summary = sm.close()
    gaps = [e for e in events if e.kind == "gap"]
    assert [g.line for g in gaps] == [1002, 1600]
    assert "not increasing" in gaps[0].reason and "line 1600 skipped" in gaps[1].reason
    assert summary.counts["bad-row"] == 1
    strict = StreamMonitor(spec.model, settings)
    with pytest.raises(DataFileError, match=r"line 1600.*--skip-bad-rows"):
        strict.process(BadRow(1600, "standard input, line 1600: column 'pressure': 'x' is not a number"))


def test_gap_rule_boundary_jitter_is_not_a_gap_two_dt_is(spec) -> None:
    """The rule: a step outside (0.5 dt, 1.5 dt] is a gap. A sample 0.4 dt late (steps of 1.4 dt
    and 0.6 dt around it) is clock jitter, not a gap; one missing sample (a 2 dt step) is a gap."""
    ds = load_data(EXAMPLE_DATA, spec.model)
    dt = spec.model.dt
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    keep = np.r_[0:1700, 1701:2500]  # sample 1700 missing: a 2 dt step into 1701
    t = ds.t[keep].copy()
    t[900] += 0.4 * dt  # jitter: 1.4 dt after sample 899, 0.6 dt before sample 901
    steps = np.diff(t) / dt
    assert steps.max() == pytest.approx(2.0) and steps[899] == pytest.approx(1.4)
    assert steps.min() == pytest.approx(0.6)
    events = []
    sm = StreamMonitor(spec.model, settings, on_event=events.append)
    sm.process(_blocks(t, ds.z[keep], ds.u[keep], keep + 2))
    summary = sm.close()
    gaps = [e for e in events if e.kind == "gap"]
    assert summary.counts["gap"] == 1 and len(gaps) == 1
    assert gaps[0].line == 1701 + 2 and gaps[0].sample_time_s == pytest.approx(ds.t[1701])
    assert "2 dt" in gaps[0].reason


def test_simulate_blocks_streams_the_scenario(spec) -> None:
    sc = cs.scenario("eha-leak-major")
    parts = list(simulate_blocks(sc, seed=2, duration_s=10.0, block_s=0.7))
    t = np.concatenate([p[0] for p in parts])
    np.testing.assert_allclose(t, np.arange(10001) * sc.dt, atol=1e-12)
    u = np.concatenate([p[2] for p in parts])
    np.testing.assert_allclose(u[4000:8000], u[:4000], atol=1e-9)  # the 4 s chirp repeats
    text = csv_header(sc.nominal) + "\n" + "".join(csv_lines(*p) for p in parts)
    rows = CsvRows(spec.model).feed(text.encode(), 0.0)
    z = np.concatenate([r.z for r in rows])
    np.testing.assert_allclose(z, np.concatenate([p[1] for p in parts]), rtol=1e-8, atol=0)


def test_scenarios_model_toml_round_trip(tmp_path) -> None:
    from chatterspec.cli import main

    path = tmp_path / "leak.toml"
    assert main(["scenarios", "eha-leak-major", "--model-toml", str(path)]) == 0
    got = load_model(path)
    nominal = cs.scenario("eha-leak-major").nominal
    for key in "ABCQR":
        np.testing.assert_array_equal(getattr(got.model, key), getattr(nominal, key))
    assert got.model.dt == nominal.dt and got.model.output_names == nominal.output_names
    assert np.all(got.psi > 0)


# --------------------------------------------------------------------------- command line
def test_pipe_simulate_into_monitor_reads_fault_start_while_producer_runs(tmp_path) -> None:
    model = tmp_path / "leak.toml"
    export_model_toml("eha-leak-major", model)  # what `chatterspec scenarios NAME --model-toml` writes
    # 60 s of data at 20x: >= 3 s of producing; the pipe buffer (~1 s of rows) keeps it from racing ahead
    prod = subprocess.Popen(
        _cli("simulate", "eha-leak-major", "--rate", "20", "--duration", "60", "--seed", "3"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=ENV,
    )
    mon = subprocess.Popen(
        _cli("monitor", str(model), "--data", "-", "--events", "jsonl"),
        stdin=prod.stdout,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )
    prod.stdout.close()  # the monitor holds the read end
    first = json.loads(mon.stdout.readline())
    producer_running = prod.poll() is None
    rest = mon.stdout.read()
    mon_err = mon.stderr.read()
    assert mon.wait(timeout=120) == 0 and prod.wait(timeout=120) == 0
    assert first["event"] == "fault-start" and first["channel"] == "pressure"
    assert producer_running, "the fault-start event should arrive while the producer still writes"
    assert set(first) >= {"sample_time_s", "wall_time", "channel", "peak_hz", "ratio"}
    assert first["ratio"] > 1 and 0 < first["peak_hz"] < 500 and first["sample_time_s"] < 2.0
    _no_traceback(mon_err + prod.stderr.read().decode())
    assert "60.00 s of data (60001 rows)" in mon_err and "stopped by end of input" in mon_err
    assert all(e["event"] in ("fault-start", "fault-end") for e in _events(rest))


def test_follow_growing_file_equals_finished_file(tmp_path, example_text, capsys, monkeypatch) -> None:
    path = tmp_path / "growing.csv"
    data = example_text.encode()
    head = data.index(b"\n", data.index(b"time")) + 1
    path.write_bytes(data[: head + 1000])  # header and a few rows, the last one cut
    mon = subprocess.Popen(
        _cli(
            "monitor",
            str(EXAMPLE_MODEL),
            "--data",
            str(path),
            "--follow",
            "--idle-timeout",
            "4",
            "--events",
            "jsonl",
            "--json",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=ENV,
    )

    def writer() -> None:
        rng = np.random.default_rng(5)
        pos = head + 1000
        with path.open("ab") as fh:
            while pos < len(data):
                n = int(rng.integers(2000, 40000))  # cuts anywhere, even inside a number
                fh.write(data[pos : pos + n])
                fh.flush()
                pos += n
                time.sleep(0.02)

    th = threading.Thread(target=writer)
    th.start()
    out, err = mon.communicate(timeout=180)
    th.join()
    assert mon.returncode == 0, err
    _no_traceback(err)
    followed = _events(out)
    summary = followed.pop()
    assert summary["event"] == "summary" and summary["n_rows"] == 8001
    assert summary["stopped_by"] == "idle timeout"
    argv = ["monitor", str(EXAMPLE_MODEL), "--data", str(EXAMPLE_DATA), "--events", "jsonl"]
    rc, out, _ = _main(argv, None, tmp_path, capsys, monkeypatch)
    assert rc == 0
    expected = _events(out)
    assert expected and [_comparable(e) for e in followed] == [_comparable(e) for e in expected]


def _stream_text(t0: float, n: int, skip: int | None = None, bad: int | None = None) -> str:
    rows = EXAMPLE_DATA.read_text().splitlines()[2:]
    body = rows[:n]
    if bad is not None:
        cells = body[bad].split(",")
        body[bad] = ",".join([*cells[:3], "nan", *cells[4:]])
    if skip is not None:
        body = body[:skip] + body[skip + 50 :]
    return "time,position,velocity,pressure,pump_speed\n" + "\n".join(body) + "\n"


def test_cli_gap_and_bad_rows(tmp_path, capsys, monkeypatch) -> None:
    base = ["monitor", str(EXAMPLE_MODEL), "--data", "-", "--events", "jsonl"]
    # a time gap: one gap event at the resuming sample, run goes on
    rc, out, err = _main(base, _stream_text(0, 3000, skip=1500), tmp_path, capsys, monkeypatch)
    assert rc == 0, err
    evs = [e for e in _events(out) if e["event"] == "gap"]
    assert len(evs) == 1 and evs[0]["sample_time_s"] == pytest.approx(1.55) and evs[0]["line"] == 1502
    # a NaN row stops the run by default, naming the line; no traceback
    text = _stream_text(0, 2000, bad=700)
    rc, out, err = _main(base, text, tmp_path, capsys, monkeypatch)
    assert rc == 2 and "line 702" in err and "--skip-bad-rows" in err
    _no_traceback(err)
    # ... and is skipped as a gap with --skip-bad-rows
    rc, out, err = _main([*base, "--skip-bad-rows"], text, tmp_path, capsys, monkeypatch)
    assert rc == 0
    _no_traceback(err)
    evs = [e for e in _events(out) if e["event"] == "gap"]
    assert len(evs) == 1 and evs[0]["line"] == 702 and "skipped" in evs[0]["reason"]
    assert "skipped standard input, line 702" in err and "1 bad row(s) skipped" in err


def test_sigterm_finalizes_recording_and_summary(tmp_path) -> None:
    rec = tmp_path / "term.rrd"
    mon = subprocess.Popen(
        _cli(
            "monitor",
            str(EXAMPLE_MODEL),
            "--data",
            "-",
            "--events",
            "jsonl",
            "--record",
            str(rec),
        ),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=ENV,
    )
    mon.stdin.write(EXAMPLE_DATA.read_bytes())  # 8 s with a fault start at 3.7 s; stdin stays open
    mon.stdin.flush()
    first = json.loads(mon.stdout.readline())  # the monitor is running and has seen the data
    assert first["event"] == "fault-start"
    mon.send_signal(signal.SIGTERM)
    _, err = mon.communicate(timeout=120)
    err = err.decode()
    assert mon.returncode == 143, err  # 128 + SIGTERM, after the summary and the recording's footer
    _no_traceback(err)
    assert "stopped by SIGTERM" in err
    rows = int(err.split(" rows)")[0].rsplit("(", 1)[1])
    assert 3700 < rows <= 8001  # at least up to the fault start, at most everything
    _verify(rec)


def test_rotated_recordings_each_verify(tmp_path, capsys, monkeypatch) -> None:
    base = tmp_path / "rot.rrd"
    argv = ["monitor", str(EXAMPLE_MODEL), "--data", "-", "--json", "--record", str(base)]
    argv += ["--record-every", "0.05"]  # 3 s of data per file: 3 files for 8 s
    rc, stdout, stderr = _main(argv, EXAMPLE_DATA.read_text(), tmp_path, capsys, monkeypatch)
    assert rc == 0, stderr
    _no_traceback(stderr)
    doc = json.loads(stdout)
    recs = doc["recordings"]
    bounds = [v for r in recs for v in (r["start_s"], r["stop_s"])]
    assert bounds == pytest.approx([0, 3, 3, 6, 6, 8.001])
    assert {str(f) for f in tmp_path.glob("rot-*.rrd")} == {r["path"] for r in recs}
    for r in recs:
        assert Path(r["path"]).stat().st_size == r["bytes"] > 0
        _verify(Path(r["path"]))
    assert doc["latency"]["frames"] == doc["n_frames"] == 36


def test_simulate_broken_pipe_is_quiet() -> None:
    prod = subprocess.Popen(
        _cli("simulate", "eha-healthy", "--rate", "0", "--duration", "600"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=ENV,
    )
    assert prod.stdout.readline().startswith(b"time,position")
    prod.stdout.close()  # the reader goes away
    assert prod.wait(timeout=120) == 0
    assert prod.stderr.read() == b""


def test_stream_option_errors_are_reported_without_traceback(tmp_path, capsys, monkeypatch) -> None:
    for argv, what in (
        (["--data", "-", "--follow"], "--follow needs a file"),
        (["--data", str(EXAMPLE_DATA), "--record-every", "1"], "apply to streams"),
        (["--data", "-", "--rate", "2"], "--rate paces a file replay"),
        (["--data", str(tmp_path / "none.csv"), "--follow"], "does not exist"),
        (["--data", "-", "--record-every", "0"], "must be >= 0.05 minutes"),
    ):
        rc, _, err = _main(["monitor", str(EXAMPLE_MODEL), *argv], None, tmp_path, capsys, monkeypatch)
        assert rc == 2 and what in err, (argv, err)
        _no_traceback(err)
    rc, _, err = _main(["monitor", str(EXAMPLE_MODEL), "--data", "-"], "", tmp_path, capsys, monkeypatch)
    assert rc == 2 and "no header line" in err


def test_restart_resets_without_a_gap_event(spec) -> None:
    """A producer that starts over (new header, time back to 0) is one restart event, not a gap."""
    ds = load_data(EXAMPLE_DATA, spec.model)
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    events = []
    sm = StreamMonitor(spec.model, settings, on_event=events.append)
    sm.process(_blocks(ds.t[:5000], ds.z[:5000], ds.u[:5000]))  # through the fault start at 3.7 s
    first = sm.monitor
    assert first.active.any()
    sm.process(Restart(5002, "a new header at line 5002 (the producer started over)"))
    sm.process(_blocks(ds.t[:1500], ds.z[:1500], ds.u[:1500], np.arange(1500) + 5003))
    summary = sm.close()
    kinds = [e.kind for e in events]
    assert kinds == ["fault-start", "restart"]
    assert events[1].open_faults == ("pressure",) and events[1].sample_time_s == pytest.approx(4.999)
    assert sm.monitor is not first and sm.monitor.n_samples == 1499  # a fresh filter: z(0) initializes
    assert summary.n_rows == 6500 and summary.counts["restart"] == 1 and summary.counts["gap"] == 0


def _os_threads() -> int:
    return len(os.listdir("/proc/self/task"))


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="counts threads in /proc")
def test_rotation_releases_rerun_streams_and_threads(spec, tmp_path, monkeypatch) -> None:
    """16 rotations: every file complete and listed, no ``.part`` left, the OS threads do not grow,
    and no recording is opened or closed on the loop's thread.

    rerun-sdk 0.41 kept each dropped recording stream (and the blueprint stream
    ``send_blueprint`` makes) with two threads each, so before the fix every rotation
    added 4 threads (and ~2 MB); a few threads of slack cover the files being opened
    ahead and swept on the rotation thread at the moment of counting (seen: +5 under load).
    """
    ds = load_data(EXAMPLE_DATA, spec.model)
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    sm = StreamMonitor(spec.model, settings, record=tmp_path / "r.rrd", record_every_s=0.5)
    # from here on, opening (70-110 ms) and closing (50-80 ms) a recording must never stop the loop:
    # both run on the rotation thread, the loop only renames the file opened ahead and hands over
    real_open, real_finish = viewer.open_sinks, live_stream._finish_file

    def watched(fn, what):
        def call(*args, **kwargs):
            if threading.current_thread() is threading.main_thread():  # fail at once, do not block
                raise AssertionError(f"a recording was {what} on the monitor loop's thread")
            return fn(*args, **kwargs)

        return call

    monkeypatch.setattr(viewer, "open_sinks", watched(real_open, "opened"))
    monkeypatch.setattr(live_stream, "_finish_file", watched(real_finish, "closed"))
    counts = []
    for lo in range(0, ds.n_samples, 500):  # one rotation per block
        hi = min(lo + 500, ds.n_samples)
        sm.process(_blocks(ds.t[lo:hi], ds.z[lo:hi], ds.u[lo:hi]))
        sm.wait_closed()
        counts.append(_os_threads())
    summary = sm.close()
    assert sm.n_recordings == len(summary.recordings) == 17  # 16 full files of 0.5 s, the last sample
    # a leak adds 4 threads per rotation (+52 here); in flight at a count, on a loaded machine: the file
    # opened ahead and the one still being swept, with their blueprint streams (2 threads each, <= 8)
    assert counts[-1] - counts[2] <= 8, counts
    assert not list(tmp_path.glob(".*.part"))
    assert sorted(str(p) for p in tmp_path.glob("r-*.rrd")) == sorted(r["path"] for r in summary.recordings)
    for r in (summary.recordings[0], summary.recordings[-1]):
        _verify(Path(r["path"]))
    # (the loop's stop per rotation is timed by benchmarks/bench_soak.py --rotations)
