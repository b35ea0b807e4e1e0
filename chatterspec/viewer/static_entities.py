"""The static entities of a monitor recording (:func:`log_static`): series styles, spectrogram axes,
threshold and expected spectra, the lanes' state configuration and the frequency note.

Logged once per stream by :class:`~chatterspec.viewer.rerun_log.RerunLogger` when it opens.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.spectral import expected_frame_spectrum
from ..online.monitor import ChatteringMonitor
from ..plants.nonlinear import is_linear
from .blueprint import series_styles
from .record_geometry import DB_RANGE
from .spectrogram_view import log_axes

if TYPE_CHECKING:  # pragma: no cover
    from rerun import StateConfiguration

__all__ = ["expected_spectrum", "log_static"]


def expected_spectrum(monitor: ChatteringMonitor) -> np.ndarray:
    """(bins, m) expected frame spectrum of ``monitor``'s healthy chattering: the model's
    (:func:`~chatterspec.detection.spectral.expected_frame_spectrum`), or for a nonlinear model the
    calibrated threshold's empirical normalization."""
    thr = monitor.threshold
    if not is_linear(monitor.model):
        return np.asarray(thr.expected)
    return expected_frame_spectrum(monitor.model, monitor.freqs_hz, monitor.settings.stft, monitor.dt)


def log_static(
    streams: list[Any],
    monitor: ChatteringMonitor,
    *,
    channels: Sequence[str],
    keys: Sequence[str],
    lanes: list[str],
    lane_configs: list[StateConfiguration],
    expected: np.ndarray,
    band_hz: tuple[float, float],
    hop_s: float,
    width: float,
    key: float,
    cusum: bool,
) -> None:
    """Log the static entities of a monitor recording to every stream of ``streams``.

    Parameters
    ----------
    streams : list of RecordingStream
    monitor : ChatteringMonitor
        Gives frequencies (Hz), threshold, units and the boundary layer.
    channels, keys, lanes : list of str
        Per channel: name, entity key and fault-state lane entity.
    lane_configs : list of rerun.StateConfiguration
        Per channel: the lane's states and labels (:meth:`~chatterspec.viewer.fault_lanes.FaultLanes.
        configuration`).
    expected : ndarray, shape (bins, m)
        Expected frame spectrum, logged as ``/expected/<c>``.
    band_hz : (float, float)
        The spectrogram's band (Hz).
    hop_s : float
        Hop between frames (s).
    width, key : int
        The spectrogram image's width and its colour key's width (pixels,
        :func:`~chatterspec.viewer.spectrogram_view.log_axes`).
    cusum : bool
        The alarm rule is CUSUM (its view draws g; else the score).
    """
    import rerun as rr

    thr = monitor.threshold
    freqs = monitor.freqs_hz
    lo, hi = band_hz
    styles = series_styles(
        channels,
        monitor.model.output_units,
        has_estimate=monitor.settings.psi is not None,
        alarm_statistic="CUSUM g [nats]" if cusum else "score -log p [nats]",
    )
    df = float(freqs[1] - freqs[0])
    note = rr.TextDocument(
        f"Spectra: {len(freqs)} bins, 0 .. {freqs[-1]:g} Hz "
        f"(step {freqs[1]:g} Hz); spectrogram {lo:g}-{hi:g} Hz, hop "
        f"{hop_s:g} s, dB re threshold in [{DB_RANGE[0]:g}, {DB_RANGE[1]:g}]. "
        f"{thr.describe()}"
    )
    for s in streams:
        for path, style in styles:
            s.log(path, style, static=True)
        for i, c in enumerate(keys):
            log_axes(s, f"/spectrogram/{c}", band_hz, df, DB_RANGE, width, key)
            s.log(f"/threshold/{c}", rr.Tensor(thr.values[:, i], dim_names=["freq"]), static=True)
            s.log(f"/expected/{c}", rr.Tensor(expected[:, i], dim_names=["freq"]), static=True)
            s.log(lanes[i], lane_configs[i], static=True)
        s.log("/frequencies", note, static=True)
