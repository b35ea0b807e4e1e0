"""Nonlinear model files: f and its Jacobian named as Python functions, in every command."""

from __future__ import annotations

import math
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.errors import ModelFileError
from chatterspec.plants.modelfile import file_scenario, load_model

ROOT = Path(__file__).resolve().parents[1]
DUFFING = ROOT / "examples" / "duffing_model.toml"
WORN = ROOT / "examples" / "duffing_worn.toml"


def test_the_example_loads_as_its_equations_say() -> None:
    spec = load_model(DUFFING)
    m = spec.model
    assert not spec.is_linear and spec.psi is None
    # explicit Euler of m x'' + c x' + k x + k3 x^3 = F: the linearization at rest is the linear
    # oscillator, f0 = sqrt(k / m) / (2 pi), zeta = c / (2 sqrt(k m)) (k = 5685 N/m, c = 15.08 N s/m)
    assert m.natural_frequency_hz == pytest.approx(math.sqrt(5685.0) / (2 * math.pi), rel=1e-9)
    assert m.damping_ratio == pytest.approx(15.08 / (2 * math.sqrt(5685.0)), rel=1e-9)
    # one step by hand: x+ = x + dt g(x, u)
    x, u = np.array([[1e-3, 0.02]]), np.array([2.0])
    acc = (2.0 - 15.08 * 0.02 - 5685.0 * 1e-3 - 5e8 * 1e-9) / 1.0
    np.testing.assert_allclose(m.transition(x, u), [[1e-3 + 1e-3 * 0.02, 0.02 + 1e-3 * acc]], rtol=1e-15)
    # the file gives dg/du = [0, 1/m]; the Euler step's df/du is dt times it, as central differences say
    B = m.input_matrix(x[0], u)
    np.testing.assert_array_equal(B, [[0.0], [1e-3 / 1.0]])
    np.testing.assert_allclose(m.replace(input_jacobian=None).input_matrix(x[0], u), B, rtol=1e-6, atol=1e-12)
    sc = file_scenario(spec)
    assert sc.duration == 4.0 and sc.input.describe() == "sine 3 Hz, amplitude 10"


def test_catalogue_nonlinear_model_exports_and_reads_back_the_same_numbers(tmp_path: Path, capsys) -> None:
    path = tmp_path / "eha4.toml"
    assert main(["scenarios", "eha4-healthy", "--model-toml", str(path)]) == 0
    spec = load_model(path)
    assert 'f = "chatterspec.plants.eha4:eha4_step"' in path.read_text()
    catalogue = cs.scenario("eha4-healthy")
    ours = file_scenario(spec)
    a, b = cs.simulate(catalogue, 2, seed=5), cs.simulate(ours, 2, seed=5)
    assert np.array_equal(a.z, b.z)  # same transition, input, noise and duration
    assert np.array_equal(cs.chattering(catalogue.nominal, a.z, a.u), cs.chattering(spec.model, a.z, a.u))
    assert load_model(path).model.fingerprint() == spec.model.fingerprint()  # stable across loads


def _write(tmp_path: Path, dynamics: str, extra: str = "") -> Path:
    shutil.copy(ROOT / "examples" / "duffing.py", tmp_path / "duffing.py")
    text = DUFFING.read_text()
    start, stop = text.index("[dynamics]"), text.index("[matrices]")
    path = tmp_path / "m.toml"
    path.write_text(text[:start] + dynamics + "\n" + extra + "\n" + text[stop:])
    return path


PARAMS = "[dynamics.parameters]\nmass = 1.0\nstiffness = 5685.0\ncubic = 5.0e8\ndamping = 15.08\n"


@pytest.mark.parametrize(
    ("dynamics", "message"),
    [
        ('[dynamics]\nf = "duffing.py:g"\n' + PARAMS, "[dynamics] jacobian"),
        ('[dynamics]\nf = "nofile.py:g"\njacobian = "duffing.py:g_jacobian"\n' + PARAMS, "cannot read"),
        ('[dynamics]\nf = "duffing.py:h"\njacobian = "duffing.py:g_jacobian"\n' + PARAMS, "no function 'h'"),
        ('[dynamics]\nf = "duffing:g"\njacobian = "duffing.py:g_jacobian"\n' + PARAMS, "importing it failed"),
        ('[dynamics]\nf = "g"\njacobian = "duffing.py:g_jacobian"\n' + PARAMS, "'file.py:function'"),
        (
            '[dynamics]\nf = "duffing.py:g"\njacobian = "duffing.py:g_jacobian"\n'
            + PARAMS
            + "lenght = 2.0\n",
            "['lenght'] are not arguments of f",
        ),
        ('[dynamics]\nf = "duffing.py:g"\njacobian = "duffing.py:g_jacobian"\n', "calling f"),
        (
            '[dynamics]\nform = "implicit"\nf = "duffing.py:g"\njacobian = "duffing.py:g"\n' + PARAMS,
            "form must",
        ),
    ],
)
def test_errors_name_the_file_and_the_field(dynamics: str, message: str, tmp_path: Path) -> None:
    path = _write(tmp_path, dynamics)
    with pytest.raises(ModelFileError) as exc:
        load_model(path)
    assert f"model file {str(path)!r}" in str(exc.value) and message in str(exc.value)


