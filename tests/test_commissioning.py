"""Commissioning (chatterspec.studies.commissioning, `chatterspec commission`): fits, check, file, bad input.

Records are short (20-60 s of the linear EHA at 1 kHz, one 10-100 Hz sweep of the pump-speed chirp),
seeds fixed, tolerances from the estimators' own standard errors or exact binomial intervals, each
with its reason. The held-out check calibrates the monitor's CUSUM threshold in-call (4 simulated
hours, a few seconds): the tests that run it share fitted models so that the calibration cache serves
the later ones.
"""

from __future__ import annotations

import hashlib
import io
import json
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.cli import main
from chatterspec.errors import (
    CommissioningError,
    IdentifiabilityError,
    ModelFileError,
    ParameterError,
)
from chatterspec.studies.alarm_budget import healthy_chattering
from chatterspec.studies.commissioning import (
    commission,
    fit_noise,
    nominal_spec,
)
from chatterspec.studies.commissioning.fits import moment_design
from chatterspec.studies.intervals import clopper_pearson

BULK, FRICTION = 207e6, 2144.0


@pytest.fixture(scope="module")
def nominal_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from chatterspec.cli.scenarios import export_model_toml

    return export_model_toml("eha-healthy", tmp_path_factory.mktemp("nominal") / "eha.toml")


@pytest.fixture(scope="module")
def nominal(nominal_file: Path) -> cs.LinearModel:
    return cs.load_model(nominal_file).model


def _plant(nominal: cs.LinearModel, **values: float) -> cs.LinearModel:
    return nominal.parameter_map.model_with(nominal, values, nominal.name)


def _record(plant: cs.LinearModel, seconds: float, seed: int, windows: tuple = ()) -> tuple:
    """One 10-100 Hz sweep of the catalogue chirp's amplitude over ``seconds``: ``(t, z, u)`` (the stream
    simulator draws only the normals of this one record)."""
    from chatterspec.online.simulated_stream import simulate_blocks

    sc = cs.Scenario(
        name="rec",
        nominal=plant,
        input=cs.Chirp(10.0, 100.0, seconds, 300.0),
        duration=seconds,
        windows=windows,
    )
    t, z, u = zip(*simulate_blocks(sc, seed, block_s=seconds), strict=True)
    return np.concatenate(t), np.concatenate(z), np.concatenate(u)


def _csv(path: Path, t: np.ndarray, z: np.ndarray, u: np.ndarray) -> Path:
    from chatterspec.online.simulated_stream import csv_header, csv_lines

    model = cs.scenario("eha-healthy").nominal
    path.write_text(csv_header(model) + "\n" + csv_lines(t, z, u))
    return path


# --------------------------------------------------------------------------- the pieces
def test_moment_design_reproduces_the_chattering_autocovariances(nominal: cs.LinearModel) -> None:
    # eq 58: the design's lag-0 and lag-1 diagonal rows at the model's own Q, R are its gamma0, gamma1
    from chatterspec.detection.spectral import chattering_autocovariance

    g = moment_design(nominal) @ np.r_[np.diag(nominal.Q), np.diag(nominal.R)]
    m = nominal.n_outputs
    i0, j0 = np.triu_indices(m)
    g0, g1 = chattering_autocovariance(nominal)
    np.testing.assert_allclose(g[np.flatnonzero(i0 == j0)], g0, rtol=1e-12)
    np.testing.assert_allclose(g[i0.size + np.arange(m) * (m + 1)], g1, rtol=1e-12)


