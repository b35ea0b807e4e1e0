"""Fault diagnosis over many realizations: the chattering, mode-based and identification routes.

In order: the figures every route reports (:class:`DiagnosisFigures`), the scenario variants with a
later onset (:func:`with_onset`) and the healthy version (:func:`healthy_version`), the chattering route
(:func:`diagnose_chattering`), the mode-based routes (:func:`diagnose_modes`), fault identification
per segment (:class:`IdentificationTally`) and the worker-process path of ``diagnose --workers``.

The figures every diagnosis route reports: false alarms on the healthy time, detection delay per onset.

:class:`DiagnosisFigures` is the base of the results of the mode-based routes
(:class:`~chatterspec.studies.diagnosis.ModeDiagnosis`: SMM-SVSF and IMM, a verdict per sample)
and of the chattering route (:class:`~chatterspec.studies.diagnosis.ChatteringDiagnosis`: a
verdict per STFT frame and channel). Each result adds what only its route has (modes, isolation delays
and the confusion matrix; or channels, segments and peak frequencies). :meth:`DiagnosisFigures.alarm_figures`
is the part of their ``describe()`` they share, so the JSON documents of ``chatterspec diagnose`` write
these figures with the same keys and the same NaN handling for every route.

Scenario variants for diagnosis: a fault present from ``t = 0`` moved to a later onset.

A catalogue scenario such as ``eha-leak-minor`` is faulty over its whole record: it has no healthy
time on which a detector could raise a false alarm, and its "onset" is the detector's own start.
:func:`with_onset` keeps the record (nominal model, input, duration, noise) and runs the nominal plant
until ``onset``, the scenario's faulty plant afterwards, so that a diagnosis measures false alarms on
``[0, onset)`` and a detection delay from a fault that starts while the detector is in its healthy
steady state. (:func:`~chatterspec.studies.diagnosis.healthy_version` is the companion that
removes the fault altogether.)

Fault diagnosis by the chattering spectrum, on the same realizations as the mode-based methods: the
chattering route of ``chatterspec diagnose --methods chattering`` (``docs/design.md`` §2).

On one :class:`~chatterspec.plants.simulate.Simulation` (the same z and u the SMM-SVSF / IMM see):

1. the auxiliary sgn-SVSF on the scenario's nominal model gives the chattering ``e(k|k-1)`` (eq 17;
   :func:`~chatterspec.detection.pipeline.chattering_record`, nonlinear models via
   :mod:`~chatterspec.filters.svsf`);
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

Calibration (:func:`calibrate_for_diagnosis`): :func:`~.calibration.thresholds.calibrate` on
:func:`healthy_version` of the scenario (same nominal model, input, record length and STFT settings,
no fault windows), from a root seed derived from, but disjoint from, the diagnosed runs' seed.

Fault diagnosis by mode probabilities (SMM-SVSF, IMM) on the same realizations: the mode-based routes of
``chatterspec diagnose`` (``docs/design.md`` §2); the chattering route
(:mod:`chatterspec.studies.diagnosis`) plugs in beside it.

Per method, on one :class:`~chatterspec.plants.simulate.Simulation`:

* **alarm**: at sample k the method declares a fault when its most probable mode is not the first
  (healthy) mode of ``filter_settings.modes``;
* **false alarms**: on the healthy samples (true mode 0), per run: does the run raise any alarm there
  (family-wise, with a Clopper-Pearson interval over runs), and the fraction of healthy samples in alarm;
* **detection delay** per fault onset: first sample at or after the onset whose argmax is a fault mode,
  minus the onset (s); **isolation delay**: first sample whose argmax is the *true* new mode; median and
  90th percentile over runs (NaN-aware: runs that never detect are counted separately);
* **isolation**: the confusion matrix (:func:`~chatterspec.studies.estimation.confusion_matrix`);
* **cost**: realization-steps per second of the filter alone.

Fault identification over many realizations, per segment of a scenario (``chatterspec diagnose``).

:class:`IdentificationTally` takes the same simulation chunks as the other diagnosis routes
(:mod:`chatterspec.studies.diagnosis`, :mod:`chatterspec.studies.diagnosis`) and
identifies every realization inside every segment of the true plant (one STFT hop inside the
edges shared with another segment: a window that straddles a change mixes two regressions).
Per segment it keeps, per realization, the selected hypothesis and the estimate of the
hypothesis that explains the true plant; :meth:`IdentificationTally.result` gives the
isolation rate, the median relative error and the interval's coverage with Clopper-Pearson
intervals. Only per-run numbers are kept: memory does not grow with the number of runs, and the
result does not depend on the chunking.

``chatterspec diagnose --workers N``: the heavy part of each chunk on worker processes, the same figures.

Each chunk of realizations is simulated and run through every method's filter on a worker
(:meth:`~chatterspec.studies.diagnosis.ChatteringTally.compute`,
:meth:`~chatterspec.studies.diagnosis.ModeTally.compute`); the calling process folds the chunks
**in chunk order** into the tallies (``absorb``), exactly the steps of the serial loop. Realization
``r``'s numbers do not depend on the chunking, and the running sums of the tallies see the same rows
in the same order, so every figure is the serial one, bit for bit (``steps/s`` aside: it is the
filters' own time, summed over the workers). Memory: at most ``2 x workers`` chunks in flight, each
sending back its mode probabilities (``runs x T x modes`` floats, ~14 MB for 64 runs of the 9 s EHA).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Unpack, cast

import numpy as np

from .._repr import short_repr
from .._validate import finite_array, open_unit, positive
from ..detection.identification import (
    NO_FAULT,
    IdentificationSetup,
    identify,
    true_hypothesis,
    true_parameters,
)
from ..detection.pipeline import chattering_record
from ..detection.spectral import STFTConfig, spectrogram
from ..detection.thresholds import Threshold
from ..detection.verdicts import frame_verdicts
from ..errors import ParameterError
from ..filters import ExtendedKalmanFilter
from ..filters.imm import IMM
from ..filters.smm_svsf import SMMSVSF
from ..jsonout import finite_or_none
from ..montecarlo import Execution, ExecutionOptions
from ..plants.models import LinearModel
from ..plants.scenarios import Scenario, Segment
from ..plants.simulate import Simulation, iter_simulations
from .intervals import clopper_pearson

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.identification import IdentificationSetup
    from ..detection.thresholds import Threshold
    from ..plants.scenarios import FilterSettings, Scenario
    from ..plants.simulate import Simulation
    from .calibration.result import Calibration

__all__ = [
    "CALIBRATION_SALT",
    "METHODS",
    "ChatteringDiagnosis",
    "ChatteringTally",
    "DiagnosisFigures",
    "IdentificationTally",
    "ModeDiagnosis",
    "ModeTally",
    "SegmentIdentification",
    "calibrate_for_diagnosis",
    "diagnose_chattering",
    "diagnose_modes",
    "diagnose_parallel",
    "faulty_at_start",
    "healthy_version",
    "segment_windows",
    "with_onset",
]


@dataclass(frozen=True, eq=False)
class DiagnosisFigures:
    """False-alarm and detection-delay figures of one diagnosis route on one set of realizations.

    Attributes
    ----------
    method : str
        The route (``"smm"``, ``"imm"`` or ``"chattering"``).
    runs : int
        Realizations.
    false_alarm_runs : int
        Runs with an alarm on the healthy time (family-wise per run).
    false_alarm_rate : float
        ``false_alarm_runs / runs``.
    false_alarm_ci : tuple of float
        99 % Clopper-Pearson interval of that rate.
    healthy_alarm_fraction : float
        Fraction of the healthy verdicts that are alarms (NaN when the scenario has no healthy time).
    onsets : tuple of float
        Fault onset times (s).
    detection_median, detection_p90 : tuple of float
        Median / 90th percentile over the detecting runs of the detection delay per onset (s; NaN when
        no run detects that onset).
    steps_per_second : float
        Realization-steps per second of the route.

    See Also
    --------
    chatterspec.studies.diagnosis.ModeDiagnosis : the mode-based routes' result.
    chatterspec.studies.diagnosis.ChatteringDiagnosis : the chattering route's result.
    """

    method: str
    runs: int
    false_alarm_runs: int
    false_alarm_rate: float
    false_alarm_ci: tuple[float, float]
    healthy_alarm_fraction: float
    onsets: tuple[float, ...]
    detection_median: tuple[float, ...]
    detection_p90: tuple[float, ...]
    steps_per_second: float

    def alarm_figures(self) -> dict[str, object]:
        """The false-alarm and detection-delay block of ``describe()``, JSON-ready (NaN -> None).

        Returns
        -------
        dict
            ``false_alarm_runs``, ``false_alarm_rate``, ``false_alarm_ci99``, ``healthy_alarm_fraction``,
            ``onsets_s``, ``detection_delay_median_s``, ``detection_delay_p90_s``, in that order.
        """
        return {
            "false_alarm_runs": self.false_alarm_runs,
            "false_alarm_rate": self.false_alarm_rate,
            "false_alarm_ci99": list(self.false_alarm_ci),
            "healthy_alarm_fraction": finite_or_none(self.healthy_alarm_fraction),
            "onsets_s": list(self.onsets),
            "detection_delay_median_s": [finite_or_none(v) for v in self.detection_median],
            "detection_delay_p90_s": [finite_or_none(v) for v in self.detection_p90],
        }


def faulty_at_start(sc: Scenario) -> bool:
    """True when scenario ``sc``'s true plant differs from its nominal model at ``t = 0``."""
    return bool(sc.segments) and sc.deviates(sc.segments[0])


