"""Thresholds from a recorded healthy run of the user's own plant (``chatterspec calibrate --data``).

:func:`chatterspec.studies.calibration.thresholds.calibrate` simulates healthy runs of the nominal model. On a
real actuator the healthy chattering is what the plant and its sensors give, which the model never
matches exactly; :func:`chatterspec.online.recorded_calibration.calibrate_recorded` reads the
thresholds from a healthy recording instead and returns the same
:class:`~chatterspec.studies.calibration.result.Calibration` (the same file, accepted by
``monitor --calibration`` and ``detect --calibration`` exactly like a simulated one), with
``Calibration.source`` saying where the data came from (file name, SHA-256, time span, samples,
frames, records).

How the recording is read
    The computation is split by layer: this module plans what a recording of a given length can
    support (:func:`plan_recording`, every refusal before any work), tallies what its frames and
    records leave behind (:class:`RecordedTally`) and turns the tally into the calibration
    (:func:`recorded_calibration`); :mod:`chatterspec.online.recorded_calibration` drives the monitor.
    The measurements are pushed, in chunks of :data:`CHUNK_S` seconds, through the monitor itself
    (:class:`~chatterspec.online.monitor.ChatteringMonitor` with the monitor's STFT, band and
    ``gamma``): its auxiliary SVSF gives the chattering, its frame engine cuts the frames on its
    global grid and its :class:`~chatterspec.detection.verdicts.FrameScore` scores them, so the
    scores are the ones the monitor computes with the file (the score under a calibration file uses
    the exponential law of the file's normalization, which does not depend on the per-frame factor;
    ``tests/test_recorded_calibration.py`` checks the identity). Memory is bounded by the chunk, the
    kept tails and one score row per frame.

Normalization (``normalization``)
    ``"model"`` (linear models; default): the closed-form healthy spectrum of the nominal model (eq 56;
    the frame spectrum of :func:`~chatterspec.detection.thresholds.frame_threshold`), as a simulated
    calibration uses, so the two can be compared (``Calibration.agreement``). ``"data"`` (beyond the
    paper): the mean frame spectrum and mean record periodogram of the recording itself (one extra
    pass over the data): the score then measures departures from the *recorded* spectrum, so a
    healthy spectrum whose shape the model does not have (coloured sensor noise, mains hum, an
    unmodelled resonance) is not taken for a fault; a nonlinear model has only this one. The frame
    spectrum is not smoothed across bins: a recording holds thousands of frames (relative standard
    error per bin at most ``1 / sqrt(non-overlapping frames)``, 4 % from 10 minutes of 1 s windows),
    and a moving average over 1 Hz bins would flatten a resonance of a few Hz (by a factor 2.9 at
    the 2 Hz resonance of the tests' second-order plant). The record periodogram, one value per
    record, is smoothed over ``2 h + 1`` bins (:func:`chatterspec.detection.thresholds.smooth_spectrum`,
    as the simulated empirical calibration). Both are estimated from the same data as the quantiles
    (an in-sample effect of one frame in thousands).

Per-frame threshold
    Per channel, the ``(1 - alpha)``-quantile over frames of the largest normalized tested bin (the
    monitor's per-frame family-wise threshold), with the distribution-free order-statistic interval
    that counts only non-overlapping frames as independent
    (:func:`~chatterspec.studies.intervals._quantile_from_top`): the same estimator and interval as
    the simulated calibration, applied to the recording's frames. The record thresholds of ``detect``
    are read the same way from consecutive records of ``record_s`` seconds (``runs`` = records).

Alarm threshold at a budget
    The recording's frame scores, as one stream, are given to
    :func:`chatterspec.detection.alarms.calibration.calibrate_rule`: alarm starts counted on a grid of
    thresholds, ``log(starts per hour)`` fitted linearly in ``h`` where alarms are rare and solved
    for the budget, with a jackknife over :data:`~chatterspec.detection.alarms.calibration.BATCHES`
    batches of consecutive time (Student ``t``) for the intervals of the threshold and of the
    realized rate. Why this method: a budget of one per day is far rarer than a recording of hours
    can count (an order-statistic or Poisson interval of a *counted* rate needs about 20 alarms, 20
    days of data), while the exponential decay of the start rate in ``h`` (Siegmund's law for the
    CUSUM, the score's exponential tail for the single-frame rules) lets the rare-alarm part of a few
    hours predict it; the jackknife over consecutive batches keeps the dependence between
    overlapping frames and neighbouring thresholds (the same alarms) in the interval, which a
    Poisson interval of one count would not.

How long a recording a budget needs (:func:`min_hours`)
    The fit needs two thresholds with at least ``MIN_COUNT`` (20) starts each, a factor ``e``
    apart in starts, at rates no higher than ``MAX_RATE_PER_STEP`` (5e-4) starts per channel frame
    (the regime where the slope is constant; above it the 1-per-day threshold came out 0.5-1 nats
    low), and every leave-one-out batch fit of the jackknife must hold them too. The most starts the
    data can hold in that regime is ``MAX_RATE_PER_STEP x frames x channels``, so with ``F`` frames
    per hour, ``m`` channels and ``B`` batches::

        T_fit = e MIN_COUNT B / ((B - 1) MAX_RATE_PER_STEP m F)   hours

    (2.3 h for the EHA: 3 channels, 18 000 frames per hour), whatever the budget; a budget frequent
    enough to be *counted*, ``X T (B - 1) / B >= MIN_COUNT``, needs ``T_count = MIN_COUNT B /
    ((B - 1) X)`` instead. A recording shorter than ``min(T_fit, T_count)`` is refused with that
    length; a longer one can still fail when its grid of thresholds does not land two points in the
    regime (then the message asks for more data). These are the method's necessary conditions, not a
    precision target: the threshold's interval says how precise it is (from 4 h of EHA data the
    CUSUM threshold's jackknife standard error is about 1.6 nats, the realized rate within a factor of
    about 2; it shrinks with the length).
"""

