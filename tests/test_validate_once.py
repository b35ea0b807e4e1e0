"""Validation at the boundary: one message per bad value at every public entry point, and the checks of
``alpha``, the tested band, the false-alarm budget and the execution settings live only in the option
objects and the boundary functions listed here (``docs/design.md``, "Validation at the boundary").

Every call below fails on its first check, before any simulation: the whole file runs in about a
second.
"""

from __future__ import annotations

import ast
import collections
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import chatterspec
from chatterspec.cli import main as cli_main
from chatterspec.errors import ParameterError

PACKAGE = Path(chatterspec.__file__).parent


def _message(call: Callable[[], object]) -> str:
    with pytest.raises(ParameterError) as info:
        call()
    return str(info.value)


def _eha():
    from chatterspec.plants.scenarios import scenario

    return scenario("eha-healthy")


def _alpha_entry_points() -> dict[str, Callable[[float], object]]:
    from chatterspec.detection import thresholds as th
    from chatterspec.detection.alarms.calibration import MonitorSettings
    from chatterspec.detection.detect import DetectorOptions, detect_chunks, detect_record, detect_scenario
    from chatterspec.detection.spectral import STFTConfig
    from chatterspec.plants.scenarios import scenario
    from chatterspec.studies.calibration.recorded import plan_recording
    from chatterspec.studies.calibration.thresholds import calibrate
    from chatterspec.studies.closed_loop import excitation_study, footprint
    from chatterspec.studies.detection_rates import false_alarm_study, power_study
    from chatterspec.studies.estimation import consistency, consistency_from_sums, estimation_study

    sc, estimator = _eha(), scenario("detc-normal")
    model, f = sc.nominal, np.linspace(0.0, 500.0, 11)
    return {
        "DetectorOptions": lambda a: DetectorOptions(alpha=a),
        "MonitorSettings": lambda a: MonitorSettings(alpha=a),
        "detect_record": lambda a: detect_record(None, a),  # type: ignore[arg-type]  # fails first on alpha
        "detect_chunks": lambda a: detect_chunks([], a),
        "detect_scenario": lambda a: detect_scenario(sc, 1, 0, a),
        "exact_threshold": lambda a: th.exact_threshold(model, f, 20, a),
        "frame_threshold": lambda a: th.frame_threshold(model, f, STFTConfig(), None, a),
        "paper_threshold": lambda a: th.paper_threshold(model, f, a),
        "threshold": lambda a: th.threshold("paper", model, f, alpha=a),
        "per_test_alpha": lambda a: th.per_test_alpha(a, 3),
        "empirical_family_wise_threshold": lambda a: th.empirical_family_wise_threshold(
            np.ones((11, 3)), f, np.ones(11, bool), np.ones(3), a
        ),
        "calibrate": lambda a: calibrate(sc, a),
        "false_alarm_study": lambda a: false_alarm_study(sc, a),
        "power_study": lambda a: power_study("leakage", alpha=a),
        "power_study(alphas)": lambda a: power_study("leakage", alphas=[1e-3, a]),
        "excitation_study": lambda a: excitation_study(alpha=a),
        "footprint": lambda a: footprint(scenario("eha-leak-major"), alpha=a),
        "estimation_study": lambda a: estimation_study(estimator, "kf", alpha=a),
        "consistency": lambda a: consistency(np.ones((2, 5)), 1, alpha=a),
        "consistency_from_sums": lambda a: consistency_from_sums(10.0, np.ones(5), 2, 1, alpha=a),
        "plan_recording": lambda a: plan_recording(model, 100_000, alpha=a),
    }


@pytest.mark.parametrize("bad", [1.5, 0.0, float("nan")])
def test_every_alpha_entry_point_refuses_a_bad_alpha_with_one_message(bad: float) -> None:
    from chatterspec.detection.detect import DetectorOptions

    expected = _message(lambda: DetectorOptions(alpha=bad))
    assert expected.startswith("alpha must"), expected
    messages = {name: _message(lambda call=call: call(bad)) for name, call in _alpha_entry_points().items()}
    assert {k: v for k, v in messages.items() if v != expected} == {}


