"""Bad input raises the specific chatterspec exception, and the message names the problem."""

from __future__ import annotations

import numpy as np
import pytest

from chatterspec import SVSF, Scenario, boundary_layer_chattering, chattering, scenario, scenario_names
from chatterspec.errors import (
    ChatterspecError,
    NonFiniteError,
    ParameterError,
    ShapeError,
    SingularMatrixError,
    UnknownScenarioError,
)
from chatterspec.plants.models import LinearModel, discretize, eha_linear, second_order
from chatterspec.plants.signals import Step

BASE = second_order(10.0, 0.1)
GOOD = {"A": BASE.A, "B": BASE.B, "C": BASE.C, "Q": BASE.Q, "R": BASE.R, "dt": 1e-3}


def _model(**changes) -> LinearModel:
    return LinearModel(**{**GOOD, **changes})


@pytest.mark.parametrize(
    ("changes", "error", "match"),
    [
        ({"A": np.ones((2, 3))}, ShapeError, "A must be square"),
        ({"A": np.ones(2)}, ShapeError, "A must have 2 dimension"),
        ({"B": np.ones((3, 1))}, ShapeError, "B must have 2 rows"),
        ({"C": np.ones((2, 3))}, ShapeError, "C must have 2 columns"),
        ({"C": np.ones((3, 2))}, ShapeError, "C has more rows"),
        ({"Q": np.eye(3)}, ShapeError, "Q must have shape"),
        ({"R": np.eye(3)}, ShapeError, "R must have shape"),
        ({"A": np.array([[1.0, np.nan], [0.0, 1.0]])}, NonFiniteError, "A contains 1 NaN/inf"),
        ({"Q": np.diag([np.inf, 1.0])}, NonFiniteError, "Q contains"),
        ({"B": np.array([0.0, np.nan])}, NonFiniteError, "B contains"),
        ({"C": np.array([[1.0, 1.0], [1.0, 1.0]])}, SingularMatrixError, "full row rank"),
        ({"Q": np.array([[1.0, 2.0], [2.0, 1.0]])}, ParameterError, "Q must be positive semi-definite"),
        ({"R": np.array([[1.0, 0.5], [0.0, 1.0]])}, ParameterError, "R must be symmetric"),
        ({"dt": 0.0}, ParameterError, "dt must be > 0"),
        ({"dt": -1e-3}, ParameterError, "dt must be > 0"),
        ({"dt": float("nan")}, ParameterError, "dt must be finite"),
    ],
)
def test_linear_model_rejects(changes: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        _model(**changes)


@pytest.mark.parametrize(
    ("call", "error", "match"),
    [
        (lambda: second_order(10.0, 0.1, dt=0.0), ParameterError, "dt"),
        (lambda: second_order(-1.0, 0.1), ParameterError, "f0_hz"),
        (lambda: second_order(10.0, -0.1), ParameterError, "zeta"),
        (lambda: second_order(10.0, 0.1, measure="velocity"), ParameterError, "measure"),
        (lambda: second_order(10.0, 0.1, discretization="tustin"), ParameterError, "discretization"),
        (lambda: eha_linear(bulk_modulus=0.0), ParameterError, "bulk_modulus"),
        (lambda: eha_linear(dt=-1e-3), ParameterError, "dt"),
        (lambda: discretize(np.eye(2), np.ones(2), -1.0), ParameterError, "dt"),
        (lambda: discretize(np.ones((2, 3)), np.ones(2), 1e-3), ShapeError, "Ac must be square"),
        (lambda: Scenario("x", BASE, Step(), 0.0), ParameterError, "duration"),
        (lambda: Scenario("x", BASE, Step(), -4.0), ParameterError, "duration"),
    ],
)
def test_factories_reject(call, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        call()


def test_singular_C_where_inverse_is_needed() -> None:
    reduced = second_order(2.0, 0.0, measure="position")
    with pytest.raises(SingularMatrixError, match="C\\^-1"):
        _ = reduced.C_inv
    near_singular = _model(C=np.array([[1.0, 1.0], [1.0, 1.0 + 1e-14]]))
    with pytest.raises(SingularMatrixError, match="singular"):
        _ = near_singular.C_inv
    with pytest.raises(SingularMatrixError, match="singular"):
        SVSF(near_singular, psi=1.0)
    # reduced-order with an unmeasured state that does not drive the measured one (Phi12 = 0)
    decoupled = _model(A=np.diag([0.9, 0.8]), C=np.array([[1.0, 0.0]]), R=np.eye(1))
    with pytest.raises(SingularMatrixError, match="Phi12"):
        SVSF(decoupled, switching="sgn")


@pytest.mark.parametrize("psi", [0.0, -1e-3, [1e-3, 0.0]])
def test_psi_must_be_positive(psi) -> None:
    with pytest.raises(ParameterError, match="psi must be > 0"):
        SVSF(BASE, psi=psi)


def test_psi_other_problems() -> None:
    with pytest.raises(ParameterError, match=r"psi .*required"):
        SVSF(BASE)
    with pytest.raises(ShapeError, match="psi must have"):
        SVSF(BASE, psi=[1.0, 2.0, 3.0])
    with pytest.raises(NonFiniteError, match="psi"):
        SVSF(BASE, psi=np.nan)
    reduced = second_order(2.0, 0.0, measure="position")
    with pytest.raises(ParameterError, match="psi_lower"):
        SVSF(reduced, psi=1e-3)
    with pytest.raises(ParameterError, match="psi must be > 0"):
        boundary_layer_chattering(np.ones((3, 2)), 0.0)


@pytest.mark.parametrize("gamma", [0.0, 1.0, -0.5, 1.5, float("nan")])
def test_gamma_must_be_in_open_unit_interval(gamma: float) -> None:
    with pytest.raises(ParameterError, match="gamma"):
        SVSF(BASE, psi=1.0, gamma=gamma)
    with pytest.raises(ParameterError, match="gamma"):
        chattering(BASE, np.zeros((10, 2)), np.zeros(10), gamma=gamma)


def test_switching_must_be_known() -> None:
    with pytest.raises(ParameterError, match="switching"):
        SVSF(BASE, psi=1.0, switching="tanh")


def test_measurements_are_checked() -> None:
    z = np.zeros((2, 50, 2))
    u = np.zeros((50, 1))
    f = SVSF(BASE, switching="sgn")
    bad = z.copy()
    bad[1, 7, 0] = np.nan
    with pytest.raises(NonFiniteError, match="z contains 1 NaN/inf"):
        f.run(bad, u)
    bad[1, 7, 0] = np.inf
    with pytest.raises(NonFiniteError, match="z contains"):
        chattering(BASE, bad, u)
    with pytest.raises(NonFiniteError, match="u contains"):
        f.run(z, np.full((50, 1), np.inf))
    with pytest.raises(ShapeError, match="must have 2 channel"):
        f.run(np.zeros((2, 50, 3)), u)
    with pytest.raises(ShapeError, match="u must have 50 samples"):
        f.run(z, np.zeros((49, 1)))
    with pytest.raises(ShapeError, match="z must have 2 or 3"):
        f.run(np.zeros(50), u)
    with pytest.raises(ShapeError, match="at least 2 samples"):
        f.run(z[:, :1], u[:1])
    state = f.initialize(z[:, 0])
    with pytest.raises(ShapeError, match="z must have shape"):
        f.update(state, np.zeros((3, 5, 2)), np.zeros((5, 1)))
    with pytest.raises(ShapeError, match="u must have shape"):
        f.update(state, np.zeros((2, 5, 2)), np.zeros((4, 1)))
    with pytest.raises(ShapeError, match="z0 must have 2 channel"):
        f.initialize(np.zeros((2, 3)))
    with pytest.raises(ShapeError, match="x0 must have shape"):
        f.run(z, u, x0=np.zeros(3))


def test_unknown_scenario_lists_names() -> None:
    with pytest.raises(UnknownScenarioError, match="unknown scenario 'nope'") as info:
        scenario("nope")
    for name in scenario_names():
        assert name in str(info.value)
    with pytest.raises(UnknownScenarioError):
        scenario(None)  # type: ignore[arg-type]


def test_simulation_arguments() -> None:
    from chatterspec import simulate

    sc = scenario("so-healthy-low")
    for runs in (0, -1, 1.5, True):
        with pytest.raises(ParameterError, match="runs"):
            simulate(sc, runs=runs)
    with pytest.raises(ParameterError, match="seed"):
        simulate(sc, 1, seed=-3)
    with pytest.raises(ParameterError, match="chunk_runs"):
        simulate(sc, 2, 0, chunk_runs=0)


def test_all_errors_are_value_errors() -> None:
    for err in (ShapeError, NonFiniteError, ParameterError, SingularMatrixError, UnknownScenarioError):
        assert issubclass(err, ChatterspecError) and issubclass(err, ValueError)