from __future__ import annotations

import hashlib
import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal, TypedDict

import numpy as np
import scipy.stats

from ..._validate import open_unit, positive
from ...detection.alarms.calibration import (
    BATCHES,
    MAX_RATE_PER_STEP,
    MIN_COUNT,
    MonitorSettings,
    RuleCalibration,
    calibrate_rule,
    check_budget,
)
from ...detection.alarms.rules import AlarmRule, make_rule
from ...detection.spectral import periodogram, periodogram_freqs
from ...detection.thresholds import (
    NORMALIZATION_SMOOTH_BINS,
    Threshold,
    empirical_family_wise_threshold,
    smooth_spectrum,
)
from ...errors import ParameterError
from ...plants.nonlinear import is_linear
from ..intervals import QuantileEstimate, _quantile_from_top, _top_needed
from .healthy import _analytic_thresholds, _frame_thresholds, _keep_top, _merge_top
from .result import Calibration, _interval_fields, _ro, _stft_dict
from .support import min_runs
from .thresholds import _desc, _tested

__all__ = [
    "CHUNK_S",
    "MAX_TAIL_BYTES",
    "HealthyRecording",
    "RecordedTally",
    "RecordingOptions",
    "RecordingPlan",
    "array_chunks",
    "min_hours",
    "plan_recording",
    "recorded_calibration",
    "recording_of_file",
]

#: Seconds of data pushed through the monitor at a time (bounded memory).
CHUNK_S = 60.0
#: Largest memory (bytes) of the kept per-bin frame tails; above it the call is refused.
MAX_TAIL_BYTES = 256 * 2**20

Normalization = Literal["model", "data"]
Chunks = Callable[[], Iterable[tuple[np.ndarray, np.ndarray]]]


class RecordingOptions(TypedDict, total=False):
    """The keywords of :func:`plan_recording` (and of the calls that plan one)."""

    settings: MonitorSettings | None
    alpha: float
    confidence: float
    normalization: Normalization | None
    record_s: float
    rule: AlarmRule | str | None
    false_alarms_per_hour: float | None
    alarm_confidence: float
    smooth_half_width: int


@dataclass(frozen=True)
class HealthyRecording:
    """Where a healthy recording came from (recorded in the calibration file).

    Attributes
    ----------
    name : str
        The data file's name (no folder), or ``"standard input"``.
    sha256 : str
        SHA-256 of the file's bytes (hex).
    """

    name: str
    sha256: str