def _band_entry_points() -> dict[str, Callable[[tuple[float, float]], object]]:
    from chatterspec.detection import thresholds as th
    from chatterspec.detection.alarms.calibration import MonitorSettings
    from chatterspec.detection.detect import DetectorOptions, detect_chunks, detect_record
    from chatterspec.detection.spectral import STFTConfig

    model, f = _eha().nominal, np.linspace(0.0, 500.0, 11)
    paper = th.paper_threshold(model, f)
    return {
        "DetectorOptions": lambda b: DetectorOptions(band=b),
        "MonitorSettings": lambda b: MonitorSettings(band=b),
        "detect_record": lambda b: detect_record(None, band=b),  # type: ignore[arg-type]
        "detect_chunks": lambda b: detect_chunks([], band=b),
        "exact_threshold": lambda b: th.exact_threshold(model, f, 20, band=b),
        "frame_threshold": lambda b: th.frame_threshold(model, f, STFTConfig(), band=b),
        "paper_threshold": lambda b: th.paper_threshold(model, f, band=b),
        "band_mask": lambda b: th.band_mask(f, b),
        "Threshold.restricted": lambda b: paper.restricted(b),
    }


@pytest.mark.parametrize("bad", [(50.0, 10.0), (-1.0, 10.0), (0.0, float("inf"))])
def test_every_band_entry_point_refuses_a_bad_band_with_one_message(bad: tuple[float, float]) -> None:
    from chatterspec.detection.thresholds import check_band

    expected = _message(lambda: check_band(bad))
    messages = {name: _message(lambda call=call: call(bad)) for name, call in _band_entry_points().items()}
    assert {k: v for k, v in messages.items() if v != expected} == {}


def _budget_entry_points() -> dict[str, Callable[[float], object]]:
    from chatterspec.detection.alarms.calibration import MonitorSettings, calibrate_rule, law_frame_rule
    from chatterspec.detection.alarms.rules import make_rule
    from chatterspec.detection.identification import identification_setup
    from chatterspec.detection.parameter_decision import parameter_alarm_settings
    from chatterspec.studies.alarm_budget import alarm_settings, calibrate_alarm
    from chatterspec.studies.calibration.recorded import min_hours, plan_recording

    model = _eha().nominal
    scores = np.zeros((4, 3))
    return {
        "law_frame_rule": lambda x: law_frame_rule(18000.0, 3, x),
        "calibrate_rule": lambda x: calibrate_rule(make_rule("cusum"), scores, 18000.0, x),
        "calibrate_alarm": lambda x: calibrate_alarm(model, MonitorSettings(), "cusum", x),
        "alarm_settings": lambda x: alarm_settings(model, MonitorSettings(), "cusum", x),
        "plan_recording": lambda x: plan_recording(model, 100_000, false_alarms_per_hour=x),
        "min_hours": lambda x: min_hours(3, 18000.0, x),
        "parameter_alarm_settings": lambda x: parameter_alarm_settings(
            identification_setup(model), hop_s=0.2, window_hops=5, false_alarms_per_hour=x
        ),
    }


@pytest.mark.parametrize("bad", [0.0, -2.0, float("inf")])
def test_every_budget_entry_point_refuses_a_bad_budget_with_one_message(bad: float) -> None:
    from chatterspec.detection.alarms.calibration import check_budget

    expected = _message(lambda: check_budget(bad))
    assert expected.startswith("false_alarms_per_hour must be positive and finite"), expected
    messages = {name: _message(lambda call=call: call(bad)) for name, call in _budget_entry_points().items()}
    assert {k: v for k, v in messages.items() if v != expected} == {}


