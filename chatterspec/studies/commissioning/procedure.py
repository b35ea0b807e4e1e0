"""The commissioning procedure: split, fit the parameters, fit the noise, identify again, psi, check.

See :mod:`chatterspec.studies.commissioning` for the method; this module holds :func:`commission`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..._validate import finite_array, open_unit, positive_int
from ...errors import IdentifiabilityError, ParameterError, ShapeError
from ...plants.models import LinearModel
from .fits import NoiseFit, ParameterFit, fit_noise, fit_parameters
from .result import PSI_SIGMAS, Commissioning, DataSource

__all__ = ["MIN_CHECK_WINDOWS", "REIDENTIFY_TOLERANCE", "chattering", "commission", "nominal_spec"]

#: The held-out span must hold at least this many STFT windows (spectrum segments, alarm frames).
MIN_CHECK_WINDOWS = 10
#: Identify again when the fitted noise moves the chattering's autocovariances (the identification's
#: weights, eq 58) by more than this fraction on some channel (the intervals then change by ~half that).
REIDENTIFY_TOLERANCE = 0.01


def chattering(model: LinearModel, z: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Eq (23): ``e(k+1) = z(k+1) - C A C^-1 z(k) - C B u(k)``, ``(T - 1, m)``: the auxiliary filter's
    chattering from zero initial error (``x(0|0) = C^-1 z(0)``, chatterspec's default).

    Parameters
    ----------
    model : LinearModel
        Full-measurement model.
    z : (T, m) array
        Measurements.
    u : (T, p) array
        Inputs.
    """
    Phi, G = model.C @ model.A @ model.C_inv, model.C @ model.B
    return z[1:] - z[:-1] @ Phi.T - u[:-1] @ G.T


def nominal_spec(model: Any) -> Any:
    """The nominal model as commissioning takes it, or the error that says why it cannot.

    Parameters
    ----------
    model : ModelSpec, str, Path or LinearModel
        A loaded model file, its path, or a model (then psi is 3 x its chattering's standard deviation,
        gamma 0.1, the detector's defaults).

    Returns
    -------
    ModelSpec

    Raises
    ------
    IdentifiabilityError
        A nonlinear model, or reduced measurement (C not square and invertible).
    ModelFileError
        A model file that cannot be read.
    """
    spec = _spec(model)
    _refuse_reduced(spec.model)
    return spec


def _spec(model: Any) -> Any:
    from ...plants.modelfile import ModelSpec, load_model
    from ...plants.nonlinear import NonlinearModel

    if isinstance(model, (str, Path)):
        model = load_model(model)
    inner = model.model if isinstance(model, ModelSpec) else model
    if isinstance(inner, NonlinearModel):
        where = model.path if isinstance(model, ModelSpec) else inner.name
        raise IdentifiabilityError(
            f"{str(where)!r} is a nonlinear model: commissioning fits the linear model's parameters and "
            "noise from the chattering's regression and MA(1) law (eq 23), which a nonlinear model does not "
            "have; commission a linear model of the plant (its linearization at the operating point)"
        )
    if isinstance(model, LinearModel):
        from ...detection.spectral import chattering_autocovariance

        psi = PSI_SIGMAS * np.sqrt(chattering_autocovariance(model)[0]) if model.full_measurement else None
        return ModelSpec(model=model, psi=psi, gamma=0.1, detector={}, path=Path(model.name))
    if not isinstance(model, ModelSpec):
        raise ParameterError(
            f"model must be a model file path, a ModelSpec or a LinearModel; got {type(model).__name__}"
        )
    return model


def _refuse_reduced(model: LinearModel) -> None:
    if model.full_measurement:
        return
    if model.parameter_map is not None:
        from ...detection.identification import identification_setup

        identification_setup(model)  # raises with the entries that involve unmeasured states
    raise IdentifiabilityError(
        f"{model.name!r}: commissioning needs every state measured (C square and invertible; C is "
        f"{model.n_outputs}x{model.n_states}): with fewer measurements the chattering is not eq 23's MA(1), "
        "so neither the parameters nor Q and R can be read from it"
    )


