"""A stream sampled at another rate than the model's dt is an error from its first rows, not 4000 gaps."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main
from chatterspec.errors import DataFileError
from chatterspec.online.monitor import MonitorSettings
from chatterspec.online.stream import CsvRows, LatencyStats
from chatterspec.plants.modelfile import load_model
from chatterspec.viewer.live_stream import StreamMonitor, drive

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_MODEL = ROOT / "examples" / "eha_model.toml"
EXAMPLE_DATA = ROOT / "examples" / "eha_data.csv"


def _resampled(step_s: float) -> str:
    """The example data (1 ms) with its time column rewritten to ``step_s`` per row."""
    lines = [s for s in EXAMPLE_DATA.read_text().splitlines() if not s.startswith("#")]
    out = [lines[0]]
    for i, row in enumerate(lines[1:]):
        fields = row.split(",")
        fields[0] = f"{i * step_s:.6f}"
        out.append(",".join(fields))
    return "\n".join(out) + "\n"


def _drive(text: str, chunk_bytes: int) -> StreamMonitor:
    spec = load_model(EXAMPLE_MODEL)
    mon = StreamMonitor(spec.model, MonitorSettings(psi=tuple(spec.psi.tolist())))
    data = text.encode()
    chunks = ((data[i : i + chunk_bytes], 0.0) for i in range(0, len(data), chunk_bytes))
    try:
        drive(chunks, CsvRows(spec.model), mon)
    finally:
        mon.close()
    return mon


@pytest.mark.parametrize("chunk_bytes", [40, 1 << 16])  # rows arriving one by one, or in one block
@pytest.mark.parametrize(("step", "rate"), [(0.002, "500 Hz"), (0.0005, "2000 Hz")])
def test_stream_at_another_rate_stops_at_its_first_rows(step: float, rate: str, chunk_bytes: int) -> None:
    with pytest.raises(
        DataFileError, match=rf"sampled every .* \({rate}\), but the model's dt is 1 ms"
    ) as exc:
        _drive(_resampled(step), chunk_bytes)
    assert "lines 2-6" in str(exc.value)


def test_stream_at_the_model_rate_is_monitored_whole() -> None:
    mon = _drive(_resampled(0.001), 40)
    assert mon.n_rows == 8001 and mon.counts["gap"] == 0 and mon.counts["fault-start"] >= 1


def test_a_short_stream_is_checked_at_end_of_input() -> None:
    three_rows = "".join(_resampled(0.002).splitlines(keepends=True)[:4])
    with pytest.raises(DataFileError, match="sampled every 2 ms"):
        _drive(three_rows, 1 << 16)


def test_cli_stream_and_file_at_another_rate_exit_2(tmp_path: Path, capsys, monkeypatch) -> None:
    text = _resampled(0.002)
    path = tmp_path / "two_ms.csv"
    path.write_text(text)
    with path.open() as fh:
        monkeypatch.setattr(sys, "stdin", fh)
        rc = main(["monitor", str(EXAMPLE_MODEL), "--data", "-"])
    err = capsys.readouterr().err
    assert rc == 2 and "sampled every 2 ms (500 Hz)" in err and "gap" not in err.replace("a gap", "")
    assert main(["monitor", str(EXAMPLE_MODEL), "--data", str(path)]) == 2
    assert "the data is sampled every 2 ms (500 Hz), but the model's dt is 1 ms" in capsys.readouterr().err


def test_latency_median_never_exceeds_the_max() -> None:
    # one observation: the median is that value (a histogram bin centre may lie above it)
    for seconds in np.geomspace(1.1e-6, 0.9, 40).tolist():
        st = LatencyStats()
        st.add(seconds)
        assert st.median() <= st.max_s == seconds
        st.add(seconds * 1.0001, 2)
        assert seconds <= st.median() <= st.max_s