def test_an_unreachable_budget_is_refused_with_one_message() -> None:
    """More starts per hour than one per two frames per channel: no threshold meets it."""
    from chatterspec.detection.alarms.calibration import MonitorSettings, law_frame_rule
    from chatterspec.studies.alarm_budget import alarm_settings, frames_per_hour

    model = _eha().nominal
    F = frames_per_hour(MonitorSettings(), model.dt)
    a = _message(lambda: law_frame_rule(F, model.n_outputs, 1e9))
    b = _message(lambda: alarm_settings(model, MonitorSettings(), "frame", 1e9))
    assert a == b and a.startswith("no alarm threshold meets 1e+09 false alarms per hour"), (a, b)


def _workers_entry_points() -> dict[str, Callable[[int], object]]:
    from chatterspec.detection.detect import detect_scenario
    from chatterspec.montecarlo import Execution, run_study
    from chatterspec.studies.calibration.thresholds import calibrate
    from chatterspec.studies.closed_loop import excitation_study
    from chatterspec.studies.detection_rates import false_alarm_study, power_study
    from chatterspec.studies.estimation import estimation_study

    sc = _eha()
    return {
        "Execution": lambda w: Execution(workers=w),
        "run_study": lambda w: run_study(object(), 10, workers=w),  # type: ignore[arg-type]
        "detect_scenario": lambda w: detect_scenario(sc, 1, 0, workers=w),
        "calibrate": lambda w: calibrate(sc, workers=w),
        "false_alarm_study": lambda w: false_alarm_study(sc, workers=w),
        "power_study": lambda w: power_study("leakage", workers=w),
        "excitation_study": lambda w: excitation_study(workers=w),
        "estimation_study": lambda w: estimation_study("detc-normal", "kf", workers=w),
    }


@pytest.mark.parametrize("bad", [0, -3, 1.5, True])
def test_every_execution_entry_point_refuses_bad_workers_with_one_message(bad: int) -> None:
    expected = f"workers must be an integer >= 1; got {bad!r}"
    messages = {name: _message(lambda call=call: call(bad)) for name, call in _workers_entry_points().items()}
    assert {k: v for k, v in messages.items() if v != expected} == {}


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["detect", "eha-healthy", "--band", "50", "10"], "band must satisfy 0 <= lo < hi"),
        (["demo", "--band", "50", "10", "--no-figures", "--no-record"], "band must satisfy 0 <= lo < hi"),
        (
            ["monitor", "examples/eha_model.toml", "--data", "examples/eha_data.csv", "--band", "50", "10"],
            "band must satisfy 0 <= lo < hi",
        ),
        (
            ["detect", "eha-healthy", "--false-alarms-per-hour", "0"],
            "--false-alarms-per-hour must be positive",
        ),
    ],
)
def test_the_cli_reports_the_option_objects_message_in_one_line(argv, expected, capsys) -> None:
    root = PACKAGE.parent
    argv = [str(root / a) if a.startswith("examples/") else a for a in argv]
    assert cli_main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and len(err.splitlines()) == 1, err


