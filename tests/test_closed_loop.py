"""The closed loop's pieces: PID step, references and dither, stability and gain design, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec.errors import ParameterError, UnstableLoopError
from chatterspec.plants.closed_loop import (
    PRBS,
    PRBS_TAPS,
    ClosedLoop,
    Hold,
    Multisine,
    PIDController,
    SCurve,
    StepSequence,
    check_closed_loop,
    closed_loop_matrix,
    design_pi,
    is_stable,
    loop_mode,
    pid_coefficients,
    pid_step,
    rigid_body_gain,
    spectral_radius,
    stable_gain_ranges,
)
from chatterspec.plants.eha4 import eha4
from chatterspec.plants.models import EHA_PARAMETERS, eha_linear
from chatterspec.plants.scenarios import CLOSED_LOOP_NAMES, EHA_CL_CONTROLLER, Scenario, scenario

STEP = getattr(pid_step, "py_func", pid_step)


def _pid_by_hand(c: PIDController, dt: float, r: np.ndarray, y: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The controller law of the module docstring, written out independently (floats, no helpers)."""
    Tf = c.derivative_filter_s
    I = D = 0.0
    y_prev = y[0]
    u = np.empty(len(r))
    for k in range(len(r)):
        e = r[k] - y[k]
        D = Tf / (Tf + dt) * D - c.kd / (Tf + dt) * (y[k] - y_prev)
        v = c.kp * (c.setpoint_weight * r[k] - y[k]) + I + D + d[k]
        u[k] = min(max(v, -c.saturation), c.saturation)
        if c.anti_windup == "back-calculation":
            I = I + c.ki * dt * e + dt / c.tracking_time * (u[k] - v)
        elif not (u[k] != v and e * (v - u[k]) > 0):  # clamping: no integration into the limit
            I = I + c.ki * dt * e
        y_prev = y[k]
    return u


@pytest.mark.parametrize("anti_windup", ["back-calculation", "clamping"])
def test_pid_step_is_the_documented_law(anti_windup: str) -> None:
    c = PIDController(kp=2e4, ki=1e5, kd=30.0, saturation=50.0, anti_windup=anti_windup, setpoint_weight=0.7)
    dt = 1e-3
    rng = np.random.default_rng(0)
    r = np.where(np.arange(300) > 20, 0.01, 0.0)  # a step that saturates the command (kp r = 200 rad/s)
    y = 0.004 * np.sin(np.arange(300) * 0.05) + 1e-5 * rng.standard_normal(300)
    d = 3.0 * np.sin(np.arange(300) * 0.9)
    coef = pid_coefficients(c, dt)
    integ = deriv = 0.0
    y_prev = y[0]
    u = np.empty(300)
    for k in range(300):
        u[k], integ, deriv = STEP(*coef, integ, deriv, y_prev, r[k], y[k], d[k])
        y_prev = y[k]
    ref = _pid_by_hand(c, dt, r, y, d)
    # a few ulps: the hand formula groups the sums differently
    np.testing.assert_allclose(u, ref, rtol=1e-12, atol=1e-9)
    assert np.abs(u).max() == 50.0  # the limit was reached


@pytest.mark.parametrize("anti_windup", ["back-calculation", "clamping"])
def test_pid_setpoint_weight_away_from_saturation(anti_windup: str) -> None:
    """The law in its linear range (the limit never reached, so the reference weight ``b`` is not masked
    by the saturation): the command equals the hand-written law for every ``b``, and at the first sample
    of a reference step, where the integrator and derivative histories do not depend on ``b`` yet, two
    weights differ by the proportional term ``kp (b - b') r`` alone."""
    dt, n = 1e-3, 300
    rng = np.random.default_rng(1)
    r = np.where(np.arange(n) > 20, 2e-3, 0.0)  # kp r = 4 rad/s, far below the 1000 rad/s limit
    y = 1e-3 * np.sin(np.arange(n) * 0.05) + 1e-6 * rng.standard_normal(n)
    d = 0.3 * np.sin(np.arange(n) * 0.9)
    u = {}
    for b in (0.0, 0.4, 1.0):
        c = PIDController(kp=2e3, ki=1e4, kd=3.0, saturation=1e3, anti_windup=anti_windup, setpoint_weight=b)
        coef = pid_coefficients(c, dt)
        integ = deriv = 0.0
        y_prev = y[0]
        u[b] = np.empty(n)
        for k in range(n):
            u[b][k], integ, deriv = STEP(*coef, integ, deriv, y_prev, r[k], y[k], d[k])
            y_prev = y[k]
        assert np.abs(u[b]).max() < 0.1 * c.saturation  # never saturated
        np.testing.assert_allclose(u[b], _pid_by_hand(c, dt, r, y, d), rtol=1e-12, atol=1e-9)
    np.testing.assert_array_equal(u[0.0][:21], u[1.0][:21])  # r = 0 before the step: b does not enter
    for b in (0.0, 0.4):
        assert u[b][21] - u[1.0][21] == pytest.approx(2e3 * (b - 1.0) * 2e-3, rel=1e-9)


