"""Fault diagnosis by the chattering spectrum, on the same realizations as the mode-based methods: the
chattering route of ``chatterspec diagnose --methods chattering`` (``docs/design.md`` §2).

On one :class:`~chatterspec.plants.simulate.Simulation` (the same z and u the SMM-SVSF / IMM see):

1. the auxiliary sgn-SVSF on the scenario's nominal model gives the chattering ``e(k|k-1)`` (eq 17;
   :func:`~chatterspec.detection.pipeline.chattering_record`, nonlinear models via
   :mod:`~chatterspec.filters.nonlinear_svsf`);
2. its STFT frames (:func:`~chatterspec.detection.spectral.spectrogram`, eq 49 per frame) are tested
   against a calibrated per-frame, family-wise-over-bins threshold
   (``Calibration.threshold("frame-family-wise")``, the live monitor's detector) with
   :func:`~chatterspec.detection.verdicts.frame_verdicts`: per frame and channel a flag, the peak
   frequency (Hz) and the peak ratio ``S / threshold``. This is exactly what
   :class:`~chatterspec.online.monitor.ChatteringMonitor` computes frame by frame, batched over runs.

The figures, per run and then over runs (beyond the papers, which show single runs):

* **false alarms**: frames whose whole window lies in a healthy segment; a run has a false alarm when
  any of them is flagged on any channel (family-wise per run, 99 % Clopper-Pearson over runs); also the
  fraction of healthy (frame, channel) pairs flagged, to compare with the per-frame alpha;
* **detection delay** per fault onset ``t0`` (next change ``t1``): the first flagged frame whose window
  ends in ``(t0, t1]``; the delay is its *end* time minus ``t0`` (the causal delay: a frame's verdict
  exists once its last sample has arrived). Runs already in alarm on the last frame that ends before
  ``t0`` are counted (``in_alarm_at_onset``): for them the onset is not a new detection. A scenario
  faulty from the start has an onset at ``t0 = 0`` (the delay is then the time to the first flag);
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
from typing import TYPE_CHECKING, Unpack, cast

import numpy as np

from .._repr import short_repr
from .._validate import open_unit
from ..detection.pipeline import chattering_record
from ..detection.spectral import STFTConfig, spectrogram
from ..detection.thresholds import Threshold
from ..detection.verdicts import frame_verdicts
from ..errors import ParameterError
from ..jsonout import finite_or_none
from ..montecarlo import ExecutionOptions
from ..plants.scenarios import Scenario
from .diagnosis_figures import DiagnosisFigures
from .intervals import clopper_pearson

if TYPE_CHECKING:  # pragma: no cover
    from ..plants.simulate import Simulation
    from .calibration_result import Calibration

__all__ = [
    "CALIBRATION_SALT",
    "ChatteringDiagnosis",
    "ChatteringTally",
    "calibrate_for_diagnosis",
    "diagnose_chattering",
    "healthy_version",
]

#: Second entropy word of the calibration's root seed: ``SeedSequence([seed, CALIBRATION_SALT])`` is a
#: stream independent of ``SeedSequence(seed)``, which simulates the diagnosed runs.
CALIBRATION_SALT = 0xCA11B


def healthy_version(sc: Scenario) -> Scenario:
    """The scenario's nominal plant over the same input, duration, dt and initial state (no fault).

    The fault windows are dropped, and so is a faulty base plant: a scenario such as ``eha-leak-minor``
    is faulty over the whole record (its ``plant`` is the leaky model), so removing the windows alone
    would not make it healthy; its healthy version simulates the nominal model. A base plant with the
    nominal A, B, C (e.g. other noise covariances) is kept.

    Parameters
    ----------
    sc : Scenario
        Any scenario.

    Returns
    -------
    Scenario
        Named ``<name>-healthy``; ``is_healthy`` is True.
    """
    out = dataclasses.replace(sc, name=f"{sc.name}-healthy", windows=())
    if not out.is_healthy:  # the base plant itself is faulty: use the nominal model (its Q and R too)
        out = dataclasses.replace(out, plant=None)
    return out


def calibrate_for_diagnosis(
    sc: Scenario,
    seed: int,
    *,
    runs: int = 500,
    alpha: float = 1e-3,
    config: STFTConfig | None = None,
    **execution: Unpack[ExecutionOptions],
) -> Calibration:
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
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`; here ``progress`` defaults to False).

    Returns
    -------
    Calibration
    """
    from .calibration import calibrate

    root = np.random.SeedSequence([int(seed), CALIBRATION_SALT])
    execution = {"progress": False, **execution}
    return calibrate(healthy_version(sc), alpha, runs, root, config=config, **execution)


