"""False-alarm study: per-bin, per-frame and family-wise rates with exact intervals."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Unpack

import numpy as np

from .._validate import open_unit, positive_int
from ..detection.spectral import STFTConfig, expected_spectrum, periodogram_freqs, spectrum_model
from ..detection.thresholds import Threshold
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions, SeedLike, seed_label
from ..plants.models import LinearModel
from ..plants.scenarios import Scenario
from .calibration_result import Calibration, _ro
from .healthy import (
    HealthyStudy,
    _analytic_thresholds,
    _check_alphas,
    _frame_thresholds,
    _n_frames,
    resolve_scenario,
)
from .intervals import RateEstimate

__all__ = [
    "FalseAlarmResult",
    "FalseAlarmStudy",
    "KindRates",
    "false_alarm_study",
]


# --------------------------------------------------------------------------- false alarms
@dataclass(frozen=True)
class KindRates:
    """False-alarm statistics of one threshold kind at one alpha.

    Attributes
    ----------
    kind : str
        ``paper``, ``exact`` (per-bin), ``exact-bonferroni`` (the default
        detector), ``exact-sidak``, ``empirical-*`` (from a calibration file),
        ``frame`` (per-bin on STFT frames) or ``frame-bonferroni`` (the STFT detector).
    alpha : float
    alpha_meaning : str
        ``per-bin``, ``family-wise`` or ``per-frame``.
    nominal_per_bin : float
        Per-bin level the threshold aims at (alpha, or alpha / n for Bonferroni).
    per_bin : RateEstimate
        Exceedances over tested bins x channels x records (or x frames). Its
        interval comes from the run-level counts (records are the independent
        units; the bins, channels and overlapping frames of one record are not):
        :func:`~chatterspec.studies.intervals.cluster_clopper_pearson`.
    per_bin_by_channel : tuple of RateEstimate
    family_wise : tuple of RateEstimate or None
        Per channel, records with any tested bin above (record kinds only).
    family_wise_any : RateEstimate or None
        Records with any channel above.
    per_frame : tuple of RateEstimate or None
        Per channel, frames with any tested bin above (frame kinds only);
        run-level intervals as for ``per_bin`` (overlapping frames are dependent).
    per_frame_any : RateEstimate or None
    mean_false_bins : tuple of float
        Mean number of false-alarm bins per record (or frame) and channel.
    verdict : str
        For per-bin kinds ``consistent`` if nominal_per_bin lies in the per-bin
        interval, else ``above``/``below``; for family-wise and per-frame kinds
        ``within`` if the interval's lower end is <= alpha, else ``exceeds``.
    rate_vs_freq : (bins, m) array
        Per-bin exceedance rate per frequency (the plot of per-bin rate vs frequency).
    freqs_hz : (bins,) array
    """

    kind: str
    alpha: float
    alpha_meaning: str
    nominal_per_bin: float
    per_bin: RateEstimate
    per_bin_by_channel: tuple[RateEstimate, ...]
    family_wise: tuple[RateEstimate, ...] | None
    family_wise_any: RateEstimate | None
    per_frame: tuple[RateEstimate, ...] | None
    per_frame_any: RateEstimate | None
    mean_false_bins: tuple[float, ...]
    verdict: str
    rate_vs_freq: np.ndarray = field(repr=False, compare=False)
    freqs_hz: np.ndarray = field(repr=False, compare=False)

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        d: dict[str, Any] = {
            "kind": self.kind,
            "alpha": self.alpha,
            "alpha_meaning": self.alpha_meaning,
            "nominal_per_bin": self.nominal_per_bin,
            "per_bin": self.per_bin.to_dict(),
            "per_bin_by_channel": [r.to_dict() for r in self.per_bin_by_channel],
            "mean_false_bins_per_record": list(self.mean_false_bins),
            "verdict": self.verdict,
        }
        if self.family_wise is not None:
            d["family_wise"] = [r.to_dict() for r in self.family_wise]
            d["family_wise_any_channel"] = self.family_wise_any.to_dict() if self.family_wise_any else None
        if self.per_frame is not None:
            d["per_frame"] = [r.to_dict() for r in self.per_frame]
            d["per_frame_any_channel"] = self.per_frame_any.to_dict() if self.per_frame_any else None
        return d


@dataclass(frozen=True)
class FalseAlarmResult:
    """Result of :func:`false_alarm_study`: one :class:`KindRates` per (alpha, kind).

    Attributes
    ----------
    scenario : str
        Name of the healthy scenario simulated.
    runs : int
        Healthy realizations (records).
    seed : int or None
        Root seed if it was an integer, else None.
    confidence : float
        Level of every interval (Clopper-Pearson; per-bin and per-frame ones with
        the effective number of trials estimated from run-level counts).
    channels : tuple of str
        Output channel names (order of the per-channel rates).
    n_frames : int
        STFT frames per record (0 when frames were not tested).
    rates : tuple of KindRates
        One entry per (alpha, threshold kind), alphas in the order given.
    """

    scenario: str
    runs: int
    seed: int | None
    confidence: float
    channels: tuple[str, ...]
    n_frames: int
    rates: tuple[KindRates, ...]

    def get(self, kind: str, alpha: float | None = None) -> KindRates:
        """The rates of ``kind`` (at ``alpha``, default the first alpha)."""
        for r in self.rates:
            if r.kind == kind and (alpha is None or math.isclose(r.alpha, alpha)):
                return r
        raise ParameterError(f"no rates for kind {kind!r} at alpha {alpha}; have {self.kinds}")

    @property
    def kinds(self) -> tuple[str, ...]:
        """Threshold kinds of the rates, in first-seen order."""
        return tuple(dict.fromkeys(r.kind for r in self.rates))

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        return {
            "scenario": self.scenario,
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "channels": list(self.channels),
            "frames_per_record": self.n_frames,
            "rates": [r.to_dict() for r in self.rates],
        }


FalseAlarmStudy = HealthyStudy


def _verdict(meaning: str, nominal: float, alpha: float, est: RateEstimate) -> str:
    if meaning == "per-bin":
        if est.contains(nominal):
            return "consistent"
        return "above" if est.ci_low > nominal else "below"
    return "within" if est.ci_low <= alpha else "exceeds"


def false_alarm_study(
    source: str | Scenario | LinearModel | Path,
    alpha: float | Sequence[float] = 1e-2,
    runs: int = 1000,
    seed: SeedLike = 0,
    *,
    calibration: Calibration | None = None,
    config: STFTConfig | None = None,
    frames: bool = True,
    confidence: float = 0.99,
    **execution: Unpack[ExecutionOptions],
) -> FalseAlarmResult:
    """False-alarm rates of every threshold kind on healthy runs, with Clopper-Pearson intervals.

    Parameters
    ----------
    source : str, Scenario, LinearModel or path
        Healthy scenario (name), scenario, user model or TOML model file.
    alpha : float or sequence of float
        Nominal level(s) in (0, 1); all share the same simulated runs.
    runs : int
        Healthy realizations (>= 1).
    seed : int
        Root seed.
    calibration : Calibration, optional
        Adds ``empirical-per-bin`` and ``empirical-family-wise`` kinds (its own
        alpha); checked against the model (:class:`CalibrationMismatchError`).
        Use a calibration made with another seed, or the rates are optimistic.
    config : STFTConfig, optional
        STFT settings of the per-frame kinds.
    frames : bool
        Also test the STFT detector (per-frame rates).
    confidence : float
        Level of the Clopper-Pearson intervals.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    FalseAlarmResult
    """
    ex = Execution(**execution)
    alphas = _check_alphas(alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    sc = resolve_scenario(source)
    if not sc.is_healthy:
        raise ParameterError(f"false-alarm study needs a healthy scenario; {sc.name!r} has faults")
    model = spectrum_model(sc.nominal)  # (the analytic thresholds need a linear model)
    N = sc.n_samples - 1
    config = STFTConfig() if config is None else config
    kinds: list[tuple[str, float, Threshold]] = []
    fkinds: list[tuple[str, float, Threshold]] = []
    freqs = periodogram_freqs(N, model.dt)
    for a in alphas:
        _, thr = _analytic_thresholds(model, N, a)
        kinds += [(k, a, t) for k, t in thr.items()]
        if frames:
            _, fthr = _frame_thresholds(model, config, a)
            fkinds += [(k, a, t) for k, t in fthr.items()]
    if calibration is not None:
        calibration.check(model, N, config if frames else None)
        for meaning in ("per-bin", "family-wise"):
            kinds.append((f"empirical-{meaning}", calibration.alpha, calibration.threshold(meaning)))
        if frames:
            fkinds.append(("empirical-per-frame", calibration.alpha, calibration.threshold("per-frame")))
    E = expected_spectrum(model, freqs, N, form="exact")
    n_frames = _n_frames(N, config, model.dt) if frames else 0
    if frames and n_frames < 1:
        raise ParameterError(f"records of {N} samples are shorter than one STFT window; pass frames=False")
    study = HealthyStudy(
        scenario=sc,
        thr_values=np.stack([t.values for _, _, t in kinds]),
        thr_tested=np.stack([t.tested for _, _, t in kinds]),
        expected=E,
        tested=kinds[1][2].tested,
        config=config if frames else None,
        fthr_values=np.stack([t.values for _, _, t in fkinds]) if frames else None,
        fthr_tested=np.stack([t.tested for _, _, t in fkinds]) if frames else None,
        fexpected=None,
    )
    out = ex.run(study, runs, seed, f"far {sc.name}")
    m = model.n_outputs
    rates: list[KindRates] = []
    # the bins (and channels) of one record are dependent trials, the records are independent:
    # intervals from run-level counts (cluster_clopper_pearson), not from bins as if independent
    for i, (name, a, t) in enumerate(kinds):
        fw = tuple(RateEstimate(int(out["fw"][i, c]), runs, confidence) for c in range(m))
        rates.append(
            _kind_rates(
                name,
                a,
                t,
                (out["bin_exceed"][i], out["false_bins_sq"][i], out["false_total_sq"][i]),
                runs,
                runs,
                confidence,
                fw,
                family_wise=fw,
                family_wise_any=RateEstimate(int(out["fw_any"][i]), runs, confidence),
                per_frame=None,
                per_frame_any=None,
                mean_false_bins=tuple(float(v) / runs for v in out["false_bins"][i]),
            )
        )
    n_fr = runs * n_frames
    for i, (name, a, t) in enumerate(fkinds):  # overlapping frames are dependent too: the same intervals
        counts, flsq = out["frame_bin_exceed"][i], out["frame_flag_sq"][i]
        pf = tuple(
            RateEstimate(int(out["frame_flag"][i, c]), n_fr, confidence, runs, float(flsq[c]))
            for c in range(m)
        )
        rates.append(
            _kind_rates(
                name,
                a,
                t,
                (counts, out["frame_false_sq"][i], out["frame_false_total_sq"][i]),
                n_fr,
                runs,
                confidence,
                pf,
                family_wise=None,
                family_wise_any=None,
                per_frame=pf,
                per_frame_any=RateEstimate(
                    int(out["frame_flag_any"][i]), n_fr, confidence, runs, float(out["frame_flag_any_sq"][i])
                ),
                mean_false_bins=tuple(float(counts[t.tested, c].sum()) / n_fr for c in range(m)),
            )
        )
    return FalseAlarmResult(
        scenario=sc.name,
        runs=runs,
        seed=seed_label(seed),
        confidence=confidence,
        channels=tuple(model.output_names),
        n_frames=n_frames,
        rates=tuple(rates),
    )


def _kind_rates(
    name: str,
    alpha: float,
    t: Threshold,
    exceed: tuple[np.ndarray, np.ndarray, float],
    trials: int,
    runs: int,
    confidence: float,
    family: tuple[RateEstimate, ...],
    **rates: Any,
) -> KindRates:
    """The :class:`KindRates` of threshold ``t`` (kind ``name`` at level ``alpha``).

    ``exceed`` = ``(counts, sq, total_sq)``: exceedances per (bin, channel) over ``trials`` records
    or frames, and the run-level sums of squares of the per-channel and pooled counts (the intervals
    count the ``runs`` records as the independent clusters); ``family``: the family-wise (or
    per-frame) rates judged against ``alpha`` when ``t`` is not a per-bin threshold; ``rates``: the
    remaining fields of :class:`KindRates`.
    """
    counts, sq, total_sq = exceed
    tested, m = t.tested, counts.shape[1]
    nt = int(np.count_nonzero(tested))
    per_ch = tuple(
        RateEstimate(int(counts[tested, c].sum()), trials * nt, confidence, runs, float(sq[c]))
        for c in range(m)
    )
    pooled = RateEstimate(int(counts[tested].sum()), trials * nt * m, confidence, runs, float(total_sq))
    meaning = t.alpha_meaning
    nominal = t.per_test_alpha if np.isfinite(t.per_test_alpha) else alpha
    ref = pooled if meaning == "per-bin" else _worst(family)
    return KindRates(
        kind=name,
        alpha=alpha,
        alpha_meaning=meaning,
        nominal_per_bin=float(nominal),
        per_bin=pooled,
        per_bin_by_channel=per_ch,
        verdict=_verdict(meaning, nominal, alpha, ref),
        rate_vs_freq=_ro(counts / trials),
        freqs_hz=_ro(t.freqs_hz),
        **rates,
    )


def _worst(ests: Iterable[RateEstimate]) -> RateEstimate:
    return max(ests, key=lambda r: r.ci_low)
