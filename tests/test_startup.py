"""Light commands do not import the heavy modules; the replacements for them give scipy's exact numbers.

Structural checks (which modules a fresh interpreter loaded), never a stopwatch: the start-up times
are measured by ``benchmarks/bench_cli.py``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
import scipy.signal
import scipy.stats

import chatterspec

ROOT = Path(__file__).resolve().parents[1]
#: The checkout whose chatterspec this test process imported (the probes import the same one).
SOURCE = Path(chatterspec.__file__).resolve().parents[1]
HEAVY = ("scipy.signal", "scipy.stats", "scipy.linalg", "numba", "rerun", "matplotlib")


def _loaded_after(code: str, modules: tuple[str, ...] = HEAVY) -> dict[str, bool]:
    """Which of ``modules`` a fresh interpreter has imported after running ``code``."""
    probe = f"import sys, json\n{code}\nprint(json.dumps({{m: m in sys.modules for m in {modules!r}}}))"
    env = {**os.environ, "PYTHONPATH": str(SOURCE)}
    cmd = [sys.executable, "-c", probe]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=tempfile.gettempdir(), env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _cli(argv: list[str]) -> str:
    return (
        "import contextlib, io\nfrom chatterspec.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
        f"    try:\n        main({argv!r})\n    except SystemExit:\n        pass"
    )


@pytest.mark.parametrize(
    "argv",
    [
        ["scenarios"],
        ["scenarios", "eha4-leak-onset"],
        ["detect", "no-such-scenario"],
        ["simulate", "eha-healthy", "--rate", "-1"],
        ["monitor", "no-such.toml", "--data", "x.csv"],
        ["calibrate", "no-such-scenario"],
    ],
)
def test_listing_and_argument_errors_import_no_heavy_module(argv: list[str]) -> None:
    loaded = _loaded_after(_cli(argv))
    assert not any(loaded.values()), {m: v for m, v in loaded.items() if v}


def test_help_imports_no_numpy() -> None:
    """``chatterspec --help`` and every ``chatterspec COMMAND --help`` build the parser only: no numpy.

    One interpreter runs them all in turn and names the first whose help loaded numpy (or anything
    heavier), so a failure says which command's parser imports too much.
    """
    from chatterspec.cli import COMMANDS

    calls = [["--help"], *([name, "--help"] for name in COMMANDS)]
    code = (
        "import contextlib, io\nfrom chatterspec.cli import main\nfirst = None\n"
        f"for argv in {calls!r}:\n"
        "    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):\n"
        "        try:\n            main(argv)\n        except SystemExit:\n            pass\n"
        f"    if first is None and any(m in sys.modules for m in ('numpy', *{HEAVY!r})):\n"
        "        first = argv\n"
        "print(first)"
    )
    probe = f"import sys\n{code}"
    env = {**os.environ, "PYTHONPATH": str(SOURCE)}
    out = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        cwd=tempfile.gettempdir(),
        env=env,
        check=True,
    )
    assert out.stdout.strip().splitlines()[-1] == "None", f"numpy loaded by chatterspec {out.stdout.strip()}"


def test_the_monitor_replay_needs_neither_scipy_signal_nor_scipy_stats_nor_rerun() -> None:
    """A replay without ``--record`` / ``--live`` opens no recording: Rerun is not imported either, from
    a data file nor from a stream (``--data -``, rows on standard input, then in the same interpreter);
    nor the batch detection pipeline (the monitor runs on data; the simulation it imports here only
    calibrates the alarm rule, cached on disk after the first run)."""
    model = ROOT / "examples" / "eha_model.toml"
    data = ROOT / "examples" / "eha_data.csv"
    code = _cli(["monitor", str(model), "--data", str(data)])
    code += f"\nsys.stdin = open({str(data)!r})\n" + _cli(
        ["monitor", str(model), "--data", "-", "--rule", "frame"]
    ).replace("from chatterspec.cli import main\n", "")
    loaded = _loaded_after(code, (*HEAVY, "chatterspec.detection.pipeline"))
    assert not loaded["scipy.signal"] and not loaded["scipy.stats"]
    assert not loaded["rerun"]
    assert not loaded["chatterspec.detection.pipeline"]


@pytest.mark.parametrize("name", ["hamming", "hann"])
def test_native_tapers_equal_scipy_bit_for_bit(name: str) -> None:
    from chatterspec._stft import get_window

    for n in [*range(1, 130), 250, 999, 1000, 1001, 2000, 4096, 10_000]:
        np.testing.assert_array_equal(get_window(name, n), scipy.signal.get_window(name, n), err_msg=str(n))
    # any other window still comes from scipy
    np.testing.assert_array_equal(get_window("blackman", 64), scipy.signal.get_window("blackman", 64))


def test_chi2_quantiles_equal_scipy_stats_bit_for_bit() -> None:
    from chatterspec.detection.thresholds import _chi2_isf

    p = np.geomspace(1e-14, 0.5, 60)[:, None]
    dof = np.array([1.0, 2.0, 2.7, 10.0, 512.0])[None, :]
    np.testing.assert_array_equal(_chi2_isf(p, dof), scipy.stats.chi2.isf(p, dof))
