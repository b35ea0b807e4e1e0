"""Detection verdicts, severity scores and onset/offset localization (``docs/design.md`` §6).

This module runs a record or a study (:func:`detect_record`, :func:`detect_chunks`,
:func:`detect_scenario`); the verdicts (whole records and STFT frames) live in
:mod:`~chatterspec.detection.verdicts`; the report (:class:`DetectionReport`, its text table
:func:`detection_table`) is here.

A channel is flagged when its spectrum exceeds the threshold at any **tested** bin; where the fault
is (``peak_hz``, ``most_significant_hz``) and how large (``peak_ratio``, ``excess_power``) are defined
in :mod:`~chatterspec.detection.verdicts`. The default detector is the ``exact`` threshold
with Bonferroni correction at family-wise alpha = 0.1 %.

The report
----------
The record-level detection report, :class:`DetectionReport` (what the runs above return), and
its text table (:func:`detection_table`: ``DetectionReport.table()`` and ``chatterspec detect``).

Settings and chunk plan
-----------------------
The detector's settings and the plan every chunk of a study is tested against, here or on workers.

Worker processes run the same code as a run in this process:
:class:`DetectorOptions` holds the settings of every entry point, :meth:`ChunkPlan.build` makes the
thresholds (and run 0's STFT intervals) from the first record, :meth:`ChunkPlan.test` one chunk's
verdicts and summed spectrum, :meth:`ChunkPlan.reduce` folds them in chunk order and
:meth:`ChunkPlan.report` gives the :class:`DetectionReport`;
:func:`detect_on_workers` runs the chunks as a :class:`DetectStudy` through
:func:`~chatterspec.montecarlo.run_study` (``detect_scenario(..., workers=N)``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypedDict, Unpack, cast

import numpy as np

from .._repr import short_repr
from .._validate import positive_int
from ..errors import ParameterError, ShapeError
from ..montecarlo import Execution, SeedLike
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, is_linear
from ..plants.scenarios import Scenario
from .pipeline import ChatteringRecord, iter_chattering
from .spectral import DEFAULT_STFT, STFTConfig, expected_spectrum, periodogram
from .thresholds import Band, Correction, Threshold, check_detector, exact_threshold, paper_threshold
from .verdicts import (
    _VERDICT_FIELDS,
    ChannelVerdict,
    FrameDetection,
    SpectrumDetection,
    _require_empirical,
    detect_spectrum,
    stft_detect,
)

if TYPE_CHECKING:  # pragma: no cover
    from .identification import IdentificationStream

__all__ = [
    "DETECT_CHUNK_RUNS",
    "DetectionReport",
    "DetectorKeywords",
    "DetectorOptions",
    "detect_chunks",
    "detect_record",
    "detect_scenario",
    "detection_table",
]


@dataclass(frozen=True, eq=False)
class DetectionReport:
    """Detection of a :class:`~chatterspec.detection.pipeline.ChatteringRecord` (or a stream of chunks).

    Attributes
    ----------
    scenario : str or None
        Scenario name.
    channels : tuple of str
    runs : int
    per_run : SpectrumDetection
        ``(runs, m)`` verdict arrays, one per realization, against the single-record
        threshold (``per_run.threshold``).
    averaged : SpectrumDetection or None
        ``(m,)`` verdict of the Monte Carlo averaged spectrum (Fig 6) against the
        averaged ``exact`` threshold with K = runs (``averaged.threshold``), whatever
        the single-record rule; None when runs == 1.
    frames : FrameDetection or None
        STFT detection of run 0 (multi-segment scenarios, or when requested).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays
    _repr_extra = ("detected",)

    scenario: str | None
    channels: tuple[str, ...]
    runs: int
    per_run: SpectrumDetection
    averaged: SpectrumDetection | None = None
    frames: FrameDetection | None = field(default=None)

    @property
    def verdicts(self) -> tuple[ChannelVerdict, ...]:
        """Single-run verdicts (runs == 1) or the averaged-spectrum verdicts (runs > 1)."""
        if self.averaged is not None:
            return self.averaged.verdicts()
        return self.per_run.verdicts(0)

    @property
    def detected(self) -> bool:
        """Any channel of :attr:`verdicts` detected."""
        return any(v.detected for v in self.verdicts)

    @property
    def detection_rate(self) -> dict[str, float]:
        """Fraction of the runs detected, per channel (single-record threshold)."""
        return {c: float(r) for c, r in zip(self.channels, self.per_run.detection_rate, strict=True)}

    def table(self) -> str:
        """The report as the text table ``chatterspec detect`` prints (one row per channel).

        Returns
        -------
        str
            See :func:`chatterspec.detection.detect.detection_table`.
        """

        return detection_table(self.to_dict())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready report.

        Keys: ``scenario``, ``runs``, ``detected``, ``threshold`` (the single-record
        threshold: kind, alpha, alpha_meaning, correction, band, n_tested,
        description), ``channels`` (list of ``{"channel", "detected", "peak_hz",
        "most_significant_hz", "peak_ratio", "excess_power", "dc_ratio",
        "ratio_threshold"}``: the single run, or with ``runs > 1`` the
        averaged-spectrum verdict plus ``"detection_rate"``, the fraction of single
        runs detected by ``threshold``), ``"averaged"`` (bool), with ``runs > 1``
        ``"averaged_threshold"`` (same keys plus ``records``), ``"verdict_threshold"``
        (``"threshold"`` or ``"averaged_threshold"``: the one ``detected``,
        ``peak_ratio`` and ``most_significant_hz`` refer to; ``ratio_threshold``
        repeats it per channel) and, when the STFT was run, ``"intervals"`` (list of
        ``{"channel", "onset_s", "offset_s"}`` for run 0, channel ``"any"`` included).
        """
        chans = []
        rates = self.detection_rate
        which = "averaged_threshold" if self.averaged is not None else "threshold"
        for v in self.verdicts:
            d = v.to_dict()
            d["ratio_threshold"] = which
            if self.runs > 1:
                d["detection_rate"] = rates[v.channel]
            chans.append(d)
        out: dict[str, object] = {
            "scenario": self.scenario,
            "runs": self.runs,
            "detected": bool(self.detected),
            "averaged": self.averaged is not None,
            "verdict_threshold": which,
            "threshold": _threshold_dict(self.per_run.threshold),
            "channels": chans,
        }
        if self.averaged is not None:
            out["averaged_threshold"] = {**_threshold_dict(self.averaged.threshold), "records": self.runs}
        if self.frames is not None:
            out["intervals"] = [
                {"channel": ch, "onset_s": on, "offset_s": off}
                for ch, ivs in self.frames.intervals.items()
                for on, off in ivs
            ]
        return out


def _threshold_dict(th: Threshold) -> dict[str, object]:
    return {
        "kind": th.kind,
        "alpha": th.alpha,
        "alpha_meaning": th.alpha_meaning,
        "correction": th.correction,
        "band": None if th.band is None else list(th.band),
        "n_tested": th.n_tested,
        "description": th.describe(),
    }


def detection_table(doc: Mapping[str, Any]) -> str:
    """The per-channel table of a detection report's :meth:`~DetectionReport.to_dict` document.

    Parameters
    ----------
    doc : mapping
        ``DetectionReport.to_dict()`` (``chatterspec detect --json`` adds ``seed`` and
        ``fault_intervals_true``, shown when present).

    Returns
    -------
    str
        Lines: the threshold, a legend, one row per channel (detected, peak Hz, most significant
        Hz, peak ratio, excess power; detection rate with runs > 1), the verdict and the STFT
        intervals (seconds) when the STFT ran. No trailing newline.
    """
    th = doc["threshold"]
    runs = doc["runs"]
    lines = []
    seed = f"  seed {doc['seed']}" if "seed" in doc else ""
    lines.append(f"scenario {doc['scenario']}  runs {runs}{seed}")
    lines.append(f"threshold: {th['description']}")
    head = (
        f"{'channel':<10} {'detected':<9} {'peak Hz':>8} {'signif Hz':>9} {'peak ratio':>11} "
        f"{'excess power':>13}"
    )
    if runs > 1:
        head += f" {'rate':>6}"
    if runs > 1 and "averaged_threshold" in doc:  # none for an empirical (nonlinear) calibration
        lines.append(f"averaged spectrum: {doc['averaged_threshold']['description']}")
        lines.append(
            "(detected, signif Hz and peak ratio: averaged spectrum vs the averaged threshold; "
            "rate: fraction of single runs detected by the single-record threshold)"
        )
    elif runs > 1:
        lines.append("(detected, signif Hz and peak ratio: run 0; rate: fraction of runs detected)")
    lines.append(
        "(peak Hz: largest excess power S - E[S]; signif Hz: largest S / threshold, ratio = peak ratio)"
    )
    lines.append(head)
    for c in doc["channels"]:
        line = (
            f"{c['channel']:<10} {'YES' if c['detected'] else 'no':<9} {c['peak_hz']:8.2f} "
            f"{c['most_significant_hz']:9.2f} {c['peak_ratio']:11.3f} {c['excess_power']:13.4f}"
        )
        if runs > 1:
            line += f" {c['detection_rate']:6.3f}"
        lines.append(line)
    lines.append(f"fault detected: {'YES' if doc['detected'] else 'no'}")
    if "intervals" in doc:
        ivs = [iv for iv in doc["intervals"] if iv["channel"] == "any"]
        shown = ", ".join(f"[{iv['onset_s']:.1f}, {iv['offset_s']:.1f}] s" for iv in ivs) or "none"
        lines.append(f"STFT intervals (any channel): {shown}")
        if "fault_intervals_true" in doc:
            true = ", ".join(f"[{a:g}, {b:g}) s" for a, b in doc["fault_intervals_true"]) or "none"
            lines.append(f"true fault windows: {true}")
    return "\n".join(lines)


class DetectorKeywords(TypedDict, total=False):
    """The keyword-only settings ``stft``, ``config``, ``band``, ``frame_threshold`` of the detectors.

    :func:`~chatterspec.detection.detect.detect_record`, :func:`~chatterspec.detection.detect.detect_chunks`
    and :func:`~chatterspec.detection.detect.detect_scenario` take them as ``**detector`` and run with
    ``DetectorOptions(alpha, threshold, correction, **detector)``; :class:`DetectorOptions` documents them.
    """

    stft: bool | None
    config: STFTConfig
    band: Band | None
    frame_threshold: Threshold | None


@dataclass(frozen=True)
class DetectorOptions:
    """The detector's settings, shared by every detection entry point.

    The defaults are theirs: the exact threshold with Bonferroni correction at family-wise
    ``alpha`` = 0.1 %, the STFT intervals when the scenario has several segments, every bin tested.

    Parameters
    ----------
    alpha : float
        False-alarm probability in (0, 1); family-wise for ``"exact"`` with a
        correction, per-bin for ``"paper"`` (the paper's rule, eq 57).
    threshold : {"exact", "paper"} or Threshold
        Threshold kind, or a ready :class:`~chatterspec.detection.thresholds.Threshold`
        (e.g. the empirical one of a saved calibration,
        ``Calibration.threshold("family-wise")``), used as is: its ``alpha``
        replaces ``alpha`` and it must cover the record's periodogram bins.
    correction : {"bonferroni", "sidak", "none"}
        Used by ``"exact"`` and by the averaged verdict of every kind (``"paper"``
        itself is per-bin).
    stft : bool, optional
        Also run the STFT detector on run 0 (intervals). Default: when the record's
        scenario has more than one segment and the record holds one window.
    config : STFTConfig
        STFT settings of those intervals (default 1 s Hamming window, 0.2 s hop).
    band : (float, float), optional
        The tested band ``(lo, hi)`` in Hz: only these bins are tested, by every threshold (single,
        averaged, STFT frames); the correction counts only them; DC and Nyquist stay
        excluded. A ready threshold is narrowed with :meth:`Threshold.restricted`.
    frame_threshold : Threshold, optional
        Per-frame threshold of the STFT intervals instead of the analytic one (see
        :func:`~chatterspec.detection.verdicts.stft_detect`); with a nonlinear model the STFT runs
        only when it is given.

    Raises
    ------
    ParameterError
        A bad ``alpha``, ``correction``, band or threshold kind (the entry points build this object
        first; :class:`ChunkPlan` and the workers take it as checked).

    See Also
    --------
    DetectorKeywords : the keyword-only settings as the ``**detector`` keywords of the entry points.
    """

    alpha: float = 1e-3
    threshold: str | Threshold = "exact"
    correction: Correction = "bonferroni"
    stft: bool | None = None
    config: STFTConfig = DEFAULT_STFT
    band: Band | None = None
    frame_threshold: Threshold | None = None

    def __post_init__(self) -> None:
        checked = check_detector(self.alpha, self.correction, self.band)
        for name, value in zip(("alpha", "correction", "band"), checked, strict=True):
            object.__setattr__(self, name, value)
        if not isinstance(self.threshold, Threshold) and self.threshold not in ("exact", "paper"):
            raise ParameterError(f"unknown threshold kind {self.threshold!r}; choose 'exact' or 'paper'")


@dataclass(frozen=True, eq=False)
class ChunkPlan:
    """What :func:`detect_chunks` tests every chunk against (picklable: worker processes use it too).

    Built from the study's first record (:meth:`build`); :meth:`test` turns one chunk's chattering
    into its verdicts and summed spectrum, :meth:`reduce` folds them in chunk order and
    :meth:`report` makes the :class:`DetectionReport`. The same chunks folded in the same order give
    the same bits however they were computed.
    """

    model: Model
    channels: tuple[str, ...]
    dt: float
    n_samples: int
    freqs: np.ndarray
    threshold: Threshold
    expected: np.ndarray
    alpha: float
    correction: Correction
    band: Band | None
    scenario_name: str | None
    frames: FrameDetection | None

    @classmethod
    def build(cls, first: ChatteringRecord, options: DetectorOptions = DetectorOptions()) -> ChunkPlan:
        """The thresholds (and run 0's STFT intervals) from the first record of a study."""
        threshold, correction, stft = options.threshold, options.correction, options.stft
        config, band, frame_threshold = options.config, options.band, options.frame_threshold
        alpha = options.alpha  # (validated by DetectorOptions)
        model, channels, dt = first.model, first.channels, first.dt
        pg = periodogram(first.values[:1], dt)
        freqs, n_samples = pg.freqs_hz, pg.n_samples
        linear = is_linear(model)
        if not linear:  # nonlinear: no closed-form E[S]; the calibrated empirical threshold carries E_hat
            _require_empirical(model, threshold)
            if frame_threshold is None:
                stft = False  # no closed-form frame spectrum either
        E = (
            expected_spectrum(model, freqs, n_samples)
            if is_linear(model)
            else _require_empirical(model, threshold)
        )
        if isinstance(threshold, Threshold):
            th = threshold
            if th.values.shape != pg.power.shape[-2:] or not np.allclose(th.freqs_hz, freqs):
                raise ShapeError(
                    f"the given threshold covers {th.values.shape[0]} bins x {th.values.shape[1]} channels "
                    f"at other frequencies than this record's periodogram {pg.power.shape[-2:]}: it was "
                    "calibrated for another record length or model"
                )
            th = th.restricted(band)
            alpha = th.alpha
        elif threshold == "exact":  # (a nonlinear model needed a Threshold: _require_empirical above)
            th = exact_threshold(cast(LinearModel, model), freqs, n_samples, alpha, correction, band=band)
        else:  # "paper" (DetectorOptions refuses any other kind)
            th = paper_threshold(cast(LinearModel, model), freqs, alpha, band=band)
        sc = first.scenario
        if stft is None:
            stft = sc is not None and len(sc.segments) > 1 and n_samples >= config.n_window(dt)
        frames = None
        if stft:
            frames = stft_detect(
                first.values[:1],
                model,
                t0=float(first.t[0]),
                config=config,
                alpha=alpha,
                channels=channels,
                band=band,
                threshold=frame_threshold,
            )
        return cls(
            model=model,
            channels=channels,
            dt=dt,
            n_samples=n_samples,
            freqs=freqs,
            threshold=th,
            expected=E,
            alpha=alpha,
            correction=correction,
            band=band,
            scenario_name=None if sc is None else sc.name,
            frames=frames,
        )

    def test(self, values: np.ndarray) -> tuple[SpectrumDetection, np.ndarray, int]:
        """One chunk ``(runs, N, m)``: its per-run verdicts, summed power ``(bins, m)`` and run count."""
        pg = periodogram(values, self.dt)
        if pg.power.shape[-2:] != (self.freqs.size, len(self.channels)):
            raise ShapeError(
                f"chunk of {values.shape[-2]} samples does not match the first chunk's {self.n_samples}"
            )
        part = detect_spectrum(pg.power, self.threshold, self.expected, self.channels)
        return part, pg.power.sum(axis=0), values.shape[0]

    @staticmethod
    def reduce(acc: list | None, part: tuple[SpectrumDetection, np.ndarray, int]) -> list:
        """Fold one chunk's :meth:`test` into the accumulator (chunk order)."""
        if acc is None:
            return [[part[0]], part[1].copy(), part[2]]
        acc[0].append(part[0])
        acc[1] += part[1]
        acc[2] += part[2]
        return acc

    def report(self, acc: list) -> DetectionReport:
        """The :class:`DetectionReport` of the folded chunks."""
        parts, power_sum, runs = acc
        per_run = SpectrumDetection(
            **{k: np.concatenate([getattr(p, k) for p in parts]) for k in _VERDICT_FIELDS},
            channels=self.channels,
            threshold=self.threshold,
        )
        averaged = None
        if runs > 1 and is_linear(self.model):
            th_avg = exact_threshold(
                self.model,
                self.freqs,
                self.n_samples,
                self.alpha,
                self.correction,
                averaged=runs,
                band=self.band,
            )
            averaged = detect_spectrum(power_sum / runs, th_avg, self.expected, self.channels)
        return DetectionReport(
            scenario=self.scenario_name,
            channels=self.channels,
            runs=runs,
            per_run=per_run,
            averaged=averaged,
            frames=self.frames,
        )


@dataclass(frozen=True, eq=False)
class DetectStudy:
    """A :class:`~chatterspec.montecarlo.Study`: one chunk's verdicts and summed spectrum."""

    scenario: Scenario
    plan: ChunkPlan
    gamma: float
    identification: Any = None  # an IdentificationStream's (setup, alpha, confidence), or None

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> Any:
        """Realizations ``first_run ..`` of ``seed`` tested: ``(accumulator, identifications)``."""
        acc, parts = None, []
        keep = self.identification is not None
        for rec in iter_chattering(
            self.scenario,
            runs,
            seed,
            chunk_runs=runs,
            first_run=first_run,
            gamma=self.gamma,
            measurements=keep,
            reuse_measurements=keep,
        ):
            acc = self.plan.reduce(acc, self.plan.test(rec.values))
            if keep:
                from .identification import identify_record

                setup, alpha, confidence = self.identification
                parts.append(identify_record(rec, alpha=alpha, confidence=confidence, setup=setup))
        return acc, parts

    def reduce(self, acc: Any, part: Any) -> Any:
        """``acc`` with one chunk's :meth:`run_chunk` folded in (chunk order, as :meth:`ChunkPlan.reduce`)."""
        if acc is None:
            return part
        acc[0][0].extend(part[0][0])
        acc[0][1] += part[0][1]
        acc[0][2] += part[0][2]
        acc[1].extend(part[1])
        return acc


def detect_on_workers(
    scenario: Scenario,
    runs: int,
    seed: SeedLike,
    options: DetectorOptions,
    execution: Execution,
    *,
    gamma: float = 0.1,
    identification: IdentificationStream | None = None,
) -> DetectionReport:
    """The worker path of :func:`~chatterspec.detection.detect.detect_scenario` (see there).

    Parameters
    ----------
    scenario, runs, seed, gamma, identification
        As in :func:`~chatterspec.detection.detect.detect_scenario` (``runs`` already checked).
    options : DetectorOptions
        The detector's settings.
    execution : Execution
        Where and in what chunks the realizations run.

    Returns
    -------
    DetectionReport
        Equal to ``detect_chunks(iter_chattering(scenario, runs, seed, chunk_runs=...), ...)``.
    """
    from ..montecarlo import root_seed_sequence

    root = root_seed_sequence(seed)
    first = next(iter_chattering(scenario, 1, root, chunk_runs=1, gamma=gamma))  # realization 0
    plan = ChunkPlan.build(first, options)
    ident = (
        None
        if identification is None
        else (identification.setup, identification.alpha, identification.confidence)
    )
    acc, parts = execution.run(
        DetectStudy(scenario, plan, gamma, ident), runs, root, f"detect {scenario.name}"
    )
    if identification is not None:  # (parts: one per chunk with identification, else none)
        for part in parts:
            identification.add(part)
    return plan.report(acc)


#: Realizations per chunk of :func:`detect_scenario` (EHA: ~100 MB of working arrays per chunk).
DETECT_CHUNK_RUNS = 256


def detect_record(
    record: ChatteringRecord,
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    **detector: Unpack[DetectorKeywords],
) -> DetectionReport:
    """Detect model mismatch in a chattering record (default: exact + Bonferroni, family-wise 0.1 %).

    Parameters
    ----------
    record : ChatteringRecord
        ``values`` (runs, N, m) and the nominal model.
    alpha, threshold, correction
        False-alarm probability in (0, 1), threshold kind (``"exact"``, ``"paper"`` or a ready
        :class:`~chatterspec.detection.thresholds.Threshold`) and multiple-test correction
        (``"bonferroni"``, ``"sidak"``, ``"none"``), as documented in :class:`DetectorOptions`.
    **detector
        ``stft``, ``config``, ``band``, ``frame_threshold``: the STFT intervals on run 0 (by default
        when the record's scenario has more than one segment), their settings, the band in Hz of the
        tested bins and a per-frame threshold (:class:`DetectorOptions`).

    Notes
    -----
    With ``runs > 1`` the report holds every run's verdict (detection rate per
    channel, single-record threshold) and the verdict of the averaged spectrum
    against the averaged ``exact`` threshold with K = runs at ``alpha`` with
    ``correction`` (family-wise by default) **whatever the single-record rule**:
    the paper's per-bin rule applied to ~2000 averaged bins would flag most
    healthy averages. Runs are assumed independent realizations. Identical to
    :func:`detect_chunks` on the record split in chunks.
    """
    options = DetectorOptions(alpha, threshold, correction, **detector)
    if not isinstance(record, ChatteringRecord):
        raise ParameterError(f"record must be a ChatteringRecord; got {type(record).__name__}")
    return _detect([record], options)


def detect_chunks(
    chunks: Iterable[ChatteringRecord],
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    **detector: Unpack[DetectorKeywords],
) -> DetectionReport:
    """:func:`detect_record` over a stream of chunks of realizations, in memory bounded by one chunk.

    Each chunk's periodograms are tested and dropped: only the per-run verdict
    scalars (``(runs, m)``, 48 bytes per run and channel), the running sum of the
    spectra (for the averaged verdict) and run 0's STFT are kept.

    Parameters
    ----------
    chunks : iterable of ChatteringRecord
        Chunks of one study (same model, length and scenario), e.g.
        :func:`chatterspec.detection.pipeline.iter_chattering`.
    alpha, threshold, correction, **detector
        As in :func:`detect_record` (:class:`DetectorOptions`).

    Raises
    ------
    ParameterError
        If ``chunks`` is empty or its records do not belong to one study.

    See Also
    --------
    detect_scenario : the chunks of a scenario, simulated here or on worker processes.
    """
    return _detect(chunks, DetectorOptions(alpha, threshold, correction, **detector))


def _detect(chunks: Iterable[ChatteringRecord], options: DetectorOptions) -> DetectionReport:
    """:func:`detect_chunks` with its settings in one object."""
    it = iter(chunks)
    first = next(it, None)
    if first is None:
        raise ParameterError("no chattering record to detect (empty chunk stream)")
    plan = ChunkPlan.build(first, options)
    acc = None
    record: ChatteringRecord | None = first
    while record is not None:
        if record is not first and record.model is not plan.model:
            if record.model.fingerprint() != plan.model.fingerprint():
                raise ParameterError("all chunks must share the nominal model of the first chunk")
        acc = plan.reduce(acc, plan.test(record.values))
        record = next(it, None)
    assert acc is not None  # (the first chunk was folded)
    return plan.report(acc)


def detect_scenario(
    scenario: Scenario,
    runs: int = 1,
    seed: SeedLike = None,
    alpha: float = 1e-3,
    threshold: str | Threshold = "exact",
    correction: Correction = "bonferroni",
    *,
    chunk_runs: int | None = DETECT_CHUNK_RUNS,
    gamma: float = 0.1,
    identification: IdentificationStream | None = None,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool | None = None,
    **detector: Unpack[DetectorKeywords],
) -> DetectionReport:
    """Simulate, filter and detect ``runs`` realizations of ``scenario`` chunk by chunk (bounded memory).

    Same numbers as ``detect_record(scenario_chattering(scenario, runs, seed), ...)``
    (verdicts identical; the averaged spectrum summed chunk by chunk, equal to
    rounding), with peak memory set by ``chunk_runs``, not by ``runs``; the same report, bit for
    bit, whatever ``workers`` or ``scheduler`` (``chatterspec detect --workers N``).

    Parameters
    ----------
    scenario : Scenario
        Catalogue or user scenario.
    runs : int
        Monte Carlo realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root of the random streams (realization r is the same whatever the chunking).
    alpha, threshold, correction, **detector
        As in :func:`detect_record` (:class:`DetectorOptions`).
    chunk_runs : int, optional
        Realizations per chunk (default 256; None: the simulator's memory-sized default in this
        process, :data:`~chatterspec.montecarlo.DEFAULT_CHUNK_RUNS` on workers).
    gamma : float
        SVSF convergence rate in (0, 1) (eq 8-10).
    identification : IdentificationStream, optional
        Fault identification of every chunk too, added to this stream in chunk order (the
        serial ``IdentificationStream.tap`` numbers); the chunks then run through
        :func:`~chatterspec.montecarlo.run_study` even with one worker.
    workers, scheduler, progress
        Local worker processes, Dask scheduler and progress bar of
        :class:`~chatterspec.montecarlo.Execution`. With one worker, no scheduler and no
        ``identification`` the chunks stream through this process (no progress bar); otherwise
        the thresholds and run 0's STFT intervals come from a one-run record here and every chunk
        is simulated, filtered and tested by :func:`~chatterspec.montecarlo.run_study`.
    """
    runs = positive_int("runs", runs)
    options = DetectorOptions(alpha, threshold, correction, **detector)
    ex = Execution(workers=workers, scheduler=scheduler, chunk_runs=chunk_runs, progress=progress)
    if ex.workers == 1 and ex.scheduler is None and identification is None:
        chunks = iter_chattering(scenario, runs, seed, chunk_runs=ex.chunk_runs, gamma=gamma)
        return _detect(chunks, options)
    return detect_on_workers(scenario, runs, seed, options, ex, gamma=gamma, identification=identification)
