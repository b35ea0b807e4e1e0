"""Catalogue scenarios of the estimator papers and of the chattering route on the nonlinear EHA4.

The DETC2015 linear 3-state EHA (``detc-normal``, ``detc-uncertain``), the SMM paper's leak timeline
(``eha4-leak-timeline``), the IMM rig analogue (``eha4-imm-analogue``) and the ``eha4-*`` chattering
scenarios; :mod:`chatterspec.plants.scenarios` lists them in its catalogue.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from .eha4 import Measure, eha4
from .filter_settings import FilterSettings
from .models import LinearModel
from .scenario_types import Scenario, Segment
from .signals import HeldUniform, Sine, SquareWave, Step, Sum

__all__: list[str] = []


# ----------------------------------------------------------------- estimator papers
#: DETC2015 eq (25) and (27): position/velocity/acceleration EHA at Ts = 1 ms, only position measured.
DETC_F = np.array([[1.0, 0.001, 0.0], [0.0, 1.0, 0.001], [-557.02, -28.616, 0.9418]])
DETC_F2 = np.array([[1.0, 0.001, 0.0], [0.0, 1.0, 0.001], [-240.0, -28.0, 0.9418]])
DETC_G = np.array([[0.0], [0.0], [557.02]])
DETC_H = np.array([[1.0, 0.0, 0.0]])
#: Fixed seed of the DETC input's uniform sequence (arbitrary, part of the scenario definition).
DETC_INPUT_SEED = 2015


def _complex_pair_block(F: np.ndarray, dt: float) -> np.ndarray | None:
    """Real 2x2 block [[s, w], [-w, s]] of the complex pole pair of (F - I)/dt (Euler inverse), if any."""
    ev = np.linalg.eigvals((F - np.eye(len(F))) / dt)
    pair = [e for e in ev if e.imag > 0]
    if not pair:
        return None
    s, w = pair[0].real, pair[0].imag
    return np.array([[s, w], [-w, s]])


def _detc_model(F: np.ndarray, Q: np.ndarray, R: np.ndarray, name: str) -> LinearModel:
    return LinearModel(
        A=F,
        B=DETC_G,
        C=DETC_H,
        Q=Q,
        R=R,
        dt=1e-3,
        state_names=("position", "velocity", "acceleration"),
        output_names=("position",),
        input_names=("u",),
        output_units=("cm",),  # the paper gives R = 0.1 cm^2 (section "Comparative analysis")
        oscillatory_block=_complex_pair_block(F, 1e-3),
        name=name,
    )


def _detc(name: str, uncertain: bool) -> Scenario:
    """DETC2015 ([DETC]) eq (25)-(27), resolved as in ``docs/design.md`` D1-D5.

    The true plant has the printed noise w_std = (0.05, 0.1, 0.1), v_std = 0.05 (eq 26); the nominal
    model carries the *filter's* printed Q = diag(1, 10, 100) and R = 0.1 (what the filters use);
    in the uncertain case the true plant switches to F2 at 0.5 s while the filters keep F.
    """
    Q_true, R_true = np.diag([0.05, 0.1, 0.1]) ** 2, np.array([[0.05**2]])
    Q_f, R_f = np.diag([1.0, 10.0, 100.0]), np.array([[0.1]])
    nominal = _detc_model(DETC_F, Q_f, R_f, "DETC2015 EHA F (filter Q, R)")
    plant = _detc_model(DETC_F, Q_true, R_true, "DETC2015 EHA F")
    windows = (Segment(0.5, 1.0, _detc_model(DETC_F2, Q_true, R_true, "DETC2015 EHA F2"), "F2"),)
    settings = FilterSettings(
        Q=Q_f,
        R=R_f,
        P0=20.0 * Q_f,
        x0=np.zeros(3),
        gamma=0.5,
        psi=(5 * 0.05,),
        cutoff_lambda=(0.5,),
        mapping="cov",
        source="DETC2015 eq 25-27 and section 'Comparative analysis': Q, R, P0 = 20 Q, gamma = 0.5, "
        "psi = 5 v_std; Lambda = 0.5 and the 'cov' mapping are resolutions (note 4.2)",
    )
    return Scenario(
        name=name,
        nominal=nominal,
        plant=plant,
        windows=windows if uncertain else (),
        input=Sum((HeldUniform(-1.0, 1.0, 1e-3, DETC_INPUT_SEED), Step(0.5))),
        duration=1.0,
        description=(
            "DETC2015 linear EHA (F, G, H = [1 0 0]); "
            + ("true plant F2 from 0.5 s; " if uncertain else "")
            + "input U(-1,1) (seeded, the same for every run) + unit step at 0.5 s"
        ),
        family="detc-eha",
        fault="model-uncertainty" if uncertain else "healthy",
        level="F2 after 0.5 s" if uncertain else "",
        fault_channel="position" if uncertain else None,
        filter_settings=settings,
    )


#: chatterspec's input for the SMM scenarios (docs/design.md S6): pump speed 94.25 rad/s, direction change
#: every second.
EHA4_SMM_INPUT = Sine(94.25, 0.5)


def _eha4_mode_timeline(
    name: str,
    modes: tuple[str, str, str],
    segment_s: float,
    dt: float,
    Q: np.ndarray,
    R: np.ndarray,
    *,
    measure: Measure = "full",
    scenario: dict[str, Any],
    filters: dict[str, Any],
) -> Scenario:
    """The EHA4 in ``modes[0]`` (the nominal model), then ``modes[1]``, then ``modes[2]``, ``segment_s`` each.

    The estimator papers' fault timelines: the filters get the plant's ``Q``, ``R``, ``P0 = 10 Q``,
    ``x0 = 0``, ``gamma = 0.1`` and the three modes' models (multiple-model filters), plus ``filters``
    (:class:`FilterSettings` fields); ``scenario`` holds the :class:`Scenario` fields left (input,
    description, fault labels).
    """
    models = tuple(eha4(mode, dt=dt, measure=measure, Q=Q, R=R) for mode in modes)
    settings = FilterSettings(
        Q=Q, R=R, P0=10.0 * Q, x0=np.zeros(4), gamma=0.1, modes=modes, mode_models=models, **filters
    )
    return Scenario(
        name=name,
        nominal=models[0],
        windows=tuple(Segment(i * segment_s, (i + 1) * segment_s, models[i], modes[i]) for i in (1, 2)),
        duration=3 * segment_s,
        family="eha4",
        filter_settings=settings,
        **scenario,
    )


def _eha4_leak_timeline() -> Scenario:
    """SMM paper ([SMM]) section 5: normal / minor / major leakage, 9 s at 1 ms."""
    return _eha4_mode_timeline(
        "eha4-leak-timeline",
        ("normal", "leak-minor", "leak-major"),
        3.0,
        1e-3,
        1e-9 * np.eye(4),
        1e-6 * np.eye(4),
        filters=dict(
            psi=(0.02, 0.5, 2.0, 0.01),
            mapping="full",
            mu0=(1 / 3, 1 / 3, 1 / 3),
            weight_floor=1e-3,
            # for the IMM route of `chatterspec diagnose` on the same plant (the SMM paper has no IMM):
            # stay 0.999 per 1 ms step, i.e. a mean dwell of 1 s in each mode, leave uniformly
            transition_matrix=np.full((3, 3), 0.0005) + np.eye(3) * (0.999 - 0.0005),
            source="SMM paper section 5: Q = 1e-9 I4, R = 1e-6 I4, P0 = 10 Q, x0 = 0, "
            "uniform mu0 (section 3), modes of Table 3; gamma = 0.1 from the IMM paper; psi and the weight "
            "floor are chatterspec's choices (docs/design.md S6), not printed; the transition matrix "
            "(0.999 on the diagonal per 1 ms step) is chatterspec's, for the IMM route of `diagnose`",
        ),
        scenario=dict(
            input=EHA4_SMM_INPUT,
            description="nonlinear EHA4 (SMM eq 4.1-4.5), C = I4; minor leakage at 3 s, major at 6 s; "
            "pump 94.25 sin(2 pi 0.5 t) rad/s",
            fault="leakage",
            level="minor at 3 s, major at 6 s",
            fault_channel="acceleration",
        ),
    )


def _eha4_imm_analogue() -> Scenario:
    """Simulation analogue of the IMM paper's rig experiment (``docs/design.md`` I10), 6 s at 0.1 ms."""
    pi = np.full((3, 3), 0.05)
    np.fill_diagonal(pi, 0.90)
    return _eha4_mode_timeline(
        "eha4-imm-analogue",
        ("normal", "leak-minor", "friction-imm-major"),
        2.0,
        1e-4,
        np.diag([1e-9, 1e-7, 1e-2, 1e2]) ** 2,
        np.diag([1e-7, 200.0]) ** 2,
        measure="position-pressure",
        filters=dict(
            psi=(5e-7, 1e3),
            psi_lower=(4.7e-3, 3.07),
            cutoff_lambda=(0.5, 0.5),
            mapping="cov",
            mu0=(0.90, 0.05, 0.05),
            transition_matrix=pi,
            source="IMM paper section 6 (T, segments, H, mu0, Pi per step, gamma = 0.1) with chatterspec's "
            "simulation analogue (docs/design.md I10): noise, Q, P0 = 10 Q, psi, Lambda = 0.5 I; the printed "
            "+-5 rad/s input, Q, R and psi cannot be simulated literally",
        ),
        scenario=dict(
            input=SquareWave(1.0, 60.0),
            description="ANALOGUE of the IMM paper's rig experiment: nonlinear EHA4 at 0.1 ms, position and "
            "pressure measured; normal / leakage (IMM 'Major' = SMM minor) / friction (IMM 'Major friction') "
            "for 2 s each; square wave +-60 rad/s at 1 Hz",
            fault="leakage+friction",
            level="leak 2 s, friction 4 s",
            fault_channel=None,
        ),
    )