def recording_of_file(path: str | Path) -> HealthyRecording:
    """The :class:`HealthyRecording` of a data file: its name and the SHA-256 of its bytes.

    Parameters
    ----------
    path : str or Path
        The data file.
    """
    path = Path(path)
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return HealthyRecording(path.name, h.hexdigest())


def array_chunks(z: np.ndarray, u: np.ndarray, samples: int) -> Chunks:
    """A re-iterable source of ``(z, u)`` chunks of ``samples`` rows from whole arrays (views, no copy).

    Parameters
    ----------
    z : (T, m) array
        Measurements.
    u : (T, p) array
        Inputs.
    samples : int
        Rows per chunk.
    """

    def chunks() -> Iterator[tuple[np.ndarray, np.ndarray]]:
        for lo in range(0, z.shape[0], samples):
            yield z[lo : lo + samples], u[lo : lo + samples]

    return chunks


def min_hours(
    channels: int, frames_per_hour: float, false_alarms_per_hour: float, batches: int = BATCHES
) -> float:
    """Shortest healthy recording (h) from which an alarm threshold for the budget can be read.

    ``min(T_fit, T_count)`` of the module docstring: the extrapolating fit's regime, or a count.

    Parameters
    ----------
    channels : int
        Channels sharing the budget.
    frames_per_hour : float
        Frames (rule steps) per hour of one channel: ``3600 / hop_s``.
    false_alarms_per_hour : float
        The budget (> 0).
    batches : int
        Jackknife batches (every leave-one-out fit must be possible too).
    """
    X = check_budget(false_alarms_per_hour)
    keep = (batches - 1) / batches
    t_fit = math.e * MIN_COUNT / (keep * MAX_RATE_PER_STEP * int(channels) * float(frames_per_hour))
    t_count = MIN_COUNT / (keep * X)
    return min(t_fit, t_count)


def _per_day(x: float) -> str:
    return f"1 false alarm per {1 / x:.3g} h" if x < 1 else f"{x:g} false alarms per hour"


@dataclass(frozen=True, eq=False)
class RecordingPlan:
    """What a healthy recording of a given length supports, checked before any work (:func:`plan_recording`).

    Attributes
    ----------
    model : LinearModel or NonlinearModel
        The monitor's nominal model.
    settings : MonitorSettings
        The monitor's STFT, band and ``gamma`` (no threshold, rule, budget or ``psi``).
    n_samples : int
        Samples of the recording.
    alpha, confidence : float
        Per-frame / per-record level and the order-statistic intervals' level.
    normalization : {"model", "data"}
        See the module docstring.
    N : int
        Record length of the ``detect`` thresholds (samples).
    runs, frames, frames_eff : int
        Records, frames and non-overlapping frames the recording holds.
    k_bin, k_frame : int
        Tail values kept per bin (records, frames) for the per-bin quantile intervals.
    frames_per_hour : float
        Frames per hour of one channel.
    rule : AlarmRule or None
        The alarm rule to calibrate (None: no alarm threshold).
    false_alarms_per_hour : float
        Its budget.
    alarm_confidence : float
        Level of the alarm intervals.
    smooth_half_width : int
        Moving-average half-width of a ``"data"`` record normalization (bins).
    """

    model: Any
    settings: MonitorSettings
    n_samples: int
    alpha: float
    confidence: float
    normalization: Normalization
    N: int
    runs: int
    frames: int
    frames_eff: int
    k_bin: int
    k_frame: int
    frames_per_hour: float
    rule: AlarmRule | None
    false_alarms_per_hour: float
    alarm_confidence: float
    smooth_half_width: int

    @property
    def hours(self) -> float:
        """Hours of chattering in the recording (the first measurement initializes the filters)."""
        return (self.n_samples - 1) * self.model.dt / 3600.0

    @property
    def freqs_hz(self) -> np.ndarray:
        """Record periodogram frequencies (Hz)."""
        return periodogram_freqs(self.N, self.model.dt)

    @property
    def frame_freqs_hz(self) -> np.ndarray:
        """Frame frequencies (Hz)."""
        return self.settings.stft.freqs_hz(self.model.dt)

    @property
    def tested(self) -> np.ndarray:
        """Tested record bins (DC and Nyquist excluded)."""
        return _tested(self.freqs_hz.size, self.N)

    @property
    def frame_tested(self) -> np.ndarray:
        """Tested frame bins (DC and Nyquist excluded; the family-wise maximum runs over them)."""
        return _tested(self.frame_freqs_hz.size, self.settings.stft.n_window(self.model.dt))

    def score_threshold(self, E_frame: np.ndarray) -> Threshold:
        """The per-frame threshold whose law the monitor's score uses with a calibration of normalization
        ``E_frame`` (the factor does not enter the score: 1 here)."""
        m = E_frame.shape[1]
        return empirical_family_wise_threshold(
            E_frame, self.frame_freqs_hz, self.frame_tested, np.ones(m), self.alpha, meaning="per-frame"
        )

    def model_spectra(self) -> tuple[np.ndarray, np.ndarray]:
        """The model's closed-form healthy record and frame spectra (``"model"`` normalization)."""
        _, thr = _analytic_thresholds(self.model, self.N, self.alpha)
        _, fthr = _frame_thresholds(self.model, self.settings.stft, self.alpha)
        E_rec, E_frame = thr["exact"].expected, fthr["frame"].expected
        assert E_rec is not None and E_frame is not None  # analytic thresholds carry their expectation
        return E_rec, E_frame