def test_clamping_and_back_calculation_both_stop_windup() -> None:
    """A long saturation: without anti-windup the integrator would grow to ki * e * t."""
    dt = 1e-3
    for aw in ("back-calculation", "clamping"):
        c = PIDController(kp=1e4, ki=1e5, saturation=10.0, anti_windup=aw)
        coef = pid_coefficients(c, dt)
        integ = deriv = 0.0
        for _ in range(2000):  # 2 s at a 10 mm error: kp e = 100 rad/s, 10x the limit
            u, integ, deriv = STEP(*coef, integ, deriv, 0.0, 0.01, 0.0, 0.0)
        assert u == 10.0
        assert abs(integ) < 10.0  # ki e t would be 2000 rad/s


def test_pid_vectorized_step_gives_the_scalar_bits() -> None:
    coef = pid_coefficients(EHA_CL_CONTROLLER, 1e-3)
    rng = np.random.default_rng(3)
    args = [rng.normal(0, s, 50) for s in (20.0, 1.0, 1e-3, 1e-2, 1e-3, 5.0)]  # I, D, y_prev, r, y, d
    vec = STEP(*coef, *args)
    for i in range(50):
        one = STEP(*coef, *(float(a[i]) for a in args))
        for a, b in zip(vec, one, strict=True):
            assert a[i] == b


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"saturation": 0.0}, "saturation must be > 0 rad/s"),
        ({"saturation": -5.0}, "saturation must be > 0 rad/s"),
        ({"saturation": float("nan")}, "saturation must be a finite pump speed"),
        ({"kp": -1.0}, "kp must be >= 0"),
        ({"anti_windup": "none"}, "anti_windup must be one of back-calculation, clamping"),
        ({"derivative_filter_s": 0.0}, "derivative_filter_s must be > 0"),
        ({"setpoint_weight": 1.5}, r"setpoint_weight must lie in \[0, 1\]"),
    ],
)
def test_controller_bad_input_names_the_parameter(kwargs: dict, match: str) -> None:
    base = {"kp": 1e4, "ki": 1e4, "saturation": 300.0}
    with pytest.raises(ParameterError, match=match):
        PIDController(**{**base, **kwargs})


def test_dither_above_the_saturation_is_refused_with_the_allowed_range() -> None:
    c = PIDController(kp=1e5, ki=1e5, saturation=300.0)
    with pytest.raises(ParameterError, match=r"input dither peak 360 rad/s .* must lie in \[0, 300\) rad/s"):
        ClosedLoop(c, Hold(), dither=Multisine(120.0))  # 3 tones: peak bound 360
    with pytest.raises(ParameterError, match=r"must lie in \[0, 3\) mm"):
        ClosedLoop(c, Hold(), dither=PRBS(0.004), dither_at="reference")  # kp * 4 mm = 400 rad/s
    with pytest.raises(ParameterError, match="dither_at must be"):
        ClosedLoop(c, Hold(), dither=PRBS(1.0), dither_at="output")
    ClosedLoop(c, Hold(), dither=Multisine(99.0))  # 297 < 300: accepted


def test_unstable_gains_raise_with_each_gains_stable_range() -> None:
    model = eha_linear()
    bad = EHA_CL_CONTROLLER.with_gains(kp=2e6)
    with pytest.raises(UnstableLoopError) as info:
        Scenario("x", model, ClosedLoop(bad, Hold()), 1.0)
    msg = str(info.value)
    assert "unstable on the nominal model of scenario 'x'" in msg
    assert "kp = 2e+06" in msg and "stable for" in msg
    ranges = stable_gain_ranges(model, bad)
    lo, hi = ranges["kp"][0]
    assert f"{lo:.4g} < kp < {hi:.4g}" in msg
    # the edges are the stability boundary: just inside stable, just outside not
    for edge, inside, outside in ((hi, 0.999, 1.001), (lo, 1.001, 0.999)):
        assert is_stable(model, bad.with_gains(kp=edge * inside))
        assert not is_stable(model, bad.with_gains(kp=edge * outside))
    assert ranges["ki"] == () and ranges["kd"] == ()  # with kp = 2e6 nothing else helps


def test_a_faulty_segment_that_the_loop_destabilizes_is_named() -> None:
    # a controller stable on the nominal EHA but not on a plant with 10x less friction
    nom = eha_linear()
    ctrl = PIDController(kp=5e5, ki=0.0, saturation=300.0)
    assert is_stable(nom, ctrl)
    weak = eha_linear(friction=0.1 * EHA_PARAMETERS["friction"])
    assert not is_stable(weak, ctrl)
    with pytest.raises(UnstableLoopError, match=r"true plant of scenario 'y' on \[0, 1\) s"):
        Scenario("y", nom, ClosedLoop(ctrl, Hold()), 1.0, plant=weak)


