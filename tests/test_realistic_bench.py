"""The realistic bench on a tiny configuration: cases, streams, routes, outcomes (the numbers in the
README come from scripts/realistic_bench.py)."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.errors import ParameterError
from chatterspec.online.realistic_bench import (
    FAULTS,
    BenchConfig,
    Route,
    bench_cases,
    commissioned_route,
    healthy_blocks,
    nominal_route,
    run_bench,
)
from chatterspec.plants.models import eha_linear

CASES = {c.name: c for c in bench_cases()}
#: A minute of healthy data, one onset per fault; 4 simulated hours for the threshold (above the fit's 2.3 h).
TINY = BenchConfig(hours=1 / 60, runs_per_phase=1, phases=(0.0,), recorded_hours=0.0, calibration_hours=4.0)


def test_the_cases() -> None:
    names = list(CASES)
    assert len(names) == len(set(names)) == 23
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


def test_tiny_bench_nominal_and_a_seam() -> None:
    calls: list[int] = []

    def refit(nominal, z, u):  # the commissioning seam: here the nominal model back, unchanged
        calls.append(z.shape[0])
        return nominal

    def broken(inputs):
        raise ParameterError("no tolerances in this model file")

    routes = [nominal_route(), commissioned_route(refit), Route("tolerances", "(c) tolerances", broken)]
    res = run_bench(routes, [CASES["exact"], CASES["bulk_modulus-30"]], TINY, progress=False)
    exact, bulk = res.cases
    a, b, c = exact.routes
    # the matched plant: no false alarm in a minute, every fault onset detected within 0.5 s
    assert a.starts == 0 and a.holds and all(f.detected == f.runs == 1 for f in a.faults)
    assert all(f.median_s <= 0.5 for f in a.faults)
    assert b.starts == a.starts and calls == [
        600_001,
        600_001,
    ]  # 10 minutes at 1 kHz per case (samples at 0, dt, ..., 600 s)
    assert c.note == "not run: no tolerances in this model file" and c.faults == ()
    # a 30 % bulk-modulus error: the nominal model alarms before the first onset, and for good
    assert bulk.routes[0].starts >= 1 and not bulk.routes[0].holds
    assert all(f.onsets_preceded == f.runs for f in bulk.routes[0].faults)
    doc = res.to_dict()
    assert doc["cases"][0]["routes"][0]["count_interval_99"] == [0, 0]
    assert "| the nominal model itself | (a) nominal model | 0 in 0.0167 h" in res.table()


def test_config_is_validated() -> None:
    with pytest.raises(ParameterError, match="hours"):
        BenchConfig(hours=0.0)
    with pytest.raises(ParameterError, match="budget"):
        BenchConfig(budget=-1.0)
