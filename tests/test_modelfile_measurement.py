"""A nonlinear model file with a nonlinear measurement: ``[dynamics] h`` and ``h_jacobian``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.errors import ModelFileError
from chatterspec.plants.modelfile import load_model

ROOT = Path(__file__).resolve().parents[1]
DUFFING = ROOT / "examples" / "duffing.py"

SENSOR = '''
import numpy as np

def h(x, **_):
    """A position sensor that saturates smoothly (m), and the velocity."""
    return np.stack([0.01 * np.tanh(100.0 * x[..., 0]), x[..., 1]], axis=-1)

def h_jacobian(x, **_):
    H = np.zeros((*x.shape[:-1], 2, 2))
    H[..., 0, 0] = 1.0 / np.cosh(100.0 * x[..., 0]) ** 2
    H[..., 1, 1] = 1.0
    return H
'''


def _model_file(tmp_path: Path, measurement: str = 'h = "sensor.py:h"\nh_jacobian = "sensor.py:h_jacobian"',
                matrices: str = "") -> Path:  # fmt: skip
    (tmp_path / "sensor.py").write_text(SENSOR)
    text = (ROOT / "examples" / "duffing_model.toml").read_text()
    text = text.replace('"duffing.py:', f'"{DUFFING}:')
    text = text.replace("oscillatory_states = [0, 1]", f"oscillatory_states = [0, 1]\n{measurement}")
    text = text.replace("C = [[1, 0], [0, 1]]", matrices)
    path = tmp_path / "sensed.toml"
    path.write_text(text)
    return path


def test_model_file_declares_h_and_the_simulation_measures_through_it(tmp_path: Path) -> None:
    spec = load_model(_model_file(tmp_path))
    model = spec.model
    assert model.h is not None and model.h_jac is not None
    sim = cs.simulate(_model_file(tmp_path), runs=2, seed=3)
    x, z = np.asarray(sim.x), np.asarray(sim.z)
    # measurement noise: position 1e-5 m standard deviation (R_diag 1e-10); 6 sigma bounds the residual
    assert np.max(np.abs(z[..., 0] - 0.01 * np.tanh(100.0 * x[..., 0]))) < 6e-5 * 1.5
    # the EKF runs on the file's h(x): its position estimate follows the state far inside the sensor range
    ekf = cs.ExtendedKalmanFilter(model)
    out = ekf.run(z[:, 1:], np.asarray(sim.u)[:-1], x0=np.zeros(2), P0=np.eye(2) * 1e-6)
    err = out.x_post[:, 200:, 0] - x[:, 2:, 0][:, 199:]
    assert np.sqrt(np.mean(err**2)) < 1e-4


def test_h_and_c_together_or_h_alone_are_refused(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="either \\[matrices\\] C"):
        load_model(_model_file(tmp_path, matrices="C = [[1, 0], [0, 1]]"))
    with pytest.raises(ModelFileError, match="h and h_jacobian go together"):
        load_model(_model_file(tmp_path, measurement='h = "sensor.py:h"'))


def test_cli_simulates_it_and_the_chattering_monitor_refuses_it(tmp_path: Path, capsys) -> None:  # type: ignore[no-untyped-def]
    path = _model_file(tmp_path)
    assert main(["simulate", str(path), "--duration", "0.2", "--rate", "0"]) == 0
    rows = capsys.readouterr().out.strip().splitlines()
    assert rows[0].startswith("time,position,velocity") and len(rows) > 150
    data = tmp_path / "data.csv"
    data.write_text("\n".join(rows) + "\n")
    code = main(["monitor", str(path), "--data", str(data)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and "linear measurement" in err, err
