"""The realistic bench on a tiny configuration: cases, streams, routes, outcomes (the numbers in the
README come from scripts/realistic_bench.py)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from chatterspec.detection.alarms.calibration import MonitorSettings
from chatterspec.errors import CommissioningError, ParameterError
from chatterspec.online.realistic_bench import (
    BENCH_TOLERANCES,
    FAULTS,
    ROUTES,
    BenchConfig,
    BenchRoute,
    ParameterMonitoring,
    RouteInputs,
    bench_cases,
    commissioned_route,
    healthy_blocks,
    nominal_route,
    route_named,
    run_bench,
    settled,
    tolerance_route,
)
from chatterspec.plants.models import eha_linear
from chatterspec.plants.parameters import with_tolerances
from chatterspec.plants.signals import ZeroInput
from chatterspec.plants.simulate import simulate
from chatterspec.studies.commissioning import commission
from chatterspec.studies.tolerance_study import chirp_scenario

CASES = {c.name: c for c in bench_cases()}
#: A minute of healthy data, one onset per fault; the frame rule, whose threshold at the budget is exact
#: (the CUSUM's is read from hours of simulated healthy data: seconds of CPU per model).
TINY = BenchConfig(hours=1 / 60, runs_per_phase=1, phases=(0.0,), recorded_hours=0.0, rule="frame")


def test_the_cases() -> None:
    names = list(CASES)
    assert len(names) == len(set(names)) == 24
    params = [c for c in CASES.values() if c.group == "parametric"]
    assert len(params) == 12  # 3 parameters and all three, at 3, 10, 30 %
    m = eha_linear()
    plant = CASES["bulk_modulus-10"].plant(m)
    assert plant.parameter_map.parameter("bulk_modulus").value == pytest.approx(0.9 * 2.07e8)
    assert np.all(plant.R == 0)  # the sensor chain adds the noise
    leak = CASES["friction+30"].faulty(m, FAULTS[0])
    assert leak.parameter_map.parameter("leakage").value == 3e-11
    assert leak.parameter_map.parameter("friction").value == pytest.approx(1.3 * 2144.0)


def test_streams_do_not_depend_on_the_block_length() -> None:
    # the plant's and the AR(1) sensor's states carry over blocks: 20 s in blocks of 5 s or 20 s agree
    m = eha_linear()
    a = np.concatenate([z for _, z, _ in healthy_blocks(CASES["ar1-0.9"], m, 20.0, 5.0, seed=3)])
    b = np.concatenate([z for _, z, _ in healthy_blocks(CASES["ar1-0.9"], m, 20.0, 20.0, seed=3)])
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=0.0)
    assert a.shape == (20_001, 3)


def _fit_unchecked(nominal, z, u):
    # the real commissioning without its held-out check (whose alarm calibration costs seconds)
    return commission(nominal, z, u, check=False)


def test_tiny_bench_every_route() -> None:
    calls: list[int] = []

    def fit(nominal, z, u):
        calls.append(z.shape[0])
        return _fit_unchecked(nominal, z, u)

    def broken(inputs):
        raise ParameterError("no such thing in this model file")

    routes = [
        nominal_route(),
        commissioned_route(fit),
        tolerance_route(),
        tolerance_route(fit=fit),
        BenchRoute("broken", "a broken route", broken),
    ]
    cfg = dataclasses.replace(TINY, hours=3 / 60, block_s=20.0)  # three pushes: a stream can stop early
    res = run_bench(routes, [CASES["exact"], CASES["bulk_modulus-30"]], cfg, progress=False)
    # one commissioning per case, shared by the routes that use it: 10 minutes at 1 kHz (0, dt, ..., 600 s)
    assert calls == [600_001, 600_001]
    exact, bulk = res.cases
    a, b, c, bc, broke = exact.routes
    # the matched plant: no false alarm in three minutes, every fault onset detected; the spectral monitors
    # within 0.5 s, the parameters' decision once a whole 1 s identification window follows the onset
    assert all(r.starts == 0 and r.holds for r in (a, b, c, bc))
    for r, most in ((a, 0.5), (b, 0.5), (c, 1.2), (bc, 1.2)):
        assert all(f.detected == f.runs == 1 and f.median_s <= most for f in r.faults), r.route
    assert broke.note == "not run: no such thing in this model file" and broke.faults == ()
    # a 30 % bulk-modulus error: the nominal model alarms at once and for good (its stream stops once
    # that is settled); so does its decision with tolerances (30 % is outside the +-15 % band: for it,
    # a fault); the commissioned model reads the plant's bulk modulus and holds, with tolerances or not
    na, nb, nc, nbc, _ = bulk.routes
    for r in (na, nc):
        assert r.starts >= 1 and not r.holds and r.hours < r.planned_hours, r.route
        assert all(f.onsets_preceded == f.runs for f in r.faults), r.route
    assert nb.holds and nbc.holds and all(f.detected == f.runs for f in nb.faults + nbc.faults)
    # 400 s of chirp give the estimate to about 0.01 % (one standard error): 1 % is far outside chance
    fitted = nbc.details["commissioned"]["bulk_modulus"]
    assert fitted == pytest.approx(0.7 * 2.07e8, rel=0.01)
    assert nbc.details["tolerances"] == nc.details["tolerances"] == dict(BENCH_TOLERANCES)
    assert "commissioned" not in nc.details
    doc = res.to_dict()
    assert doc["cases"][0]["routes"][0]["count_interval_99"] == [0, 0]
    table = res.table()
    # no start in 0.05 h: the 99 % Poisson interval of the rate is [0, 5.30 / 0.05 h]
    row = "| the nominal model itself | (a) nominal model | 0 [0, 106] (0 in 0.05 h) | 1/1 [0.01, 1.00], "
    assert row in table
    assert "| (c) nominal + tolerances | 0 [0, 106] (0 in 0.05 h) |" in table
    assert "| (a) nominal model | 180 [0.9, 1.34e+03] (1 in the first 0.00556 of 0.05 h)" in table


def test_a_refused_commissioning_is_the_routes_note() -> None:
    # AR(1) sensor noise (rho 0.9) makes the pressure chattering's lag-1 autocovariance positive, which
    # white noise cannot: commissioning refuses to fit R, and the routes that use it say why
    cfg = dataclasses.replace(TINY, hours=1 / 120)
    routes = [commissioned_route(), route_named("commissioned-tolerances")]
    res = run_bench(routes, [CASES["ar1-0.9"]], cfg, progress=False)
    for r in res.cases[0].routes:
        assert r.note.startswith("not run: commissioning refused: the fitted R is not positive definite")
        assert not r.holds and r.faults == ()


def test_a_commissioning_that_fails_its_check_is_refused() -> None:
    failures = ["pressure: the chattering is correlated beyond lag 1 (portmanteau 66.2, p = 7.6e-07)"]
    failed = SimpleNamespace(adequate=False, check=SimpleNamespace(failures=lambda: failures))
    block = (np.zeros(2), np.zeros((2, 3)), np.zeros((2, 1)))  # (t, z, u): the stub ignores them
    inputs = RouteInputs(eha_linear(), CASES["adc12"], TINY, lambda duration_s, seed: iter([block]))
    with pytest.raises(CommissioningError, match="refused: not adequate on the held-out data: pressure: the"):
        commissioned_route(lambda m, z, u: failed).prepare(inputs)


def test_parameter_monitoring_online_and_on_records_agree() -> None:
    # the bench counts route (c)'s false alarms with the online decision and scores its onsets on whole
    # records: on the same data (a bulk-modulus drop of 25 % at 20 s) both give the same alarm
    model = with_tolerances(eha_linear(), dict(BENCH_TOLERANCES))
    mon = ParameterMonitoring.of(model, MonitorSettings().stft, "cusum", 1 / 24, {})
    sim = simulate(chirp_scenario("drop", 30.0, None, {"bulk_modulus": 0.75 * 2.07e8}, 20.0), 2, 0)
    scored = mon.onsets(sim.z, sim.u, sim.t, (20.0, 30.0))
    # the first window wholly after the onset ends 1 s (and a sample) after it
    np.testing.assert_allclose(scored.delays, 1.001, atol=1e-9)
    assert scored.false_starts == scored.preceded == 0
    for r in range(2):
        online = mon.counter()
        for k in range(0, sim.z.shape[1], 7000):  # pushes that do not fall on the 0.2 s hops
            online.push(sim.z[r, k : k + 7000], sim.u[k : k + 7000])
        assert online.starts == 1 and online.frames == 145
        # the chirp excites every declared parameter in every window but the first (0-1 s: the pressure
        # chattering of the filter's start)
        assert online.blind == 1


def test_a_held_actuator_is_counted_as_blind_time() -> None:
    # no input: the declared parameters move nothing the chattering shows, so every identification window
    # is "not excited" and the bench counts it (a parameter decision that raises no false alarm there
    # also detects nothing); the spectrum's counter has no such state
    model = with_tolerances(eha_linear(), dict(BENCH_TOLERANCES))
    sim = simulate(dataclasses.replace(chirp_scenario("hold", 10.0), input=ZeroInput()), 1, 0)
    mon = ParameterMonitoring.of(model, MonitorSettings().stft, "cusum", 1 / 24, {})
    online = mon.counter()
    online.push(sim.z[0], sim.u)
    assert online.frames > 0 and online.blind == online.frames and online.starts == 0
    spectral = nominal_route().prepare(RouteInputs(eha_linear(), CASES["exact"], TINY, lambda d, s: iter(())))
    counter = spectral.counter()
    counter.push(sim.z[0], sim.u)
    assert counter.blind == 0 and counter.frames > 0


def test_settled() -> None:
    # 1 per day over 24 h: the 99 % interval of the count is [0, 4]
    assert settled(5, 0, 100, 0.01, 4)  # more starts than the interval allows, whatever follows
    assert not settled(4, 0, 100, 0.01, 4)
    # 300 frames in alarm in the first 1 % of the stream: more than 1 % of the whole stream's 30000
    assert settled(1, 301, 300, 0.01, 4) and not settled(1, 299, 300, 0.01, 4)


def test_routes_by_name() -> None:
    assert [route_named(n).name for n in ROUTES] == list(ROUTES)
    with pytest.raises(ParameterError, match="unknown route 'own'; known: nominal, commissioned"):
        route_named("own")


def test_config_is_validated() -> None:
    with pytest.raises(ParameterError, match="hours"):
        BenchConfig(hours=0.0)
    with pytest.raises(ParameterError, match="budget"):
        BenchConfig(budget=-1.0)
