"""What a recorded FILE opens on, read back from the .rrd: its last blueprint is paused on the whole record
(also for a streamed file, whose span is only known when it closes), the chattering views have a fixed
symmetric y range, and the interval events name both the most significant bin and the bin of largest
excess."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.detection.thresholds import db_over_threshold, two_bins_text
from chatterspec.plants.datafile import load_data
from chatterspec.plants.modelfile import load_model
from chatterspec.plants.scenarios import scenario

rr = pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings  # noqa: E402
from chatterspec.online.stream import RowBlock  # noqa: E402
from chatterspec.viewer import blueprint, recordings, spectrograms  # noqa: E402
from chatterspec.viewer.blueprint import (  # noqa: E402
    MARGIN,
    QUANTILE,
    STRIDE,
    ChatteringExtent,
    labelled_half_range,
)
from chatterspec.viewer.live_stream import StreamMonitor  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
EXAMPLE_MODEL = ROOT / "examples" / "eha_model.toml"
EXAMPLE_DATA = ROOT / "examples" / "eha_data.csv"  # 8 s at 1 kHz, leakage from 4 s
PAUSED, FOLLOWING = 1, 3  # rerun's PlayState enum in the file


def _time_panels(path: Path) -> list[tuple[int, int | None, tuple[int, int] | None]]:
    """Per blueprint in the file: (last log time, play state, time selection (ns)), in the order sent."""
    reader = RrdReader(path)
    out = []
    for store in reader.blueprints():
        t_log, state, sel = -1, None, None
        for chunk in reader.stream(store=store).to_chunks():
            rb = chunk.to_record_batch()
            names = rb.schema.names
            if "log_time" in names:
                t_log = max([t_log, *rb.column("log_time").cast("int64").to_pylist()])
            if "TimePanelBlueprint:play_state" in names:
                state = rb.column("TimePanelBlueprint:play_state").to_pylist()[-1][0]
            if "TimePanelBlueprint:time_selection" in names:
                s = rb.column("TimePanelBlueprint:time_selection").to_pylist()[-1][0]
                sel = (s["min"], s["max"])
        out.append((t_log, state, sel))
    return sorted(out)


def test_streamed_file_opens_paused_on_the_whole_record(tmp_path: Path) -> None:
    """``... | chatterspec monitor --record f.rrd``: the span is not known when the file opens (a live-like
    blueprint, following), so the file's final blueprint, sent on close, is paused on exactly the span of
    a file recorded with the record's length known in advance (``record_span``)."""
    spec = load_model(EXAMPLE_MODEL)
    ds = load_data(EXAMPLE_DATA, spec.model)
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    path = tmp_path / "s.rrd"
    sm = StreamMonitor(spec.model, settings, record=path)
    for lo in range(0, ds.n_samples, 700):
        hi = min(lo + 700, ds.n_samples)
        sm.process(RowBlock(ds.t[lo:hi], ds.z[lo:hi], ds.u[lo:hi], np.arange(lo, hi) + 2, 0.0))
    sm.close()
    fresh = ChatteringMonitor(spec.model, settings, t0=float(ds.t[0]))
    span = spectrograms.record_span(fresh, ds.n_samples, raw=True)
    panels = _time_panels(path)
    assert len(panels) == 2
    assert panels[0][1] == FOLLOWING  # sent when the file opened
    _, state, sel = panels[-1]  # the last one sent: what the viewer opens
    assert state == PAUSED
    # the same integer ns as a file whose span is known in advance (one rounding rule, 1 ns of slack for
    # the float sums of frame centres)
    assert sel is not None
    assert (
        abs(sel[0] - int(spectrograms.to_ns(span[0]))) <= 1
        and abs(sel[1] - int(spectrograms.to_ns(span[1]))) <= 1
    )


def test_rotated_files_open_paused_on_their_own_span(tmp_path: Path) -> None:
    spec = load_model(EXAMPLE_MODEL)
    ds = load_data(EXAMPLE_DATA, spec.model)
    settings = MonitorSettings(psi=tuple(spec.psi), gamma=spec.gamma)
    sm = StreamMonitor(spec.model, settings, record=tmp_path / "r.rrd", record_every_s=3.0)
    for lo in range(0, ds.n_samples, 500):
        hi = min(lo + 500, ds.n_samples)
        sm.process(RowBlock(ds.t[lo:hi], ds.z[lo:hi], ds.u[lo:hi], np.arange(lo, hi) + 2, 0.0))
    summary = sm.close()
    with_frames = [
        r for r in summary.recordings if r["stop_s"] is not None and r["stop_s"] - r["start_s"] > 2
    ]
    assert len(with_frames) >= 2
    for r in with_frames:
        *_, (_, state, sel) = _time_panels(Path(r["path"]))
        assert state == PAUSED and sel is not None
        # each file's span covers its own period of data (within the STFT window of its edges)
        assert sel[0] / 1e9 <= r["start_s"] + 1.0 and sel[1] / 1e9 >= r["stop_s"] - 1.0
        assert sel[1] - sel[0] <= 1e9 * (r["stop_s"] - r["start_s"] + 2.0)


