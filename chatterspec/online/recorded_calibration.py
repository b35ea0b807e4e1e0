"""Thresholds from a recorded healthy run, read through the monitor itself (``calibrate --data``).

:func:`calibrate_recorded` pushes the recording, in chunks of
:data:`~chatterspec.studies.recorded_calibration.CHUNK_S` seconds, through a
:class:`~chatterspec.online.monitor.ChatteringMonitor` with the monitor's settings and tallies what
its chattering, frames and scores give (:mod:`chatterspec.studies.recorded_calibration`, where the
method, its intervals and the refusals are documented): the thresholds are read from exactly the
numbers the monitor computes with the resulting file.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..detection.alarms import AlarmRule
from ..detection.empirical import NORMALIZATION_SMOOTH_BINS
from ..detection.monitor_settings import MonitorSettings
from ..plants.nonlinear import is_linear
from ..studies.calibration_result import Calibration
from ..studies.recorded_calibration import (
    Chunks,
    HealthyRecording,
    Normalization,
    RecordedTally,
    RecordingPlan,
    plan_recording,
    recorded_calibration,
)
from .monitor import ChatteringMonitor

__all__ = ["calibrate_recorded"]


def _tally(plan: RecordingPlan, chunks: Chunks, E_rec: Any = None, E_frame: Any = None) -> RecordedTally:
    """One pass of the recording through the monitor (scored under ``E_frame``'s law when given)."""
    tally = RecordedTally(plan, E_rec, E_frame)
    if E_frame is not None:
        settings = replace(plan.settings, threshold=plan.score_threshold(E_frame))
    elif is_linear(plan.model):  # the first pass of a "data" normalization: its spectra only
        settings = plan.settings
    else:  # a nonlinear model's monitor needs some threshold: a flat one (the spectra do not depend on it)
        m = plan.model.n_outputs
        settings = replace(
            plan.settings, threshold=plan.score_threshold(np.ones((plan.frame_freqs_hz.size, m)))
        )
    mon = ChatteringMonitor(plan.model, settings)
    for z, u in chunks():
        upd = mon.push(z, u)
        fr = upd.frames
        tally.add(upd.t, upd.chattering, fr.power, fr.score if E_frame is not None else None)
    return tally


def calibrate_recorded(
    model: Any,
    chunks: Chunks,
    n_samples: int,
    *,
    settings: MonitorSettings | None = None,
    alpha: float = 1e-2,
    confidence: float = 0.99,
    normalization: Normalization | None = None,
    record_s: float = 4.0,
    rule: AlarmRule | str | None = None,
    false_alarms_per_hour: float | None = None,
    alarm_confidence: float = 0.95,
    recording: HealthyRecording | None = None,
    smooth_half_width: int = NORMALIZATION_SMOOTH_BINS,
) -> Calibration:
    """Per-frame, record and (optionally) alarm thresholds from a healthy recording.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The monitor's nominal model (full measurement).
    chunks : callable
        Returns a fresh iterable of consecutive ``(z (K, m), u (K, p))`` chunks of the recording
        (called once per pass: twice with ``normalization="data"``), e.g.
        :func:`~chatterspec.studies.recorded_calibration.array_chunks`.
    n_samples : int
        Samples in the recording (the sum of the chunks' ``K``).
    settings : MonitorSettings, optional
        The monitor's STFT, band and ``gamma`` (default ``MonitorSettings()``).
    alpha : float
        Per-frame (and per-record) false-alarm probability of the thresholds, in (0, 1).
    confidence : float
        Level of the order-statistic intervals.
    normalization : {"model", "data"}, optional
        Default ``"model"`` for a linear model, ``"data"`` for a nonlinear one.
    record_s : float
        Record length (s) of the ``detect`` thresholds.
    rule, false_alarms_per_hour
        With either, the alarm threshold too (default cusum at one false alarm per day).
    alarm_confidence : float
        Level of the alarm intervals.
    recording : HealthyRecording, optional
        Where the data came from, recorded in ``Calibration.source``.
    smooth_half_width : int
        Moving-average half-width of a ``"data"`` record normalization (bins).

    Returns
    -------
    Calibration
        ``runs`` = records of ``record_s``; ``seed`` None; ``source`` the provenance.

    Raises
    ------
    ParameterError
        See :func:`~chatterspec.studies.recorded_calibration.plan_recording` (too short a recording
        for a record, the alpha or the budget, with the length that would do).
    """
    plan = plan_recording(
        model,
        n_samples,
        settings=settings,
        alpha=alpha,
        confidence=confidence,
        normalization=normalization,
        record_s=record_s,
        rule=rule,
        false_alarms_per_hour=false_alarms_per_hour,
        alarm_confidence=alarm_confidence,
        smooth_half_width=smooth_half_width,
    )
    if plan.normalization == "model":
        E_rec, E_frame = plan.model_spectra()
    else:
        E_rec, E_frame = _tally(plan, chunks).normalization()
    return recorded_calibration(_tally(plan, chunks, E_rec, E_frame), recording)