def test_noise_fit_recovers_r_and_bounds_what_it_cannot_see(nominal: cs.LinearModel) -> None:
    import dataclasses

    true = dataclasses.replace(nominal, R=nominal.R * 1.5, Q=np.diag([1e-12, 2e-6, 1.0]))
    e = np.concatenate(list(healthy_chattering(true, 200_000, seed=4)))  # the exact MA(1) law, eq 23
    nf = fit_noise(nominal, e)
    # every identified entry within 3.29 standard errors of the truth: a two-sided 99.9 % band, Bonferroni
    # over the 4 identified entries (R x 3, velocity Q) keeps a false failure below 0.4 %
    est = np.r_[nf.q[1], nf.r]
    se = np.r_[nf.q_std_error[1], nf.r_std_error]
    truth = np.r_[2e-6, np.diag(true.R)]
    assert np.all(np.abs(est - truth) <= 3.29 * se), (est, truth, se)
    assert list(nf.q_identified) == [False, True, False] and nf.r_identified.all()
    # position and pressure Q sit far under their measurement-noise share: bounded, nominal kept
    assert nf.q[0] == 1e-12 and nf.q[2] == 1.0
    assert nf.q_ci_high[0] >= 1e-12 and nf.q_ci_high[2] >= 1.0
    assert nf.p_value > 1e-3  # the MA(1) law holds: Hansen's statistic is not extreme


def test_noise_fit_refuses_a_coloured_sensor(nominal: cs.LinearModel) -> None:
    # AR(1) velocity sensor noise (rho 0.9): its chattering's lag-1 autocovariance turns positive, which
    # white measurement noise cannot give (-Phi R, eq 23)
    rng = np.random.default_rng(7)
    n = 100_000
    w = np.zeros((n + 1, 3))
    w[:, 0] = 1e-3 * rng.standard_normal(n + 1)
    w[:, 2] = 1e3 * rng.standard_normal(n + 1)
    a = 1e-3 * np.sqrt(1 - 0.81) * rng.standard_normal(n + 1)
    w[:, 1] = _ar1(a, 0.9)
    Phi = nominal.C @ nominal.A @ nominal.C_inv
    e = w[1:] - w[:-1] @ Phi.T + np.sqrt(np.diag(nominal.Q)) * rng.standard_normal((n, 3))
    with pytest.raises(CommissioningError, match=r"R is not positive definite: R on velocity .*coloured"):
        fit_noise(nominal, e)


def _ar1(a: np.ndarray, rho: float) -> np.ndarray:
    import scipy.signal

    return scipy.signal.lfilter([1.0], [1.0, -rho], a)


def test_whiteness_beyond_lag_one() -> None:
    from chatterspec.studies.commissioning.adequacy import ma1_portmanteau

    rng = np.random.default_rng(11)
    x = rng.standard_normal((200, 20_001))
    # MA(1) series of four shapes, down to a first difference (the EHA position channel is 0.999998...)
    shapes = (0.0, -0.75, -0.999, -1.0)
    res = np.array([[ma1_portmanteau(row[1:] + th * row[:-1], 20) for row in x] for th in shapes])
    # chi-squared(20) under the null: the mean of 200 statistics has standard error sqrt(40 / 200) = 0.45,
    # 20 +- 2 is 4.5 of them; at level 0.01 the 200 tests reject Binomial(200, 0.01) times, and 8 or more
    # has probability 0.2 %: both bounds fail a correct test with well under 1 % (fixed seed anyway)
    assert np.all(np.abs(res[..., 0].mean(axis=1) - 20) < 2), res[..., 0].mean(axis=1)
    assert np.all((res[..., 1] < 0.01).sum(axis=1) <= 7), (res[..., 1] < 0.01).sum(axis=1)
    # an AR(1) component (correlated at every lag) is rejected
    assert ma1_portmanteau(_ar1(x[0], 0.3), 20)[1] < 1e-10  # r_2 = 0.09 over 20 000 samples


