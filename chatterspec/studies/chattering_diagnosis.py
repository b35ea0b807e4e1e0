"""Fault diagnosis by the chattering spectrum, on the same realizations as the mode-based methods: the
chattering half of issue 9 item 6 (``chatterspec diagnose --methods chattering``).

On one :class:`~chatterspec.plants.simulate.Simulation` (the same z and u the SMM-SVSF / IMM see):

1. the auxiliary sgn-SVSF on the scenario's nominal model gives the chattering ``e(k|k-1)`` (eq 17;
   :func:`~chatterspec.detection.pipeline.chattering_record`, nonlinear models via
   :mod:`~chatterspec.filters.nonlinear_svsf`);
2. its STFT frames (:func:`~chatterspec.detection.spectral.spectrogram`, eq 49 per frame) are tested
   against a calibrated per-frame, family-wise-over-bins threshold
   (``Calibration.threshold("frame-family-wise")``, the live monitor's detector) with
   :func:`~chatterspec.online.monitor.frame_verdicts`: per frame and channel a flag, the peak
   frequency (Hz) and the peak ratio ``S / threshold``. This is exactly what
   :class:`~chatterspec.online.monitor.ChatteringMonitor` computes frame by frame, batched over runs.

The figures, per run and then over runs (beyond the papers, which show single runs):

* **false alarms**: frames whose whole window lies in a healthy segment; a run has a false alarm when
  any of them is flagged on any channel (family-wise per run, 99 % Clopper-Pearson over runs); also the
  fraction of healthy (frame, channel) pairs flagged, to compare with the per-frame alpha;
* **detection delay** per fault onset ``t0`` (next change ``t1``): the first flagged frame whose window
  ends in ``(t0, t1]``; the delay is its *end* time minus ``t0`` (the causal delay: a frame's verdict
  exists once its last sample has arrived). Runs already in alarm on the last frame that ends before
  ``t0`` are counted (``in_alarm_at_onset``): for them the onset is not a new detection;
* **isolation**: per segment, the fraction of its frames flagged on each channel, the channel flagged
  most, and the median peak frequency (Hz) of its flagged frames on that channel;
* **cost**: realization-steps per second of chattering + STFT + verdicts (the calibration is reported
  separately: it runs once per call, or is loaded from a file).

Calibration (:func:`calibrate_for_diagnosis`): :func:`~chatterspec.studies.calibration.calibrate` on
:func:`healthy_version` of the scenario (same nominal model, input, record length and STFT settings,
no fault windows), from a root seed derived from, but disjoint from, the diagnosed runs' seed.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from .._validate import open_unit
from ..detection.pipeline import chattering_record
from ..detection.spectral import STFTConfig, spectrogram
from ..detection.thresholds import Threshold
from ..errors import ParameterError
from ..online.monitor import frame_verdicts
from ..plants.scenarios import Scenario
from .intervals import clopper_pearson

__all__ = [
    "CALIBRATION_SALT",
    "ChatteringDiagnosis",
    "calibrate_for_diagnosis",
    "diagnose_chattering",
    "healthy_version",
]

#: Second entropy word of the calibration's root seed: ``SeedSequence([seed, CALIBRATION_SALT])`` is a
#: stream independent of ``SeedSequence(seed)``, which simulates the diagnosed runs.
CALIBRATION_SALT = 0xCA11B


def healthy_version(sc: Scenario) -> Scenario:
    """The scenario without its fault windows (same nominal model, input, duration and dt).

    Parameters
    ----------
    sc : Scenario
        Any scenario.

    Returns
    -------
    Scenario
        Named ``<name>-healthy``; ``is_healthy`` is True.
    """
    return dataclasses.replace(sc, name=f"{sc.name}-healthy", windows=())


def calibrate_for_diagnosis(
    sc: Scenario,
    seed: int,
    *,
    runs: int = 500,
    alpha: float = 1e-3,
    config: STFTConfig | None = None,
    progress: bool | None = False,
):
    """Calibrate the per-frame chattering threshold on healthy runs of ``sc`` (other seeds than ``sc``'s).

    Parameters
    ----------
    sc : Scenario
        The diagnosed scenario; its :func:`healthy_version` is calibrated.
    seed : int
        The diagnosed runs' seed; the calibration uses ``SeedSequence([seed, CALIBRATION_SALT])``.
    runs : int
        Healthy calibration runs (a nonlinear model also uses 200 more pilot runs for the
        normalization spectrum, :mod:`~chatterspec.studies.empirical_calibration`).
    alpha : float
        Per-frame false-alarm probability of the threshold.
    config : STFTConfig, optional
        STFT settings (default 1 s Hamming, 0.2 s hop).
    progress : bool or None
        Progress bar (see :func:`~chatterspec.studies.montecarlo.run_study`).

    Returns
    -------
    Calibration
    """
    from .calibration import calibrate

    root = np.random.SeedSequence([int(seed), CALIBRATION_SALT])
    return calibrate(healthy_version(sc), alpha, runs, root, config=config, progress=progress)


@dataclass(frozen=True, eq=False)
class ChatteringDiagnosis:
    """Diagnosis figures of the chattering route.

    Attributes
    ----------
    method : str
        ``"chattering"``.
    channels : tuple of str
        Measured channels.
    runs : int
        Realizations.
    frames_per_run : int
        STFT frames per run.
    healthy_frames_per_run : int
        Frames whose whole window lies in a healthy segment.
    alpha_per_frame : float
        Nominal per-frame (family-wise over bins) false-alarm probability of the threshold.
    false_alarm_runs : int
        Runs with a flag on any healthy frame and channel.
    false_alarm_rate : float
        ``false_alarm_runs / runs``.
    false_alarm_ci : tuple of float
        99 % Clopper-Pearson interval of that rate.
    healthy_alarm_fraction : float
        Fraction of healthy (run, frame, channel) verdicts that are flags (compare with
        ``alpha_per_frame``).
    onsets : tuple of float
        Fault onset times (s).
    detection_median, detection_p90 : tuple of float
        Median / 90th percentile over the detecting runs of the causal detection delay (s) per onset.
    missed : tuple of int
        Runs with no flagged frame ending in ``(onset, next change]``.
    in_alarm_at_onset : tuple of int
        Runs whose last frame ending before the onset was already flagged.
    segments : tuple of str
        Segment labels (``"healthy"`` or the segment's label) in time order.
    segment_span_s : tuple of tuple of float
        ``(start, stop)`` of each segment (s).
    flag_fraction : (segments, m) array
        Fraction of the frames inside each segment (all runs) flagged on each channel.
    flagged_channel : tuple of str or None
        Per segment, the channel flagged most (None when no frame of the segment is flagged).
    peak_hz : tuple of float
        Per segment, median peak frequency (Hz) of the flagged frames on that channel (NaN if none).
    steps_per_second : float
        Realization-steps per second of chattering + STFT + verdicts.
    calibration : dict
        Where the threshold came from (runs, alpha, seconds or file).
    """

    method: str
    channels: tuple[str, ...]
    runs: int
    frames_per_run: int
    healthy_frames_per_run: int
    alpha_per_frame: float
    false_alarm_runs: int
    false_alarm_rate: float
    false_alarm_ci: tuple[float, float]
    healthy_alarm_fraction: float
    onsets: tuple[float, ...]
    detection_median: tuple[float, ...]
    detection_p90: tuple[float, ...]
    missed: tuple[int, ...]
    in_alarm_at_onset: tuple[int, ...]
    segments: tuple[str, ...]
    segment_span_s: tuple[tuple[float, float], ...]
    flag_fraction: np.ndarray
    flagged_channel: tuple[str | None, ...]
    peak_hz: tuple[float, ...]
    steps_per_second: float
    calibration: dict

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""

        def f(v: float) -> float | None:
            return None if not np.isfinite(v) else float(v)

        return {
            "method": self.method,
            "channels": list(self.channels),
            "runs": self.runs,
            "frames_per_run": self.frames_per_run,
            "healthy_frames_per_run": self.healthy_frames_per_run,
            "alpha_per_frame": self.alpha_per_frame,
            "false_alarm_runs": self.false_alarm_runs,
            "false_alarm_rate": self.false_alarm_rate,
            "false_alarm_ci99": list(self.false_alarm_ci),
            "healthy_alarm_fraction": f(self.healthy_alarm_fraction),
            "onsets_s": list(self.onsets),
            "detection_delay_median_s": [f(v) for v in self.detection_median],
            "detection_delay_p90_s": [f(v) for v in self.detection_p90],
            "missed": list(self.missed),
            "in_alarm_at_onset": list(self.in_alarm_at_onset),
            "isolation": [
                {
                    "segment": name,
                    "span_s": list(span),
                    "flag_fraction": dict(zip(self.channels, (float(v) for v in frac), strict=True)),
                    "flagged_channel": ch,
                    "peak_hz": f(pk),
                }
                for name, span, frac, ch, pk in zip(
                    self.segments,
                    self.segment_span_s,
                    self.flag_fraction,
                    self.flagged_channel,
                    self.peak_hz,
                    strict=True,
                )
            ],
            "steps_per_second": self.steps_per_second,
            "calibration": dict(self.calibration),
        }


def _quantiles(arr: np.ndarray) -> tuple[float, float]:
    ok = arr[np.isfinite(arr)]
    if not ok.size:
        return float("nan"), float("nan")
    return float(np.median(ok)), float(np.quantile(ok, 0.9))


def diagnose_chattering(
    sim: object,
    threshold: Threshold,
    *,
    config: STFTConfig | None = None,
    gamma: float = 0.1,
    calibration_info: dict | None = None,
) -> ChatteringDiagnosis:
    """Chattering-spectrum diagnosis of the realizations of ``sim``.

    Parameters
    ----------
    sim : Simulation
        Realizations (runs, T, m) of a scenario whose nominal model has full measurement.
    threshold : Threshold
        Per-frame threshold on the STFT frame spectra of ``config`` (power units per channel),
        e.g. ``calibration.threshold("frame-family-wise")``.
    config : STFTConfig, optional
        STFT settings (default 1 s Hamming, 0.2 s hop); must match the threshold's frequencies.
    gamma : float
        Convergence rate of the auxiliary SVSF in (0, 1) (eq 8-10).
    calibration_info : dict, optional
        Provenance of the threshold, copied into the result.

    Returns
    -------
    ChatteringDiagnosis
    """
    gamma = open_unit("gamma", gamma)
    config = STFTConfig() if config is None else config
    if not isinstance(threshold, Threshold):
        raise ParameterError(f"threshold must be a Threshold; got {type(threshold).__name__}")
    sc = sim.scenario  # type: ignore[attr-defined]
    model = sc.nominal
    dt = model.dt
    W = config.n_window(dt)
    fr = config.freqs_hz(dt)
    if threshold.values.shape[0] != fr.size or not np.allclose(threshold.freqs_hz, fr):
        raise ParameterError(
            f"the threshold has {threshold.values.shape[0]} frequency bins, the STFT of "
            f"{config.window_s} s windows at dt = {dt} s has {fr.size}: calibrate with the same STFT settings"
        )
    z, u, t = sim.z, sim.u, sim.t  # type: ignore[attr-defined]
    runs, T = z.shape[:2]
    t0 = time.perf_counter()
    rec = chattering_record(model, z, u, gamma=gamma)
    spec = spectrogram(rec.values, dt, config)
    flags, peak_hz, _ = frame_verdicts(spec.power, threshold)  # (runs, F, m)
    wall = time.perf_counter() - t0
    F = flags.shape[1]
    # frame j covers chattering samples [jH, jH + W) = simulation samples [jH + 1, jH + W]
    first = spec.frame_starts + 1
    last = spec.frame_starts + W
    seg = sc.segment_index(t)
    healthy_seg = np.array([not sc.deviates(s) for s in sc.segments])
    seg_first, seg_last = seg[first], seg[last]
    pure = seg_first == seg_last  # the whole window lies in one segment
    healthy = pure & healthy_seg[seg_first]
    any_flag = flags.any(axis=-1)  # (runs, F)
    fa_runs = int(np.count_nonzero(any_flag[:, healthy].any(axis=1))) if healthy.any() else 0
    end_t = t[last]
    change = np.flatnonzero((seg[1:] != seg[:-1]) & ~healthy_seg[seg[1:]]) + 1
    ends = np.append(change[1:], T)
    det_med, det_p90, missed, in_alarm = [], [], [], []
    for k0, k1 in zip(change, ends, strict=True):
        cand = (last >= k0) & (last <= min(k1, T - 1))
        hit = any_flag[:, cand]
        idx = np.where(hit.any(axis=1), np.argmax(hit, axis=1), -1)
        delay = np.where(idx >= 0, end_t[cand][np.maximum(idx, 0)] - t[k0], np.nan)
        med, p90 = _quantiles(delay)
        det_med.append(med)
        det_p90.append(p90)
        missed.append(int(np.count_nonzero(idx < 0)))
        before = np.flatnonzero(last < k0)
        in_alarm.append(int(np.count_nonzero(any_flag[:, before[-1]])) if before.size else 0)
    names, spans, frac, chan, peaks = [], [], [], [], []
    for s, segment in enumerate(sc.segments):
        names.append("healthy" if healthy_seg[s] else (segment.label or "fault"))
        spans.append((float(segment.start), float(segment.stop)))
        sel = pure & (seg_first == s)
        if not sel.any():
            frac.append(np.full(flags.shape[-1], np.nan))
            chan.append(None)
            peaks.append(float("nan"))
            continue
        fl = flags[:, sel]  # (runs, f, m)
        ff = fl.mean(axis=(0, 1))
        frac.append(ff)
        if not fl.any():
            chan.append(None)
            peaks.append(float("nan"))
            continue
        c = int(np.argmax(ff))
        chan.append(model.output_names[c])
        peaks.append(float(np.median(peak_hz[:, sel, c][fl[..., c]])))
    return ChatteringDiagnosis(
        method="chattering",
        channels=tuple(model.output_names),
        runs=runs,
        frames_per_run=F,
        healthy_frames_per_run=int(np.count_nonzero(healthy)),
        alpha_per_frame=float(threshold.alpha),
        false_alarm_runs=fa_runs,
        false_alarm_rate=fa_runs / runs,
        false_alarm_ci=clopper_pearson(fa_runs, runs, 0.99),
        healthy_alarm_fraction=float(flags[:, healthy].mean()) if healthy.any() else float("nan"),
        onsets=tuple(float(t[k]) for k in change),
        detection_median=tuple(det_med),
        detection_p90=tuple(det_p90),
        missed=tuple(missed),
        in_alarm_at_onset=tuple(in_alarm),
        segments=tuple(names),
        segment_span_s=tuple(spans),
        flag_fraction=np.array(frac),
        flagged_channel=tuple(chan),
        peak_hz=tuple(peaks),
        steps_per_second=runs * T / wall if wall > 0 else float("inf"),
        calibration=dict(calibration_info or {}),
    )