def test_a_file_model_pickles_with_its_source(tmp_path: Path) -> None:
    """A worker process (spawned, or a Dask worker elsewhere) runs the same code without the file."""
    dynamics = '[dynamics]\nform = "continuous"\nf = "duffing.py:g"\njacobian = "duffing.py:g_jacobian"\n'
    path = _write(tmp_path, dynamics + PARAMS)
    model = load_model(path).model
    blob = pickle.dumps(model)
    (tmp_path / "duffing.py").unlink()
    code = (
        "import pickle, sys, numpy as np\n"
        "m = pickle.loads(sys.stdin.buffer.read())\n"
        "print(repr(m.transition(np.array([[1e-3, 0.02]]), np.array([2.0])).tolist()))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], input=blob, capture_output=True, check=True, cwd=tmp_path
    )
    here = model.transition(np.array([[1e-3, 0.02]]), np.array([2.0])).tolist()
    assert out.stdout.decode().strip() == repr(here)


def test_calibrate_detect_simulate_and_monitor_take_the_model_file(
    tmp_path: Path, capsys, monkeypatch
) -> None:
    cal = tmp_path / "duffing.npz"
    # alpha 0.05 per frame: 60 runs support it for detect (>= 19) and per frame (>= 5)
    argv = ["calibrate", str(DUFFING), "--runs", "60", "--alpha", "0.05", "--no-progress", "--out", str(cal)]
    assert main(argv) == 0
    assert "normalization: empirical" in capsys.readouterr().out
    assert main(["detect", str(DUFFING), "--calibration", str(cal), "--json"]) == 0
    assert json_doc(capsys)["threshold"]["kind"] == "empirical"
    assert main(["detect", str(DUFFING)]) == 2  # a nonlinear model has no analytic threshold
    assert "calibrat" in capsys.readouterr().err
    worn = tmp_path / "worn.csv"
    assert main(["simulate", str(WORN), "--rate", "0", "--duration", "8", "--seed", "1"]) == 0
    worn.write_text(capsys.readouterr().out)
    assert main(["monitor", str(DUFFING), "--data", str(worn)]) == 2
    err = capsys.readouterr().err
    assert "is a nonlinear model" in err and "chatterspec calibrate" in err and "--calibration" in err
    assert main(["monitor", str(DUFFING), "--data", str(worn), "--calibration", str(cal)]) == 0
    out = capsys.readouterr().out
    # the 20 % weaker spring shows at the 3 Hz drive from the first frame on (a 75x ratio in the
    # example's 60 s run): far beyond the threshold, so one short record suffices
    # the alarm at the end of the first frame (1.00 s), the onset estimated at the record's start
    assert "fault start on" in out
    assert "at t = 1.00 s (end of the deciding frame), onset estimated 0.00 s" in out


def json_doc(capsys) -> dict:
    import json

    return json.loads(capsys.readouterr().out)


def _user_module(tmp_path: Path, tail: str) -> Path:
    """A model file whose f is the Duffing g changed by ``tail`` (Python appended to duffing.py)."""
    source = (ROOT / "examples" / "duffing.py").read_text() + "\n_g = g\n" + tail
    (tmp_path / "user.py").write_text(source)
    dynamics = '[dynamics]\nform = "continuous"\nf = "user.py:g"\njacobian = "user.py:g_jacobian"\n'
    return _write(tmp_path, dynamics + PARAMS)


def test_a_user_f_of_the_wrong_shape_is_refused_at_load(tmp_path: Path) -> None:
    # (..., 1) for (..., 2) broadcast silently into x + dt g: 4001 wrong rows were written
    path = _user_module(tmp_path, "def g(x, u, **kw):\n    return _g(x, u, **kw)[..., :1]\n")
    with pytest.raises(
        ModelFileError, match=r"f = 'user.py:g' returned shape \(2, 1\) for x of shape \(2, 2\)"
    ):
        load_model(path)


def test_a_user_f_that_raises_mid_run_is_one_line(tmp_path: Path, capsys) -> None:
    tail = (
        "calls = [0]\n\ndef g(x, u, **kw):\n    calls[0] += 1\n    if calls[0] > 50:\n"
        "        raise ValueError('sensor model exploded')\n    return _g(x, u, **kw)\n"
    )
    path = _user_module(tmp_path, tail)
    assert main(["simulate", str(path), "--rate", "0", "--duration", "1"]) == 2
    out, err = capsys.readouterr()
    assert out.startswith("time,position,velocity,force\n")  # the rows before the failure were written
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "[dynamics] f = 'user.py:g' raised ValueError: sensor model exploded" in err