def test_chattering_extent_is_a_robust_symmetric_range() -> None:
    rng = np.random.default_rng(7)
    ext = ChatteringExtent(2)
    assert ext.ranges() is None  # nothing seen: auto range
    e = rng.normal(0.0, [1e-4, 2.0], size=(20_000, 2))
    e[8, 0] = 1.0  # one glitch, on a sample that enters the quantile (a filter's start) cannot set the range
    ext.add(e)
    ext.add(e[1000:2000] * 3)  # a later, louder batch widens it
    got = ext.ranges()
    want = MARGIN * np.fmax(
        np.quantile(np.abs(e[::STRIDE]), QUANTILE, axis=0),
        np.quantile(np.abs(3 * e[1000:2000:STRIDE]), QUANTILE, axis=0),
    )
    np.testing.assert_allclose(got, [labelled_half_range(w) for w in want])
    assert got[0] < labelled_half_range(MARGIN * 1.0) / 100  # the glitch of 1.0 is not the extent
    # the boundary layer stays in view; an all-zero channel keeps the auto range
    assert ext.ranges(psi=[1.0, 0.0])[0] == pytest.approx(labelled_half_range(MARGIN * 1.0))
    zero = ChatteringExtent(1)
    zero.add(np.zeros((10, 1)))
    assert zero.ranges() == [None]


def test_blueprint_takes_the_chattering_range() -> None:
    bp = blueprint.blueprint(("a", "b"), chattering_range=[2e-4, None])
    cols = bp.root_container.contents[0].contents
    axis = cols[0].contents[0].properties["ScalarAxis"]
    (batch,) = [b for b in axis.as_component_batches() if "range" in str(b.component_descriptor()).lower()]
    assert batch.as_arrow_array().to_pylist() == [[-2e-4, 2e-4]]
    assert "ScalarAxis" not in cols[1].contents[0].properties  # None: auto range


def test_file_blueprint_has_the_record_chattering_range(tmp_path: Path) -> None:
    sc = scenario("eha-leak-major")
    sim = cs.simulate(sc, runs=1, seed=3)
    path = tmp_path / "d.rrd"
    recordings.record_detection(sim, path=path)
    reader = RrdReader(path)
    # the recorded chattering, and the y ranges of the last blueprint's views
    e = []
    for chunk in reader.stream().filter(content=blueprint.CHATTERING, is_static=False).to_chunks():
        e.extend(chunk.to_record_batch().column("Scalars:scalars").to_pylist())
    m = len(ChatteringMonitor(sc.nominal, MonitorSettings()).channels)
    e = np.asarray(e)[:, :m]
    ranges = []
    last = max(reader.blueprints(), key=lambda s: _time_panels_one(reader, s))
    for chunk in reader.stream(store=last).to_chunks():
        rb = chunk.to_record_batch()
        if "ScalarAxis:range" in rb.schema.names:
            ranges.extend(r[0] for r in rb.column("ScalarAxis:range").to_pylist() if r)
    halves = sorted(r[1] for r in ranges if r[0] == -r[1])  # the symmetric ones: the chattering views
    assert len(halves) == m
    # one batch (the record is shorter than 20 000 samples): MARGIN x the 99.9 % quantile of |e| over every
    # STRIDE-th sample (or psi)
    psi = np.zeros(m) if sc.psi is None else np.asarray(sc.psi, dtype=float)  # record_detection's psi
    want = MARGIN * np.fmax(np.quantile(np.abs(e[::STRIDE]), QUANTILE, axis=0), np.abs(psi))
    np.testing.assert_allclose(halves, np.sort([labelled_half_range(w) for w in want]), rtol=1e-6)


def test_labelled_half_range_holds_a_labelled_power_of_ten() -> None:
    # the viewer labels powers of ten only, and only lines far enough apart: +-p at 91 % of the half-height
    for a in (1e-4, 1.0, 1.1, 1.2, 2.0, 2.2, 2.3, 9.9, 0.00615, 7572.0):
        r = labelled_half_range(a)
        p = 10.0 ** np.round(np.log10(r / 1.1))
        assert r == pytest.approx(1.1 * p)
        assert a <= r * (1 + 1e-12) and r <= 10.0 * a * (1 + 1e-12), (a, r)  # the data fill >= a tenth
    assert labelled_half_range(0.00615) == pytest.approx(0.011)
    assert labelled_half_range(1.1) == pytest.approx(1.1)
    assert labelled_half_range(2.0) == pytest.approx(11.0)


