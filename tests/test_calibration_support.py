"""A calibration whose run count cannot support its alpha is refused, with the minimum stated."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from chatterspec.cli import main
from chatterspec.studies.calibration.thresholds import calibrate
from chatterspec.studies.intervals import quantile_ci_ranks

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE_MODEL = ROOT / "examples" / "eha_model.toml"
EXAMPLE_DATA = ROOT / "examples" / "eha_data.csv"


def _expected_exceedance(n: int, alpha: float) -> float:
    """P(a new exchangeable value exceeds the order statistic of rank ceil(n (1 - alpha)) of n)."""
    r = min(max(math.ceil(n * (1 - alpha)), 1), n)
    return (n + 1 - r) / (n + 1)


@pytest.mark.parametrize("alpha", [0.1, 0.02, 0.01, 1e-3])
def test_minimum_runs_is_where_the_threshold_stops_being_the_sample_maximum(alpha: float) -> None:
    from chatterspec.studies.calibration.support import min_runs, min_runs_bounded

    n = min_runs(alpha)
    assert _expected_exceedance(n, alpha) <= alpha * (1 + 1e-12)
    assert _expected_exceedance(n - 1, alpha) > alpha  # one run fewer: the maximum, rate 1/n > alpha
    # the bounded-interval minimum is where the order-statistic interval gets a finite upper end
    nb = min_runs_bounded(alpha, 0.99)
    assert quantile_ci_ranks(nb, 1 - alpha, 0.99)[2] <= nb
    assert quantile_ci_ranks(nb - 1, 1 - alpha, 0.99)[2] == nb  # rank n + 1: unbounded


def test_calibrate_refuses_runs_that_support_alpha_for_no_use(capsys) -> None:
    # 5 runs at alpha 0.001: the threshold would be the largest of 5 healthy values (rate ~1/6, not 0.1 %)
    assert main(["calibrate", "eha-healthy", "--runs", "5", "--alpha", "0.001", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot support alpha = 0.001" in err and "--runs >= 999" in err and "--runs >= 250" in err
    assert err.count("\n") == 1 and "Traceback" not in err


@pytest.fixture(scope="module")
def small_calibration(tmp_path_factory) -> Path:
    """20 healthy runs at alpha 0.01: the record threshold needs 99 runs, the per-frame one 25."""
    path = tmp_path_factory.mktemp("cal") / "small.npz"
    calibrate("eha-healthy", alpha=0.01, runs=20, seed=0, progress=False).save(path)
    return path


def test_detect_refuses_a_calibration_with_too_few_runs(small_calibration: Path, capsys) -> None:
    assert main(["detect", "eha-leak-major", "--calibration", str(small_calibration)]) == 2
    err = capsys.readouterr().err
    assert "20 healthy runs cannot support alpha = 0.01 per record" in err and "--runs >= 99" in err


def test_monitor_refuses_a_calibration_with_too_few_runs(tmp_path: Path, capsys) -> None:
    small = tmp_path / "small.npz"
    calibrate(EXAMPLE_MODEL, alpha=0.01, runs=20, seed=0, progress=False).save(small)
    argv = ["monitor", str(EXAMPLE_MODEL), "--data", str(EXAMPLE_DATA), "--calibration"]
    assert main([*argv, str(small)]) == 2
    err = capsys.readouterr().err
    assert "per frame" in err and "--runs >= 25" in err  # 99 values / 4 independent frames per 4 s run
    enough = tmp_path / "enough.npz"  # 25 runs: enough per frame (the CLI warns it is too few for detect)
    assert main(["calibrate", str(EXAMPLE_MODEL), "--runs", "25", "--no-progress", "--out", str(enough)]) == 0
    assert "will be refused by detect" in capsys.readouterr().err
    assert main([*argv, str(enough)]) == 0