def test_closed_loop_matrix_is_the_loop_without_noise() -> None:
    """One step of Acl equals one step of the simulated loop's arithmetic (no saturation, r = 0)."""
    model = eha_linear()
    c = PIDController(kp=5e4, ki=3e5, kd=20.0, saturation=1e9)
    M = closed_loop_matrix(model, c)
    coef = pid_coefficients(c, model.dt)
    x = np.array([0.002, -0.01, 3e4])
    integ, d_prev, y_prev = 4.0, -1.5, 0.0021
    u, integ2, d = STEP(*coef, integ, d_prev, y_prev, 0.0, x[0], 0.0)
    s_next = M @ np.array([*x, integ, d_prev, y_prev])
    np.testing.assert_allclose(s_next, [*(model.A @ x + model.B[:, 0] * u), integ2, d, x[0]], rtol=1e-12)


def test_design_pi_places_the_rigid_body_poles() -> None:
    model = eha_linear()
    kv = rigid_body_gain(model)
    L, a, Ac, Dp = (EHA_PARAMETERS[k] for k in ("leakage", "friction", "piston_area", "pump_displacement"))
    # the continuous value Dp / (Ac + L a / Ac), to the Euler discretization's 0.5 %
    assert kv == pytest.approx(Dp / (Ac + L * a / Ac), rel=6e-3)
    c = design_pi(model, 0.5, 300.0)
    wc = 2 * np.pi * 0.5
    assert c.kp == pytest.approx(2 * wc / kv) and c.ki == pytest.approx(wc * wc / kv)
    mode = loop_mode(model, c)
    # a critically damped pair at 0.5 Hz on the integrator; the hydraulic mode (39 Hz) shifts it a little
    assert mode.damping_ratio == pytest.approx(1.0, abs=1e-6)  # real poles
    assert 0.3 < mode.natural_frequency_hz < 0.5
    assert spectral_radius(model, c) < 1
    with pytest.raises(ParameterError, match="does not integrate the input"):
        from chatterspec.plants.models import second_order

        rigid_body_gain(second_order(10.0, 0.1))


def test_eha4_design_uses_its_linearization() -> None:
    m = eha4()
    assert rigid_body_gain(m) == pytest.approx(rigid_body_gain(eha_linear()), rel=1e-3)
    check_closed_loop(m, design_pi(m, 0.5, 120.0))


def test_references_and_dither_signals() -> None:
    t = np.arange(0, 4.0, 1e-3)
    sc = SCurve((0.25, 1.25), (0.01, -0.01), 0.5)
    r = sc.sample(t)
    assert r[0] == 0 and r[t.searchsorted(0.75)] == pytest.approx(0.01) and r[-1] == pytest.approx(-0.01)
    v = np.diff(r) / 1e-3
    assert np.abs(v).max() == pytest.approx(sc.peak_velocity, rel=1e-3)  # 1.875 * 20 mm / 0.5 s
    assert np.abs(np.diff(v)).max() < 1e-3  # velocity continuous (no jump of a step)
    assert sc.peak == 0.01 and sc.moves == 2
    with pytest.raises(ParameterError, match="moves overlap"):
        SCurve((0.0, 0.3), (1.0, 0.0), 0.5)
    st = StepSequence((0.5, 1.0), (0.02, 0.0), initial=0.01)
    got = st.sample(np.array([0.0, 0.4999, 0.5, 0.999, 1.0]))
    np.testing.assert_array_equal(got, [0.01, 0.01, 0.02, 0.02, 0.0])
    with pytest.raises(ParameterError, match="increasing"):
        StepSequence((1.0, 0.5), (0.0, 1.0))
    for order in (3, 7, 10):
        bits = PRBS(1.0, order=order).bits()  # maximal length: 2^(n-1) ones in 2^n - 1 clocks,
        assert bits.sum() == 2 ** (order - 1)  # two-valued autocorrelation -1 off zero lag
        s = 2.0 * bits - 1.0
        assert all(np.dot(s, np.roll(s, k)) == -1 for k in range(1, len(s)))
    assert len(PRBS_TAPS) == 15
    ms = Multisine(2.0, (20.0, 30.0, 40.0))
    assert np.abs(ms.sample(t)).max() <= ms.peak == 6.0
    assert np.sqrt(np.mean(ms.sample(t) ** 2)) == pytest.approx(ms.rms, rel=1e-3)


def test_catalogue_scenarios_are_closed_loop_and_stable() -> None:
    for name in CLOSED_LOOP_NAMES:
        sc = scenario(name)
        assert sc.closed_loop is not None
        assert sc.describe()["closed_loop"]["controller"]["saturation"] > 0
        with pytest.raises(ParameterError, match="closed loop"):
            sc.input.sample(sc.time)  # no input signal to sample: the controller computes u
    mode = loop_mode(eha_linear(), EHA_CL_CONTROLLER)
    assert mode.damping_ratio == pytest.approx(1.0, abs=1e-6)
