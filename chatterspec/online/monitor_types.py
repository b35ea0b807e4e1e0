"""The online monitor's settings and outputs (frozen dataclasses), re-exported by :mod:`.monitor`.

:class:`MonitorSettings` (what the monitor tests and how it raises alarms), :class:`DetectionEvent`
(a fault start or end), :class:`FrameBlock` (the frames one push completed) and
:class:`MonitorUpdate` (everything one push produced).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from .._validate import finite_array, open_unit
from ..detection.alarm_calibration import RuleCalibration
from ..detection.alarms import AlarmRule, CusumRule, FrameRule, PersistenceRule
from ..detection.spectral import STFTConfig
from ..detection.thresholds import Threshold, check_band
from ..errors import ParameterError

__all__ = ["DetectionEvent", "EventKind", "FrameBlock", "MonitorSettings", "MonitorUpdate"]

EventKind = Literal["fault-start", "fault-end"]


@dataclass(frozen=True)
class MonitorSettings:
    """Detector settings of the online monitor.

    Parameters
    ----------
    stft : STFTConfig
        Window and hop (default 1 s Hamming, 0.2 s hop).
    alpha : float
        Per-frame false-alarm probability (0 < alpha < 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise correction over the tested bins of a frame.
    gamma : float
        SVSF convergence rate (both filters).
    psi : tuple of float, optional
        Smoothing boundary layer per output. When given, the ``sat`` SVSF runs
        too (its estimate is reported and the boundary drawn next to the
        chattering); ``None`` runs only the auxiliary filter.
    threshold : Threshold, optional
        Per-frame threshold to use instead of the analytic
        :func:`~chatterspec.detection.thresholds.frame_threshold`, e.g. the empirical one of
        a saved calibration, ``load_calibration(...).threshold("frame-family-wise")``
        (then ``alpha`` and ``correction`` are ignored). It must cover the STFT
        frequencies of ``stft``.
    band : (float, float), optional
        ``(lo, hi)`` in Hz: test only the frame bins with ``lo <= f <= hi`` (beyond the
        paper, see :mod:`chatterspec.detection.thresholds`); the correction counts only
        them. With ``threshold`` given, that threshold is restricted to the band
        (:meth:`~chatterspec.detection.thresholds.Threshold.restricted`: its level is then
        conservative). ``None`` (default): every bin but DC and Nyquist.
    rule : FrameRule, PersistenceRule or CusumRule, optional
        The alarm rule (:mod:`chatterspec.detection.alarms`) that turns the frame score
        (``-log`` of the frame's p-value, :mod:`chatterspec.detection.frame_score`) into
        fault-start / fault-end events, with its threshold set (e.g. by
        :func:`chatterspec.studies.alarm_budget.alarm_settings` for a false-alarm budget).
        ``None`` (default): the per-frame rule at ``alpha``, events where the per-frame
        verdict (``FrameBlock.flags``) changes, as before the alarm layer.
    budget : RuleCalibration, optional
        How ``rule``'s threshold was set for a budget in false alarms per hour (reported in
        events, summaries and recordings); its ``rule`` must be ``rule``.
    """

    stft: STFTConfig = field(default_factory=STFTConfig)
    alpha: float = 1e-3
    correction: Literal["none", "bonferroni", "sidak"] = "bonferroni"
    gamma: float = 0.1
    psi: tuple[float, ...] | None = None
    threshold: Threshold | None = None
    band: tuple[float, float] | None = None
    rule: AlarmRule | None = None
    budget: RuleCalibration | None = None

    def __post_init__(self) -> None:
        if self.rule is not None and not isinstance(self.rule, FrameRule | PersistenceRule | CusumRule):
            raise ParameterError(f"rule must be an alarm rule; got {type(self.rule).__name__}")
        if self.budget is not None:
            if not isinstance(self.budget, RuleCalibration):
                raise ParameterError(f"budget must be a RuleCalibration; got {type(self.budget).__name__}")
            if self.budget.rule != self.rule:
                raise ParameterError(
                    f"budget was calibrated for {self.budget.rule.to_dict()}; the rule is "
                    f"{None if self.rule is None else self.rule.to_dict()}"
                )
        if self.band is not None:
            object.__setattr__(self, "band", check_band(self.band))
        if not isinstance(self.stft, STFTConfig):
            raise ParameterError(f"stft must be an STFTConfig; got {type(self.stft).__name__}")
        object.__setattr__(self, "alpha", open_unit("alpha", self.alpha))
        object.__setattr__(self, "gamma", open_unit("gamma", self.gamma))
        if self.correction not in ("none", "bonferroni", "sidak"):
            raise ParameterError(
                f"correction must be 'none', 'bonferroni' or 'sidak'; got {self.correction!r}"
            )
        if self.threshold is not None and not isinstance(self.threshold, Threshold):
            raise ParameterError(f"threshold must be a Threshold; got {type(self.threshold).__name__}")
        if self.psi is not None:
            psi = tuple(float(p) for p in np.atleast_1d(finite_array("psi", self.psi, ndim=(0, 1))))
            if any(p <= 0 for p in psi):
                raise ParameterError(f"psi must be > 0; got {list(psi)}")
            object.__setattr__(self, "psi", psi)

    @property
    def false_alarms_per_hour(self) -> float | None:
        """The budget of :attr:`budget` (alarm starts per hour, all channels), or None."""
        return None if self.budget is None else self.budget.false_alarms_per_hour


@dataclass(frozen=True)
class DetectionEvent:
    """A change of a channel's verdict.

    Attributes
    ----------
    kind : {"fault-start", "fault-end"}
    channel : str
    channel_index : int
    time_s : float
        Centre time of the frame where the verdict changed (s).
    frame : int
        Global frame number.
    peak_hz : float
        ``fault-start``: frequency of the largest ``S / threshold`` in that frame;
        ``fault-end``: of the largest ratio seen during the fault.
    peak_ratio : float
        The corresponding ``S / threshold`` (> 1 means above threshold).
    estimate_s : float
        Onset / offset estimate of :func:`chatterspec.detection.detect.frame_intervals`:
        half a hop before ``time_s`` (the start of frame 0's window when the
        very first frame is flagged).
    rule : str
        The alarm rule that raised the event (``frame``, ``persistence``, ``cusum``).
    score : float
        The frame score ``-log p`` (nats) of the event's frame.
    statistic : float
        The rule's statistic at that frame (score, window count or CUSUM ``g``).
    threshold : float
        The rule's threshold ``h`` (same units as ``statistic``).
    false_alarms_per_hour : float or None
        The budget the threshold was set for (alarm starts per hour, all channels), None when
        the rule runs at a per-frame ``alpha``.
    """

    kind: EventKind
    channel: str
    channel_index: int
    time_s: float
    frame: int
    peak_hz: float
    peak_ratio: float
    estimate_s: float = float("nan")
    rule: str = "frame"
    score: float = float("nan")
    statistic: float = float("nan")
    threshold: float = float("nan")
    false_alarms_per_hour: float | None = None

    def describe(self) -> str:
        what = "fault start" if self.kind == "fault-start" else "fault end"
        peak = "peak" if self.kind == "fault-start" else "largest peak during the fault"
        return (
            f"{what} on {self.channel} at t = {self.time_s:.2f} s (estimated {self.estimate_s:.2f} s) "
            f"({peak} {self.peak_ratio:.2f} x threshold at {self.peak_hz:.1f} Hz) "
            f"[{alarm_label(self.rule, self.false_alarms_per_hour)}]"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers become None)."""
        return {
            "kind": self.kind,
            "channel": self.channel,
            "time_s": self.time_s,
            "estimate_s": _finite(self.estimate_s),
            "frame": self.frame,
            "peak_hz": self.peak_hz,
            "peak_ratio": self.peak_ratio,
            "rule": self.rule,
            "score": _finite(self.score),
            "statistic": _finite(self.statistic),
            "threshold": _finite(self.threshold),
            "false_alarms_per_hour": self.false_alarms_per_hour,
        }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def alarm_label(rule: str, false_alarms_per_hour: float | None) -> str:
    """``"cusum rule, 1 false alarm per 24 h"``: the rule and its budget in words."""
    if false_alarms_per_hour is None:
        return f"{rule} rule, per-frame alpha"
    x = float(false_alarms_per_hour)
    per = f"1 false alarm per {1 / x:.3g} h" if x < 1 else f"{x:.3g} false alarms per hour"
    return f"{rule} rule, {per}"


@dataclass(frozen=True, eq=False)
class FrameBlock:
    """STFT frames completed by one push.

    Attributes
    ----------
    index : (F,) int array
        Global frame numbers.
    times_s : (F,) array
        Frame-centre times (s).
    power : (F, bins, m) array
        Frame spectra (columns of :func:`chatterspec.detection.spectral.spectrogram`).
    flags : (F, m) bool array
        Per-frame, per-channel verdict (any tested bin above the threshold).
    peak_hz, peak_ratio : (F, m) arrays
        Frequency and value of the largest ``S / threshold`` over the tested bins.
    score : (F, m) array or None
        The frame score ``-log p`` (nats, :mod:`chatterspec.detection.frame_score`).
    alarm : (F, m) bool array or None
        The alarm state after each frame (the rule's decision; events are its changes).
    alarm_statistic : (F, m) array or None
        The rule's statistic after each frame (score, window count or CUSUM ``g``).
    """

    index: np.ndarray
    times_s: np.ndarray
    power: np.ndarray
    flags: np.ndarray
    peak_hz: np.ndarray
    peak_ratio: np.ndarray
    score: np.ndarray | None = None
    alarm: np.ndarray | None = None
    alarm_statistic: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return self.index.shape[0]


@dataclass(frozen=True, eq=False)
class MonitorUpdate:
    """What one :meth:`ChatteringMonitor.push` produced.

    Attributes
    ----------
    t : (K,) array
        Times of the new chattering samples (s).
    chattering : (K, m) array
        ``e(k|k-1)`` of the auxiliary filter.
    measured : (K, m) array or None
        The measurements at those times (raw pushes only).
    estimate : (K, m) array or None
        ``C x(k|k)`` of the ``sat`` SVSF (when ``psi`` is set and raw data pushed).
    frames : FrameBlock
    events : tuple of DetectionEvent
    """

    t: np.ndarray
    chattering: np.ndarray
    measured: np.ndarray | None
    estimate: np.ndarray | None
    frames: FrameBlock
    events: tuple[DetectionEvent, ...]