@dataclass(frozen=True, eq=False)
class ChatteringDiagnosis(DiagnosisFigures):
    """Diagnosis figures of the chattering route.

    The false-alarm and detection-delay figures (and ``method``, ``runs``, ``steps_per_second``) are
    those every route reports (:class:`~chatterspec.studies.diagnosis_figures.DiagnosisFigures`); here
    a verdict is one STFT frame on one channel.

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

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    # method, runs, the false-alarm and detection-delay figures, steps_per_second: DiagnosisFigures
    channels: tuple[str, ...]
    frames_per_run: int
    healthy_frames_per_run: int
    alpha_per_frame: float
    missed: tuple[int, ...]
    in_alarm_at_onset: tuple[int, ...]
    segments: tuple[str, ...]
    segment_span_s: tuple[tuple[float, float], ...]
    flag_fraction: np.ndarray
    flagged_channel: tuple[str | None, ...]
    peak_hz: tuple[float, ...]
    calibration: dict

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""
        return {
            "method": self.method,
            "channels": list(self.channels),
            "runs": self.runs,
            "frames_per_run": self.frames_per_run,
            "healthy_frames_per_run": self.healthy_frames_per_run,
            "alpha_per_frame": self.alpha_per_frame,
            **self.alarm_figures(),
            "missed": list(self.missed),
            "in_alarm_at_onset": list(self.in_alarm_at_onset),
            "isolation": [
                {
                    "segment": name,
                    "span_s": list(span),
                    "flag_fraction": dict(zip(self.channels, (float(v) for v in frac), strict=True)),
                    "flagged_channel": ch,
                    "peak_hz": finite_or_none(pk),
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
    sim: Simulation,
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

    Notes
    -----
    Same as one :meth:`ChatteringTally.add` of ``sim`` (use the tally to feed the runs in chunks).
    """
    tally = ChatteringTally(sim.scenario, threshold, config=config, gamma=gamma)
    tally.add(sim)
    return tally.result(calibration_info)