def _time_panels_one(reader: RrdReader, store) -> int:
    return max(
        (
            max(c.to_record_batch().column("log_time").cast("int64").to_pylist(), default=-1)
            for c in reader.stream(store=store).to_chunks()
            if "log_time" in c.to_record_batch().schema.names
        ),
        default=-1,
    )


def test_two_bins_text() -> None:
    assert (
        two_bins_text(1.0, 41.2, 76.0, 24.4)
        == "most significant 1.0 Hz +41 dB, largest excess 76.0 Hz +24 dB"
    )
    assert two_bins_text(8.0, 55.0, 8.0, 55.0) == "8.0 Hz +55 dB (most significant = largest excess)"
    assert two_bins_text(8.0, 3.0, math.nan, math.nan) == "most significant 8.0 Hz +3 dB"
    assert db_over_threshold(100.0) == pytest.approx(20.0)


def test_interval_events_name_both_bins(tmp_path: Path) -> None:
    """Each interval event names, for the interval's frame of largest ``S / threshold``, the most
    significant bin and the bin of largest excess ``S - E`` among the bins over the threshold, each with
    its dB over the threshold: recomputed here from the spectra, threshold and expected spectrum stored
    in the file."""
    sc = scenario("so-timeline-constant")
    sim = cs.simulate(sc, runs=1, seed=3)
    path = tmp_path / "t.rrd"
    recordings.record_detection(sim, path=path)
    reader = RrdReader(path)

    def temporal(entity: str, column: str) -> tuple[np.ndarray, list]:
        t, v = [], []
        for chunk in reader.stream().filter(content=entity, is_static=False).to_chunks():
            rb = chunk.to_record_batch()
            t.extend(rb.column("time").cast("int64").to_pylist())
            v.extend(rb.column(column).to_pylist())
        order = np.argsort(t, kind="stable")
        return np.asarray(t)[order], [v[i] for i in order]

    def static(entity: str) -> np.ndarray:
        (chunk,) = reader.stream().filter(content=entity, is_static=True).to_chunks()
        return np.asarray(
            chunk.to_record_batch().column("Tensor:data").to_pylist()[0][0]["buffer"], dtype=float
        )

    t_ev, texts = temporal("/events", "TextLog:text")
    intervals = [(t, s[0]) for t, s in zip(t_ev, texts, strict=True) if "(estimate)" in s[0]]
    assert intervals
    mon = ChatteringMonitor(sc.nominal, MonitorSettings(), t0=float(sim.t[0]))  # record_detection's
    channels, freqs, tested = mon.channels, mon.freqs_hz, np.asarray(mon.threshold.tested)
    _, verdict = temporal(blueprint.VERDICT, "Scalars:scalars")
    flags = np.asarray(verdict)[:, : len(channels)] == 1.0
    for c, name in enumerate(channels):
        key = blueprint._entity(name)
        thr, exp = static(f"/threshold/{key}"), static(f"/expected/{key}")
        _, spectra = temporal(f"/spectrum/{key}", "Tensor:data")
        power = np.asarray([np.asarray(s[0]["buffer"], dtype=float) for s in spectra])
        ratio = np.where(tested[:, c] if tested.ndim == 2 else tested, power / thr, -np.inf)
        padded = np.concatenate(([False], flags[:, c], [False]))
        edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
        mine = [s for _, s in intervals if f" s {name} flagged" in s]
        assert len(mine) == len(edges) // 2
        for (a, b), text in zip(zip(edges[::2], edges[1::2], strict=True), mine, strict=True):
            k = a + int(np.argmax(ratio[a:b].max(axis=1)))
            sig = int(np.argmax(ratio[k]))
            exc = int(np.argmax(np.where(ratio[k] > 1.0, power[k] - exp, -np.inf)))
            db = db_over_threshold
            want = two_bins_text(freqs[sig], db(ratio[k, sig]), freqs[exc], db(ratio[k, exc]))
            assert re.match(rf"[\d.-]+ s {name} flagged frames \(estimate\), ", text), text
            assert text.endswith(f"(estimate), {want}"), (text, want)


@pytest.mark.parametrize("rows_below", [0, 1])
def test_event_log_holds_whole_rows(rows_below: int) -> None:
    # The lanes row (the event log beside the lanes) in the viewer's pixels at 1600x1000: the log's top,
    # whole table rows and its bottom margin, plus less than the ~6 px from a row's top to its text (a row
    # cut there shows no half text), and at least the height the lanes ask for.
    b = blueprint
    for n_lanes in range(1, 13):
        rows, _ = b.layout_geometry(3, n_lanes, rows_below=rows_below)
        real = rows[1] * b._REAL_PX / b._WINDOW[1]  # [columns, lanes, (row below)]
        table = real - b._LOG_TOP_PX - b._LOG_BOTTOM_PX
        assert 0.0 <= table % b._LOG_ROW_PX < 6.0, (n_lanes, table)
        assert rows[1] >= 45.0 + b._LANE_PX * n_lanes - 1e-9  # every lane visible