def with_onset(sc: Scenario, onset: float) -> Scenario:
    """The scenario with its fault starting at ``onset`` seconds instead of ``t = 0``.

    Parameters
    ----------
    sc : Scenario
        A scenario whose true plant is faulty at ``t = 0`` (:func:`faulty_at_start`), e.g.
        ``eha-leak-minor`` (faulty base plant) or ``eha4-leak-minor`` (a fault window from 0 s).
    onset : float
        Fault onset in seconds, ``0 < onset < duration``.

    Returns
    -------
    Scenario
        Named ``<name>-onset<onset>s``: the nominal plant (its ``Q`` and ``R``) on ``[0, onset)``;
        from ``onset`` on, the plant that was active there (every later window unchanged).

    Raises
    ------
    ParameterError
        ``onset`` outside ``(0, duration)``, or a scenario that is healthy at ``t = 0`` (it has an
        onset of its own).
    """
    t0 = positive("onset", onset, unit="s")
    if not t0 < sc.duration:
        raise ParameterError(f"onset must be < the record length {sc.duration:g} s; got {t0:g} s")
    if not faulty_at_start(sc):
        first = next((s.start for s in sc.segments if sc.deviates(s)), None)
        where = "no fault at all" if first is None else f"its first fault starts at {first:g} s"
        raise ParameterError(
            f"scenario {sc.name!r} is healthy at t = 0 ({where}): an onset applies only to a scenario "
            "faulty from the start"
        )
    windows = []
    for s in sc.segments:
        if s.stop <= t0 or not sc.deviates(s):
            continue
        windows.append(Segment(max(s.start, t0), s.stop, s.model, s.label or sc.fault))
    label = f"{sc.level or sc.fault} from {t0:g} s"
    return dataclasses.replace(
        sc,
        name=f"{sc.name}-onset{t0:g}s",
        plant=None,
        windows=tuple(windows),
        level=label,
        description=f"{sc.description}; nominal plant before {t0:g} s",
    )


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
        normalization spectrum, :mod:`~chatterspec.studies.calibration.thresholds`).
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
    from .calibration.thresholds import calibrate

    root = np.random.SeedSequence([int(seed), CALIBRATION_SALT])
    execution = {"progress": False, **execution}
    return calibrate(healthy_version(sc), alpha, runs, root, config=config, **execution)