def _data(model: LinearModel, z: Any, u: Any) -> tuple[np.ndarray, np.ndarray]:
    z = finite_array("z", z, ndim=2)
    T, m = z.shape
    if m != model.n_outputs:
        raise ShapeError(f"z must have shape (T, {model.n_outputs}) (one column per output); got {z.shape}")
    u = np.zeros((T, model.n_inputs)) if u is None else finite_array("u", u, ndim=(1, 2))
    u = u[:, None] if u.ndim == 1 else u
    if u.shape != (T, model.n_inputs):
        raise ShapeError(f"u must have shape ({T}, {model.n_inputs}) to match z; got {u.shape}")
    return z, u


def _split(model: LinearModel, settings: Any, T: int, holdout: float, check: bool) -> int:
    """Samples of the fit span; ParameterError when the held-out span cannot hold the check."""
    n_check = round(holdout * T) if check else 0
    W = settings.stft.n_window(model.dt)
    need = MIN_CHECK_WINDOWS * W + 1
    if check and n_check < need:
        total = need / holdout
        raise ParameterError(
            f"the recording is too short: {T * model.dt:.4g} s; the held-out check needs {MIN_CHECK_WINDOWS} "
            f"STFT windows ({need * model.dt:.4g} s) in the held-out {holdout:.3g} of it: record at least "
            f"{total * model.dt:.4g} s"
        )
    if T - n_check < 4:
        raise ParameterError(f"the fit span holds {T - n_check} samples; it needs at least 4")
    return T - n_check


def _reidentify(model: LinearModel, noise: NoiseFit) -> bool:
    """Whether the fitted noise moved the autocovariances the identification weighed with (eq 58)."""
    from ...detection.spectral import chattering_autocovariance

    g0, g1 = chattering_autocovariance(model)
    d0 = np.abs(noise.gamma0_model - g0) / np.abs(g0)
    d1 = np.abs(noise.gamma1_model - g1) / np.maximum(np.abs(g1), 1e-300)
    return bool(max(d0.max(), np.where(g1 != 0, d1, 0.0).max()) > REIDENTIFY_TOLERANCE)


def _fit(
    model: LinearModel, z: np.ndarray, u: np.ndarray, confidence: float, t0: float, record_s: float
) -> tuple[LinearModel, ParameterFit | None, NoiseFit, int]:
    """Parameters (when declared) and noise on the fit span, identified again once if the noise moved."""
    nominal, pf, values = model, None, None
    if model.parameter_map is not None:
        values = {p.name: p.value for p in model.parameter_map.parameters}
        pf = fit_parameters(model, z, u, confidence=confidence, t0=t0, record_s=record_s)
        model = pf.model
    noise = fit_noise(model, chattering(model, z, u), confidence=confidence)
    passes = 1
    if pf is not None and _reidentify(model, noise):
        pf = fit_parameters(
            noise.apply(model), z, u, confidence=confidence, t0=t0, record_s=record_s, nominal=values
        )
        model = pf.model
        noise = fit_noise(model, chattering(model, z, u), confidence=confidence, nominal=nominal)
        passes = 2
    return noise.apply(model), pf, noise, passes


