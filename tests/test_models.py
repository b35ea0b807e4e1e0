"""Model factories: eq 30/63 second-order matrices, the EHA of eq 65/67 and Table 2."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

from chatterspec import scenario, scenario_names
from chatterspec.plants.models import (
    EHA_PARAMETERS,
    LinearModel,
    discretize,
    eha_linear,
    eha_velocity_pressure_block,
    oscillatory_mode,
    second_order,
)

P = EHA_PARAMETERS
BE = P["bulk_modulus"]


def physical_mode(L: float, a: float, be: float) -> tuple[float, float]:
    """Natural frequency (Hz) and damping of the EHA velocity-pressure block, written out by hand.

    Characteristic polynomial of [[-a/M, Ac/M], [-be Ac/V0, -be L/V0]]:
    wn^2 = be (a L + Ac^2) / (M V0), 2 zeta wn = a/M + be L/V0.
    """
    Ac, M, V0 = P["piston_area"], P["mass"], P["volume"]
    wn = math.sqrt(be * (a * L + Ac**2) / (M * V0))
    return wn / (2 * math.pi), (a / M + be * L / V0) / (2 * wn)


# physical parameters of every EHA catalogue entry (docs/design.md §5)
EHA_TRUTH = {
    "eha-healthy": {},
    "eha-leak-minor": {"leakage": 3e-11},
    "eha-leak-medium": {"leakage": 6e-11},
    "eha-leak-major": {"leakage": 9e-11},
    "eha-friction-minor": {"friction": 4000.0},
    "eha-friction-major": {"friction": 7000.0},
    "eha-bulk-50down": {"bulk_modulus": 0.5 * BE},
    "eha-bulk-25down": {"bulk_modulus": 0.75 * BE},
    "eha-bulk-25up": {"bulk_modulus": 1.25 * BE},
    "eha-bulk-50up": {"bulk_modulus": 1.5 * BE},
}


def test_eha_catalogue_is_complete() -> None:
    # the open-loop EHA catalogue (the closed-loop eha-cl-* scenarios: tests/test_closed_loop.py)
    open_loop = {n for n in scenario_names() if n.startswith("eha-") and not n.startswith("eha-cl-")}
    assert open_loop == set(EHA_TRUTH)


def test_eha_healthy_mode_is_physical() -> None:
    model = eha_linear()
    assert model.natural_frequency_hz == pytest.approx(39.07, abs=0.005)
    assert model.damping_ratio == pytest.approx(0.5936, abs=0.00005)


@pytest.mark.parametrize("name", sorted(EHA_TRUTH))
def test_eha_catalogue_modes_match_physical_formula(name: str) -> None:
    params = {"leakage": P["leakage"], "friction": P["friction"], "bulk_modulus": BE, **EHA_TRUTH[name]}
    f_hz, zeta = physical_mode(params["leakage"], params["friction"], params["bulk_modulus"])
    sc = scenario(name)
    assert sc.plant.natural_frequency_hz == pytest.approx(f_hz, rel=1e-12)
    assert sc.plant.damping_ratio == pytest.approx(zeta, rel=1e-12)
    # the filter's nominal model is always the healthy actuator
    f0, z0 = physical_mode(P["leakage"], P["friction"], BE)
    assert sc.nominal.natural_frequency_hz == pytest.approx(f0, rel=1e-12)
    assert sc.nominal.damping_ratio == pytest.approx(z0, rel=1e-12)


# Table 2 as printed: (parameters, natural frequency string, damping string).
TABLE_2 = [
    ({}, "38.9", "0.5924"),
    ({"leakage": 3e-11}, "38.43", "0.5895"),
    ({"leakage": 6e-11}, "37.88", "0.5861"),
    ({"leakage": 9e-11}, "37.32", "0.5826"),
    ({"friction": 4000.0}, "38.82", "1.1091"),
    ({"friction": 7000.0}, "38.7", "1.9484"),
    ({"bulk_modulus": 0.5 * BE}, "27.5", "0.8392"),
    ({"bulk_modulus": 0.75 * BE}, "33.69", "0.6846"),
    ({"bulk_modulus": 1.25 * BE}, "43.49", "0.5295"),
    ({"bulk_modulus": 1.5 * BE}, "47.64", "0.4830"),
]
# Entries the paper truncates instead of rounding (computed 38.4395 -> "38.43", 37.8851 -> "37.88").
TRUNCATED = {"38.43", "37.88"}


def _decimals(s: str) -> int:
    return len(s.split(".")[1])


@pytest.mark.parametrize(("params", "f_str", "z_str"), TABLE_2)
def test_table2_digits_need_flipped_leakage_sign(params: dict, f_str: str, z_str: str) -> None:
    """Table 2 is reproduced digit for digit only with leakage_sign = -1 (docs/design.md C4)."""
    mode = oscillatory_mode(eha_velocity_pressure_block(**params, leakage_sign=-1))
    f, z = mode.natural_frequency_hz, mode.damping_ratio
    df, dz = _decimals(f_str), _decimals(z_str)
    if f_str in TRUNCATED:
        assert math.floor(f * 10**df) / 10**df == pytest.approx(float(f_str), abs=1e-12)
        assert round(f, df) != pytest.approx(float(f_str), abs=1e-12)
    else:
        assert round(f, df) == pytest.approx(float(f_str), abs=1e-12)
    assert round(z, dz) == pytest.approx(float(z_str), abs=1e-12)
    # the physical sign does not reproduce the table (all rows differ, by 0.17 Hz or more)
    phys = oscillatory_mode(eha_velocity_pressure_block(**params))
    assert abs(phys.natural_frequency_hz - float(f_str)) > 0.1


def test_eha_discrete_matrices_eq67() -> None:
    m = eha_linear()
    Ts, Ac, M, V0, Dp = 1e-3, P["piston_area"], P["mass"], P["volume"], P["pump_displacement"]
    a, L = P["friction"], P["leakage"]
    expected_A = np.array(
        [
            [1.0, Ts, 0.0],
            [0.0, 1 - Ts * a / M, Ts * Ac / M],
            [0.0, -Ts * BE * Ac / V0, 1 - Ts * BE * L / V0],
        ]
    )
    np.testing.assert_allclose(m.A, expected_A, rtol=1e-14, atol=0)
    np.testing.assert_allclose(m.B[:, 0], [0.0, 0.0, Ts * BE * Dp / V0], rtol=1e-14)
    np.testing.assert_array_equal(m.C, np.eye(3))
    np.testing.assert_array_equal(m.Q, np.diag([1e-12, 1e-6, 1.0]))
    np.testing.assert_array_equal(m.R, np.diag([1e-6, 1e-6, 1e6]))


@pytest.mark.parametrize(
    ("f0", "a21", "a22", "digits"),
    [
        (10.0, -3.9478, 0.98743, (4, 5)),  # eq 63 as corrected in docs/design.md C1
        (9.0, -3.1978, 0.9887, (4, 4)),  # the matrix eq 63 actually prints
        (11.0, -4.7769, 0.9862, (4, 4)),  # section IV.B, Fig 5
    ],
)
def test_second_order_matches_paper_matrices(f0: float, a21: float, a22: float, digits: tuple) -> None:
    m = second_order(f0, 0.1)
    assert m.A[0, 0] == 1.0
    assert m.A[0, 1] == pytest.approx(1e-3, rel=1e-15)
    assert round(m.A[1, 0], digits[0]) == pytest.approx(a21, abs=1e-12)
    assert round(m.A[1, 1], digits[1]) == pytest.approx(a22, abs=1e-12)
    np.testing.assert_allclose(m.B[:, 0], [0.0, 0.1], rtol=1e-15)
    np.testing.assert_array_equal(m.C, np.eye(2))
    assert m.natural_frequency_hz == pytest.approx(f0, rel=1e-14)
    assert m.damping_ratio == pytest.approx(0.1, rel=1e-14)


def test_second_order_fig2_model() -> None:
    """Fig 2 nominal: f0 2 Hz, zeta 0, C = [1 0]; A21 = -Ts w0^2 (eq 31 prints -0.0125 = -Ts w0)."""
    m = second_order(2.0, 0.0, measure="position")
    w0 = 4 * np.pi
    np.testing.assert_allclose(m.A, [[1.0, 1e-3], [-1e-3 * w0**2, 1.0]], rtol=1e-15)
    np.testing.assert_array_equal(m.C, [[1.0, 0.0]])
    assert not m.full_measurement
    assert m.spectral_radius == pytest.approx(np.sqrt(1 + 1e-6 * w0**2), rel=1e-12)


@pytest.mark.parametrize(
    "model",
    [
        pytest.param(lambda d: second_order(10.0, 0.1, discretization=d), id="second-order"),
        pytest.param(lambda d: second_order(2.0, 0.0, measure="position", discretization=d), id="fig2"),
        pytest.param(lambda d: eha_linear(discretization=d), id="eha"),
    ],
)
def test_zoh_matches_scipy_cont2discrete(model) -> None:
    euler, zoh = model("euler"), model("zoh")
    # recover the continuous matrices from the Euler model (A = I + Ts Ac, B = Ts Bc)
    dt = euler.dt
    Ac = (euler.A - np.eye(euler.n_states)) / dt
    Bc = euler.B / dt
    Ad, Bd, *_ = scipy.signal.cont2discrete((Ac, Bc, euler.C, np.zeros((euler.n_outputs, 1))), dt, "zoh")
    np.testing.assert_allclose(zoh.A, Ad, rtol=1e-10, atol=1e-13 * np.abs(Ad).max())
    np.testing.assert_allclose(zoh.B, Bd, rtol=1e-10, atol=1e-13 * np.abs(Bd).max())


def test_discretize_methods() -> None:
    Ac = np.array([[0.0, 1.0], [-4.0, -0.4]])
    Bc = np.array([0.0, 2.0])
    A, B = discretize(Ac, Bc, 0.01, "euler")
    np.testing.assert_allclose(A, np.eye(2) + 0.01 * Ac)
    np.testing.assert_allclose(B, 0.01 * Bc[:, None])
    Az, Bz = discretize(Ac, Bc, 0.01, "zoh")
    Ad, Bd, *_ = scipy.signal.cont2discrete((Ac, Bc[:, None], np.eye(2), np.zeros((2, 1))), 0.01)
    np.testing.assert_allclose(Az, Ad, rtol=1e-12)
    np.testing.assert_allclose(Bz, Bd, rtol=1e-12, atol=1e-16)


def test_linear_model_is_frozen_and_readonly() -> None:
    m = second_order(10.0, 0.1)
    with pytest.raises(AttributeError):
        m.dt = 2e-3  # type: ignore[misc]
    with pytest.raises(ValueError, match="read-only"):
        m.A[0, 0] = 2.0
    np.testing.assert_allclose(m.C_inv, np.eye(2))
    assert m.fingerprint() == second_order(10.0, 0.1).fingerprint()
    assert m.fingerprint() != second_order(11.0, 0.1).fingerprint()


def test_linear_model_general_C() -> None:
    base = second_order(10.0, 0.1)
    C = np.array([[1.0, 0.5], [0.2, 2.0]])
    m = LinearModel(A=base.A, B=base.B, C=C, Q=base.Q, R=base.R, dt=base.dt)
    assert m.full_measurement
    np.testing.assert_allclose(m.C_inv @ C, np.eye(2), atol=1e-15)
    assert m.state_names == ("x1", "x2") and m.output_names == ("z1", "z2") and m.input_names == ("u1",)