# --------------------------------------------------------------------------- parameters
def test_parameter_intervals_cover_their_truth_over_random_plants(nominal_file: Path, nominal) -> None:
    # 40 plants, every parameter off by U(-30 %, +30 %), 10 s each (fit only); per parameter the
    # fraction of 95 % intervals that hold the truth must have a Clopper-Pearson interval containing 0.95
    # at 99.67 % (99 % family-wise over the 3 parameters: a correct interval fails this test with
    # probability below 1 %, and with this fixed seed it is deterministic)
    spec = cs.load_model(nominal_file)
    names = nominal.parameter_map.parameter_names
    values = np.array([nominal.parameter_map.parameter(p).value for p in names])
    rng = np.random.default_rng(2029)
    factors = rng.uniform(0.7, 1.3, size=(40, len(names)))
    hits = np.zeros(factors.shape, dtype=bool)
    for i, f in enumerate(factors):  # every plant is another model: one simulation and fit each
        truth = values * f
        _, z, u = _record(_plant(nominal, **dict(zip(names, truth, strict=True))), 10.0, seed=100 + i)
        res = commission(spec, z, u, check=False)
        hits[i] = [p.ci_low <= t <= p.ci_high for p, t in zip(res.parameters.parameters, truth, strict=True)]
    for j, name in enumerate(names):
        lo, hi = clopper_pearson(int(hits[:, j].sum()), hits.shape[0], 1 - 0.01 / 3)
        assert lo <= 0.95 <= hi, (name, hits[:, j].mean())


def test_identifiability_refusals(nominal: cs.LinearModel) -> None:
    import dataclasses

    # a plant at rest whose velocity carries no process noise: velocity is its sensor noise only
    still = dataclasses.replace(nominal, Q=np.diag([1e-12, 0.0, 1.0]))
    sc = cs.Scenario(name="rest", nominal=still, input=cs.Constant(0.0), duration=20.0)
    sim = cs.simulate(sc, runs=1, seed=1)
    with pytest.raises(IdentifiabilityError, match=r"friction is not identifiable: velocity never leaves"):
        commission(nominal, sim.z[0], sim.u, check=False)
    with pytest.raises(IdentifiabilityError, match=r"chirp or steps covering ~10-63 Hz"):
        commission(nominal, sim.z[0], sim.u, check=False)
    # a quarter second of the chirp: the parameters are fitted, but too loosely; the message says how long
    _, z, u = _record(nominal, 0.25, seed=2)
    with pytest.raises(IdentifiabilityError, match=r"too short: .* a recording of about [0-9.]+ s would do"):
        commission(nominal, z, u, check=False)
    reduced = dataclasses.replace(
        nominal, C=nominal.C[:2], R=nominal.R[:2, :2], output_names=(), output_units=()
    )
    with pytest.raises(IdentifiabilityError, match="every state measured"):
        nominal_spec(reduced)
    with pytest.raises(IdentifiabilityError, match="nonlinear"):
        nominal_spec(cs.scenario("eha4-healthy").nominal)


def test_a_recording_too_short_for_the_check_says_how_long(nominal: cs.LinearModel) -> None:
    _, z, u = _record(nominal, 20.0, seed=3)
    with pytest.raises(ParameterError, match=r"too short: 20 s; .* record at least 30 s"):
        commission(nominal, z, u)


# --------------------------------------------------------------------------- the held-out check
@pytest.fixture(scope="module")
def mismatched(nominal: cs.LinearModel) -> cs.LinearModel:
    """The plant the nominal model mismatches: bulk modulus 10 % low, friction 10 % high."""
    return _plant(nominal, bulk_modulus=0.9 * BULK, friction=1.1 * FRICTION)


@pytest.fixture(scope="module")
def healthy_and_leaky(nominal_file: Path, mismatched: cs.LinearModel) -> tuple:
    """Commissioning from 60 s of the mismatched plant, healthy, and with a leak from 50 s (in the check
    span); the first 50 s are the same samples, so both fits agree and share the alarm calibration."""
    leaky = _plant(mismatched, leakage=3e-11)
    out = []
    for windows in ((), (cs.Segment(50.0, 60.0, leaky),)):
        t, z, u = _record(mismatched, 60.0, seed=5, windows=windows)
        out.append((commission(nominal_file, z, u), t, z, u))
    return tuple(out)