@dataclass(frozen=True, eq=False)
class ChatteringDiagnosis(DiagnosisFigures):
    """Diagnosis figures of the chattering route.

    The false-alarm and detection-delay figures (and ``method``, ``runs``, ``steps_per_second``) are
    those every route reports (:class:`~chatterspec.studies.diagnosis.DiagnosisFigures`); here
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


#: Mode-based methods offered here.
METHODS = ("smm", "imm")


@dataclass(frozen=True, eq=False)
class ModeDiagnosis(DiagnosisFigures):
    """Diagnosis figures of one mode-based method.

    The false-alarm and detection-delay figures (and ``method``, ``runs``, ``steps_per_second``) are
    those every route reports (:class:`~chatterspec.studies.diagnosis.DiagnosisFigures`); here
    a verdict is one sample's most probable mode.

    Attributes
    ----------
    method : str
        ``"smm"`` or ``"imm"``.
    modes : tuple of str
        Mode names (index 0 = healthy).
    runs : int
        Realizations.
    false_alarm_runs : int
        Runs with at least one alarm on a healthy sample.
    false_alarm_rate : float
        ``false_alarm_runs / runs`` (family-wise per run).
    false_alarm_ci : tuple of float
        99 % Clopper-Pearson interval of that rate.
    healthy_alarm_fraction : float
        Fraction of the healthy samples (all runs) in alarm.
    onsets : tuple of float
        Fault onset times in seconds.
    detection_median, detection_p90 : tuple of float
        Median / 90th percentile over the detecting runs of the detection delay per onset (s).
    isolation_median, isolation_p90 : tuple of float
        Same for the isolation delay (argmax = true new mode).
    missed : tuple of int
        Runs that never isolate the new mode before the next switch, per onset.
    confusion : (r, r) array
        Mean mode probability per actual mode (percent; columns sum to 100).
    steps_per_second : float
        Realization-steps per second of the filter.
    new_modes : tuple of int
        Index of the mode switched to at each onset.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    # method, runs, the false-alarm and detection-delay figures, steps_per_second: DiagnosisFigures
    modes: tuple[str, ...]
    isolation_median: tuple[float, ...]
    isolation_p90: tuple[float, ...]
    missed: tuple[int, ...]
    confusion: np.ndarray
    new_modes: tuple[int, ...] = ()

    def describe(self) -> dict[str, object]:
        """JSON-ready summary (NaN -> None)."""
        return {
            "method": self.method,
            "modes": list(self.modes),
            "runs": self.runs,
            **self.alarm_figures(),
            "isolation_delay_median_s": [finite_or_none(v) for v in self.isolation_median],
            "isolation_delay_p90_s": [finite_or_none(v) for v in self.isolation_p90],
            "missed": list(self.missed),
            "confusion_percent": [[finite_or_none(v) for v in row] for row in self.confusion],
            "steps_per_second": self.steps_per_second,
            "new_modes": [self.modes[i] for i in self.new_modes],
        }


