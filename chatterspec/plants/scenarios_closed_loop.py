"""The closed-loop catalogue: the EHA under a PI position controller (``eha-cl-*``, ``eha4-cl-*``).

Every scenario of :mod:`chatterspec.plants.scenarios` drives its plant open loop. These put the
actuator under a position controller (:class:`~chatterspec.plants.closed_loop.ClosedLoop`), the
situation the core paper leaves open (section VI): the pump speed is whatever the controller
commands, and long stretches hold still. The filters keep the open-loop nominal model and get the
measured (saturated) controller output as ``u``.

Linear EHA (eq 65/67, Table 1; 4 s at 1 ms, as the open-loop ``eha-*``):

* noise: eq 66 except the position sensor, whose standard deviation is 10 um
  (:data:`EHA_CL_POSITION_NOISE`; eq 66 has 1 mm). A position loop feeds its sensor's noise into
  the pump: with 1 mm the PI loop below would command 103 rad/s rms of pure noise, which itself
  excites the actuator (``chatterspec power leakage --closed-loop`` measures both sensors);
* controller :data:`EHA_CL_CONTROLLER`: PI by pole placement on the rigid-body approximation
  (``kp = 2 zeta wc / Kv``, ``ki = wc^2 / Kv``, ``Kv = 3.65e-4`` m/s per rad/s) at 3 Hz, damping 1,
  reference weight 0.5 in the proportional term, pump speed limited to +-300 rad/s (the open-loop
  chirp's amplitude), back-calculation anti-windup with the integral time as tracking time;
* reference :data:`EHA_CL_REFERENCE`: four minimum-jerk moves of 10-20 mm (0.5 s each, peak speed
  0.075 m/s); the ``hold`` scenarios keep the position at 0 mm;
* ``eha-cl-healthy``, ``eha-cl-leak-minor`` / ``-medium`` / ``-major`` (Table 2's leakage levels),
  ``eha-cl-friction-major``, ``eha-cl-bulk-25down`` (bulk modulus 0.75 from 2 s to the end),
  ``eha-cl-hold-healthy``, ``eha-cl-hold-leak-medium``.

Nonlinear 4-state EHA (SMM eq 4.1-4.5, C = I4, Q = 1e-9 I4, R = 1e-6 I4, 1 ms):

* controller :data:`EHA4_CL_CONTROLLER`: the same design at 1 Hz on the linearization at rest,
  +-120 rad/s (explicit Euler needs |v| < 0.056 m/s; 120 rad/s gives at most 0.044 m/s); the SMM
  paper's 1 mm position noise (R = 1e-6 I4) is kept, so the loop commands ~34 rad/s rms of noise;
* ``eha4-cl-healthy`` (4 s) and ``eha4-cl-leak-timeline`` (9 s: minor leakage from 3 s, major from
  6 s, the SMM paper's timeline, with ``eha4-leak-timeline``'s filter settings for the SMM-SVSF and
  IMM routes of ``chatterspec diagnose``), tracking +-5 mm moves of 1 s.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Unpack

import numpy as np

from .closed_loop import ClosedLoop
from .controllers import PIDController
from .eha4 import eha4
from .loop_design import design_pi
from .models import EHA_PARAMETERS, EHAFault, eha_linear
from .references import Hold, SCurve
from .scenario_types import Scenario, Segment
from .scenarios_estimators import _eha4_leak_timeline

__all__ = [
    "CLOSED_LOOP_NAMES",
    "EHA4_CL_CONTROLLER",
    "EHA4_CL_REFERENCE",
    "EHA_CL_CONTROLLER",
    "EHA_CL_REFERENCE",
    "closed_loop_entries",
    "eha_closed_loop_scenario",
]

#: Closed-loop bandwidth (Hz), damping and reference weight of the linear EHA's PI design.
EHA_CL_DESIGN: dict[str, float] = {"bandwidth_hz": 3.0, "damping": 1.0, "setpoint_weight": 0.5}
#: Standard deviation (m) of the closed-loop scenarios' position sensor (eq 66: 1e-3 m).
EHA_CL_POSITION_NOISE = 1e-5
#: Pump-speed limit of the linear EHA loop (rad/s): the open-loop chirp's amplitude.
EHA_CL_SATURATION = 300.0

#: The linear EHA's PI position controller (kp 103 rad/s per mm, ki 974 rad/s per mm s).
EHA_CL_CONTROLLER: PIDController = design_pi(
    eha_linear(),
    EHA_CL_DESIGN["bandwidth_hz"],
    EHA_CL_SATURATION,
    damping=EHA_CL_DESIGN["damping"],
    setpoint_weight=EHA_CL_DESIGN["setpoint_weight"],
)

#: The catalogue reference (m): 0 -> 10 -> -10 -> 10 -> 0 mm, minimum-jerk moves of 0.5 s from 0.25 s.
EHA_CL_REFERENCE = SCurve((0.25, 1.25, 2.25, 3.25), (0.01, -0.01, 0.01, 0.0), 0.5)

_EHA4_Q, _EHA4_R = 1e-9 * np.eye(4), 1e-6 * np.eye(4)

#: The nonlinear EHA's PI controller: 1 Hz, damping 1, reference weight 0.5, +-120 rad/s.
EHA4_CL_CONTROLLER: PIDController = design_pi(
    eha4("normal", dt=1e-3, Q=_EHA4_Q, R=_EHA4_R), 1.0, 120.0, damping=1.0, setpoint_weight=0.5
)

#: +-5 mm minimum-jerk moves of 1 s every 1.5 s from 0.5 s (9 s record; a 4 s record sees the first three).
EHA4_CL_REFERENCE = SCurve((0.5, 2.0, 3.5, 5.0, 6.5, 8.0), (0.005, -0.005, 0.005, -0.005, 0.005, 0.0), 1.0)

EHA_CL_DURATION = 4.0  # s: the open-loop EHA records' length (N = 4000 chattering samples)

#: The closed-loop catalogue names, in catalogue order (part of the CLI contract).
CLOSED_LOOP_NAMES: tuple[str, ...] = (
    "eha-cl-healthy",
    "eha-cl-leak-minor",
    "eha-cl-leak-medium",
    "eha-cl-leak-major",
    "eha-cl-friction-major",
    "eha-cl-bulk-25down",
    "eha-cl-hold-healthy",
    "eha-cl-hold-leak-medium",
    "eha4-cl-healthy",
    "eha4-cl-leak-timeline",
)

_LEAKAGE = {"minor": 3e-11, "medium": 6e-11, "major": 9e-11}  # Table 2, m^3/(s Pa)


class _EHAOptions(EHAFault, total=False):
    """The keyword arguments of :func:`eha_closed_loop_scenario` after the loop."""

    fault: str
    level: str
    channel: str | None
    onset_s: float
    position_noise: float
    noise: float


def eha_closed_loop_scenario(
    name: str,
    loop: ClosedLoop,
    *,
    fault: str = "healthy",
    level: str = "",
    channel: str | None = None,
    onset_s: float = 0.0,
    position_noise: float = EHA_CL_POSITION_NOISE,
    noise: float = 1.0,
    duration_s: float = EHA_CL_DURATION,
    **params: Unpack[EHAFault],
) -> Scenario:
    """A linear-EHA scenario under ``loop``, with the true plant's parameters ``params`` from ``onset_s``.

    Parameters
    ----------
    name : str
        Scenario name.
    loop : ClosedLoop
        Controller, reference (m) and dither.
    fault, level, channel : str
        Metadata (fault family, level, the output the fault acts on).
    onset_s : float
        Time (s) from which the true plant differs (0: the whole record).
    position_noise : float
        Standard deviation (m) of the position measurement (default 10 um; eq 66: 1e-3 m).
    noise : float
        Multiplier of the measurement-noise covariance ``R = diag(position_noise^2, 1e-6, 1e6)``
        (nominal and true plant).
    duration_s : float
        Record length (s; default 4, the catalogue's).
    **params : float
        :func:`~chatterspec.plants.models.eha_linear` parameters of the true plant (``leakage``,
        ``friction``, ``bulk_modulus``).
    """
    R = noise * np.diag([position_noise**2, 1e-6, 1e6])
    nominal = eha_linear(R=R)
    windows: tuple[Segment, ...] = ()
    plant = None
    what = ", ".join(f"{k} = {v:.3g}" for k, v in params.items()) or "healthy"
    if params and onset_s > 0:
        windows = (Segment(onset_s, duration_s, eha_linear(R=R, **params), what),)
        what += f" from {onset_s:g} s"
    elif params:
        plant = eha_linear(R=R, **params)
    return Scenario(
        name=name,
        nominal=nominal,
        plant=plant,
        windows=windows,
        input=loop,
        duration=duration_s,
        description=f"linear EHA, {what}; PI position loop, reference {loop.reference.describe()}"
        + ("" if loop.dither is None else f", dither {loop.dither.describe()}"),
        family="eha-closed-loop",
        fault=fault,
        level=level,
        fault_channel=channel,
    )


def _eha(name: str, hold: bool = False, **kw: Unpack[_EHAOptions]) -> Scenario:
    ref = Hold(0.0) if hold else EHA_CL_REFERENCE
    return eha_closed_loop_scenario(name, ClosedLoop(EHA_CL_CONTROLLER, ref), **kw)


def _eha4(name: str, leak_timeline: bool) -> Scenario:
    models = {
        mode: eha4(mode, dt=1e-3, Q=_EHA4_Q, R=_EHA4_R) for mode in ("normal", "leak-minor", "leak-major")
    }
    loop = ClosedLoop(EHA4_CL_CONTROLLER, EHA4_CL_REFERENCE)
    if not leak_timeline:
        return Scenario(
            name=name,
            nominal=models["normal"],
            input=loop,
            duration=4.0,
            description="nonlinear EHA4 (SMM eq 4.1-4.5), C = I4, Q = 1e-9 I4, R = 1e-6 I4, healthy; "
            f"{loop.describe()}; chattering thresholds are empirical (calibrate eha4-cl-healthy)",
            family="eha4-closed-loop",
        )
    return Scenario(
        name=name,
        nominal=models["normal"],
        windows=(
            Segment(3.0, 6.0, models["leak-minor"], "leak-minor"),
            Segment(6.0, 9.0, models["leak-major"], "leak-major"),
        ),
        input=loop,
        duration=9.0,
        description="nonlinear EHA4 (SMM eq 4.1-4.5), C = I4; minor leakage at 3 s, major at 6 s; "
        + loop.describe(),
        family="eha4-closed-loop",
        fault="leakage",
        level="minor at 3 s, major at 6 s",
        fault_channel="acceleration",
        filter_settings=_eha4_leak_timeline().filter_settings,
    )


def closed_loop_entries() -> dict[str, Callable[[], Scenario]]:
    """Builders of :data:`CLOSED_LOOP_NAMES` for the catalogue (``plants.scenarios`` registers them)."""
    be = EHA_PARAMETERS["bulk_modulus"]
    cat: dict[str, Callable[[], Scenario]] = {"eha-cl-healthy": lambda: _eha("eha-cl-healthy")}
    for lv, L in _LEAKAGE.items():
        cat[f"eha-cl-leak-{lv}"] = partial(
            _eha, f"eha-cl-leak-{lv}", fault="leakage", level=lv, channel="pressure", leakage=L
        )
    cat["eha-cl-friction-major"] = lambda: _eha(
        "eha-cl-friction-major", fault="friction", level="major", channel="velocity", friction=7000.0
    )
    cat["eha-cl-bulk-25down"] = lambda: _eha(
        "eha-cl-bulk-25down",
        fault="bulk-modulus",
        level="25down from 2 s",
        channel="pressure",
        onset_s=2.0,
        bulk_modulus=0.75 * be,
    )
    cat["eha-cl-hold-healthy"] = lambda: _eha("eha-cl-hold-healthy", hold=True)
    cat["eha-cl-hold-leak-medium"] = lambda: _eha(
        "eha-cl-hold-leak-medium",
        hold=True,
        fault="leakage",
        level="medium, held still",
        channel="pressure",
        leakage=_LEAKAGE["medium"],
    )
    cat["eha4-cl-healthy"] = lambda: _eha4("eha4-cl-healthy", False)
    cat["eha4-cl-leak-timeline"] = lambda: _eha4("eha4-cl-leak-timeline", True)
    return cat