def test_check_is_adequate_on_healthy_data_and_names_pressure_on_a_leak(healthy_and_leaky: tuple) -> None:
    (ok, *_), (bad, *_) = healthy_and_leaky
    assert ok.adequate, ok.table()
    assert ok.estimate("bulk_modulus") == pytest.approx(0.9 * BULK, rel=1e-3)
    assert not bad.adequate
    failures = bad.check.failures()
    assert failures and all("pressure" in f for f in failures), failures
    press = bad.check.channels[2]
    assert not press.white and not press.spectrum_ok and press.alarm_starts == 1, bad.table()
    assert 50.0 <= press.alarm_times_s[0] <= 52.0
    lo, hi = press.bands_hz[0]
    assert 80.0 <= lo <= hi <= 100.0  # the sweep is at 85-100 Hz while the leak lasts
    assert "NOT ADEQUATE" in bad.table() and "pressure" in bad.table()


def test_alarm_count_is_the_online_monitors(healthy_and_leaky: tuple, nominal_file: Path) -> None:
    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
    from chatterspec.studies.alarm_budget import alarm_settings

    _, (res, t, z, u) = healthy_and_leaky
    spec = cs.load_model(nominal_file)
    settings = alarm_settings(res.model, MonitorSettings.from_detector(spec.detector, gamma=spec.gamma))
    k = round(res.check_span_s[0] / res.model.dt)
    mon = ChatteringMonitor(res.model, settings, t0=float(t[k]))
    starts = [ev for upd in mon.stream(z[k:], u[k:], 997) for ev in upd.events if ev.kind == "fault-start"]
    got = [(ev.channel, ev.time_s) for ev in starts]
    want = [(c.channel, s) for c in res.check.channels for s in c.alarm_times_s]
    assert len(got) == len(want) == 1
    assert got[0][0] == want[0][0] and got[0][1] == pytest.approx(want[0][1], abs=1e-9)


# --------------------------------------------------------------------------- the file
def test_written_file_reads_back_with_its_provenance(healthy_and_leaky: tuple, tmp_path: Path) -> None:
    res = healthy_and_leaky[0][0]
    path = res.write(tmp_path / "fitted.toml")
    spec = cs.load_model(path)
    np.testing.assert_array_equal(spec.model.A, res.model.A)
    np.testing.assert_array_equal(spec.model.R, res.model.R)
    np.testing.assert_array_equal(spec.psi, res.psi)
    np.testing.assert_array_equal(res.spec.model.B, spec.model.B)  # the in-memory spec is the file's
    prov = spec.commissioning
    assert prov["chatterspec_version"] == cs.__version__ and prov["fit_span_s"][0] == 0.0
    bm = prov["parameters"]["bulk_modulus"]
    assert bm["nominal"] == BULK and bm["ci_low"] <= bm["estimate"] <= bm["ci_high"]
    assert spec.model.parameter_map.parameter("bulk_modulus").value == bm["estimate"]
    assert prov["check"]["adequate"] and prov["noise"]["R_identified"] == [True, True, True]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fitted.toml"]  # no temporary file left


def test_a_failed_check_writes_nothing_unless_forced(healthy_and_leaky: tuple, tmp_path: Path) -> None:
    bad = healthy_and_leaky[1][0]
    target = tmp_path / "fitted.toml"
    target.write_text("# the user's previous file\n")
    with pytest.raises(CommissioningError, match=r"not adequate .*pressure.*nothing written"):
        bad.write(target)
    assert target.read_text() == "# the user's previous file\n" and len(list(tmp_path.iterdir())) == 1
    bad.write(target, force=True)
    check = cs.load_model(target).commissioning["check"]
    assert check["forced"] and not check["adequate"] and any("pressure" in f for f in check["failures"])


