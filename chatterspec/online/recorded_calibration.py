"""Thresholds from a recorded healthy run, read through the monitor itself (``calibrate --data``).

:func:`calibrate_recorded` pushes the recording, in chunks of
:data:`~chatterspec.studies.calibration.recorded.CHUNK_S` seconds, through a
:class:`~chatterspec.online.monitor.ChatteringMonitor` with the monitor's settings and tallies what
its chattering, frames and scores give (:mod:`chatterspec.studies.calibration.recorded`, where the
method, its intervals and the refusals are documented): the thresholds are read from exactly the
numbers the monitor computes with the resulting file.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Unpack

import numpy as np

from ..plants.nonlinear import is_linear
from ..studies.calibration.recorded import (
    Chunks,
    HealthyRecording,
    RecordedTally,
    RecordingOptions,
    RecordingPlan,
    plan_recording,
    recorded_calibration,
)
from ..studies.calibration.result import Calibration
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
    recording: HealthyRecording | None = None,
    **options: Unpack[RecordingOptions],
) -> Calibration:
    """Per-frame, record and (optionally) alarm thresholds from a healthy recording.

    Parameters
    ----------
    model, n_samples
        As :func:`~chatterspec.studies.calibration.recorded.plan_recording` (``n_samples``: the sum of
        the chunks' ``K``).
    chunks : callable
        Returns a fresh iterable of consecutive ``(z (K, m), u (K, p))`` chunks of the recording
        (called once per pass: twice with ``normalization="data"``), e.g.
        :func:`~chatterspec.studies.calibration.recorded.array_chunks`.
    recording : HealthyRecording, optional
        Where the data came from, recorded in ``Calibration.source``.
    **options
        The keywords of :func:`~chatterspec.studies.calibration.recorded.plan_recording`: the
        monitor's ``settings`` (STFT, band, gamma), ``alpha``, ``confidence``, ``normalization``
        (``"model"`` or ``"data"``), ``record_s``, ``rule`` and ``false_alarms_per_hour`` (either
        asks for the alarm threshold), ``alarm_confidence``, ``smooth_half_width``.

    Returns
    -------
    Calibration
        ``runs`` = records of ``record_s``; ``seed`` None; ``source`` the provenance.

    Raises
    ------
    ParameterError
        See :func:`~chatterspec.studies.calibration.recorded.plan_recording` (too short a recording
        for a record, the alpha or the budget, with the length that would do).
    """
    plan = plan_recording(model, n_samples, **options)
    if plan.normalization == "model":
        E_rec, E_frame = plan.model_spectra()
    else:
        E_rec, E_frame = _tally(plan, chunks).normalization()
    return recorded_calibration(_tally(plan, chunks, E_rec, E_frame), recording)
