"""The plan :func:`~chatterspec.detection.detect.detect_chunks` tests every chunk of a study against.

Split from :mod:`chatterspec.detection.detect` so that worker processes
(:mod:`chatterspec.detection.detect_parallel`) run the same code: :meth:`ChunkPlan.build` makes the
thresholds (and run 0's STFT intervals) from the first record, :meth:`ChunkPlan.test` one chunk's
verdicts and summed spectrum, :meth:`ChunkPlan.reduce` folds them in chunk order and
:meth:`ChunkPlan.report` gives the :class:`~chatterspec.detection.detect.DetectionReport`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import open_unit
from ..errors import ParameterError, ShapeError
from ..plants.nonlinear import is_linear
from .frames import FrameDetection, stft_detect
from .pipeline import ChatteringRecord
from .report import DetectionReport
from .spectral import DEFAULT_STFT, STFTConfig, expected_spectrum, periodogram
from .spectrum_verdicts import _VERDICT_FIELDS, SpectrumDetection, _require_empirical, detect_spectrum
from .thresholds import Band, Correction, Threshold, check_band, exact_threshold, paper_threshold

__all__ = ["ChunkPlan", "DetectorOptions"]


@dataclass(frozen=True)
class DetectorOptions:
    """The detector's settings: the keywords :func:`~chatterspec.detection.detect.detect_record`,
    :func:`~chatterspec.detection.detect.detect_chunks`, :func:`~chatterspec.detection.detect.detect_scenario`
    and :func:`~chatterspec.detection.detect_parallel.detect_parallel` share (documented there).

    The defaults are theirs: the exact threshold with Bonferroni correction at family-wise
    ``alpha`` = 0.1 %, the STFT intervals when the scenario has several segments, every bin tested.
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

    model: object
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
        E = expected_spectrum(model, freqs, n_samples) if linear else threshold.expected
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
        elif threshold == "exact":
            th = exact_threshold(model, freqs, n_samples, alpha, correction, band=band)
        elif threshold == "paper":
            th = paper_threshold(model, freqs, alpha, band=band)
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
