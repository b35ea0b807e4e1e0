"""The detector's settings and the plan every chunk of a study is tested against, here or on workers.

Split from :mod:`chatterspec.detection.detect` so that worker processes run the same code:
:class:`DetectorOptions` holds the settings of every entry point, :meth:`ChunkPlan.build` makes the
thresholds (and run 0's STFT intervals) from the first record, :meth:`ChunkPlan.test` one chunk's
verdicts and summed spectrum, :meth:`ChunkPlan.reduce` folds them in chunk order and
:meth:`ChunkPlan.report` gives the :class:`~chatterspec.detection.detect.DetectionReport`;
:func:`detect_on_workers` runs the chunks as a :class:`DetectStudy` through
:func:`~chatterspec.montecarlo.run_study` (``detect_scenario(..., workers=N)``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypedDict, cast

import numpy as np

from .._validate import open_unit
from ..errors import ParameterError, ShapeError
from ..montecarlo import Execution, SeedLike
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, is_linear
from ..plants.scenarios import Scenario
from .frames import FrameDetection, stft_detect
from .pipeline import ChatteringRecord, iter_chattering
from .report import DetectionReport
from .spectral import DEFAULT_STFT, STFTConfig, expected_spectrum, periodogram
from .spectrum_verdicts import _VERDICT_FIELDS, SpectrumDetection, _require_empirical, detect_spectrum
from .thresholds import Band, Correction, Threshold, check_band, exact_threshold, paper_threshold

if TYPE_CHECKING:  # pragma: no cover
    from .identification import IdentificationStream

__all__ = ["ChunkPlan", "DetectStudy", "DetectorKeywords", "DetectorOptions", "detect_on_workers"]


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
        ``(lo, hi)`` in Hz: only these bins are tested, by every threshold (single,
        averaged, STFT frames); the correction counts only them; DC and Nyquist stay
        excluded. A ready threshold is narrowed with :meth:`Threshold.restricted`.
    frame_threshold : Threshold, optional
        Per-frame threshold of the STFT intervals instead of the analytic one (see
        :func:`~chatterspec.detection.frames.stft_detect`); with a nonlinear model the STFT runs
        only when it is given.

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
        alpha = open_unit("alpha", options.alpha)
        if band is not None:
            band = check_band(band)
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
        elif threshold == "paper":
            th = paper_threshold(cast(LinearModel, model), freqs, alpha, band=band)
        else:
            raise ParameterError(f"unknown threshold kind {threshold!r}; choose 'exact' or 'paper'")
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
