"""The nonlinear 4-state EHA (SMM paper eq 4.1-4.5, corrected): physics, Jacobian, linearization, modes."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from chatterspec.errors import ParameterError
from chatterspec.plants.eha4 import EHA4_MODES, EHA4_PARAMETERS, eha4, eha4_mode_parameters
from chatterspec.plants.models import eha_linear

EPS = np.finfo(float).eps
SCALE = np.array([0.02, 0.03, 2.0, 4e5])  # typical |x| per state on the SMM scenario (m, m/s, m/s^2, Pa)


def _points(rng: np.random.Generator, k: int) -> np.ndarray:
    """States away from the sgn switching surfaces x2 = 0 and x4 = 0 (|x2| >= 1e-3, |x4| >= 1 Pa)."""
    x = rng.uniform(-1, 1, size=(k, 4)) * SCALE
    x[:, 1] = np.where(x[:, 1] >= 0, 1, -1) * np.maximum(np.abs(x[:, 1]), 1e-3)
    x[:, 3] = np.where(x[:, 3] >= 0, 1, -1) * np.maximum(np.abs(x[:, 3]), 1.0)
    return x


@pytest.mark.parametrize("mode", list(EHA4_MODES))
@pytest.mark.parametrize("dt", [1e-3, 1e-4])
def test_jacobian_equals_central_differences(mode: str, dt: float) -> None:
    """Away from the sgn surfaces f is a polynomial of degree <= 2 in each state, so central
    differences have no truncation error (the x2^2 term's third derivative is 0; the cross term
    x2 x3 is exact for a one-coordinate step). What remains is rounding: each f_i is a sum of
    terms of size <= s_i (s_i = the largest |term|), evaluated with a relative error of a few eps,
    so the difference quotient errs by at most ~ c eps s_i / h_j; we allow c = 16.
    Steps h_j = 1e-6 SCALE_j keep every sign fixed (|x2| >= 1e-3 >> h_2 = 3e-8, |x4| >= 1 >> h_4)."""
    m = eha4(mode, dt=dt)
    rng = np.random.default_rng(42)
    x = _points(rng, 50)
    u = rng.uniform(-100, 100, size=(50, 1))
    J = m.jacobian(x, u)
    assert J.shape == (50, 4, 4)
    h = 1e-6 * SCALE
    fd = np.empty_like(J)
    for j in range(4):
        e = np.zeros(4)
        e[j] = h[j]
        fd[:, :, j] = (m.transition(x + e, u) - m.transition(x - e, u)) / (2 * h[j])
    # term size bound per output: |J| |x| (linear and quadratic terms) + the input term + |f|
    term = np.abs(J) @ np.abs(x)[..., None]
    s = term[..., 0] + np.abs(m.transition(x, u)) + 1e-3 * np.abs(u) * 1e3
    tol = 16 * EPS * s[:, :, None] / h[None, None, :]
    assert np.all(np.abs(fd - J) <= tol), np.max(np.abs(fd - J) / tol)


def test_transition_is_the_euler_step_of_the_physics() -> None:
    """x3+ - x3 = T * jerk with the jerk derived independently from the force balance
    M a = A_E P - F_f(v) and the pressure dynamics (V0/be) P' = u - A_E v - L P, with
    P = (M a + F_f(v)) / A_E eliminated (docs/design.md S1-S2). Checks the two corrections."""
    p = EHA4_PARAMETERS
    A, M, V0, be, L = p["piston_area"], p["mass"], p["volume"], p["bulk_modulus"], p["leakage"]
    a1, a2, a3, Dp, QL0 = p["a1"], p["a2"], p["a3"], p["pump_displacement"], p["flow_offset"]
    T = 1e-3
    m = eha4(dt=T)
    rng = np.random.default_rng(3)
    x = _points(rng, 20)
    w = rng.uniform(-100, 100, size=(20, 1))
    v, a = x[:, 1], x[:, 2]
    Ff = a2 * v + (a1 * v**2 + a3) * np.sign(v)
    dFf = (a2 + 2 * a1 * np.abs(v)) * a  # d/dt F_f
    P = (M * a + Ff) / A
    flow = Dp * w[:, 0] - np.sign(x[:, 3]) * QL0
    Pdot = be / V0 * (flow - A * v - L * P)
    jerk = (A * Pdot - dFf) / M
    nxt = m.transition(x, w)
    np.testing.assert_allclose((nxt[:, 2] - a) / T, jerk, rtol=1e-9, atol=1e-9 * np.abs(jerk).max())
    np.testing.assert_allclose(nxt[:, 3], P, rtol=1e-13)  # (4.4): force balance at (x2(k), x3(k))
    np.testing.assert_allclose(nxt[:, 0], x[:, 0] + T * x[:, 1], rtol=1e-15)
    np.testing.assert_allclose(nxt[:, 1], x[:, 1] + T * x[:, 2], rtol=1e-15)


def test_linearization_at_rest_gives_the_linear_eha_mode() -> None:
    """At v = 0 (sgn 0 = 0) the velocity-acceleration block has wn^2 = (A_E^2 + a2 L) be/(M V0) and
    2 zeta wn = a2/M + be L/V0: the same characteristic polynomial as the linear EHA's
    velocity-pressure block. With the SMM paper's M = 7.376 kg and L = 4.78e-12 it is 39.08 Hz /
    0.594; the chattering paper's rounded M = 7.38 and L = 4.8e-12 give 39.07 / 0.5936 (relative
    differences 2.6e-4 and 2.7e-4, from M alone about sqrt(7.38/7.376) - 1 = 2.7e-4)."""
    m = eha4()
    assert round(m.natural_frequency_hz, 2) == 39.08
    assert round(m.damping_ratio, 3) == 0.594
    same = eha_linear(leakage=4.78e-12, mass=7.376)
    assert m.natural_frequency_hz == pytest.approx(same.natural_frequency_hz, rel=1e-12)
    assert m.damping_ratio == pytest.approx(same.damping_ratio, rel=1e-12)
    rounded = eha_linear()
    assert rounded.natural_frequency_hz == pytest.approx(39.07, abs=0.005)
    assert m.natural_frequency_hz / rounded.natural_frequency_hz - 1 == pytest.approx(2.6e-4, abs=0.2e-4)
    # the whole spectrum: Euler eigenvalues 1 + dt eig(Ac) of the (pos, vel, acc) block equal the
    # linear EHA's (pos, vel, pressure) ones -- the same system in other coordinates
    lin = m.linearize()
    ev4 = np.sort_complex(np.linalg.eigvals(lin.A[:3, :3]))
    ev3 = np.sort_complex(np.linalg.eigvals(same.A))
    np.testing.assert_allclose(ev4, ev3, rtol=1e-12)
    # input gain: T A_E be D_p / (M V0) on the acceleration, nothing else
    want = 1e-3 * 1.52e-3 * 2.07e8 * 5.57e-7 / (7.376 * 1.08e-3)
    np.testing.assert_allclose(lin.B[:, 0], [0, 0, want, 0], rtol=1e-14)
    # x4 is algebraic: its column of the Jacobian is zero
    np.testing.assert_array_equal(lin.A[:, 3], 0.0)


def test_modes_and_swapped_imm_labels() -> None:
    minor, major = eha4_mode_parameters("leak-minor"), eha4_mode_parameters("leak-major")
    assert (minor["leakage"], minor["flow_offset"]) == (2.52e-11, 1.38e-5)  # SMM Table 3 minor
    assert (major["leakage"], major["flow_offset"]) == (6.01e-11, 1.47e-5)
    fmaj, fmin = eha4_mode_parameters("friction-imm-major"), eha4_mode_parameters("friction-imm-minor")
    assert (fmaj["a1"], fmaj["a2"], fmaj["a3"]) == (1.162e6, -7440.0, 500.0)
    assert (fmin["a1"], fmin["a2"], fmin["a3"]) == (4.462e6, 1.863e4, 551.0)

    # the IMM "minor" friction row gives the larger friction force at every speed (labels swapped)
    def force(q: dict[str, float], v: np.ndarray) -> np.ndarray:
        return q["a2"] * v + q["a1"] * v**2 + q["a3"]

    v = np.linspace(1e-4, 0.1, 200)
    assert np.all(force(fmin, v) > force(fmaj, v))
    # the "major" row has negative viscous friction: locally unstable at rest (negative damping)
    assert eha4("friction-imm-major").damping_ratio < 0
    # leakage faults shift the one-step acceleration by T A_E be/(M V0) dQ_L0 (note 2.3: 0.450, 0.485)
    x = np.array([[0.0, 0.0, 0.0, 1e5]])  # at rest only the flow offset differs
    d_minor = eha4().transition(x, np.zeros(1)) - eha4("leak-minor").transition(x, np.zeros(1))
    d_major = eha4().transition(x, np.zeros(1)) - eha4("leak-major").transition(x, np.zeros(1))
    assert d_minor[0, 2] == pytest.approx(0.450, abs=0.002)
    assert d_major[0, 2] == pytest.approx(0.485, abs=0.002)


def test_measurement_options_and_defaults() -> None:
    full = eha4()
    np.testing.assert_array_equal(full.C, np.eye(4))
    np.testing.assert_array_equal(full.Q, 1e-9 * np.eye(4))
    np.testing.assert_array_equal(full.R, 1e-6 * np.eye(4))
    pp = eha4(measure="position-pressure", dt=1e-4, R=np.diag([1e-14, 4e4]))
    np.testing.assert_array_equal(pp.C, [[1, 0, 0, 0], [0, 0, 0, 1]])
    assert pp.output_names == ("position", "pressure") and pp.output_units == ("m", "Pa")
    assert pp.dt == 1e-4 and not pp.full_measurement
    q = pickle.loads(pickle.dumps(pp))
    assert q.fingerprint() == pp.fingerprint() != full.fingerprint()
    assert eha4(leakage=1e-11).parameters["leakage"] == 1e-11


def test_bad_input() -> None:
    with pytest.raises(ParameterError, match="unknown EHA4 mode"):
        eha4("leak-medium")
    with pytest.raises(TypeError, match="unexpected keyword"):
        eha4(leak=1e-11)
    with pytest.raises(ParameterError, match="mass"):
        eha4(mass=-1.0)
    with pytest.raises(ParameterError, match="leakage"):
        eha4(leakage=-1e-12)
    with pytest.raises(ParameterError, match="measure"):
        eha4(measure="position")
    with pytest.raises(ParameterError, match="dt"):
        eha4(dt=0)