def test_provenance_table_must_be_a_table(nominal_file: Path, tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text('commissioning = "yes"\n' + nominal_file.read_text())
    with pytest.raises(ModelFileError, match=r"\[commissioning\] must be a table"):
        cs.load_model(path)


# --------------------------------------------------------------------------- the command line
def test_cli_round_trip_commission_then_monitor_holds(
    nominal_file: Path, mismatched: cs.LinearModel, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    data = _csv(tmp_path / "healthy.csv", *_record(mismatched, 60.0, seed=5))
    out = tmp_path / "fitted.toml"
    assert main(["commission", str(nominal_file), "--data", str(data), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "verdict: ADEQUATE" in text and f"wrote {out}" in text
    fresh = _csv(tmp_path / "fresh.csv", *_record(mismatched, 30.0, seed=9))

    def starts(model: Path) -> int:
        assert main(["monitor", str(model), "--data", str(fresh), "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        return sum(ev["kind"] == "fault-start" for ev in doc["events"])

    assert starts(out) == 0  # the commissioned model holds on fresh healthy data of the plant
    assert starts(nominal_file) >= 1  # the nominal model alarms on the same data (bulk modulus 10 % off)


def test_cli_reads_standard_input(
    nominal_file: Path, mismatched: cs.LinearModel, tmp_path: Path, capsys, monkeypatch
) -> None:
    raw = _csv(tmp_path / "healthy.csv", *_record(mismatched, 60.0, seed=5)).read_bytes()
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(raw)))
    assert main(["commission", str(nominal_file), "--data", "-", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["data"] == {"name": "-", "sha256": hashlib.sha256(raw).hexdigest()} and doc["adequate"]
    assert doc["out"] is None


def _missing_column(tmp_path: Path, t, z, u) -> Path:
    data = _csv(tmp_path / "bad.csv", t, z, u)
    data.write_text(data.read_text().replace("pressure,", "p,", 1))
    return data


def _nan_sample(tmp_path: Path, t, z, u) -> Path:
    z = z.copy()
    z[5, 0] = np.nan
    return _csv(tmp_path / "bad.csv", t, z, u)


@pytest.mark.parametrize(
    ("make", "message"),
    [(_missing_column, "missing column(s) ['pressure']"), (_nan_sample, "'position' has 1 NaN/inf sample")],
    ids=["column", "nan"],
)
def test_cli_bad_data_is_one_line_and_writes_nothing(
    nominal_file: Path, nominal, tmp_path: Path, capsys, make, message
) -> None:
    data = make(tmp_path, *_record(nominal, 2.0, seed=1))
    out = tmp_path / "fitted.toml"
    assert main(["commission", str(nominal_file), "--data", str(data), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and err[0].startswith("chatterspec commission: error:")
    assert not out.exists()


def test_cli_rate_mismatch(nominal_file: Path, nominal, tmp_path: Path, capsys) -> None:
    t, z, u = _record(nominal, 2.0, seed=1)
    data = _csv(tmp_path / "slow.csv", 2 * t, z, u)  # rows 2 ms apart for a 1 ms model
    assert main(["commission", str(nominal_file), "--data", str(data)]) == 2
    assert "sampled every 2 ms" in capsys.readouterr().err


def test_toml_tables_round_trip(tmp_path: Path) -> None:
    from chatterspec.plants.modelfile import toml_table

    table = {"a": 1, "b": 0.1 + 0.2, "c": "x y", "d": [True, False], "e": {"f": [1.5, 2]}, "odd key": -3e-300}
    path = tmp_path / "t.toml"
    path.write_text(toml_table("top.sub", table) + "\n")
    assert tomllib.loads(path.read_text()) == {"top": {"sub": table}}


def test_cli_unusable_out_fails_before_reading(nominal_file: Path, tmp_path: Path, capsys) -> None:
    blocker = tmp_path / "plain-file"
    blocker.write_text("x")
    argv = ["commission", str(nominal_file), "--data", str(tmp_path / "none.csv")]
    assert main([*argv, "--out", str(blocker / "fitted.toml")]) == 2
    err = capsys.readouterr().err
    assert "--out" in err and "cannot be written" in err and "none.csv" not in err  # before the data


def test_a_failed_rename_leaves_the_target_and_no_temporary(
    healthy_and_leaky: tuple, tmp_path: Path, monkeypatch
) -> None:
    import os

    def fail(src, dst):
        raise OSError(28, "No space left on device")

    target = tmp_path / "fitted.toml"
    target.write_text("# before\n")
    monkeypatch.setattr(os, "replace", fail)
    with pytest.raises(OSError, match="No space"):
        healthy_and_leaky[0][0].write(target)
    assert target.read_text() == "# before\n" and [p.name for p in tmp_path.iterdir()] == ["fitted.toml"]