# --------------------------------------------------------------------------- chattering on the EHA4
EHA4_CHATTERING_DURATION = 4.0  # s: the chattering paper's record length


def _eha4_chattering(name: str, mode: str | None) -> Scenario:
    """Nonlinear EHA4 for the chattering detector: C = I4, eha4-leak-timeline's noise and input, 4 s.

    The fault (``mode``, a key of ``EHA4_MODES``) is active for the whole record; ``None`` is healthy.
    There is no closed-form expected spectrum: thresholds come from ``calibrate eha4-healthy``.
    """
    Q, R = 1e-9 * np.eye(4), 1e-6 * np.eye(4)
    nominal = eha4("normal", dt=1e-3, Q=Q, R=R)
    windows = (
        () if mode is None else (Segment(0.0, EHA4_CHATTERING_DURATION, eha4(mode, dt=1e-3, Q=Q, R=R), mode),)
    )
    return Scenario(
        name=name,
        nominal=nominal,
        windows=windows,
        input=EHA4_SMM_INPUT,
        duration=EHA4_CHATTERING_DURATION,
        description="nonlinear EHA4 (SMM eq 4.1-4.5), C = I4, Q = 1e-9 I4, R = 1e-6 I4, "
        f"pump 94.25 sin(2 pi 0.5 t) rad/s; {'healthy' if mode is None else mode + ' for the whole record'}; "
        "chattering thresholds are empirical (calibrate eha4-healthy)",
        family="eha4",
        fault="healthy" if mode is None else "leakage",
        level="" if mode is None else mode.removeprefix("leak-"),
        fault_channel=None if mode is None else "acceleration",
    )


