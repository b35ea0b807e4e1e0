"""CLI check-through: closed output pipes and unstable power-sweep fault sizes."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from chatterspec.cli import main as cli_main
from chatterspec.errors import ParameterError
from chatterspec.studies.detection_rates import POWER_FAMILIES, power_scenario

ROOT = Path(__file__).resolve().parents[1]


class _ClosedPipe:
    """A stdout whose reader went away: every write raises BrokenPipeError."""

    def write(self, text: str) -> int:
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self) -> None:
        raise BrokenPipeError(32, "Broken pipe")


@pytest.mark.parametrize("argv", [["scenarios"], ["detect", "so-f11-high", "--json"]])
def test_closed_stdout_is_not_an_error(argv: list[str], monkeypatch, capsys) -> None:
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    assert cli_main(argv) == 0
    assert capsys.readouterr().err == ""


def test_piped_into_a_closed_reader_exits_quietly() -> None:
    """`chatterspec scenarios | head -0`: the read end is closed before the first write."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    for argv in (["scenarios"], ["--help"]):
        proc = subprocess.Popen(
            [sys.executable, "-m", "chatterspec", *argv],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            env=env,
        )
        proc.stdout.close()  # type: ignore[union-attr]
        err = proc.stderr.read().decode()  # type: ignore[union-attr]
        assert proc.wait(timeout=60) == 0, err
        assert "Traceback" not in err and "BrokenPipe" not in err and "Broken pipe" not in err, err


def test_unstable_power_sizes_are_rejected_with_the_stable_range() -> None:
    # Euler-discretized 2nd order (zeta 0.1, dt 1 ms): |eig|^2 = 1 - 2 zeta w dt + (w dt)^2 < 1 iff
    # w < 2 zeta / dt, i.e. f0 < 0.2 / (2 pi 1e-3) = 31.83 Hz: an independent oracle for the bound
    f_max = 2 * 0.1 / 1e-3 / (2 * math.pi)
    assert power_scenario("f0", 0.99 * f_max).plant is not None
    with pytest.raises(ParameterError) as exc:
        power_scenario("f0", 1.01 * f_max)
    assert f"size < {f_max:.3g}" in str(exc.value), str(exc.value)
    with pytest.raises(ParameterError, match=r"leakage size 0.5 .*unstable.*stable range is 0 < size < "):
        power_scenario("leakage", 0.5)
    # every default grid point is stable
    for family, spec in POWER_FAMILIES.items():
        for size in spec["sizes"]:
            A = power_scenario(family, size).plant.A
            assert np.abs(np.linalg.eigvals(A)).max() <= 1 + 1e-9


def test_cli_power_unstable_size_fails_before_any_simulation(capsys, monkeypatch) -> None:
    """An unstable size is rejected while the grid is built: no realization is simulated or filtered
    (it used to run the whole Monte Carlo study, ~20 s, before an internal NaN message)."""
    import chatterspec.montecarlo as montecarlo
    import chatterspec.studies.detection_rates as power

    def never(*args, **kwargs):
        pytest.fail("the Monte Carlo study or a simulation ran for an unstable fault size")

    monkeypatch.setattr(montecarlo.Execution, "run", never)
    monkeypatch.setattr(power, "iter_chattering", never)
    assert cli_main(["power", "leakage", "--sizes", "0.5", "--runs", "8"]) == 2
    err = capsys.readouterr().err
    assert "unstable" in err and "stable range" in err and "NaN" not in err, err


@pytest.mark.parametrize(
    "argv",
    [
        ["spectrum", "eha-healthy", "--plot", "/proc/nope/x.png"],
        ["figures", "--figures-dir", "/proc/figs"],
        ["detect", "eha-healthy", "--record", "/proc/x.rrd"],
        ["demo", "--recordings-dir", "/proc/rec"],
    ],
)
def test_bad_output_path_fails_before_the_heavy_imports(argv: list[str]) -> None:
    """A bad path fails at once; measured 0.1-0.25 s per command (was 1.1-2.4 s, imports first)."""
    code = (
        "import sys\nfrom chatterspec.cli import main\n"
        f"rc = main({argv!r})\n"
        "heavy = [m for m in ('matplotlib', 'scipy', 'chatterspec.plants.scenarios') if m in sys.modules]\n"
        "print(rc, heavy)\n"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=60,
    )
    assert proc.stdout.strip() == "2 []", (proc.stdout, proc.stderr)
    assert "cannot be written" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