def plan_recording(
    model: Any,
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
    smooth_half_width: int = NORMALIZATION_SMOOTH_BINS,
) -> RecordingPlan:
    """Check what a recording of ``n_samples`` supports and plan its calibration (every refusal here).

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The monitor's nominal model (full measurement).
    n_samples : int
        Samples in the recording.
    settings : MonitorSettings, optional
        The monitor's STFT, band and ``gamma`` (default ``MonitorSettings()``; a model file's are
        those of its ``[detector]`` and ``[svsf]`` tables, as ``chatterspec monitor`` builds them).
        Its threshold, rule, budget and ``psi`` are ignored.
    alpha : float
        Per-frame (and per-record) false-alarm probability of the thresholds, in (0, 1).
    confidence : float
        Level of the order-statistic intervals.
    normalization : {"model", "data"}, optional
        Default ``"model"`` for a linear model, ``"data"`` (the only one) for a nonlinear one.
    record_s : float
        Record length (s) of the ``detect`` thresholds (a model file's ``[simulation]`` duration, 4 s
        by default, is what ``detect MODEL.toml`` uses).
    rule, false_alarms_per_hour
        With either, the alarm threshold too: rule (name or rule; default cusum) and budget in
        alarm starts per hour, all channels together (default one per day).
    alarm_confidence : float
        Level of the alarm threshold's and rate's intervals (0.95 as the simulated calibration).
    smooth_half_width : int
        ``h`` of the ``"data"`` normalization's moving average over record periodogram bins.

    Raises
    ------
    ParameterError
        Bad parameters; a recording too short for one record or for the per-frame alpha (the
        message gives the length that would do); a budget the recording cannot support (the
        message gives the hours it needs, :func:`min_hours`); tails above :data:`MAX_TAIL_BYTES`.
    """
    settings = MonitorSettings() if settings is None else settings
    alpha = open_unit("alpha", alpha)
    confidence = open_unit("confidence", confidence)
    alarm_confidence = open_unit("alarm_confidence", alarm_confidence)
    record_s = positive("record_s", record_s, unit="s")
    linear = is_linear(model)
    norm: Normalization = normalization or ("model" if linear else "data")
    if norm not in ("model", "data"):
        raise ParameterError(f"normalization must be 'model' or 'data'; got {norm!r}")
    if norm == "model" and not linear:
        raise ParameterError(
            "a nonlinear model has no closed-form healthy spectrum: use normalization 'data'"
        )
    wants_alarm = rule is not None or false_alarms_per_hour is not None
    X = check_budget(1.0 / 24.0 if false_alarms_per_hour is None else false_alarms_per_hour)
    alarm_rule = (
        (make_rule(rule or "cusum") if isinstance(rule, str) or rule is None else rule)
        if wants_alarm
        else None
    )
    dt = model.dt
    stft = settings.stft
    W, H = stft.n_window(dt), stft.n_hop(dt)
    N = max(1, round(record_s / dt))
    n_chat = int(n_samples) - 1  # the first measurement initializes the filters
    hours = n_chat * dt / 3600.0
    nf = (n_chat - W) // H + 1 if n_chat >= W else 0
    nf_eff = (n_chat - W) // W + 1 if n_chat >= W else 0
    runs = n_chat // N
    m = model.n_outputs
    F_hour = 3600.0 / (H * dt)
    if runs < 1 or nf < 1:
        need_s = max(record_s, stft.window_s) + dt
        raise ParameterError(
            f"the recording holds {n_chat * dt:.3g} s of chattering, shorter than "
            + (f"one record of {record_s:g} s" if runs < 1 else f"one STFT window of {stft.window_s:g} s")
            + f"; record at least {need_s:g} s"
        )
    need_frames = min_runs(alpha)  # non-overlapping frames for the per-frame alpha
    if nf_eff < need_frames:
        raise ParameterError(
            f"alpha = {alpha:g} per frame needs at least {need_frames} non-overlapping frames "
            f"({need_frames * stft.window_s / 60:.3g} min of healthy data); the recording has {nf_eff} "
            f"({hours * 60:.3g} min): record longer or use a larger --alpha"
        )
    if alarm_rule is not None:
        need = min_hours(m, F_hour, X)
        if hours < need:
            raise ParameterError(
                f"{_per_day(X)} needs at least {need:.3g} h of healthy data at the {alarm_rule.name} rule "
                f"({m} channels, {F_hour:.0f} frames per hour); you gave {hours:.3g} h"
            )
    q = 1.0 - alpha
    k_bin = _top_needed(runs, q, confidence)
    k_frame = _top_needed(nf, q, confidence, nf_eff)
    n_bins, n_fbins = N // 2 + 1, stft.freqs_hz(dt).size
    tail_bytes = 8 * m * (2 * k_frame * n_fbins + k_bin * n_bins)
    if tail_bytes > MAX_TAIL_BYTES:
        raise ParameterError(
            f"alpha = {alpha:g} on {nf} frames keeps {k_frame} tail values per frequency bin "
            f"({tail_bytes / 2**20:.0f} MB > {MAX_TAIL_BYTES / 2**20:.0f} MB): use a smaller alpha or a "
            "shorter recording"
        )
    return RecordingPlan(
        model=model,
        settings=replace(settings, threshold=None, rule=None, budget=None, psi=None),
        n_samples=int(n_samples),
        alpha=alpha,
        confidence=confidence,
        normalization=norm,
        N=N,
        runs=runs,
        frames=nf,
        frames_eff=nf_eff,
        k_bin=k_bin,
        k_frame=k_frame,
        frames_per_hour=F_hour,
        rule=alarm_rule,
        false_alarms_per_hour=X,
        alarm_confidence=alarm_confidence,
        smooth_half_width=int(smooth_half_width),
    )