def _eha4_chattering_entries() -> dict[str, Callable[[], Scenario]]:
    return {
        "eha4-healthy": lambda: _eha4_chattering("eha4-healthy", None),
        "eha4-leak-minor": lambda: _eha4_chattering("eha4-leak-minor", "leak-minor"),
        "eha4-leak-major": lambda: _eha4_chattering("eha4-leak-major", "leak-major"),
        "eha4-leak-onset": _eha4_leak_onset,
    }


def _eha4_leak_onset() -> Scenario:
    """Like eha4-healthy (same nominal model and 4 s length, so its calibration applies) with the
    major leakage from 2 s on: the STFT intervals / live monitor localize the onset."""
    base = _eha4_chattering("eha4-leak-onset", None)
    Q, R = 1e-9 * np.eye(4), 1e-6 * np.eye(4)
    leak = Segment(2.0, EHA4_CHATTERING_DURATION, eha4("leak-major", dt=1e-3, Q=Q, R=R), "leak-major")
    return Scenario(
        name=base.name,
        nominal=base.nominal,
        windows=(leak,),
        input=base.input,
        duration=base.duration,
        description=base.description.replace("healthy;", "healthy, major leakage from 2 s;"),
        family="eha4",
        fault="leakage",
        level="major at 2 s",
        fault_channel="acceleration",
    )