def _filter_for(method: str, settings: FilterSettings) -> SMMSVSF | IMM:
    fs = settings
    if not fs.modes:
        raise ParameterError("the scenario's filter_settings name no modes: mode-based diagnosis needs them")
    models = fs.mode_models
    if method == "smm":
        if fs.psi is None:
            raise ParameterError("SMM-SVSF needs filter_settings.psi (the boundary layer)")
        return SMMSVSF(
            models,
            psi=np.array(fs.psi),
            gamma=0.1 if fs.gamma is None else fs.gamma,
            mapping=fs.mapping if fs.mapping in ("full", "pinv", "cov") else None,
            weight_floor=1e-3 if fs.weight_floor is None else fs.weight_floor,
            mu0=None if fs.mu0 is None else np.array(fs.mu0),
            modes=fs.modes,
        )
    if method == "imm":
        if fs.transition_matrix is None:
            raise ParameterError("IMM needs filter_settings.transition_matrix (the scenario prints none)")
        return IMM(
            [ExtendedKalmanFilter(mdl) for mdl in models],
            fs.transition_matrix,
            mu0=None if fs.mu0 is None else np.array(fs.mu0),
            modes=fs.modes,
        )
    raise ParameterError(f"method must be one of {', '.join(METHODS)}; got {method!r}")


def _delays(first: np.ndarray, t: np.ndarray, k0: int) -> np.ndarray:
    return np.where(first >= 0, t[k0 + np.maximum(first, 0)] - t[k0], np.nan)


def diagnose_modes(
    sim: Simulation, methods: Sequence[str] = METHODS, *, keep: dict | None = None
) -> list[ModeDiagnosis]:
    """Run each mode-based method on the same realizations and measure its diagnosis figures.

    Parameters
    ----------
    sim : Simulation
        Realizations of a scenario whose ``filter_settings`` name the modes (mode 0 = healthy), e.g.
        ``simulate(scenario("eha4-leak-timeline"), runs, seed)``.
    methods : sequence of str
        Any of :data:`METHODS`. IMM uses a bank of EKFs and the scenario's transition matrix.
    keep : dict, optional
        When given, ``keep[method]`` receives ``(t, mu, modes)``: the times ``sim.t[1:]`` (s), the mode
        probabilities ``(runs, T - 1, r)`` and the mode names (for ``diagnose --record`` and figures).

    Returns
    -------
    list of ModeDiagnosis
        One per method, in the given order.

    Notes
    -----
    Same as one :meth:`ModeTally.add` of ``sim`` per method (use the tallies to feed runs in chunks).
    """
    sc = sim.scenario
    results = []
    for method in methods:
        tally = ModeTally(sc, method)
        tally.add(sim, keep=keep, keep_runs=None)
        results.append(tally.result())
    return results