class RecordedTally:
    """What the frames and records of one pass over a recording leave behind.

    Without normalization spectra (the first pass of a ``"data"`` normalization) it sums the frame
    spectra and record periodograms; with them it keeps each frame's score and largest normalized
    tested bin, each record's largest normalized tested bin, and the per-bin tails.

    Parameters
    ----------
    plan : RecordingPlan
    E_rec, E_frame : (bins, m) arrays, optional
        The normalization spectra (record periodogram, frame spectrum); None: sum the spectra.
    """

    def __init__(
        self, plan: RecordingPlan, E_rec: np.ndarray | None = None, E_frame: np.ndarray | None = None
    ) -> None:
        self.plan = plan
        self.E_rec, self.E_frame = E_rec, E_frame
        self._tested, self._ftested = plan.tested, plan.frame_tested
        self._buf = np.empty((0, plan.model.n_outputs))
        self.records = 0
        self.frames = 0
        self.sum_rec: np.ndarray | None = None
        self.sum_frame: np.ndarray | None = None
        self.top_bin: np.ndarray | None = None
        self.top_frame: np.ndarray | None = None
        self.rec_max: list[np.ndarray] = []
        self.frame_max: list[np.ndarray] = []
        self.scores: list[np.ndarray] = []
        self.t_first: float | None = None
        self.t_last = 0.0

    def add(self, t: np.ndarray, chattering: np.ndarray, power: np.ndarray, score: np.ndarray | None) -> None:
        """One push's output: chattering times ``t`` (K,) and values (K, m), frame spectra (F, bins, m)
        and the monitor's frame scores (F, m)."""
        if t.size:
            self.t_first = float(t[0]) - self.plan.model.dt if self.t_first is None else self.t_first
            self.t_last = float(t[-1])
        if power.shape[0]:
            self.frames += power.shape[0]
            if score is not None and self.E_frame is not None:
                self.scores.append(score)
            self._fold("frame", power, self.E_frame, self._ftested, self.plan.k_frame)
        N = self.plan.N
        e = np.concatenate([self._buf, chattering]) if self._buf.shape[0] else chattering
        n_rec = e.shape[0] // N
        if n_rec:
            S = periodogram(e[: n_rec * N].reshape(n_rec, N, -1), self.plan.model.dt).power
            self.records += n_rec
            self._fold("rec", S, self.E_rec, self._tested, self.plan.k_bin)
        self._buf = e[n_rec * N :].copy()

    def _fold(self, kind: str, P: np.ndarray, E: np.ndarray | None, tested: np.ndarray, k: int) -> None:
        """Spectra ``P`` (n, bins, m) of frames (``kind="frame"``) or records (``"rec"``): summed without
        a normalization ``E``; else the largest normalized tested bin of each and the per-bin tails."""
        if E is None:
            s = P.sum(axis=0)
            total = getattr(self, f"sum_{kind}")
            setattr(self, f"sum_{kind}", s if total is None else total + s)
            return
        Y = P / E
        getattr(self, f"{kind}_max").append(Y[:, tested].max(axis=1))
        name = "top_frame" if kind == "frame" else "top_bin"
        top, kept = _keep_top(Y, k), getattr(self, name)
        setattr(self, name, top.copy() if kept is None else _merge_top(kept, top, k))

    def normalization(self) -> tuple[np.ndarray, np.ndarray]:
        """The ``"data"`` normalization from a first pass: mean record periodogram (smoothed) and mean
        frame spectrum (module docstring)."""
        self._check()
        assert self.sum_rec is not None and self.sum_frame is not None  # _check: records and frames seen
        E_rec = smooth_spectrum(self.sum_rec / self.records, self.plan.smooth_half_width)
        E_frame = smooth_spectrum(self.sum_frame / self.frames, 0)
        return E_rec, E_frame

    def _check(self) -> None:
        p = self.plan
        if self.records != p.runs or self.frames != p.frames:
            raise ParameterError(
                f"the chunks held {self.records} records and {self.frames} frames; n_samples = "
                f"{p.n_samples} promises {p.runs} and {p.frames}: pass the recording's length"
            )