# --- the structural check -------------------------------------------------------------------------------
#: Where a check of alpha, the tested band, the budget or the execution settings may be written: the
#: option objects' ``__post_init__`` and the validators, plus the public primitives that take the value
#: itself (threshold constructors, consistency tests, alarm calibration), the study entry points whose
#: ``alpha`` is not a detector option, and the model file and CLI boundaries. ``(module, function)``
#: -> number of checks.
BOUNDARY = {
    ("detection/detect.py", "DetectorOptions.__post_init__"): 1,
    ("detection/alarms/calibration.py", "MonitorSettings.__post_init__"): 1,
    ("detection/alarms/calibration.py", "law_frame_rule"): 2,
    ("detection/alarms/calibration.py", "calibrate_rule"): 2,
    ("montecarlo.py", "Execution.__post_init__"): 2,
    ("studies/budget_diagnosis.py", "BudgetSettings.__post_init__"): 1,
    ("detection/parameter_decision.py", "calibrate_parameter_rule"): 1,
    ("detection/parameter_decision.py", "ParameterAlarmSettings.__post_init__"): 1,
    ("detection/parameter_decision.py", "record_decisions"): 1,
    ("detection/parameter_decision.py", "monitor_parameters"): 1,
    ("detection/thresholds.py", "Threshold.restricted"): 1,
    ("detection/thresholds.py", "band_mask"): 1,
    ("detection/thresholds.py", "check_detector"): 2,  # alpha and the tested band, for all of these:
    ("detection/thresholds.py", "per_test_alpha"): 1,
    ("detection/thresholds.py", "exact_threshold"): 1,
    ("detection/thresholds.py", "frame_threshold"): 1,
    ("detection/thresholds.py", "paper_threshold"): 1,
    ("detection/thresholds.py", "empirical_family_wise_threshold"): 1,
    ("studies/estimation.py", "consistency_from_sums"): 1,  # the NIS / NEES test level
    ("studies/estimation.py", "estimation_study"): 1,  # (the same, before the runs)
    ("studies/commissioning/procedure.py", "commission"): 1,  # the adequacy tests' level
    ("studies/calibration/healthy.py", "_check_alphas"): 1,  # a list of levels
    ("studies/calibration/thresholds.py", "calibrate"): 1,
    ("studies/calibration/recorded.py", "min_hours"): 1,
    ("studies/calibration/recorded.py", "plan_recording"): 2,
    ("studies/closed_loop.py", "excitation_study"): 1,
    ("studies/closed_loop.py", "footprint"): 1,
    ("studies/detection_rates.py", "power_study"): 1,
    ("studies/alarm_budget.py", "calibrate_alarm"): 1,
    ("plants/modelfile.py", "_detector_band"): 1,  # the model file's [detector] band
    ("plants/simulate.py", "chunk_runs_of"): 1,  # the chunk size of iter_simulations and iter_chattering
    ("online/realistic_bench.py", "BenchConfig.__post_init__"): 1,
    ("cli/_options.py", "alarm_choice"): 1,  # names the CLI option
    ("cli/calibrate.py", "_check_alarm_plan"): 1,  # (the same, with the calibration's frame rate)
}

#: The checks counted: ``open_unit("alpha", ...)``, ``positive``/``positive_int`` of a budget or
#: execution setting, and every call of the band, detector-level and budget validators.
_NAMED = {"alpha", "workers", "chunk_runs", "false_alarms_per_hour", "steps_per_hour"}


def validation_sites(package: Path = PACKAGE) -> collections.Counter[tuple[str, str]]:
    """``(module, enclosing function) -> checks`` over the package source (parsed, not imported)."""
    sites: collections.Counter[tuple[str, str]] = collections.Counter()

    def visit(node: ast.AST, module: str, scope: list[str]) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                visit(child, module, [*scope, child.name])
                continue
            if isinstance(child, ast.Call):
                f = child.func
                name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
                first = child.args[0] if child.args else None
                named = isinstance(first, ast.Constant) and first.value in _NAMED
                if name in ("check_band", "check_budget", "check_detector") or (
                    name in ("open_unit", "positive", "positive_int") and named
                ):
                    sites[(module, ".".join(scope))] += 1
            visit(child, module, scope)

    for path in sorted(package.rglob("*.py")):
        visit(ast.parse(path.read_text(encoding="utf-8")), path.relative_to(package).as_posix(), [])
    return sites


def test_the_checks_live_only_at_the_boundary() -> None:
    """A new re-check in an inner layer (or a moved boundary) fails here: add it to BOUNDARY only with
    a reason, and say it in docs/design.md."""
    found = dict(validation_sites())
    assert found == BOUNDARY


def test_the_structural_check_sees_a_re_check(tmp_path: Path) -> None:
    """The counter finds a check written in an inner function (a copy of the package would be slow:
    one module is enough)."""
    mod = tmp_path / "inner.py"
    mod.write_text(
        "def helper(alpha, band, x):\n"
        "    alpha = open_unit('alpha', alpha)\n"
        "    band = check_band(band)\n"
        "    check_detector(alpha, 'none', band)\n"
        "    return _validate.positive_int('workers', x), check_budget(x)\n"
    )
    assert dict(validation_sites(tmp_path)) == {("inner.py", "helper"): 5}