class ModeTally:
    """One method of :func:`diagnose_modes` fed chunk by chunk: memory bounded independently of the runs.

    Each :meth:`add` runs the filter on one chunk of realizations and keeps only per-run scalars (the
    detection and isolation delays per onset) and running totals (false-alarm runs, healthy samples in
    alarm, the confusion sums); :meth:`result` gives the same :class:`ModeDiagnosis` (bit for bit,
    ``steps_per_second`` aside) as :func:`diagnose_modes` on the concatenated runs whatever the
    chunking: each realization's filter output depends only on that realization, the counts are
    integers, the medians come from the same multisets of delays, and the confusion sums continue
    numpy's sequential sum over (run, sample) rows from one chunk to the next.

    Parameters
    ----------
    scenario : Scenario
        The diagnosed scenario (``filter_settings`` with modes; mode 0 = healthy).
    method : str
        One of :data:`METHODS`.
    """

    def __init__(self, scenario: Scenario, method: str) -> None:
        sc = scenario
        fs = sc.filter_settings
        if fs is None:
            raise ParameterError(f"scenario {sc.name!r} has no filter_settings (no modes to diagnose)")
        self.scenario = sc
        self.method = method
        self._filter = _filter_for(method, fs)
        self._fs = fs
        t = sc.time[1:]
        T = t.size
        true = np.asarray(fs.mode_index(sc))[1:]
        self._t, self._true = t, true
        self._x0 = np.zeros(sc.nominal.n_states) if fs.x0 is None else fs.x0
        self._P0 = fs.P0 if fs.P0 is not None else np.asarray(sc.nominal.Q) * 10.0
        change = np.flatnonzero((true[1:] != true[:-1]) & (true[1:] > 0)) + 1
        if true[0] > 0:  # faulty from the start: an onset at the first sample
            change = np.insert(change, 0, 0)
        self._change = change
        self._ends = np.append(change[1:], T)[: change.size]
        self._healthy = true == 0
        r = len(fs.modes)
        self._sums = [np.zeros(r) for _ in range(r)]
        self.runs = 0
        self._wall = 0.0
        self._fa_runs = 0
        self._healthy_alarms = 0
        self._dd: list[list[np.ndarray]] = [[] for _ in self._change]
        self._di: list[list[np.ndarray]] = [[] for _ in self._change]

    def add(self, sim: Simulation, *, keep: dict | None = None, keep_runs: int | None = 1) -> None:
        """Run the filter on one chunk of realizations and keep its per-run figures.

        Parameters
        ----------
        sim : Simulation
            Realizations (k, T, m) of the tally's scenario (e.g. one chunk of
            :func:`~chatterspec.plants.simulate.iter_simulations`).
        keep : dict, optional
            When given and nothing is kept yet, ``keep[method]`` receives ``(t, mu, modes)`` as in
            :func:`diagnose_modes`, with the first ``keep_runs`` realizations of this chunk.
        keep_runs : int or None
            Realizations kept in ``keep`` (None: all of this chunk).
        """
        self.absorb(self.compute(sim), keep=keep, keep_runs=keep_runs)

    def compute(self, sim: Simulation) -> tuple[np.ndarray, np.ndarray, float]:
        """The heavy part of :meth:`add` (the mode filter), without changing the tally.

        Returns ``(mu (k, T, r), argmax mode (k, T), seconds)`` for :meth:`absorb`: worker processes
        compute, the tally absorbs in chunk order (the same figures, bit for bit, as :meth:`add`).
        """
        z, u = sim.z[:, 1:], sim.u[..., :-1, :]  # u per run in closed loop
        if z.shape[1] != self._t.size:
            raise ParameterError(
                f"every chunk must have the scenario's {self._t.size + 1} samples; got {z.shape[1] + 1}"
            )
        t0 = time.perf_counter()
        out = self._filter.run(z, u, x0=self._x0, P0=self._P0)
        return out.mu, out.argmax_mode, time.perf_counter() - t0

    def absorb(
        self,
        computed: tuple[np.ndarray, np.ndarray, float],
        *,
        keep: dict | None = None,
        keep_runs: int | None = 1,
    ) -> None:
        """Count one chunk's :meth:`compute` output (``keep``, ``keep_runs`` as in :meth:`add`)."""
        fs = self._fs
        mu_raw, am, seconds = computed
        self._wall += seconds
        k = mu_raw.shape[0]
        mu = finite_array("mu", mu_raw, ndim=3)  # as confusion_matrix checks it
        if keep is not None and self.method not in keep:
            kept = mu if keep_runs is None else mu[:keep_runs].copy()
            keep[self.method] = (self._t, kept, tuple(fs.modes))
        self.runs += k
        true, healthy = self._true, self._healthy
        alarm = am != 0
        if healthy.any():
            self._fa_runs += int(np.count_nonzero(alarm[:, healthy].any(axis=1)))
            self._healthy_alarms += int(np.count_nonzero(alarm[:, healthy]))
        for i, (k0, k1) in enumerate(zip(self._change, self._ends, strict=True)):
            seg = slice(k0, k1)
            hit_d = alarm[:, seg]
            hit_i = am[:, seg] == true[k0]
            first_d = np.where(hit_d.any(axis=1), np.argmax(hit_d, axis=1), -1)
            first_i = np.where(hit_i.any(axis=1), np.argmax(hit_i, axis=1), -1)
            self._dd[i].append(_delays(first_d, self._t, int(k0)))
            self._di[i].append(_delays(first_i, self._t, int(k0)))
        # confusion sums per actual mode a: numpy sums the (run, sample) rows of mu[true == a] one after
        # the other (axis-0 reduction); prepending the running sum continues that same sequence, so the
        # result is the whole-array mean of confusion_matrix bit for bit, whatever the chunking
        r = mu.shape[-1]
        for a in range(r):
            sel = true == a
            if sel.any():
                rows = mu[:, sel].reshape(-1, r)
                self._sums[a] = np.concatenate([self._sums[a][None], rows]).sum(axis=0)

    def result(self) -> ModeDiagnosis:
        """The diagnosis figures of every realization added so far.

        Returns
        -------
        ModeDiagnosis
        """
        if not self.runs:
            raise ParameterError("no realization was added to the tally: call add(sim) first")
        runs, T = self.runs, self._t.size
        fs, true, healthy = self._fs, self._true, self._healthy
        det_med: list[float] = []
        det_p90: list[float] = []
        iso_med: list[float] = []
        iso_p90: list[float] = []
        missed = []
        for dparts, iparts in zip(self._dd, self._di, strict=True):
            dd, di = np.concatenate(dparts), np.concatenate(iparts)
            for arr, med, p90 in ((dd, det_med, det_p90), (di, iso_med, iso_p90)):
                ok = arr[np.isfinite(arr)]
                med.append(float(np.median(ok)) if ok.size else float("nan"))
                p90.append(float(np.quantile(ok, 0.9)) if ok.size else float("nan"))
            missed.append(int(np.count_nonzero(~np.isfinite(di))))
        r = len(fs.modes)
        confusion = np.full((r, r), np.nan)
        for a in range(r):
            n = int(np.count_nonzero(true == a)) * runs
            if n:
                confusion[:, a] = 100.0 * (self._sums[a] / n)
        n_healthy = int(np.count_nonzero(healthy))
        return ModeDiagnosis(
            method=self.method,
            modes=tuple(fs.modes),
            runs=runs,
            false_alarm_runs=self._fa_runs,
            false_alarm_rate=self._fa_runs / runs,
            false_alarm_ci=clopper_pearson(self._fa_runs, runs, 0.99),
            healthy_alarm_fraction=self._healthy_alarms / (runs * n_healthy) if n_healthy else float("nan"),
            onsets=tuple(float(v) for v in self._t[self._change]),
            detection_median=tuple(det_med),
            detection_p90=tuple(det_p90),
            isolation_median=tuple(iso_med),
            isolation_p90=tuple(iso_p90),
            missed=tuple(missed),
            confusion=confusion,
            steps_per_second=runs * T / self._wall if self._wall > 0 else float("inf"),
            new_modes=tuple(int(true[k]) for k in self._change),
        )