def recorded_calibration(tally: RecordedTally, recording: HealthyRecording | None = None) -> Calibration:
    """The :class:`~chatterspec.studies.calibration.result.Calibration` of a finished tally.

    Parameters
    ----------
    tally : RecordedTally
        A pass with the normalization spectra over the whole recording.
    recording : HealthyRecording, optional
        Where the data came from, recorded in ``Calibration.source``.

    Raises
    ------
    ParameterError
        The tally does not hold the frames and records its plan promised, or the alarm fit fails.
    """
    tally._check()
    p = tally.plan
    model, dt, m = p.model, p.model.dt, p.model.n_outputs
    q = 1.0 - p.alpha
    E_rec, E_frame = tally.E_rec, tally.E_frame
    if E_rec is None or E_frame is None:
        raise ParameterError("the tally has no normalization spectra: it is a first (summing) pass")

    def per_channel(v: np.ndarray, n: int, n_eff: int | None) -> tuple[QuantileEstimate, ...]:
        val, lo, hi = _quantile_from_top(_desc(v), n, q, p.confidence, n_eff)
        return tuple(
            QuantileEstimate(q, float(val[c]), float(lo[c]), float(hi[c]), n, p.confidence) for c in range(m)
        )

    assert tally.top_bin is not None and tally.top_frame is not None  # the plan promised records and frames
    bin_q = _quantile_from_top(_desc(tally.top_bin), p.runs, q, p.confidence)
    frame_q = _quantile_from_top(_desc(tally.top_frame), p.frames, q, p.confidence, p.frames_eff)
    alarm = None if p.rule is None else _alarm(p, np.concatenate(tally.scores))
    if p.normalization == "model":
        _, thr = _analytic_thresholds(model, p.N, p.alpha)
        _, fthr = _frame_thresholds(model, p.settings.stft, p.alpha)
        analytic: dict[str, Any] = {
            "analytic": {k: _ro(t.values) for k, t in thr.items()},
            "family_wise_analytic": {
                "bonferroni": float(scipy.stats.chi2.isf(thr["exact-bonferroni"].per_test_alpha, 2) / 2),
                "sidak": float(scipy.stats.chi2.isf(thr["exact-sidak"].per_test_alpha, 2) / 2),
                "n_tested": thr["exact"].n_tested,
            },
            "frame_analytic": {k: _ro(t.values) for k, t in fthr.items()},
        }
        info: dict[str, Any] = {}
    else:
        analytic = {"analytic": {}, "family_wise_analytic": {}, "frame_analytic": {}}
        info = {
            "estimator": "mean frame spectrum of the healthy recording (not smoothed); mean record "
            "periodogram, moving average over 2h+1 bins",
            "smooth_half_width_bins": p.smooth_half_width,
            "records": p.runs,
            "frames": p.frames,
        }
    name = "recording" if recording is None else recording.name
    s = p.settings
    source = {
        "kind": "recorded healthy data",
        "data": name,
        "sha256": None if recording is None else recording.sha256,
        "span_s": [tally.t_first, tally.t_last],
        "samples": p.n_samples,
        "hours": p.hours,
        "frames": p.frames,
        "non_overlapping_frames": p.frames_eff,
        "records": p.runs,
        "record_s": p.N * dt,
        "band_hz": None if s.band is None else list(s.band),
        "gamma": s.gamma,
    }
    tail_bytes = 8 * m * (2 * p.k_frame * p.frame_freqs_hz.size + p.k_bin * p.freqs_hz.size)
    return Calibration(
        scenario=f"recorded {name}",
        model_name=model.name,
        model_fingerprint=model.fingerprint(),
        dt=dt,
        n_samples=p.N,
        stft=_stft_dict(s.stft),
        alpha=p.alpha,
        runs=p.runs,
        seed=None,
        confidence=p.confidence,
        channels=tuple(model.output_names),
        freqs_hz=_ro(p.freqs_hz),
        tested=_ro(p.tested),
        expected=_ro(E_rec),
        **_interval_fields("per_bin", bin_q),
        family_wise=per_channel(np.concatenate(tally.rec_max), p.runs, None),
        frame_freqs_hz=_ro(p.frame_freqs_hz),
        frame_tested=_ro(p.frame_tested),
        frame_expected=_ro(E_frame),
        **_interval_fields("per_frame", frame_q),
        frame_family_wise=per_channel(np.concatenate(tally.frame_max), p.frames, p.frames_eff),
        normalization="analytic" if p.normalization == "model" else "empirical",
        normalization_info=info,
        tails={"method": "exact", "budget_bytes": MAX_TAIL_BYTES, "exact_bytes": int(tail_bytes)},
        alarm=alarm,
        source=source,
        **analytic,
    )


def _alarm(p: RecordingPlan, scores: np.ndarray) -> RuleCalibration:
    """:func:`calibrate_rule` on the recording's scores as one stream; a failed fit says what to record."""
    X, rule = p.false_alarms_per_hour, p.rule
    assert rule is not None
    try:
        return calibrate_rule(rule, scores[None], p.frames_per_hour, X, confidence=p.alarm_confidence)
    except ParameterError as exc:
        raise ParameterError(
            f"{_per_day(X)} at the {rule.name} rule: the {p.hours:.3g} h of healthy data give no fit of the "
            f"start rate where alarms are rare ({exc}); either the recording is too short for its alarm "
            f"rate (record more, e.g. {2 * p.hours:.3g} h) or the scores are not stationary noise (a "
            "mismatch the input drives, as a wrong model parameter: commission the model first)"
        ) from None