class ChatteringTally:
    """:func:`diagnose_chattering` fed chunk by chunk: memory bounded independently of the run count.

    Each :meth:`add` runs the auxiliary SVSF, the STFT and the frame verdicts on one chunk of
    realizations and keeps only per-run scalars (first-detection delays) and counts (false-alarm
    runs, flags per segment and channel, a histogram of the peak bins); :meth:`result` gives the
    same :class:`ChatteringDiagnosis` (every figure bit for bit, ``steps_per_second`` aside) as
    :func:`diagnose_chattering` on the concatenated runs, whatever the chunking: every realization's
    numbers depend only on that realization, the counts are integers, and the medians come from the
    same multisets of values.

    Parameters
    ----------
    scenario : Scenario
        The diagnosed scenario (nominal model with full measurement).
    threshold : Threshold
        Per-frame threshold (see :func:`diagnose_chattering`).
    config : STFTConfig, optional
        STFT settings (default 1 s Hamming, 0.2 s hop); must match the threshold's frequencies.
    gamma : float
        Convergence rate of the auxiliary SVSF in (0, 1) (eq 8-10).
    """

    def __init__(
        self,
        scenario: Scenario,
        threshold: Threshold,
        *,
        config: STFTConfig | None = None,
        gamma: float = 0.1,
    ) -> None:
        self.gamma = open_unit("gamma", gamma)
        self.config = STFTConfig() if config is None else config
        if not isinstance(threshold, Threshold):
            raise ParameterError(f"threshold must be a Threshold; got {type(threshold).__name__}")
        self.scenario = scenario
        self.threshold = threshold
        model = scenario.nominal
        dt = model.dt
        self._W = self.config.n_window(dt)
        fr = self.config.freqs_hz(dt)
        if threshold.values.shape[0] != fr.size or not np.allclose(threshold.freqs_hz, fr):
            raise ParameterError(
                f"the threshold has {threshold.values.shape[0]} frequency bins, the STFT of "
                f"{self.config.window_s} s windows at dt = {dt} s has {fr.size}: calibrate with the same "
                "STFT settings"
            )
        self._freqs = np.asarray(threshold.freqs_hz, dtype=float)
        self.runs = 0
        self._wall = 0.0
        self._geo: dict | None = None

    def _geometry(self, frame_starts: np.ndarray, t: np.ndarray, F: int, m: int) -> dict:
        sc = self.scenario
        T = t.size
        # frame j covers chattering samples [jH, jH + W) = simulation samples [jH + 1, jH + W]
        first = frame_starts + 1
        last = frame_starts + self._W
        seg = sc.segment_index(t)
        healthy_seg = np.array([not sc.deviates(s) for s in sc.segments])
        seg_first, seg_last = seg[first], seg[last]
        pure = seg_first == seg_last  # the whole window lies in one segment
        change = np.flatnonzero((seg[1:] != seg[:-1]) & ~healthy_seg[seg[1:]]) + 1
        if not healthy_seg[seg[0]]:  # faulty from the start (e.g. eha-leak-minor): an onset at t = 0
            change = np.insert(change, 0, 0)
        ends = np.append(change[1:], T)[: change.size]
        S = len(sc.segments)
        self._fa_runs = 0
        self._healthy_flags = 0
        self._delays: list[list[np.ndarray]] = [[] for _ in change]
        self._in_alarm = [0] * change.size
        self._seg_flags = np.zeros((S, m), dtype=np.int64)
        self._seg_frames = np.zeros(S, dtype=np.int64)
        self._peak_hist = np.zeros((S, m, self._freqs.size), dtype=np.int64)
        return {
            "t": t,
            "T": T,
            "F": F,
            "m": m,
            "last": last,
            "healthy_seg": healthy_seg,
            "seg_first": seg_first,
            "pure": pure,
            "healthy": pure & healthy_seg[seg_first],
            "end_t": t[last],
            "change": change,
            "ends": ends,
        }

    def add(self, sim: Simulation) -> None:
        """Diagnose one chunk of realizations and keep its per-run figures.

        Parameters
        ----------
        sim : Simulation
            Realizations (k, T, m) of the tally's scenario (e.g. one chunk of
            :func:`~chatterspec.plants.simulate.iter_simulations`).
        """
        self.absorb(sim.t, self.compute(sim))

    def compute(self, sim: Simulation) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """The heavy part of :meth:`add` (auxiliary SVSF, STFT, frame verdicts), without changing the tally.

        Returns ``(flags (k, F, m), peak_hz (k, F, m), frame_starts (F,), seconds)`` for :meth:`absorb`:
        worker processes compute, the tally absorbs in chunk order (the same figures as :meth:`add`).
        """
        model = self.scenario.nominal
        t0 = time.perf_counter()
        rec = chattering_record(model, sim.z, sim.u, gamma=self.gamma)
        spec = spectrogram(rec.values, model.dt, self.config)
        flags, peak_hz, _ = frame_verdicts(spec.power, self.threshold)  # (k, F, m)
        return flags, peak_hz, spec.frame_starts, time.perf_counter() - t0

    def absorb(self, t: np.ndarray, computed: tuple[np.ndarray, np.ndarray, np.ndarray, float]) -> None:
        """Count one chunk's :meth:`compute` output (sample times ``t`` of the record, s)."""
        flags, peak_hz, frame_starts, seconds = computed
        k = flags.shape[0]
        self._wall += seconds
        if self._geo is None:
            self._geo = self._geometry(frame_starts, t, flags.shape[1], flags.shape[2])
        g = self._geo
        if flags.shape[1:] != (g["F"], g["m"]):
            raise ParameterError(
                f"every chunk must have the scenario's record length: got {flags.shape[1]} frames of "
                f"{flags.shape[2]} channels, the first chunk had {g['F']} of {g['m']}"
            )
        self.runs += k
        any_flag = cast(np.ndarray, flags.any(axis=-1))  # (k, F)
        healthy, last, T = g["healthy"], g["last"], g["T"]
        if healthy.any():
            self._fa_runs += int(np.count_nonzero(any_flag[:, healthy].any(axis=1)))
            self._healthy_flags += int(np.count_nonzero(flags[:, healthy]))
        for i, (k0, k1) in enumerate(zip(g["change"], g["ends"], strict=True)):
            cand = (last >= k0) & (last <= min(k1, T - 1))
            hit = any_flag[:, cand]
            idx = np.where(hit.any(axis=1), np.argmax(hit, axis=1), -1)
            self._delays[i].append(
                np.where(idx >= 0, g["end_t"][cand][np.maximum(idx, 0)] - g["t"][k0], np.nan)
            )
            before = np.flatnonzero(last < k0)
            self._in_alarm[i] += int(np.count_nonzero(any_flag[:, before[-1]])) if before.size else 0
        for s in range(len(self.scenario.segments)):
            sel = g["pure"] & (g["seg_first"] == s)
            if not sel.any():
                continue
            fl = flags[:, sel]  # (k, f, m)
            self._seg_flags[s] += np.count_nonzero(fl, axis=(0, 1))
            self._seg_frames[s] += fl.shape[0] * fl.shape[1]
            pk = peak_hz[:, sel]
            for c in range(g["m"]):
                # peak_hz is the tested bin's frequency: count the bins of the flagged frames
                b = np.searchsorted(self._freqs, pk[..., c][fl[..., c]])
                self._peak_hist[s, c] += np.bincount(b, minlength=self._freqs.size)

    def _hist_median(self, counts: np.ndarray) -> float:
        """``np.median`` of the multiset ``freqs[b]`` repeated ``counts[b]`` times (same bits)."""
        n = int(counts.sum())
        cum = np.cumsum(counts)

        def nth(i: int) -> float:
            return float(self._freqs[np.searchsorted(cum, i, side="right")])

        if n % 2:
            return nth(n // 2)
        return (nth(n // 2 - 1) + nth(n // 2)) / 2.0

    def result(self, calibration_info: dict | None = None) -> ChatteringDiagnosis:
        """The diagnosis figures of every realization added so far.

        Parameters
        ----------
        calibration_info : dict, optional
            Provenance of the threshold, copied into the result.

        Returns
        -------
        ChatteringDiagnosis
        """
        if self._geo is None:
            raise ParameterError("no realization was added to the tally: call add(sim) first")
        g = self._geo
        runs, T, m = self.runs, g["T"], g["m"]
        model = self.scenario.nominal
        healthy = g["healthy"]
        n_healthy = int(np.count_nonzero(healthy))
        det_med, det_p90 = [], []
        missed = []
        for parts in self._delays:
            delay = np.concatenate(parts)
            med, p90 = _quantiles(delay)
            det_med.append(med)
            det_p90.append(p90)
            missed.append(int(np.count_nonzero(np.isnan(delay))))
        names, spans, frac, peaks = [], [], [], []
        chan: list[str | None] = []
        for s, segment in enumerate(self.scenario.segments):
            names.append("healthy" if g["healthy_seg"][s] else (segment.label or "fault"))
            spans.append((float(segment.start), float(segment.stop)))
            if not self._seg_frames[s]:
                frac.append(np.full(m, np.nan))
                chan.append(None)
                peaks.append(float("nan"))
                continue
            ff = self._seg_flags[s] / self._seg_frames[s]
            frac.append(ff)
            if not self._seg_flags[s].any():
                chan.append(None)
                peaks.append(float("nan"))
                continue
            c = int(np.argmax(ff))
            chan.append(model.output_names[c])
            peaks.append(self._hist_median(self._peak_hist[s, c]))
        return ChatteringDiagnosis(
            method="chattering",
            channels=tuple(model.output_names),
            runs=runs,
            frames_per_run=g["F"],
            healthy_frames_per_run=n_healthy,
            alpha_per_frame=float(self.threshold.alpha),
            false_alarm_runs=self._fa_runs,
            false_alarm_rate=self._fa_runs / runs,
            false_alarm_ci=clopper_pearson(self._fa_runs, runs, 0.99),
            healthy_alarm_fraction=(
                self._healthy_flags / (runs * n_healthy * m) if n_healthy else float("nan")
            ),
            onsets=tuple(float(g["t"][k]) for k in g["change"]),
            detection_median=tuple(det_med),
            detection_p90=tuple(det_p90),
            missed=tuple(missed),
            in_alarm_at_onset=tuple(self._in_alarm),
            segments=tuple(names),
            segment_span_s=tuple(spans),
            flag_fraction=np.array(frac),
            flagged_channel=tuple(chan),
            peak_hz=tuple(peaks),
            steps_per_second=runs * T / self._wall if self._wall > 0 else float("inf"),
            calibration=dict(calibration_info or {}),
        )