#: Trim (s) at an edge shared with another segment: the monitor's default hop.
EDGE_TRIM_S = 0.2


def segment_windows(sc: Scenario, trim_s: float = EDGE_TRIM_S) -> list[tuple[int, tuple[float, float]]]:
    """``(segment index, (start, stop))`` windows inside each segment, ``trim_s`` inside shared edges.

    Parameters
    ----------
    sc : Scenario
        Its segments of true plant.
    trim_s : float
        Seconds left out on each side of an edge shared with another segment.
    """
    out = []
    last = len(sc.segments) - 1
    for i, s in enumerate(sc.segments):
        lo = s.start + (trim_s if i > 0 else sc.dt)
        hi = s.stop - (trim_s if i < last else 0.0)
        if hi - lo > 2 * trim_s:
            out.append((i, (lo, hi)))
    return out


@dataclass(frozen=True)
class SegmentIdentification:
    """Identification over the runs of one segment.

    Attributes
    ----------
    segment_s : (float, float)
        The segment; ``window_s`` the part identified.
    true_hypothesis : str or None
        The hypothesis that explains the segment's true plant ("no fault" when it matches the
        nominal model, None when no declared hypothesis does).
    true_values : dict
        Its parameters' true values.
    runs : int
    selection_rate : dict
        Fraction of runs selecting each name.
    isolation : (float, float, float)
        Fraction selecting the true hypothesis and its 99 % Clopper-Pearson interval.
    median_estimate, median_relative_error : dict
        Per parameter of the true hypothesis (NaN for "no fault").
    coverage : dict
        Per parameter: (fraction of intervals holding the true value, 99 % CP low, high).
    """

    segment_s: tuple[float, float]
    window_s: tuple[float, float]
    true_hypothesis: str | None
    true_values: dict[str, float]
    runs: int
    selection_rate: dict[str, float]
    isolation: tuple[float, float, float]
    median_estimate: dict[str, float] = field(default_factory=dict)
    median_relative_error: dict[str, float] = field(default_factory=dict)
    coverage: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""

        def r(x: float) -> float | None:
            return None if not np.isfinite(x) else float(f"{x:.6g}")

        return {
            "segment_s": list(self.segment_s),
            "window_s": [round(v, 9) for v in self.window_s],
            "true_hypothesis": self.true_hypothesis,
            "true_values": self.true_values,
            "runs": self.runs,
            "selection_rate": {k: round(v, 6) for k, v in self.selection_rate.items() if v},
            "isolation": [r(v) for v in self.isolation],
            "median_estimate": {k: r(v) for k, v in self.median_estimate.items()},
            "median_relative_error": {k: r(v) for k, v in self.median_relative_error.items()},
            "coverage": {k: [r(x) for x in v] for k, v in self.coverage.items()},
        }


