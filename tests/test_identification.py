"""Fault identification: estimates in physical units, intervals, isolation, bad input.

Statistical checks use fixed seeds and binomial / chi-squared tolerances at a two-sided level
of 1e-3 (each says why); the long validation over >= 500 runs per catalogue fault is
``scripts/identification_study.py`` (numbers in ``docs/paper-notes.md``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from chatterspec.detection.identification import (
    NO_FAULT,
    IdentificationStream,
    OnlineIdentifier,
    identification_setup,
    identify,
    true_hypothesis,
    true_parameters,
)
from chatterspec.detection.pipeline import iter_chattering
from chatterspec.errors import IdentifiabilityError, ParameterError
from chatterspec.online.identification_monitor import IdentificationUpdate
from chatterspec.plants.models import eha_linear, second_order
from chatterspec.plants.parameters import MatrixEntry, ParameterMap, PhysicalParameter
from chatterspec.plants.scenarios import Scenario, Segment, scenario
from chatterspec.plants.signals import Chirp, Constant
from chatterspec.plants.simulate import simulate

LEVEL = 1e-3  # two-sided level of every statistical check below


def _stream(name: str, runs: int, seed: int, **kw: object) -> tuple[object, object, object]:
    sc = scenario(name)
    setup = identification_setup(sc.nominal)
    st = IdentificationStream(setup, **kw)
    for _ in st.tap(iter_chattering(sc, runs, seed, chunk_runs=128, measurements=True)):
        pass
    return sc, setup, st


@pytest.mark.parametrize("name", ["eha-leak-minor", "eha-friction-major", "eha-bulk-25down"])
def test_estimate_interval_and_isolation_on_catalogue_faults(name: str) -> None:
    runs = 300
    sc, setup, st = _stream(name, runs, 3)
    idn = st.result()
    truth = true_hypothesis(setup, sc.segments[0].model)
    assert truth == {"eha-leak-minor": "leakage", "eha-friction-major": "friction"}.get(name, "bulk_modulus")
    true_value = true_parameters(setup, sc.segments[0].model)[truth][0]
    est = idn.estimate(truth)
    lo, hi = idn.interval(truth)
    h = idn.hypothesis_names.index(truth)
    se = idn.fit["se"][:, h, 0]
    # unbiased: the mean of 300 estimates within a z-quantile of the truth (SE of the mean from the
    # reported standard errors)
    z = (est.mean() - true_value) / (np.sqrt(np.mean(se**2)) / np.sqrt(runs))
    assert abs(z) < stats.norm.isf(LEVEL / 2), z
    # the reported standard error is the spread of the estimates: (n-1) s^2 / sigma^2 ~ chi2(n-1)
    ratio = (runs - 1) * est.var(ddof=1) / np.mean(se**2)
    assert stats.chi2.ppf(LEVEL / 2, runs - 1) < ratio < stats.chi2.isf(LEVEL / 2, runs - 1)
    # 95 % intervals: the number holding the true value is Binomial(300, 0.95)
    k = int(np.sum((lo <= true_value) & (true_value <= hi)))
    assert stats.binomtest(k, runs, 0.95).pvalue > LEVEL, k
    # isolation: the true hypothesis is rejected at alpha = 1e-3 only by chance, so selecting it
    # in fewer runs than the binomial quantile of a 99 % rate would contradict the target
    picked = sum(s == truth for s in idn.selected)
    assert picked >= stats.binom.ppf(LEVEL, runs, 0.99), picked
    # median relative error well inside the 10 % target
    assert np.median(np.abs(est - true_value) / true_value) < 0.1


def test_healthy_records_select_no_fault_at_the_test_level() -> None:
    runs = 2000
    # alpha = 0.05: 100 expected rejections make the level testable with 2000 runs; the no-fault
    # Wald statistic is chi2 with 4 dof, so the count is Binomial(2000, 0.05)
    _, _, st = _stream("eha-healthy", runs, 11, alpha=0.05)
    sel = st.result().selected
    k = sum(s != NO_FAULT for s in sel)
    assert stats.binomtest(k, runs, 0.05).pvalue > LEVEL, k


def test_instrumental_variables_remove_the_errors_in_variables_bias() -> None:
    """Plain least squares of the pressure chattering on x(k) = (z2, z3, u)(k) is biased: the noise of
    z(k) is also in eta(k+1), E[x eta3] = (-Phi32 R22, -Phi33 R33, 0). The IV estimate is not."""
    sc = scenario("eha-healthy")
    runs = 200
    sim = simulate(sc, runs, 5)
    A, B, R = sc.nominal.A, sc.nominal.B, sc.nominal.R
    e3 = sim.z[:, 2:, 2] - sim.z[:, 1:-1] @ A[2] - sim.u[1:-1, 0] * B[2, 0]  # eq 23, C = I
    X = np.stack([sim.z[:, 1:-1, 1], sim.z[:, 1:-1, 2], np.broadcast_to(sim.u[1:-1, 0], e3.shape)], axis=-1)
    inv_xx = np.linalg.inv(np.einsum("rka,rkb->rab", X, X))
    ls = np.einsum("rab,rkb,rk->ra", inv_xx, X, e3)[:, 1]
    c = np.array([-A[2, 1] * R[1, 1], -A[2, 2] * R[2, 2], 0.0]) * e3.shape[1]
    expected_bias = np.mean(inv_xx[:, 1] @ c)
    iv = identify(sc.nominal, sim.z, sim.u).fit["entries"][:, setup_index(sc, "A[3,3]")]
    se_ls, se_iv = ls.std(ddof=1) / np.sqrt(runs), iv.std(ddof=1) / np.sqrt(runs)
    zq = stats.norm.isf(LEVEL / 2)
    assert abs(ls.mean() - expected_bias) < zq * se_ls  # the bias is there, as predicted
    assert abs(expected_bias) > 5 * zq * se_ls
    assert abs(iv.mean()) < zq * se_iv  # and gone with the instruments


def setup_index(sc: Scenario, label: str) -> int:
    return identification_setup(sc.nominal).labels.index(label)


def test_second_order_timeline_natural_frequency_within_0_2_hz() -> None:
    sc = scenario("so-timeline-constant")
    sim = simulate(sc, 20, 2)
    idn = identify(sc.nominal, sim.z, sim.u, window_s=(0.2, 1.8))  # the faulty segment, a hop inside
    f0 = idn.estimate("natural_frequency")
    assert np.all(np.abs(f0 - 8.0) < 0.2), f0
    assert all(s == "natural_frequency" for s in idn.selected)
    damp = identify(sc.nominal, sim.z, sim.u, window_s=(4.2, 5.8))
    assert all(s == "damping" for s in damp.selected)
    lo, hi = damp.interval("damping")
    # 20 intervals at 95 %: Binomial(20, 0.95) holds at least 16 of them with probability 1 - 1.6e-3
    assert np.sum((lo <= 0.1) & (0.1 <= hi)) >= stats.binom.ppf(LEVEL, 20, 0.95)


def test_same_numbers_whatever_the_chunking_and_the_fused_path_keeps_z() -> None:
    sc = scenario("eha-leak-medium")
    setup = identification_setup(sc.nominal)
    a = IdentificationStream(setup)
    b = IdentificationStream(setup)
    recs = list(a.tap(iter_chattering(sc, 70, 4, chunk_runs=70, measurements=True)))
    list(b.tap(iter_chattering(sc, 70, 4, chunk_runs=16, measurements=True)))
    assert np.array_equal(a.result().fit["theta"], b.result().fit["theta"], equal_nan=True)
    c = IdentificationStream(setup)  # on a worker thread, one reused measurement buffer: same numbers
    chunks = iter_chattering(sc, 70, 4, chunk_runs=16, measurements=True, reuse_measurements=True)
    list(c.tap(chunks, background=True))
    assert np.array_equal(a.result().fit["theta"], c.result().fit["theta"], equal_nan=True)
    sim = simulate(sc, 70, 4)
    assert np.array_equal(recs[0].z, sim.z)  # the measurements the fused kernel writes are the simulation's
    direct = identify(sc.nominal, sim.z, sim.u)
    assert np.allclose(direct.fit["theta"], a.result().fit["theta"], rtol=1e-9, equal_nan=True)


def test_online_identifier_matches_batch_and_ignores_push_sizes() -> None:
    nominal = eha_linear()
    sc = Scenario(
        name="onset",
        nominal=nominal,
        input=Chirp(10.0, 100.0, 6.0, 300.0),
        duration=6.0,
        windows=(Segment(3.0, 6.0, eha_linear(leakage=6e-11)),),
    )
    sim = simulate(sc, 1, 1)
    setup = identification_setup(nominal)
    out = {}
    for size in (1, 137, 6001):
        oi = OnlineIdentifier(setup, hop_samples=200, window_hops=5)
        reps = []
        for lo in range(0, 6001, size):
            o = oi.push(sim.z[0, lo : lo + size], sim.u[lo : lo + size])
            reps += [o.report(i) for i in range(o.n_windows)]
        out[size] = reps
    assert len(out[1]) == len(out[6001]) == 25
    assert all(x.to_dict() == y.to_dict() for x, y in zip(out[1], out[137], strict=True))
    assert all(x.to_dict() == y.to_dict() for x, y in zip(out[1], out[6001], strict=True))
    last = out[1][-1]
    batch = identify(nominal, sim.z, sim.u, window_s=last.window_s).report(0)
    assert batch.to_dict()["hypotheses"] == last.to_dict()["hypotheses"]
    assert last.selected == "leakage" and out[1][0].selected == NO_FAULT


@pytest.mark.parametrize("hops", [None, 1, 2, 7])
def test_file_replay_identifies_ahead_with_each_pushs_windows(hops: int | None, monkeypatch) -> None:  # type: ignore[no-untyped-def]
    """An unpaced file replay identifies several pushes' windows in one batch and hands each push the
    windows it completes: the same windows per push and the same numbers, to the bit, as identifying push
    by push (a paced replay of the same pushes). Pushes of one hop complete one window each (fitted alone
    again: a single window's fit takes other array layouts); batches of 8 hops or more end inside the
    record. ``None``: the default pushes (5 hops here)."""
    from chatterspec.detection.parameter_decision import parameter_alarm_settings
    from chatterspec.online.identification_monitor import IdentificationMonitor
    from chatterspec.online.monitor import ChatteringMonitor, MonitorSettings
    from chatterspec.plants.datafile import load_data
    from chatterspec.plants.modelfile import load_model
    from chatterspec.viewer import recordings
    from chatterspec.viewer.sinks import open_sinks

    examples = Path(__file__).resolve().parents[1] / "examples"
    spec = load_model(examples / "eha_model.toml")
    data = load_data(examples / "eha_data.csv", spec.model)
    setup = identification_setup(spec.model)
    monkeypatch.setattr(recordings, "UNPACED_HOPS", 5)
    monkeypatch.setattr(recordings, "IDENTIFY_AHEAD_HOPS", 8)
    monkeypatch.setattr(recordings, "_pace", lambda *a: None)  # (a paced replay without the waiting)

    def replay(rate: float | None) -> list[IdentificationUpdate]:
        mon = ChatteringMonitor(spec.model, MonitorSettings(), t0=float(data.t[0]))
        ident = IdentificationMonitor(
            setup,
            parameter_alarm_settings(setup, hop_s=mon.n_hop * mon.dt, window_hops=5),
            t0=float(data.t[0]),
            frame_samples=mon.n_window,
        )
        got: list[IdentificationUpdate] = []
        # a paced replay pushes what an unpaced one does (its default: one hop)
        chunk = (5 if hops is None else hops) * mon.n_hop if rate is not None or hops is not None else None
        recordings.run_monitor(
            mon,
            open_sinks(),
            z=data.z,
            u=data.u,
            chunk_samples=chunk,
            rate=rate,
            identifier=ident,
            on_identification=got.append,
        )
        return got

    ahead, pushes = replay(None), replay(1.0)
    assert len(ahead) == len(pushes) > 4
    assert sum(u.found.n_windows for u in ahead) > 20  # more than one batch
    for a, b in zip(ahead, pushes, strict=True):
        np.testing.assert_array_equal(a.found.frames, b.found.frames)
        assert [(w.label, w.states, w.channel_states) for w in a.windows] == [
            (w.label, w.states, w.channel_states) for w in b.windows
        ]
        for k in ("estimate", "std_error", "ci_low", "ci_high", "score", "detectable"):
            np.testing.assert_array_equal(getattr(a.block, k), getattr(b.block, k), err_msg=k)
        if a.found.result is not None and b.found.result is not None:
            for k, v in a.found.result.fit.items():
                np.testing.assert_array_equal(v, b.found.result.fit[k], err_msg=k)


def test_report_table_and_json() -> None:
    sc = scenario("eha-leak-major")
    sim = simulate(sc, 1, 0)
    rep = identify(sc.nominal, sim.z, sim.u).report(0)
    d = rep.to_dict()
    assert d["selected"] == "leakage"
    rows = {r["hypothesis"]: r for r in d["hypotheses"]}
    assert rows[NO_FAULT]["parameter"] is None and not rows[NO_FAULT]["fits"]
    leak = rows["leakage"]
    assert set(leak) >= {"parameter", "estimate", "ci_low", "ci_high", "unit", "p_value", "statistic"}
    assert leak["unit"] == "m^3/(s Pa)" and leak["ci_low"] < 9e-11 < leak["ci_high"]
    assert "<- selected" in rep.table() and "leakage" in repr(rep)


@pytest.mark.parametrize("confidence", [0.95, 0.8])
def test_report_intervals_are_the_wald_intervals_at_the_confidence(confidence: float) -> None:
    """The report (``detect --json``, the monitor's lines) gives each estimate +- the two-sided normal
    quantile times its standard error, the same numbers as :meth:`Identification.interval` (a 90 %
    quantile, 1.645, under a 95 % label would be a narrower interval than promised)."""
    sc = scenario("eha-leak-major")
    sim = simulate(sc, 1, 0)
    idn = identify(sc.nominal, sim.z, sim.u, confidence=confidence)
    rep = idn.report(0)
    z = stats.norm.ppf(0.5 + confidence / 2)
    finite = [e for e in rep.estimates if np.isfinite(e.estimate)]
    assert finite
    for e in finite:
        assert e.confidence == confidence
        assert e.ci_low == pytest.approx(e.estimate - z * e.std_error, rel=1e-12)
        assert e.ci_high == pytest.approx(e.estimate + z * e.std_error, rel=1e-12)
        lo, hi = idn.interval(e.hypothesis, e.parameter)
        assert (e.ci_low, e.ci_high) == pytest.approx((lo[0], hi[0]), rel=1e-12)


# --------------------------------------------------------------------------- bad input
def test_reduced_order_measurement_says_what_cannot_be_identified() -> None:
    model = scenario("so-boundary-layer").nominal
    with pytest.raises(IdentifiabilityError, match="every state measured") as err:
        identification_setup(model)
    assert "unmeasured velocity" in str(err.value)


def test_model_without_parameter_map_or_nonlinear_is_refused() -> None:
    with pytest.raises(IdentifiabilityError, match="declares no physical parameters"):
        identification_setup(eha_linear(discretization="zoh"))
    with pytest.raises(IdentifiabilityError, match="nonlinear"):
        identification_setup(scenario("eha4-healthy").nominal)


def test_hypothesis_naming_an_unknown_parameter() -> None:
    with pytest.raises(ParameterError, match="does not have; its parameters: leakage, friction, bulk_mod"):
        identification_setup(eha_linear(), [["leakage", "viscosity"]])


def test_regressor_without_excitation_gives_no_estimate() -> None:
    """A parameter that enters only B, with the input identically zero: no estimate, and why."""
    base = eha_linear()
    pm = ParameterMap(
        (PhysicalParameter("pump_displacement", 5.57e-7, "m^3/rad"), PhysicalParameter("leakage", 4.8e-12)),
        (
            MatrixEntry("B", 2, 0, _formula("dt*bulk_modulus*pump_displacement/volume")),
            MatrixEntry("A", 2, 2, _formula("1 - dt*bulk_modulus*leakage/volume")),
        ),
        {"bulk_modulus": 2.07e8, "volume": 1.08e-3},
    )
    model = base.replace(parameter_map=pm)
    sc = Scenario(name="still", nominal=model, input=Constant(0.0), duration=1.0)
    sim = simulate(sc, 3, 0)
    rep = identify(model, sim.z, sim.u).report(0)
    pump = rep.estimate("pump_displacement")[0]
    assert np.isnan(pump.estimate) and "no excitation" in pump.reason
    assert "no excitation" in rep.table()


def test_window_too_short_and_formula_mismatch() -> None:
    sc = scenario("eha-leak-major")
    sim = simulate(sc, 1, 0)
    with pytest.raises(ParameterError, match="needs at least 2"):
        identify(sc.nominal, sim.z, sim.u, window_s=(1.0, 1.001))
    wrong = eha_linear().replace(parameter_map=eha_linear(friction=3000.0).parameter_map)
    with pytest.raises(ParameterError, match=r"A\[2,2\]"):
        identification_setup(wrong)


def _formula(text: str) -> object:
    from chatterspec.plants.parameters import compile_formula

    return compile_formula(text)


@pytest.mark.parametrize(
    "text", ["__import__('os')", "x.real", "[1, 2]", "a if b else c", "sqrt(x, 2)", "1 < 2", "'s'"]
)
def test_formulas_refuse_anything_but_arithmetic(text: str) -> None:
    with pytest.raises(ParameterError):
        _formula(text)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0*10**10**10", "overflows"),  # a big-integer power ran for ever (no output, no end)
        ("9**9**9**9", "overflows"),
        ("x + " * 300 + "1", "at most 1000 characters"),
        ("(" * 500 + "x" + ")" * 500, "at most 1000 characters"),
    ],
)
def test_formulas_are_bounded_in_time_and_size(text: str, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        _formula(text)({"x": 1.0})


def test_integer_literals_evaluate_as_the_same_floats() -> None:
    values = {"dt": 1e-3, "friction": 2144.0, "mass": 7.38}
    assert _formula("1 - dt*friction/mass")(values) == 1 - 1e-3 * 2144.0 / 7.38
    assert _formula("2**3 - 7/2")({}) == 4.5 and _formula("mass**2")(values) == 7.38**2


def test_second_order_map_reproduces_the_factory() -> None:
    for zeta in (0.0, 0.1):
        m = second_order(10.0, zeta)
        m.parameter_map.check(m)
        other = second_order(12.0, zeta)
        setup = identification_setup(m)
        assert true_hypothesis(setup, other) == "natural_frequency"
        assert true_parameters(setup, other)["natural_frequency"][0] == pytest.approx(12.0, rel=1e-12)


def test_collinear_regressors_give_no_estimate_and_say_why() -> None:
    """Pressure proportional to velocity (constructed data): the pressure channel's entries cannot be
    separated, so the hypotheses that move them get no estimate; friction (velocity channel) still does."""
    rng = np.random.default_rng(0)
    T = 2001
    z2 = np.cumsum(rng.standard_normal(T)) * 1e-2
    z = np.stack([np.cumsum(z2) * 1e-3, z2, 2e5 * z2], axis=-1)
    u = rng.standard_normal((T, 1))
    rep = identify(eha_linear(), z, u).report(0)
    assert "collinear" in rep.estimate("leakage")[0].reason
    assert "collinear" in rep.estimate("bulk_modulus")[0].reason
    assert np.isfinite(rep.estimate("friction")[0].estimate)


def test_models_with_parameter_maps_pickle() -> None:
    """Models travel to worker processes: the compiled formulas must pickle (rebuilt from their text)."""
    import pickle

    m = pickle.loads(pickle.dumps(eha_linear(leakage=9e-11)))
    assert np.array_equal(
        m.parameter_map.evaluate(1e-3), eha_linear(leakage=9e-11).parameter_map.evaluate(1e-3)
    )


def test_every_combination_is_a_hypothesis_and_declared_names_are_kept() -> None:
    from pathlib import Path

    from chatterspec.plants.modelfile import load_model

    model = load_model(Path(__file__).resolve().parents[1] / "examples" / "eha_model.toml").model
    names = [h.name for h in identification_setup(model).hypotheses]
    assert names == [
        "leakage",
        "friction",
        "bulk_modulus",
        "leakage+friction",  # declared in the file (same name as the generated one)
        "leakage+bulk_modulus",
        "friction+bulk_modulus",
        "leakage+friction+bulk_modulus",
    ]
    assert [h.name for h in identification_setup(model, ["leakage"]).hypotheses] == ["leakage"]
    # two parameters entering only as a product cannot be told apart: their combination is left out of
    # the default hypotheses, and refused when declared
    from chatterspec.plants.parameters import compile_formula

    so = second_order(10.0, 0.1)
    entry = MatrixEntry("A", 1, 1, compile_formula("1 - 2*dt*zeta*w", "test"))
    pm = ParameterMap((PhysicalParameter("zeta", 0.1), PhysicalParameter("w", 2 * np.pi * 10.0)), (entry,))
    model = so.replace(parameter_map=pm)
    assert [h.name for h in identification_setup(model).hypotheses] == ["zeta", "w"]
    with pytest.raises(IdentifiabilityError, match="cannot be told apart"):
        identification_setup(model, [["zeta", "w"]])


def test_parameters_with_parallel_effects_are_refused_not_inverted() -> None:
    """Two parameters that move the active entries alike leave the normal matrix singular: the fit
    refuses that realization (reason 4) instead of raising LinAlgError or returning an arbitrary split."""
    from chatterspec.detection.identification import REASONS, _separable

    parallel = np.array([[1.0, 1.0], [1.0, 1.0]])  # unit-normalized columns, identical
    apart = np.array([[1.0, 0.3], [0.3, 1.0]])
    N = np.stack([parallel, apart, parallel])
    ok = np.array([True, True, False])  # a refused row stays as it was (identity in its place)
    assert _separable(N, ok).tolist() == [False, True, True]
    assert "cannot be told apart" in REASONS[4]


def _deviations_by_entries(setup, h: int, theta: np.ndarray) -> np.ndarray:
    """The deviations read from the map's evaluation of every entry (A and B filled, then gathered)."""
    pm, model = setup.parameter_map, setup.model
    names = setup.hypotheses[h].parameters
    full = pm.evaluate(model.dt, {p: theta[..., i] for i, p in enumerate(names)}) - pm.evaluate(model.dt)
    dA = np.zeros((*theta.shape[:-1], model.n_states, model.n_states))
    dB = np.zeros((*theta.shape[:-1], model.n_states, model.n_inputs))
    for k, e in enumerate(pm.entries):
        (dA if e.matrix == "A" else dB)[..., e.row, e.col] = full[..., k]
    qj = setup.J.size
    return np.stack(
        [
            dA[..., i, setup.J[c]] if c < qj else dB[..., i, setup.L[c - qj]]
            for i, c in zip(setup.R[setup.rows], setup.cols, strict=True)
        ],
        axis=-1,
    )


def test_deviations_and_jacobian_in_one_evaluation_are_the_separate_numbers() -> None:
    # the fit evaluates only the formulas a hypothesis moves, and the Jacobian's shifted points in one
    # call: bit for bit the deviations of the whole map and the central differences one parameter at a
    # time (the joint EHA hypothesis is not affine: bulk_modulus * leakage)
    setup = identification_setup(eha_linear())
    rng = np.random.default_rng(3)
    for h in range(len(setup.hypotheses)):
        theta0 = setup.nominal(h)
        theta = theta0 * (1.0 + 0.3 * rng.standard_normal((5, theta0.size)))
        assert np.array_equal(setup.deviations(h, theta), _deviations_by_entries(setup, h, theta))
        G, g = setup.jacobian_deviations(h, theta)
        scale = np.maximum(np.abs(theta), np.abs(theta0))
        for i in range(theta0.size):
            step = np.zeros_like(theta)
            step[:, i] = 1e-6 * scale[:, i]
            col = (setup.deviations(h, theta + step) - setup.deviations(h, theta - step)) / (
                2 * step[:, i : i + 1]
            )
            assert np.array_equal(G[..., i], col)
        assert np.array_equal(g, setup.deviations(h, theta))
        assert G.flags.c_contiguous


def test_hop_blocks_are_the_gathered_blocks_without_a_copy() -> None:
    """The online identifier's blocks (rows ``start + b H .. start + (b + 1) H + 1``, two rows shared with
    the next block) are a view with the values and strides of the gathered copy they replace (the sums
    then see the same layouts, hence the same bits)."""
    from chatterspec.detection.identification import _hop_blocks

    x = np.random.default_rng(2).normal(size=(57, 3))
    for start, count, H in ((0, 5, 10), (3, 4, 12), (7, 1, 48)):
        view = _hop_blocks(x, start, count, H)
        gathered = x[start + np.arange(count)[:, None] * H + np.arange(H + 2)[None, :]]
        assert view.strides[1:] == gathered.strides[1:]
        np.testing.assert_array_equal(view, gathered)
        assert np.shares_memory(view, x) and not view.flags.writeable


def test_window_states_of_a_push_at_once() -> None:
    """The identification monitor's per-push decisions: the state names of code rows are the rows' names;
    the spectral alarm state of many frame ends at once is each end's (open alarms from their start, closed
    ones from start to end, half a sample of slack). (Its WindowDecision builder: test_monitor.py.)"""
    from chatterspec.detection.parameter_decision import STATES
    from chatterspec.online.identification_monitor import IdentificationMonitor, _state_names

    codes = np.random.default_rng(1).integers(0, len(STATES), size=(40, 3))
    assert _state_names(codes) == [tuple(STATES[k] for k in row) for row in codes.tolist()]
    assert _state_names(codes[:0]) == []

    mon = IdentificationMonitor.__new__(IdentificationMonitor)  # only the spectral alarm state is used
    mon.dt, mon.channels = 0.001, ("a", "b", "c")
    ends = np.round(np.arange(0.0, 3.0, 0.05), 9) - np.array([0.0, 0.0004, 0.0006] * 20)
    slack = 0.5 * mon.dt
    # an alarm closed exactly at a frame end plus the slack: that frame is after it
    mon._open = {"c": 2.0}
    mon._closed = [("a", 0.5, 1.0), ("a", 1.5, 1.75), ("b", 0.2, float(ends[9]) + slack)]
    want = [
        [
            any(s <= t + slack < e for ch, s, e in mon._closed if ch == c)
            or (c in mon._open and mon._open[c] <= t + slack)
            for c in mon.channels
        ]
        for t in ends.tolist()
    ]
    got = mon._spectral(ends)
    np.testing.assert_array_equal(got, np.array(want))
    assert got[:, 0].any() and got[:, 2].any() and got[8, 1] and not got[9, 1]


def test_column_norms_are_numpys_norms_to_the_bit() -> None:
    """The Gauss-Newton loop's column norms: ``np.linalg.norm(x, axis=1)``'s operations, the same bits."""
    from chatterspec.detection.identification import _column_norms

    x = np.random.default_rng(4).normal(size=(9, 7, 3)) * np.logspace(-12, 12, 3)
    assert _column_norms(x).tobytes() == np.linalg.norm(x, axis=1).tobytes()
