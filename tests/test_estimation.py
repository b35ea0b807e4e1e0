"""``chatterspec estimate`` and the estimation study driver (chunking, JSON, recording, bad input)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from chatterspec.cli import main
from chatterspec.errors import NonFiniteError, ParameterError
from chatterspec.studies.estimation import (
    build_filter,
    consistency,
    consistency_from_sums,
    estimate_records,
    estimation_study,
    parse_filters,
    state_error_metrics,
)


def test_chunking_and_workers_do_not_change_the_numbers():
    a = estimation_study("detc-uncertain", "kf,svsf2", runs=130, seed=3, chunk_runs=64, progress=False)
    b = estimation_study("detc-uncertain", "kf,svsf2", runs=130, seed=3, chunk_runs=192, progress=False)
    for name in ("kf", "svsf2"):
        np.testing.assert_allclose(a.get(name).per_run.rmse, b.get(name).per_run.rmse, rtol=0, atol=0)
        assert a.get(name).nees.statistic == pytest.approx(b.get(name).nees.statistic, rel=1e-12)


def test_study_equals_the_direct_computation_on_the_same_runs():
    res = estimation_study("detc-normal", "kf,svsf", runs=70, seed=5, progress=False)
    rec = estimate_records("detc-normal", "kf,svsf", runs=70, seed=5)
    for name in ("kf", "svsf"):
        m = state_error_metrics(rec.x[:, 1:], rec.outputs[name].x_post)
        np.testing.assert_allclose(res.get(name).rmse.mean, m.rmse.mean(axis=0), rtol=1e-12)
        np.testing.assert_allclose(
            res.get(name).bias.stderr, m.bias.std(axis=0, ddof=1) / np.sqrt(70), rtol=1e-9
        )


def test_consistency_from_sums_equals_consistency():
    rng = np.random.default_rng(0)
    v = rng.chisquare(2, size=(40, 300))
    a = consistency(v, 2, kind="NIS")
    b = consistency_from_sums(float(v.sum()), v.sum(axis=0), 40, 2, kind="NIS")
    assert a == b


def test_a_numpy_integer_seed_is_reported_like_the_python_int():
    # a numpy integer is a valid seed everywhere (chatterspec.montecarlo); the result must label it,
    # not say None
    a = estimation_study("detc-normal", "kf", runs=2, seed=np.int64(3), progress=False)
    b = estimation_study("detc-normal", "kf", runs=2, seed=3, progress=False)
    assert a.seed == 3 and type(a.to_dict()["seed"]) is int
    assert a.to_dict() == b.to_dict()


def test_kf_is_reported_inconsistent_under_the_printed_tuning():
    # on detc-normal the printed filter Q, R are 100-10^4 x the truth's (Q = diag(1, 10, 100) against
    # w_std^2 = (0.0025, 0.01, 0.01); R = 0.1 against 0.0025), so the innovations are far smaller than
    # S says: the NIS must fall below the lower chi-squared bound, and the table must say so.
    res = estimation_study("detc-normal", "kf", runs=64, seed=0, progress=False)
    nis = res.get("kf").nis
    assert not nis.consistent and nis.statistic < nis.lower


def test_paired_difference_has_the_paired_standard_error():
    res = estimation_study("detc-normal", "kf,svsf", runs=64, seed=1, progress=False)
    d = res.difference("svsf", "kf")
    diff = res.get("svsf").per_run.rmse - res.get("kf").per_run.rmse
    np.testing.assert_allclose(d.mean, diff.mean(axis=0))
    np.testing.assert_allclose(d.stderr, diff.std(axis=0, ddof=1) / 8.0)
    with pytest.raises(ParameterError, match="metric"):
        res.difference("svsf", "kf", metric="nope")


def test_eha4_ekf_runs_on_the_nonlinear_plant():
    res = estimation_study("eha4-leak-timeline", "kf", runs=2, seed=0, chunk_runs=64, progress=False)
    kf = res.get("kf")
    assert res.state_names == ("position", "velocity", "acceleration", "pressure")
    assert type(build_filter("kf", "eha4-leak-timeline")).__name__ == "ExtendedKalmanFilter"
    # C = I4 with R = 1e-6 I4: the EKF position error must be well below the measurement std 1e-3
    assert kf.rmse.mean[0] < 1e-3
    assert np.all(np.isfinite(kf.rmse.mean))


@pytest.mark.parametrize(
    ("filters", "match"),
    [("kf,foo", "unknown filter"), ("", "no filter"), ("kf,kf", "once")],
)
def test_bad_filter_lists(filters, match):
    with pytest.raises(ParameterError, match=match):
        parse_filters(filters)


def test_scenario_without_settings_is_refused():
    with pytest.raises(ParameterError, match="filter settings"):
        estimation_study("eha-healthy", "kf", runs=1)


def test_diverging_estimates_are_reported_not_averaged():
    with pytest.raises(NonFiniteError):
        state_error_metrics(np.zeros((1, 3, 2)), np.full((1, 3, 2), np.nan))


def test_cli_json_and_table(capsys):
    assert (
        main(["estimate", "detc-normal", "--filters", "kf,svsf2", "--runs", "8", "--json", "--no-progress"])
        == 0
    )
    doc = json.loads(capsys.readouterr().out)
    assert [f["filter"] for f in doc["filters"]] == ["kf", "svsf2"]
    assert set(doc["filters"][0]["rmse"]) == {"position", "velocity", "acceleration"}
    assert doc["runs"] == 8 and doc["filter_settings"]["gamma"] == 0.5
    assert main(["estimate", "detc-normal", "--filters", "svsf", "--runs", "2", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "RMSE" in out and "NEES" in out and "svsf" in out


@pytest.mark.parametrize(
    ("argv", "msg"),
    [
        (["estimate", "detc-normal", "--filters", "kf,nope"], "unknown filter"),
        (["estimate", "eha-healthy"], "filter settings"),
        (["estimate", "nope"], "unknown scenario"),
        (["estimate", "detc-normal", "--record", "out.txt"], ".rrd"),
    ],
)
def test_cli_bad_input_exits_2(argv, msg, capsys):
    assert main(argv) == 2
    assert msg in capsys.readouterr().err


def test_cli_refuses_unwritable_record_path_before_computing(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["estimate", "detc-normal", "--runs", "1", "--record", str(blocker / "a.rrd")]) == 2
    assert "is not a folder" in capsys.readouterr().err


def test_cli_record_writes_truth_estimates_and_innovations(tmp_path, capsys):
    rr = pytest.importorskip("rerun")
    path = tmp_path / "est.rrd"
    argv = ["estimate", "detc-uncertain", "--filters", "kf,svsf2", "--runs", "2", "--no-progress"]
    assert main([*argv, "--record", str(tmp_path / "sub" / "est.rrd")]) == 2  # a missing folder: refused
    assert not (tmp_path / "sub").exists() and "does not exist (create it first)" in capsys.readouterr().err
    assert main([*argv, "--record", str(path)]) == 0
    assert path.exists()
    from rerun.chunk import RrdReader  # noqa: F401  (API of rerun 0.41)

    reader = rr.chunk.RrdReader(str(path))
    rows = {}
    for chunk in reader.stream().to_chunks():
        if not chunk.is_static:  # the static rows are the series' styles
            rows[chunk.entity_path] = rows.get(chunk.entity_path, 0) + chunk.num_rows
    assert rows["/states/velocity/truth"] == 1001
    assert rows["/states/velocity/svsf2"] == 1000
    assert rows["/innovations/position/kf"] == 1000
    assert rows["/errors/acceleration/kf"] == 1000
    # a designed layout (not Rerun's automatic grid): per state, truth and estimates beside the errors
    from chatterspec.viewer.recordings import estimate_blueprint

    bp = estimate_blueprint(("position", "velocity"), ("position",), ["kf", "svsf2"], (0.0, 1.0), ("m", ""))
    rows = bp.root_container.contents[:2]  # one row per state: estimates beside the errors
    assert [[v.origin for v in row.contents] for row in rows] == [
        ["/states/position", "/errors/position"],
        ["/states/velocity", "/errors/velocity"],
    ]
    assert rows[0].contents[0].name.startswith("position [m]: truth")
    # then the innovations with the colours' legend, and the true plant's lane (where the fault starts)
    assert [v.origin for v in bp.root_container.contents[2].contents] == ["/innovations/position", "/info"]
    assert bp.root_container.contents[3].origin == "/state"


def test_estimation_error_figure(tmp_path):
    from chatterspec.figures.estimators import estimation_error_figure
    from chatterspec.figures.plot_studies import save

    rec = estimate_records("detc-uncertain", "kf,svsf2", runs=3, seed=0)
    fig = estimation_error_figure(rec, run=2)
    assert len(fig.axes) == 6
    # the left column shows realization 2's error of the first filter
    line = fig.axes[0].get_lines()[0]
    np.testing.assert_allclose(line.get_ydata(), rec.error("kf")[2, :, 0])
    assert save(fig, tmp_path / "f.png").stat().st_size > 10_000
    with pytest.raises(ParameterError, match="run"):
        estimation_error_figure(rec, run=3)


def test_two_local_workers_give_identical_numbers():
    kw = {"runs": 128, "seed": 9, "chunk_runs": 64, "progress": False}
    a = estimation_study("detc-uncertain", "kf,svsf", workers=1, **kw)
    b = estimation_study("detc-uncertain", "kf,svsf", workers=2, **kw)
    for name in ("kf", "svsf"):
        np.testing.assert_array_equal(a.get(name).per_run.bias, b.get(name).per_run.bias)
        assert a.get(name).nis == b.get(name).nis


def test_cli_refuses_record_path_under_a_file(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert main(["estimate", "detc-normal", "--runs", "1", "--record", str(blocker / "sub" / "a.rrd")]) == 2
    assert "cannot be written" in capsys.readouterr().err
    assert blocker.read_text() == "x"


def test_time_blocks_inside_a_chunk_do_not_change_the_numbers(monkeypatch):
    import chatterspec.studies.estimation as est

    a = estimation_study("detc-uncertain", "kf,svsf,svsf2", runs=64, seed=4, progress=False)
    monkeypatch.setattr(est, "TIME_BLOCK", 137)
    b = estimation_study("detc-uncertain", "kf,svsf,svsf2", runs=64, seed=4, progress=False)
    for name in ("kf", "svsf", "svsf2"):
        np.testing.assert_array_equal(a.get(name).per_run.rmse, b.get(name).per_run.rmse)
        assert a.get(name).nees.statistic == pytest.approx(b.get(name).nees.statistic, rel=1e-12)
