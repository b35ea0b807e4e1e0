"""A diverging model or a NaN from the user's f is an error naming the sample, on both kernel paths."""

from __future__ import annotations

import math

import numpy as np
import pytest

import chatterspec as cs
from chatterspec.errors import NonFiniteError
from chatterspec.filters.kalman import ExtendedKalmanFilter, KalmanFilter
from chatterspec.plants.models import LinearModel
from chatterspec.plants.nonlinear import NonlinearModel

PATHS = ["compiled", "numpy"]


def _path(which: str, monkeypatch: pytest.MonkeyPatch) -> None:
    if which == "numpy":
        monkeypatch.setenv("CHATTERSPEC_JIT", "0")


def _unobservable_growth() -> tuple[LinearModel, int]:
    """A state multiplied by 1e3 per step that C does not see, and the sample where P overflows.

    With diagonal A, Q and C = [0, 1] the unobserved state's variance is never corrected:
    P11(k) = 1e6 P11(k-1) + Q11, so with P11(0) = 1 it first exceeds the largest double at the
    smallest k with 1e6^k > DBL_MAX (k = 52); from there the gain and the estimate are NaN.
    """
    model = LinearModel(
        A=np.diag([1e3, 0.9]),
        B=np.zeros((2, 1)),
        C=np.array([[0.0, 1.0]]),
        Q=np.diag([1e-4, 1e-4]),
        R=np.eye(1) * 1e-2,
        dt=1e-3,
    )
    k_overflow = math.ceil(math.log10(np.finfo(float).max) / 6.0)
    return model, k_overflow


@pytest.mark.parametrize("which", PATHS)
@pytest.mark.parametrize("per_run_P0", [False, True])
@pytest.mark.parametrize("cls", [KalmanFilter, ExtendedKalmanFilter])
def test_diverging_model_is_an_error_with_the_sample(
    cls: type, per_run_P0: bool, which: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    _path(which, monkeypatch)
    model, k_bad = _unobservable_growth()
    z = np.random.default_rng(0).standard_normal((2, 200, 1))
    P0 = np.broadcast_to(np.eye(2), (2, 2, 2)) if per_run_P0 else np.eye(2)
    with pytest.raises(
        NonFiniteError, match=rf"from sample k = {k_bad} \(output index {k_bad - 1}, realization 0\)"
    ):
        cls(model).run(z, np.zeros((200, 1)), x0=np.ones(2), P0=P0)


def _nan_beyond(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    """x + u, but NaN once the first state exceeds 5.5 (a user f that fails mid-run)."""
    return np.where(x[..., :1] > 5.5, np.nan, x + u)


def _identity_jacobian(x: np.ndarray, u: np.ndarray) -> np.ndarray:
    return np.broadcast_to(np.eye(2), (*np.shape(x)[:-1], 2, 2)).copy()


def _ramp_model(outputs: int = 2) -> NonlinearModel:
    """Both states measured, or (``outputs=1``) the first only."""
    C, R = np.eye(2)[:outputs], np.eye(outputs) * 1e-6
    return NonlinearModel(f=_nan_beyond, jac=_identity_jacobian, C=C, Q=np.eye(2) * 1e-6, R=R, dt=1.0)


@pytest.mark.parametrize("which", PATHS)
def test_user_f_returning_nan_mid_run_stops_the_ekf_at_that_sample(
    which: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # noise-free ramp z(k) = k of the first state (u = 1): the EKF's x(k|k) = (k, k) exactly (zero
    # innovation), so f first returns NaN when it is evaluated at x(6|6) = 6 > 5.5, i.e. for the
    # prediction of sample 7 (one output: the compiled EKF loop of the other 2-state, 1-output tests)
    _path(which, monkeypatch)
    T = 20
    z = np.arange(1.0, T + 1)[:, None]
    with pytest.raises(NonFiniteError, match=r"from sample k = 7 \(output index 6, realization 0\)"):
        ExtendedKalmanFilter(_ramp_model(1)).run(z, np.ones((T, 1)), x0=np.zeros(2), P0=np.eye(2))


def test_user_f_returning_nan_mid_run_stops_the_chattering_at_that_sample() -> None:
    # e(k+1|k) = z(k+1) - f(z(k), u(k)) (eq 23 with C = I): NaN first when z(k) = 6, i.e. for sample 7
    T = 20
    z = np.repeat(np.arange(0.0, T)[:, None], 2, axis=1)
    with pytest.raises(NonFiniteError, match=r"from sample k = 7 "):
        cs.chattering(_ramp_model(), z, np.ones((T, 1)))


def test_a_stable_model_passes_the_check() -> None:
    model, _ = _unobservable_growth()
    stable = LinearModel(A=np.diag([0.5, 0.9]), B=model.B, C=model.C, Q=model.Q, R=model.R, dt=model.dt)
    out = KalmanFilter(stable).run(np.zeros((1, 50, 1)), np.zeros((50, 1)), x0=np.ones(2), P0=np.eye(2))
    assert np.isfinite(out.x_post).all()
