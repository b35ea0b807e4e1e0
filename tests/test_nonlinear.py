"""NonlinearModel: validation, batching, linearization, Euler discretization, the linear-only guard."""

from __future__ import annotations

import pickle
from functools import partial

import numpy as np
import pytest

from chatterspec.errors import ModelKindError, NonFiniteError, ParameterError, ShapeError, SingularMatrixError
from chatterspec.plants.models import LinearModel, second_order
from chatterspec.plants.nonlinear import NonlinearModel, is_linear, require_linear


def _lin_f(x: np.ndarray, u: np.ndarray, *, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    return x @ A.T + u @ B.T


def _lin_jac(x: np.ndarray, u: np.ndarray, *, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
    return np.broadcast_to(A, shape + A.shape).copy()


def wrap(m: LinearModel, **kw: object) -> NonlinearModel:
    """A LinearModel written as a NonlinearModel (f = A x + B u)."""
    return NonlinearModel(
        f=partial(_lin_f, A=m.A, B=m.B),
        jac=partial(_lin_jac, A=m.A, B=m.B),
        C=m.C,
        Q=m.Q,
        R=m.R,
        dt=m.dt,
        n_inputs=m.n_inputs,
        **kw,
    )


# pendulum-like continuous dynamics for the Euler tests: x1' = x2, x2' = -w^2 sin(x1) - c x2 + u
def _pend(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    out = np.empty((*np.broadcast_shapes(x.shape[:-1], u.shape[:-1]), 2))
    out[..., 0] = x[..., 1]
    out[..., 1] = -100.0 * np.sin(x[..., 0]) - 2.0 * x[..., 1] + u[..., 0]
    return out


def _pend_jac(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    J = np.zeros((*np.broadcast_shapes(x.shape[:-1], u.shape[:-1]), 2, 2))
    J[..., 0, 1] = 1.0
    J[..., 1, 0] = -100.0 * np.cos(x[..., 0])
    J[..., 1, 1] = -2.0
    return J


def pendulum(**kw: object) -> NonlinearModel:
    return NonlinearModel.from_continuous(
        _pend, _pend_jac, np.eye(2), 1e-6 * np.eye(2), 1e-4 * np.eye(2), 1e-3, oscillatory_states=(0, 1), **kw
    )


def test_wrapped_linear_model_agrees_with_linear_model() -> None:
    m = second_order(10.0, 0.1)
    w = wrap(m)
    x = np.random.default_rng(0).normal(size=(7, 3, 2))
    u = np.random.default_rng(1).normal(size=(7, 3, 1))
    np.testing.assert_allclose(w.transition(x, u), m.transition(x, u), rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(w.jacobian(x, u), m.jacobian(x, u))
    assert (w.n_states, w.n_outputs, w.n_inputs) == (2, 2, 1)
    assert w.full_measurement and not w.is_linear
    np.testing.assert_array_equal(w.C_inv, np.eye(2))
    # u of shape (p,) broadcasts against x's leading axes
    assert w.transition(x, np.array([0.5])).shape == (7, 3, 2)
    lin = w.linearize(np.array([0.3, -1.0]), np.array([2.0]))
    np.testing.assert_array_equal(lin.A, m.A)
    # B by central differences of an affine input: exact up to rounding of f (~eps |f| / h, h = 2e-6)
    np.testing.assert_allclose(lin.B, m.B, rtol=0, atol=1e-9)
    assert isinstance(lin, LinearModel) and lin.dt == m.dt


def test_from_continuous_is_explicit_euler() -> None:
    p = pendulum()
    x = np.array([[0.2, -0.5], [1.0, 0.3]])
    u = np.array([[1.0], [-2.0]])
    np.testing.assert_allclose(p.transition(x, u), x + 1e-3 * _pend(x, u), rtol=1e-15)
    np.testing.assert_allclose(p.jacobian(x, u), np.eye(2) + 1e-3 * _pend_jac(x, u), rtol=1e-15)
    # small-signal frequency at rest: w = 10 rad/s, 2 zeta w = 2 -> zeta = 0.1
    assert p.natural_frequency_hz == pytest.approx(10 / (2 * np.pi), rel=1e-12)
    assert p.damping_ratio == pytest.approx(0.1, rel=1e-12)
    # the same as LinearModel.from_continuous of the Jacobian at rest
    lin = LinearModel.from_continuous(
        _pend_jac(np.zeros(2), np.zeros(1)), np.array([[0.0], [1.0]]), np.eye(2), p.Q, p.R, 1e-3
    )
    pl = p.linearize()
    np.testing.assert_allclose(pl.A, lin.A, rtol=1e-15)
    np.testing.assert_allclose(pl.B, lin.B, rtol=0, atol=1e-12)
    # an operating point away from rest changes the mode (cos(x1) < 1)
    mode = p.mode_at(np.array([0.5, 0.0]))
    assert mode.natural_frequency_hz == pytest.approx(10 * np.sqrt(np.cos(0.5)) / (2 * np.pi), rel=1e-12)
    assert p.mode_at(np.array([np.pi, 0.0])) is None  # inverted: no oscillatory mode


def test_validation_errors_name_what_to_fix() -> None:
    m = second_order(10.0, 0.1)
    base = {
        "f": partial(_lin_f, A=m.A, B=m.B),
        "jac": partial(_lin_jac, A=m.A, B=m.B),
        "C": m.C,
        "Q": m.Q,
        "R": m.R,
        "dt": 1e-3,
    }

    def bad_jac(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.zeros((*x.shape[:-1], 2, 3))

    def bad_f(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return x[..., :1]

    with pytest.raises(ShapeError, match="Jacobian"):
        NonlinearModel(**{**base, "jac": bad_jac})
    with pytest.raises(ShapeError, match=r"f\(x, u\)"):
        NonlinearModel(**{**base, "f": bad_f})

    def nan_jac(x: np.ndarray, u: np.ndarray) -> np.ndarray:
        return np.full((*x.shape[:-1], 2, 2), np.nan)

    with pytest.raises(NonFiniteError, match="not finite at the rest state"):
        NonlinearModel(**{**base, "jac": nan_jac})
    with pytest.raises(ModelKindError, match="callables"):
        NonlinearModel(**{**base, "f": np.eye(2)})
    with pytest.raises(NonFiniteError, match="C"):
        NonlinearModel(**{**base, "C": [[np.nan, 0.0], [0.0, 1.0]]})
    with pytest.raises(ParameterError, match="symmetric"):
        NonlinearModel(**{**base, "Q": [[1.0, 0.5], [0.0, 1.0]]})
    with pytest.raises(ParameterError, match="positive semi-definite"):
        NonlinearModel(**{**base, "R": [[1.0, 0.0], [0.0, -1.0]]})
    with pytest.raises(ShapeError, match="R"):
        NonlinearModel(**{**base, "R": np.eye(3)})
    with pytest.raises(SingularMatrixError, match="row rank"):
        NonlinearModel(**{**base, "C": [[1.0, 1.0], [2.0, 2.0]], "R": np.eye(2)})
    with pytest.raises(ParameterError, match="dt"):
        NonlinearModel(**{**base, "dt": 0.0})
    with pytest.raises(ShapeError, match="state_names"):
        NonlinearModel(**{**base, "state_names": ("a",)})
    with pytest.raises(ShapeError, match="oscillatory_states"):
        NonlinearModel(**{**base, "oscillatory_states": (0, 5)})
    with pytest.raises(TypeError, match="unexpected keyword"):
        NonlinearModel(**base, Ts=1e-3)
    w = NonlinearModel(**base)
    with pytest.raises(ShapeError, match="x must have shape"):
        w.transition(np.zeros((3, 4)), np.zeros(1))
    with pytest.raises(ShapeError, match="u must have shape"):
        w.jacobian(np.zeros((3, 2)), np.zeros(2))
    with pytest.raises(ShapeError, match="x0"):
        w.linearize(np.zeros(3))
    partial_c = NonlinearModel(**{**base, "C": [[1.0, 0.0]], "R": [[1.0]]})
    with pytest.raises(SingularMatrixError, match="full measurement"):
        _ = partial_c.C_inv


def test_require_linear_guard() -> None:
    m = second_order(10.0, 0.1)
    assert require_linear(m, "x") is m and is_linear(m)
    w = wrap(m)
    assert not is_linear(w)
    with pytest.raises(ModelKindError, match="the expected spectrum needs a linear model"):
        require_linear(w, "the expected spectrum")
    with pytest.raises(ModelKindError, match="LinearModel"):
        require_linear(object(), "x")
    assert issubclass(ModelKindError, ParameterError)  # callers catching ParameterError still do


def test_pickle_and_fingerprint() -> None:
    p = pendulum(parameters={"w": 10.0})
    q = pickle.loads(pickle.dumps(p))
    x = np.array([[0.1, 0.2]])
    np.testing.assert_array_equal(q.transition(x, np.zeros(1)), p.transition(x, np.zeros(1)))
    assert q.fingerprint() == p.fingerprint()
    assert pendulum(parameters={"w": 11.0}).fingerprint() != p.fingerprint()
    assert p.replace(R=2e-4 * np.eye(2)).fingerprint() != p.fingerprint()
    with pytest.raises(ParameterError, match="dt is built into"):
        p.replace(dt=2e-3)
    d = p.to_dict()
    assert d["kind"] == "nonlinear" and d["parameters"] == {"w": 10.0} and "_pend" in d["transition"]


def test_linear_only_code_paths_reject_nonlinear_models(capsys: pytest.CaptureFixture[str]) -> None:
    """The expected spectrum, the SVSF and the monitor need A and B: a
    nonlinear model gets a ModelKindError naming the code path, and the CLI reports it (exit 2)."""
    from chatterspec.cli import main
    from chatterspec.detection.pipeline import chattering_record
    from chatterspec.detection.spectral import expected_spectrum
    from chatterspec.filters.svsf import SVSF
    from chatterspec.online.monitor import ChatteringMonitor
    from chatterspec.plants.eha4 import eha4

    m = eha4()
    u = np.zeros((5, 1))
    # the chattering pipeline takes a nonlinear model with full measurement
    # (tests/test_nonlinear_chattering.py), not one with fewer measurements than states
    with pytest.raises(SingularMatrixError, match="full measurement"):
        chattering_record(eha4(measure="position-pressure"), np.zeros((1, 5, 2)), u)
    with pytest.raises(ModelKindError, match="expected chattering spectrum"):
        expected_spectrum(m, np.array([1.0, 2.0]), 100)
    with pytest.raises(ModelKindError, match="chattering SVSF"):
        SVSF(m, psi=1.0)
    with pytest.raises(ModelKindError, match="monitor"):
        ChatteringMonitor(m)
    assert main(["detect", "eha4-leak-timeline", "--runs", "1"]) == 2
    err = capsys.readouterr().err
    assert "needs a linear model" in err and "Traceback" not in err