class IdentificationTally:
    """Accumulates identification over simulation chunks (see the module docstring).

    Parameters
    ----------
    sc : Scenario
    setup : IdentificationSetup
    alpha, confidence : float
    """

    def __init__(
        self, sc: Scenario, setup: IdentificationSetup, *, alpha: float = 1e-3, confidence: float = 0.95
    ) -> None:
        self.sc, self.setup, self.alpha, self.confidence = sc, setup, alpha, confidence
        self.windows = segment_windows(sc)
        self.truth = []
        for i, _ in self.windows:
            model = cast(LinearModel, sc.segments[i].model)  # (the setup's linear plant, per segment)
            name = true_hypothesis(setup, model)
            values: dict[str, float] = {}
            if name not in (None, NO_FAULT):
                params = next(h.parameters for h in setup.hypotheses if h.name == name)
                values = dict(zip(params, map(float, true_parameters(setup, model)[name]), strict=True))
            self.truth.append((name, values))
        self._selected: list[list[str]] = [[] for _ in self.windows]
        self._est: list[list[np.ndarray]] = [[] for _ in self.windows]
        self._cover: list[list[np.ndarray]] = [[] for _ in self.windows]

    def add(self, sim: Simulation) -> None:
        """Identify every run of a simulation chunk in every segment window."""
        self.absorb(sim.t, self.compute(sim))

    def compute(self, sim: Simulation) -> list[tuple[list[str], np.ndarray | None, np.ndarray | None]]:
        """The heavy part of :meth:`add` (on a worker with ``diagnose --workers``): per window the
        selected names, the true hypothesis's estimates and whether its intervals cover the truth."""
        out = []
        for w, (_, window) in enumerate(self.windows):
            idn = identify(
                self.setup.model,
                sim.z,
                sim.u,
                hypotheses=self.setup.hypotheses,
                window_s=window,
                t0=float(sim.t[0]),
                alpha=self.alpha,
                confidence=self.confidence,
            )
            name, values = self.truth[w]
            est = cover = None
            if values:
                assert name is not None  # (values: a named hypothesis)
                est = np.stack([idn.estimate(name, p) for p in values], axis=1)
                lo_hi = [idn.interval(name, p) for p in values]
                tv = np.array(list(values.values()))
                cover = np.stack(
                    [(lo <= t) & (t <= hi) for (lo, hi), t in zip(lo_hi, tv, strict=True)], axis=1
                )
            out.append((idn.selected, est, cover))
        return out

    def absorb(
        self, t: np.ndarray, computed: list[tuple[list[str], np.ndarray | None, np.ndarray | None]]
    ) -> None:
        """Fold one chunk's :meth:`compute` in (chunks in order: the serial figures)."""
        for w, (selected, est, cover) in enumerate(computed):
            self._selected[w] += selected
            if est is not None:
                assert cover is not None  # (computed with est)
                self._est[w].append(est)
                self._cover[w].append(cover)

    def result(self) -> list[SegmentIdentification]:
        """One :class:`SegmentIdentification` per segment window."""
        out = []
        for w, (i, window) in enumerate(self.windows):
            seg = self.sc.segments[i]
            name, values = self.truth[w]
            sel = self._selected[w]
            n = len(sel)
            names = [NO_FAULT, *(h.name for h in self.setup.hypotheses), "unexplained"]
            rate = {k: sel.count(k) / n for k in names} if n else {}
            hit = sel.count(name) if name is not None else 0
            lo, hi = clopper_pearson(hit, n, 0.99) if n else (np.nan, np.nan)
            med, rel, cov = {}, {}, {}
            if values and self._est[w]:
                est = np.concatenate(self._est[w])
                cv = np.concatenate(self._cover[w])
                for j, (p, t) in enumerate(values.items()):
                    med[p] = float(np.nanmedian(est[:, j]))
                    rel[p] = float(np.nanmedian(np.abs(est[:, j] - t) / abs(t))) if t != 0 else float("nan")
                    k = int(cv[:, j].sum())
                    cl, ch = clopper_pearson(k, n, 0.99)
                    cov[p] = (k / n, cl, ch)
            out.append(
                SegmentIdentification(
                    segment_s=(seg.start, seg.stop),
                    window_s=window,
                    true_hypothesis=name,
                    true_values=values,
                    runs=n,
                    selection_rate=rate,
                    isolation=(hit / n if n else np.nan, lo, hi),
                    median_estimate=med,
                    median_relative_error=rel,
                    coverage=cov,
                )
            )
        return out