def commission(
    model: Any,
    z: np.ndarray,
    u: np.ndarray | None = None,
    *,
    holdout: float = 1.0 / 3.0,
    confidence: float = 0.95,
    alpha: float = 0.01,
    lags: int = 20,
    check: bool = True,
    t0: float = 0.0,
    calibration_hours: float | None = None,
    source: DataSource | None = None,
) -> Commissioning:
    """Fit a model to a healthy recording of the plant and check it on a held-out part of it.

    The first ``1 - holdout`` of the recording is the fit span: every physical parameter the model
    declares is fitted at once (eq 23, identifiability checked first:
    :func:`~chatterspec.studies.commissioning.fits.fit_parameters`), then diag(Q) and diag(R)
    from the chattering's lag-0 and lag-1 autocovariances at the fitted model (the MA(1) law of eq 23 /
    56: :func:`~chatterspec.studies.commissioning.fits.fit_noise`), then the parameters once more
    with the fitted noise when it moved the identification's weights; psi is 3 standard deviations of
    the fitted model's chattering per output (eq 58). The last ``holdout`` is the check span
    (:func:`~chatterspec.studies.commissioning.adequacy.check_model`): whiteness, spectrum and the
    monitor's alarm count at its budget.

    Parameters
    ----------
    model : ModelSpec, str, Path or LinearModel
        The nominal model: a loaded model file, its path, or a model (psi then 3 x its chattering std,
        gamma 0.1, the default detector). Linear, full measurement.
    z : (T, m) array
        The healthy recording's measurements, one sample per ``dt`` (output units).
    u : (T, p) array, optional
        Its inputs (``u(k)`` drives the plant from sample k to k+1); default zeros.
    holdout : float
        Fraction of the recording, at its end, kept for the check (0 < holdout < 1; default a third).
    confidence : float
        Level of every interval (parameters, Q, R).
    alpha : float
        Probability (at most) that a recording of a plant the fitted model describes fails the check.
    lags : int
        Ljung-Box lags of the whiteness test.
    check : bool
        Run the held-out check (False: fit on the whole recording, no check; ``holdout`` ignored).
    t0 : float
        Time (s) of ``z[0]``.
    calibration_hours : float, optional
        Hours of simulated healthy data that set the alarm rule's threshold for the check (default: the
        monitor's in-call hours).
    source : DataSource, optional
        Where the recording came from (name and SHA-256), recorded in the fitted model file.

    Returns
    -------
    Commissioning
        The fitted model, its intervals, the check; ``.write(path)`` writes the model file.

    Raises
    ------
    IdentifiabilityError
        A nonlinear model, reduced measurement, or parameters the data cannot identify (the message names
        them and what excitation or length would identify them).
    CommissioningError
        A fitted R or Q that the data make negative (coloured noise, a disturbance).
    ParameterError, ShapeError, NonFiniteError
        Bad options, a recording too short for the check, data of the wrong shape or with NaN/inf.
    """
    from ...detection.alarms.calibration import MonitorSettings

    spec = nominal_spec(model)
    nominal = spec.model
    holdout = open_unit("holdout", holdout)
    confidence, alpha = open_unit("confidence", confidence), open_unit("alpha", alpha)
    lags = positive_int("lags", lags)
    z, u = _data(nominal, z, u)
    settings = MonitorSettings.from_detector(spec.detector, gamma=spec.gamma)
    T, dt = z.shape[0], nominal.dt
    n_fit = _split(nominal, settings, T, holdout, check)
    fitted, pf, noise, passes = _fit(nominal, z[:n_fit], u[:n_fit], confidence, t0, T * dt)
    from ...detection.spectral import chattering_autocovariance

    psi = PSI_SIGMAS * np.sqrt(chattering_autocovariance(fitted)[0])
    adequacy = None
    if check:
        from ..alarm_budget import alarm_settings
        from .adequacy import check_model

        rule = alarm_settings(fitted, settings, hours=calibration_hours)
        e = chattering(fitted, z[n_fit:], u[n_fit:])
        adequacy = check_model(fitted, rule, e, t0=t0 + n_fit * dt, alpha=alpha, lags=lags)
    return Commissioning(
        nominal=spec,
        model=fitted,
        psi=psi,
        gamma=spec.gamma,
        detector=dict(spec.detector),
        parameters=pf,
        noise=noise,
        passes=passes,
        fit_span_s=(float(t0), float(t0 + n_fit * dt)),
        check_span_s=(float(t0 + n_fit * dt), float(t0 + T * dt)) if check else None,
        check=adequacy,
        source=source,
        confidence=confidence,
        options={"holdout": holdout, "alpha": alpha, "lags": lags},
    )
