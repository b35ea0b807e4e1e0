"""The Rerun side: recordings and the live viewer of the online monitor.

Rerun output of the online monitor (:mod:`chatterspec.online`, the numeric side: monitor, push
kernels, stream reading): sinks (file / live viewer, :mod:`~chatterspec.viewer.sinks`), the logger
and its identification entities (:mod:`~chatterspec.viewer.rerun_log`), the layout and default blueprint
(:mod:`~chatterspec.viewer.blueprint`), the spectrogram (:mod:`~chatterspec.viewer.spectrograms`), the
event log and lanes (:mod:`~chatterspec.viewer.events`), the recordings the commands write (monitor runs,
detections, estimates, diagnoses: :mod:`~chatterspec.viewer.recordings`) and the live stream monitor
(:mod:`~chatterspec.viewer.live_stream`).

The public names are importable from here: ``from chatterspec.viewer import RerunLogger``.

``rerun`` is imported lazily inside the functions: ``import chatterspec.online``
does not load it, and the numeric core never imports this module.

Entity layout (timeline ``time``: integer nanoseconds, every time rounded once by
:func:`chatterspec.viewer.spectrograms.to_ns`; ``<c>`` is an output channel name, ``<k>`` its
1-based index). Per-sample and per-frame series hold ONE row per sample / frame for all
``m`` channels (series ``j`` = channel ``j``, named and coloured in the static
``SeriesLines`` / ``SeriesPoints``): Rerun's cost is per row (a 16-byte row id and an
8-byte time besides the values), so this halves the recording time of the per-channel
layout. Each channel's view shows only its own series (blueprint overrides of
``visible_series``; hidden series do not enter the auto-scaled y range):

========================================  =============================================================
``/chattering/e``                         everything per sample, one row per sample: the chattering
                                          ``e(k|k-1)`` of the auxiliary filter per channel (series
                                          ``0 .. m-1``), then for raw data per channel the measurement
                                          [and the ``sat``-SVSF estimate ``C x(k|k)``] (series
                                          ``m + c k + j``, k = 1 or 2): m, 2 m or 3 m per row
``/chattering/psi``                       the SVSF boundary layer ``+psi_0, -psi_0, +psi_1, ...`` (when
                                          known): 2 m per row, at each batch's first and last sample
``/spectrum/<c>``                         one STFT column per hop (``Tensor``, dim ``freq``, float32;
                                          float64 with ``RerunLogger(spectrum_dtype="float64")``)
``/spectrogram/<c>/image``                ``10 log10(S / threshold)`` dB over the band, clipped to
                                          ``DB_RANGE`` (``DepthImage``, float16, top row = highest
                                          frequency, with its scale ``Transform3D``), in a 2-D view
``/spectrogram/<c>/freq_ticks``, ``key``, frequency labels, the dB colour key (a gradient image) and its
``key_ticks``, ``outside``                labels; marks of flagged frames whose peak lies outside the
                                          band (static; :mod:`chatterspec.viewer.spectrograms`)
``/detection/statistic_db``               ``10 log10`` of the largest ``S / threshold`` over the tested
                                          bins: m per row, one row per frame
``/detection/threshold_db``               the decision level, 0 dB (one series)
``/detection/fault/<c>``                  the statistic at flagged frames only (red points)
``/frequency/fault/<c>``                  the largest-``S / threshold`` frequency at flagged frames only
                                          (red points; the per-frame peak series are drawn dimmed)
``/detection/verdict``                    per-frame verdict, 1 = fault, 0 = healthy (m, not drawn), then
                                          the alarm rule's statistic (m), the frame score ``-log p`` (m)
                                          and the rule's threshold (1): 3 m + 1 per row
``/frequency/peak_hz``                    tested bin with the largest excess power ``S - E`` (Hz): m per row
``/frequency/most_significant_hz``        tested bin with the largest ``S / threshold`` (Hz): m per row
``/threshold/<c>``, ``/expected/<c>``     static frame threshold and expected healthy spectrum per bin
``/state/0_truth``                        true fault timeline (simulated data only), the top lane
``/state/0m_<method>``                     most probable mode of a multiple-model diagnosis (``diagnose``)
``/state/<k>_<c>``                        fault-state lane of channel ``c``, in channel order: the alarm
                                          layer's state (:mod:`chatterspec.online.fault_state`), ``FAULT``,
                                          ``healthy`` or ``no evidence``, changed at the alarm times (end
                                          of the deciding frame), file and live alike; episodes labelled
                                          with their onset / offset estimates
                                          (:mod:`chatterspec.viewer.events`)
``/events``                               text log: alarm raised / cleared (at its alarm time) and, in a
                                          file, each fault interval estimate at its onset; identification
                                          lines under ``/events/identification``
========================================  =============================================================

The paths are constants of :mod:`chatterspec.viewer.blueprint` (``CHATTERING``, ``PSI``,
``STATISTIC``, ``THRESHOLD``, ``VERDICT``, ``PEAK_HZ``, ``MOST_SIGNIFICANT_HZ``,
:func:`~chatterspec.viewer.blueprint.fault_entity`, :func:`~chatterspec.viewer.blueprint.lane_entity`).

Everything time-indexed is sent column-wise (``send_columns``) from zero-copy arrow
views, also the spectra: one ``Tensor`` row per frame, built in bulk from numpy
(``rr.Tensor`` has no batch constructor), so a reader sees the same rows as from one
``rr.log`` per frame. A live viewer gets every update at once; a file gets the per-sample
series in batches of 20 s of 1 kHz data and the frames in batches of a minute at a 0.2 s hop
(and the rest on close).

The spectrogram band defaults to the detector's tested bins capped at 3x the model's
highest natural frequency (EHA: 1-150 Hz). Rerun draws tensors without ticks, so the
spectrogram is an image in a 2-D view beside labelled points (frequency labels, a dB colour
key). In a file it is ONE float16 image per channel for the whole record (one column per
frame, padded by ``pad_columns`` blank columns on each side so that it covers the whole
record; blocks of at most an hour on longer streams), logged at the record's start, and the
file's blueprint shows exactly that span (``record_span``) in every time view (linked x axes,
lanes too) and opens paused on the whole record. A live viewer gets a scrolling image of the
last ``scroll_frames`` columns (always that many, blank before they fill) after every frame,
and follows the incoming data.

Colours come from :mod:`chatterspec.palette` (shared with the figures): red only for faults.

Default recording folder of ``chatterspec demo``: ``recordings/`` in the
current directory (git-ignored).

A FILE opens paused on the whole record: the logger sends the file's final blueprint when it closes
(:meth:`~chatterspec.viewer.rerun_log.RerunLogger.close`): the record's span, known in advance
(``detect``, ``demo``, ``diagnose``) or measured (a streamed or rotated file, whose first blueprint
still follows the data), and each chattering view's y range from the record's robust amplitude
(:mod:`~chatterspec.viewer.blueprint`). The viewer opens a file on the last blueprint it holds.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public name -> its module (imported on first access: ``import chatterspec.viewer`` stays light and
#: never imports ``rerun``).
_EXPORTS = {
    "RerunLogger": "rerun_log",
    "record_span": "spectrograms",
    "to_ns": "spectrograms",
    "DB_RANGE": "spectrograms",
    "Sinks": "sinks",
    "open_sinks": "sinks",
    "default_recording_path": "sinks",
    "viewer_url": "sinks",
    "LiveViewerWarning": "sinks",
    "RecordingSummary": "recordings",
    "record_detection": "recordings",
    "run_monitor": "recordings",
    "scenario_truth": "recordings",
    "StreamMonitor": "live_stream",
    "StreamEvent": "live_stream",
    "StreamSummary": "live_stream",
    "drive": "live_stream",
    "record_estimates": "recordings",
    "record_diagnosis": "recordings",
    "record_budget_diagnosis": "recordings",
    "IdentificationLog": "rerun_log",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