def _tallies(
    scenario: Scenario,
    methods: tuple[str, ...],
    threshold: Threshold | None,
    identification: tuple[IdentificationSetup, float, float] | None = None,
) -> list[ChatteringTally | ModeTally | IdentificationTally]:
    def chattering() -> ChatteringTally:
        assert threshold is not None  # (given with the chattering route)
        return ChatteringTally(scenario, threshold)

    out: list[ChatteringTally | ModeTally | IdentificationTally] = [
        chattering() if m == "chattering" else ModeTally(scenario, m) for m in methods
    ]
    if identification is not None:  # (setup, alpha, confidence): fault identification per segment, last
        setup, alpha, confidence = identification
        out.append(IdentificationTally(scenario, setup, alpha=alpha, confidence=confidence))
    return out


@dataclass(frozen=True, eq=False)
class _DiagnoseStudy:
    """A :class:`~chatterspec.montecarlo.Study` whose accumulator is the tallies themselves."""

    scenario: Scenario
    methods: tuple[str, ...]
    threshold: Threshold | None
    keep: bool
    identification: tuple[IdentificationSetup, float, float] | None = None

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> Any:
        (sim,) = iter_simulations(self.scenario, runs, seed, chunk_runs=runs, first_run=first_run)
        tallies = _tallies(self.scenario, self.methods, self.threshold, self.identification)
        return sim.t, [tally.compute(sim) for tally in tallies]

    def reduce(self, acc: Any, part: Any) -> Any:
        if acc is None:
            acc = {
                "tallies": _tallies(self.scenario, self.methods, self.threshold, self.identification),
                "keep": {},
            }
        t, computed = part
        for tally, c in zip(acc["tallies"], computed, strict=True):
            if isinstance(tally, ModeTally):
                tally.absorb(c, keep=acc["keep"] if self.keep else None, keep_runs=1)
            else:
                tally.absorb(t, c)
        return acc


def diagnose_parallel(
    scenario: Scenario,
    methods: tuple[str, ...],
    threshold: Threshold | None,
    runs: int,
    seed: int,
    *,
    keep: bool = False,
    identification: tuple[IdentificationSetup, float, float] | None = None,
    **execution: Unpack[ExecutionOptions],
) -> tuple[list[ChatteringTally | ModeTally | IdentificationTally], dict[str, Any]]:
    """The tallies of ``methods`` over ``runs`` realizations, computed on workers (same figures as serial).

    Parameters
    ----------
    scenario : Scenario
        The diagnosed scenario.
    methods : tuple of str
        ``"chattering"``, ``"smm"``, ``"imm"`` (as ``chatterspec diagnose --methods``).
    threshold : Threshold or None
        The chattering route's per-frame threshold (None without that route).
    runs, seed : int
        Realizations and root seed.
    keep : bool
        Keep realization 0's mode probabilities per mode method (for ``--record``).
    identification : (IdentificationSetup, float, float), optional
        ``(setup, alpha, confidence)``: fault identification per segment too
        (:class:`~chatterspec.studies.diagnosis.IdentificationTally`), returned last.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    (list of tallies, dict)
        The tallies in ``methods`` order (call ``result()``), and the kept mode probabilities.
    """

    ex = Execution(**execution)
    study = _DiagnoseStudy(scenario, tuple(methods), threshold, keep, identification)
    acc = ex.run(study, runs, seed, "diagnose")
    return acc["tallies"], acc["keep"]
