"""Model (TOML) and data (CSV / NPZ) files for ``chatterspec monitor``."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from chatterspec.errors import DataFileError, ModelFileError, ParameterError, UnstableModelWarning
from chatterspec.plants.datafile import load_data
from chatterspec.plants.modelfile import load_model
from chatterspec.plants.models import eha_linear

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

GOOD = """
name = "so"
dt = 0.001
[channels]
outputs = ["x", "v"]
inputs = ["u"]
[matrices]
A = [[1.0, 0.001], [-3.9478, 0.98743]]
B = [[0.0], [0.1]]
C = [[1.0, 0.0], [0.0, 1.0]]
Q_diag = [1e-8, 1e-6]
R = [[1e-8, 0.0], [0.0, 1e-6]]
[svsf]
psi = [1e-3, 1e-2]
"""


def _write(tmp_path: Path, text: str, name: str = "m.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_example_model_and_data_load() -> None:
    spec = load_model(EXAMPLES / "eha_model.toml")
    ref = eha_linear()
    np.testing.assert_allclose(spec.model.A, ref.A, rtol=1e-15)
    assert spec.model.output_names == ("position", "velocity", "pressure")
    assert spec.model.output_units == ("m", "m/s", "Pa")
    assert spec.psi.shape == (3,) and spec.gamma == 0.1
    assert spec.detector["alpha"] == 0.001
    data = load_data(EXAMPLES / "eha_data.csv", spec.model)
    assert data.z.shape == (8001, 3) and data.u.shape == (8001, 1)
    assert data.time_column == "time"
    # what load_model returns stands for its model (it raised a bare AttributeError)
    assert np.array_equal(load_data(EXAMPLES / "eha_data.csv", spec).z, data.z)
    with pytest.raises(ParameterError, match="load_data needs the model the data belong to"):
        load_data(EXAMPLES / "eha_data.csv", str(EXAMPLES / "eha_model.toml"))
    assert (EXAMPLES / "eha_data.csv").stat().st_size < 500_000


def test_good_model_and_continuous_form(tmp_path: Path) -> None:
    spec = load_model(_write(tmp_path, GOOD))
    assert spec.model.n_states == 2 and spec.model.input_names == ("u",)
    cont = GOOD.replace(
        "A = [[1.0, 0.001], [-3.9478, 0.98743]]", 'form = "continuous"\nA = [[0.0, 1.0], [-3947.8, -12.57]]'
    )
    cont = cont.replace("B = [[0.0], [0.1]]", "B = [[0.0], [100.0]]")
    spec2 = load_model(_write(tmp_path, cont, "c.toml"))
    np.testing.assert_allclose(spec2.model.A, [[1.0, 0.001], [-3.9478, 0.98743]], rtol=1e-12)
    np.testing.assert_allclose(spec2.model.B, [[0.0], [0.1]])


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (
            lambda s: s.replace("A = [[1.0, 0.001], [-3.9478, 0.98743]]\n", ""),
            "[matrices] matrix A is missing",
        ),
        (
            lambda s: s.replace("B = [[0.0], [0.1]]", "B = [[0.0], [0.1], [0.2]]"),
            "[matrices] B must have shape (2, 1)",
        ),
        (
            lambda s: s.replace("C = [[1.0, 0.0], [0.0, 1.0]]", "C = [[1.0, 0.0, 0.0]]"),
            "[matrices] C must have shape (2, 2)",
        ),
        (lambda s: s.replace("Q_diag = [1e-8, 1e-6]", "Q_diag = [nan, 1e-6]"), "Q_diag contains NaN"),
        (lambda s: s.replace("[[1.0, 0.001]", "[[inf, 0.001]"), "[matrices] A contains NaN or infinite"),
        (
            lambda s: s.replace("psi = [1e-3, 1e-2]", "psi = [1e-3]"),
            "[svsf] psi must have one entry per output",
        ),
        (lambda s: s.replace("dt = 0.001", "dt = -1.0"), "'dt' must be > 0"),
        (lambda s: s.replace("[channels]", "[chanels]"), "table [channels] is missing"),
        (
            lambda s: s.replace("R = [[1e-8, 0.0], [0.0, 1e-6]]", "R = [[1e-8, 1.0], [0.0, 1e-6]]"),
            "R must be symmetric",
        ),
        (lambda s: s + "\n[detector]\nalfa = 0.1\n", "unknown key(s) ['alfa']"),
        (lambda s: s.replace('name = "so"', "name = "), "not valid TOML"),
    ],
)
def test_malformed_model_files_name_file_and_field(tmp_path: Path, edit, message: str) -> None:
    path = _write(tmp_path, edit(GOOD))
    with pytest.raises(ModelFileError) as exc:
        load_model(path)
    assert message in str(exc.value)
    assert str(path) in str(exc.value)


def test_unstable_model_warns(tmp_path: Path) -> None:
    path = _write(tmp_path, GOOD.replace("[-3.9478, 0.98743]", "[-3.9478, 1.2]"))
    with pytest.warns(UnstableModelWarning, match="unstable"):
        load_model(path)


def test_missing_model_file(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="no such file"):
        load_model(tmp_path / "nope.toml")


@pytest.fixture
def model(tmp_path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_model(_write(tmp_path, GOOD)).model


def _csv(tmp_path: Path, rows: list[str], header: str = "time,x,v,u") -> Path:
    p = tmp_path / "d.csv"
    p.write_text(header + "\n" + "\n".join(rows) + "\n")
    return p


def _rows(n: int = 5) -> list[str]:
    return [f"{k * 0.001:.3f},{k * 0.1},{k * 0.2},1.0" for k in range(n)]


def test_csv_columns_by_name_in_any_order(tmp_path: Path, model) -> None:
    rows = [f"1.0,{k * 0.2},{k * 0.001:.3f},{k * 0.1}" for k in range(5)]
    data = load_data(_csv(tmp_path, rows, header="u,v,time,x"), model)
    np.testing.assert_allclose(data.z[:, 0], np.arange(5) * 0.1)
    np.testing.assert_allclose(data.z[:, 1], np.arange(5) * 0.2)
    np.testing.assert_allclose(data.t, np.arange(5) * 0.001)


def test_missing_column(tmp_path: Path, model) -> None:
    path = _csv(tmp_path, [r.rsplit(",", 1)[0] for r in _rows()], header="time,x,v")
    with pytest.raises(DataFileError, match=r"missing column\(s\) \['u'\]") as exc:
        load_data(path, model)
    assert str(path) in str(exc.value)


def test_nan_sample_stops_with_row_and_time(tmp_path: Path, model) -> None:
    rows = _rows()
    rows[3] = "0.003,nan,0.6,1.0"
    with pytest.raises(
        DataFileError, match=r"column 'x' has 1 NaN/inf sample\(s\), first at line 5 \(t = 0.003 s\)"
    ):
        load_data(_csv(tmp_path, rows), model)
    rows[3] = "0.003,,0.6,1.0"  # empty cell = missing value
    with pytest.raises(DataFileError, match="column 'x'"):
        load_data(_csv(tmp_path, rows), model)


def test_non_monotonic_and_irregular_timestamps(tmp_path: Path, model) -> None:
    rows = _rows()
    rows[2], rows[3] = rows[3], rows[2]
    path = _csv(tmp_path, rows)
    with pytest.raises(DataFileError, match="column 'time' is not strictly increasing: line 5") as exc:
        load_data(path, model)
    assert str(path) in str(exc.value)
    rows = _rows()
    rows[4] = "0.010,0.4,0.8,1.0"
    with pytest.raises(DataFileError, match="not sampled at the model's dt"):
        load_data(_csv(tmp_path, rows), model)


def test_bad_cell_and_ragged_row(tmp_path: Path, model) -> None:
    rows = _rows()
    rows[1] = "0.001,abc,0.2,1.0"
    with pytest.raises(DataFileError, match=r"column 'x', line 3: 'abc' is not a number"):
        load_data(_csv(tmp_path, rows), model)
    rows[1] = "0.001,0.1,0.2"
    with pytest.raises(DataFileError, match="line 3 has 3 fields"):
        load_data(_csv(tmp_path, rows), model)


def test_every_csv_message_uses_file_line_numbers(tmp_path: Path, model) -> None:
    """One convention: the line of the file (header and comment lines counted), as an editor shows it."""
    p = tmp_path / "c.csv"
    good = _rows()

    def write(rows: list[str]) -> Path:
        p.write_text("# a comment\ntime,x,v,u\n" + "\n".join(rows) + "\n")  # data row k on line k + 3
        return p

    cases = [
        (2, "0.002,abc,0.4,1.0", r"column 'x', line 5: 'abc' is not a number"),
        (2, "0.002,0.2", "line 5 has 2 fields"),
        (2, "0.002,inf,0.4,1.0", r"first at line 5 \(t = 0.002 s\)"),
        (2, "0.0005,0.2,0.4,1.0", "not strictly increasing: line 5"),
        (2, "0.0025,0.2,0.4,1.0", "between line 4 and line 5"),
    ]
    for k, row, message in cases:
        rows = list(good)
        rows[k] = row
        with pytest.raises(DataFileError, match=message):
            load_data(write(rows), model)


def test_npz_of_garbage_does_not_mention_pickle(tmp_path: Path, model) -> None:
    p = tmp_path / "g.npz"
    p.write_bytes(np.random.default_rng(0).bytes(300))
    with pytest.raises(DataFileError, match=r"not a \.npz archive") as exc:
        load_data(p, model)
    assert "pickle" not in str(exc.value)
    p.write_bytes(b"PK\x03\x04" + b"\x00" * 60)  # a zip header, then nothing readable
    with pytest.raises(DataFileError, match=r"not a readable \.npz archive") as exc:
        load_data(p, model)
    assert "allow_pickle" not in str(exc.value)


def test_wrong_shaped_A_is_reported_as_A(tmp_path: Path) -> None:
    a3 = "A = [[1, 0.001, 0], [-3.9, 0.98, 0], [0, 0, 1]]"  # square, but 3 states where B and C have 2
    bad = GOOD.replace("A = [[1.0, 0.001], [-3.9478, 0.98743]]", a3)
    assert bad != GOOD
    path = _write(tmp_path, bad)
    with pytest.raises(ModelFileError) as exc:
        load_model(path)
    assert "A must" in str(exc.value) and "B must" not in str(exc.value), str(exc.value)


@pytest.mark.parametrize(
    "detector, field",
    [
        ("window_s = 1.0\nhop_s = 2.0", "hop_s"),
        ('window = "hammingx"', "window"),
        ("window_s = 0.001\nhop_s = 0.001", "window_s"),
    ],
)
def test_detector_stft_errors_name_the_file_and_field(tmp_path: Path, detector: str, field: str) -> None:
    path = _write(tmp_path, GOOD + "\n[detector]\n" + detector + "\n")
    with pytest.raises(ModelFileError) as exc:
        load_model(path)
    msg = str(exc.value)
    assert str(path) in msg and f"[detector] {field}" in msg, msg


def test_npz_and_generated_time(tmp_path: Path, model) -> None:
    p = tmp_path / "d.npz"
    np.savez(p, x=np.arange(6.0), v=np.ones(6), u=np.zeros(6))
    data = load_data(p, model)
    assert data.time_column is None
    np.testing.assert_allclose(data.t, np.arange(6) * 0.001)
    np.savez(p, x=np.arange(6.0), v=np.ones(6))
    with pytest.raises(DataFileError, match="missing column"):
        load_data(p, model)
    np.savez(p, x=np.arange(6.0), v=np.ones(5), u=np.zeros(6))
    with pytest.raises(DataFileError, match="different lengths"):
        load_data(p, model)
