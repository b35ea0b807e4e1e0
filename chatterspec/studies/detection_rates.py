"""Rates of the spectral detector on simulated runs: false alarms and detection power.

False-alarm study (:func:`false_alarm_study`): per-bin, per-frame and family-wise rates with exact
intervals.

Detection power (:func:`power_study`) vs fault size and noise, and ROC curves.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Unpack, cast

import numpy as np

from .._validate import open_unit, positive_int
from ..detection.pipeline import iter_chattering
from ..detection.spectral import STFTConfig, expected_spectrum, periodogram, periodogram_freqs, spectrum_model
from ..detection.thresholds import Threshold
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions, SeedLike, seed_label
from ..plants.models import EHA_PARAMETERS, EHAFault, LinearModel, eha_linear, second_order
from ..plants.scenarios import Scenario
from ..plants.signals import Chirp, Step
from ..plants.simulate import as_scenario
from .calibration.healthy import (
    HealthyStudy,
    _analytic_thresholds,
    _check_alphas,
    _frame_thresholds,
    _n_frames,
    _SummedChunks,
)
from .calibration.result import Calibration, _ro
from .intervals import RateEstimate

__all__ = [
    "POWER_FAMILIES",
    "FalseAlarmResult",
    "FalseAlarmStudy",
    "KindRates",
    "PowerResult",
    "false_alarm_study",
    "power_scenario",
    "power_study",
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
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    FalseAlarmResult
    """
    ex = Execution(**execution)
    alphas = _check_alphas(alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    sc = as_scenario(source)
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


# --------------------------------------------------------------------------- power
#: Fault families of :func:`power_study`: default sizes (first = healthy), noise levels (R multipliers),
#: the fault channel and the unit of the size.
POWER_FAMILIES: dict[str, dict[str, Any]] = {
    "leakage": {
        "sizes": (EHA_PARAMETERS["leakage"], 1e-11, 2e-11, 3e-11, 6e-11, 9e-11),
        "noise": (1.0, 10.0),
        "channel": "pressure",
        "unit": "m^3/(s Pa)",
    },
    "bulk-modulus": {
        "sizes": (1.0, 0.95, 0.9, 0.75, 0.5),
        "noise": (1.0, 10.0),
        "channel": "pressure",
        "unit": "x nominal",
    },
    "friction": {
        "sizes": (EHA_PARAMETERS["friction"], 3000.0, 4000.0, 7000.0),
        "noise": (1.0, 10.0),
        "channel": "velocity",
        "unit": "N s/m",
    },
    "f0": {
        "sizes": (10.0, 10.25, 10.5, 11.0, 12.0),
        "noise": (1.0, 100.0),
        "channel": "velocity",
        "unit": "Hz (true f0, nominal 10 Hz)",
    },
}

_SO_Q = np.diag([1e-8, 1e-6])
_SO_R = np.diag([1e-8, 1e-6])


def power_scenario(family: str, size: float, noise: float = 1.0) -> Scenario:
    """The scenario of one point of a power sweep.

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
    size : float
        Leakage coefficient, bulk-modulus factor, friction coefficient or true f0 (Hz).
    noise : float
        Multiplier of the measurement noise covariance R (nominal and true plant):
        EHA ``R = noise * diag(1e-6, 1e-6, 1e6)``; second order ``noise * diag(1e-8, 1e-6)``
        (100 = the catalogue's "high" noise).
    """
    if family not in POWER_FAMILIES:
        raise ParameterError(f"unknown fault family {family!r}; valid: {', '.join(POWER_FAMILIES)}")
    size, noise = float(size), float(noise)
    if not (np.isfinite(size) and size > 0 and np.isfinite(noise) and noise > 0):
        raise ParameterError(f"fault size and noise level must be finite and > 0; got {size}, {noise}")
    plant = _true_plant(family, size, noise)
    _check_stable(family, size, plant)
    if family == "f0":
        nominal = second_order(10.0, 0.1, Q=_SO_Q, R=noise * _SO_R)
        inp: Any = Step(0.0)
    else:
        nominal = eha_linear(R=noise * np.diag([1e-6, 1e-6, 1e6]))
        inp = Chirp(10.0, 100.0, 4.0, 300.0)
    return Scenario(
        name=f"power-{family}-{size:g}-noise{noise:g}",
        nominal=nominal,
        plant=plant,
        input=inp,
        duration=4.0,
        family="second-order" if family == "f0" else "eha",
        fault=family,
        fault_channel=POWER_FAMILIES[family]["channel"],
    )


def _true_plant(family: str, size: float, noise: float = 1.0) -> LinearModel:
    """The true (faulty) plant of :func:`power_scenario` (Euler-discretized like the paper's models)."""
    if family == "f0":
        return second_order(size, 0.1, Q=_SO_Q, R=noise * _SO_R)
    key = {"leakage": "leakage", "bulk-modulus": "bulk_modulus", "friction": "friction"}[family]
    value = size * EHA_PARAMETERS["bulk_modulus"] if family == "bulk-modulus" else size
    return eha_linear(R=noise * np.diag([1e-6, 1e-6, 1e6]), **cast(EHAFault, {key: value}))


#: Largest spectral radius of the true plant's discrete A accepted as stable (the EHA position is an
#: integrator: an eigenvalue of exactly 1).
_RHO_MAX = 1.0 + 1e-9


def _spectral_radius(family: str, size: float) -> float:
    return float(np.abs(np.linalg.eigvals(_true_plant(family, size).A)).max())


def _stable_range(family: str) -> tuple[float, float]:
    """``(lo, hi)``: fault sizes around the healthy one with a stable true plant (log-scale bisection)."""
    healthy = float(POWER_FAMILIES[family]["sizes"][0])

    def edge(direction: float) -> float:
        inside, step = healthy, 2.0**direction
        outside = healthy * step
        while _stable(family, outside):  # widen until unstable or implausibly far (then: no edge)
            inside, outside = outside, outside * step
            if not 1e-12 < outside / healthy < 1e12:
                return 0.0 if direction < 0 else np.inf
        for _ in range(60):  # geometric bisection: 2^-60 relative width
            mid = float(np.sqrt(inside * outside))
            inside, outside = (mid, outside) if _stable(family, mid) else (inside, mid)
        return inside

    return edge(-1.0), edge(1.0)


def _stable(family: str, size: float) -> bool:
    try:
        return _spectral_radius(family, size) <= _RHO_MAX
    except ParameterError:
        return False


def _check_stable(family: str, size: float, plant: LinearModel) -> None:
    """A fault size whose true plant is unstable diverges in simulation: reject it up front."""
    rho = float(np.abs(np.linalg.eigvals(plant.A)).max())
    if rho <= _RHO_MAX:
        return
    lo, hi = _stable_range(family)
    unit = POWER_FAMILIES[family]["unit"]
    raise ParameterError(
        f"{family} size {size:g} ({unit}) makes the true plant unstable (discrete A at dt = {plant.dt:g} s "
        f"has spectral radius {rho:.3g} > 1; the simulation would diverge); the stable range is "
        f"{lo:.3g} < size < {hi:.3g} ({unit})"
    )


@dataclass(frozen=True, eq=False)
class PowerStudyChunks(_SummedChunks):
    """Chunk function of :func:`power_study`: detection counts per (point, kind, alpha, channel)."""

    scenarios: tuple[Scenario, ...]
    thr_values: tuple[np.ndarray, ...]  # per point: (K, A, bins, m)
    thr_tested: np.ndarray  # (K, bins)

    def run_chunk(self, first_run: int, runs: int, seed: np.random.SeedSequence) -> dict[str, np.ndarray]:
        """The summary of realizations ``first_run .. first_run + runs - 1`` (a Monte Carlo chunk)."""
        det, det_any = [], []
        for sc, thr in zip(self.scenarios, self.thr_values, strict=True):
            rec = next(iter_chattering(sc, runs, seed, chunk_runs=runs, first_run=first_run))
            S = periodogram(rec.values, rec.dt).power  # (r, bins, m)
            d = np.empty((thr.shape[0], thr.shape[1], runs, S.shape[-1]), dtype=bool)
            for k in range(thr.shape[0]):
                St = S[:, self.thr_tested[k]]  # (r, bt, m)
                d[k] = (St[None] > thr[k][:, None, self.thr_tested[k]]).any(axis=2)  # (A, r, m)
            det.append(d.sum(axis=2))
            det_any.append(d.any(axis=-1).sum(axis=2))
        return {"det": np.stack(det), "det_any": np.stack(det_any)}


@dataclass(frozen=True, eq=False)
class PowerResult:
    """Detection probability per (noise, size, kind, alpha), with Clopper-Pearson intervals.

    Attributes
    ----------
    family : str
    sizes, noise : tuple of float
        Grid (``sizes[0]`` is the healthy value: its "detection" rate is the false-alarm rate).
    kinds : tuple of str
        ``paper`` (per-bin alpha, the paper's rule), ``exact`` (per-bin), ``exact-bonferroni`` (default).
    alphas : (A,) array
        Alpha grid of the ROC; ``alpha`` is the reporting level.
    runs : int
        Realizations per (noise, size) grid point (common random numbers).
    seed : int or None
        Root seed if it was an integer, else None.
    confidence : float
        Level of the Clopper-Pearson intervals.
    channel : str
        Fault channel used for the verdict.
    channels : tuple of str
        All output channel names (last axis of ``counts``).
    counts : (noise, sizes, kinds, A, m) int array
        Records detected (any tested bin above the threshold) per channel.
    counts_any : (noise, sizes, kinds, A) int array
        Records detected on any channel.
    """

    family: str
    sizes: tuple[float, ...]
    noise: tuple[float, ...]
    kinds: tuple[str, ...]
    alphas: np.ndarray
    alpha: float
    runs: int
    seed: int | None
    confidence: float
    channel: str
    channels: tuple[str, ...]
    counts: np.ndarray
    counts_any: np.ndarray

    def _ia(self, alpha: float | None) -> int:
        a = self.alpha if alpha is None else alpha
        return int(np.argmin(np.abs(np.log(self.alphas) - np.log(a))))

    def detection(self, kind: str = "exact-bonferroni", alpha: float | None = None) -> np.ndarray:
        """(noise, sizes) detection probability on the fault channel."""
        c = self.channels.index(self.channel)
        return self.counts[:, :, self.kinds.index(kind), self._ia(alpha), c] / self.runs

    def estimate(self, i_noise: int, i_size: int, kind: str, alpha: float | None = None) -> RateEstimate:
        """Detection rate at noise level ``i_noise``, fault size ``i_size``, threshold ``kind``, ``alpha``."""
        c = self.channels.index(self.channel)
        k = int(self.counts[i_noise, i_size, self.kinds.index(kind), self._ia(alpha), c])
        return RateEstimate(k, self.runs, self.confidence)

    def roc(self, i_noise: int, i_size: int, kind: str = "exact-bonferroni") -> tuple[np.ndarray, np.ndarray]:
        """``(false_alarm_rate, detection_rate)`` over the alpha grid (healthy = ``sizes[0]``)."""
        c = self.channels.index(self.channel)
        k = self.kinds.index(kind)
        far = self.counts[i_noise, 0, k, :, c] / self.runs
        det = self.counts[i_noise, i_size, k, :, c] / self.runs
        return far, det

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        points = []
        for i, nz in enumerate(self.noise):
            for j, sz in enumerate(self.sizes):
                points.append(
                    {
                        "noise": nz,
                        "size": sz,
                        "healthy": j == 0,
                        "detection": {k: self.estimate(i, j, k).to_dict() for k in self.kinds},
                    }
                )
        roc = []
        for i, nz in enumerate(self.noise):
            for j, sz in enumerate(self.sizes[1:], start=1):
                far, det = self.roc(i, j)
                roc.append(
                    {
                        "noise": nz,
                        "size": sz,
                        "false_alarm_rate": far.tolist(),
                        "detection_rate": det.tolist(),
                    }
                )
        return {
            "family": self.family,
            "unit": POWER_FAMILIES[self.family]["unit"],
            "channel": self.channel,
            "alpha": self.alpha,
            "runs": self.runs,
            "seed": self.seed,
            "confidence": self.confidence,
            "points": points,
            "roc": {"kind": "exact-bonferroni", "alphas": self.alphas.tolist(), "curves": roc},
        }


def power_study(
    family: str,
    sizes: Sequence[float] | None = None,
    noise: Sequence[float] | None = None,
    alpha: float = 1e-3,
    runs: int = 200,
    seed: SeedLike = 0,
    *,
    alphas: Sequence[float] | None = None,
    confidence: float = 0.99,
    **execution: Unpack[ExecutionOptions],
) -> PowerResult:
    """Detection power vs fault size and noise level, and ROC curves.

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
        Fault family (:data:`POWER_FAMILIES`).
    sizes : sequence of float, optional
        Fault sizes; the family's healthy value is prepended if missing.
    noise : sequence of float, optional
        Measurement-noise multipliers (see :func:`power_scenario`).
    alpha : float
        Reporting level in (0, 1).
    runs : int
        Realizations per grid point (common random numbers across points).
    seed : int
    alphas : sequence of float, optional
        ROC alpha grid (default 1e-5 .. 0.5 log-spaced, plus ``alpha``).
    confidence : float
        Level of the Clopper-Pearson intervals.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    PowerResult
    """
    ex = Execution(**execution)
    if family not in POWER_FAMILIES:
        raise ParameterError(f"unknown fault family {family!r}; valid: {', '.join(POWER_FAMILIES)}")
    grid = np.geomspace(1e-5, 0.5, 15) if alphas is None else np.asarray(alphas, dtype=float)
    alpha, *levels = (open_unit("alpha", a) for a in (alpha, *grid))
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    spec = POWER_FAMILIES[family]
    healthy = spec["sizes"][0]
    sizes_t = tuple(float(s) for s in (spec["sizes"] if sizes is None else sizes))
    if not sizes_t or not math.isclose(sizes_t[0], healthy):
        sizes_t = (healthy, *(s for s in sizes_t if not math.isclose(s, healthy)))
    noise_t = tuple(float(s) for s in (spec["noise"] if noise is None else noise))
    grid = np.unique(np.append(levels, alpha))
    kinds = ("paper", "exact", "exact-bonferroni")
    scenarios, thr_values = [], []
    tested = None
    for nz in noise_t:
        for sz in sizes_t:
            sc = power_scenario(family, sz, nz)
            model, N = sc.nominal, sc.n_samples - 1
            per_alpha = [
                _analytic_thresholds(cast(LinearModel, model), N, a)[1] for a in grid
            ]  # linear plants
            thr_values.append(np.stack([np.stack([t[k].values for t in per_alpha]) for k in kinds]))
            tested = np.stack([per_alpha[0][k].tested for k in kinds])
            scenarios.append(sc)
    assert tested is not None  # (one scenario at least)
    study = PowerStudyChunks(tuple(scenarios), tuple(thr_values), tested)
    out = ex.run(study, runs, seed, f"power {family}")
    shape = (len(noise_t), len(sizes_t))
    return PowerResult(
        family=family,
        sizes=sizes_t,
        noise=noise_t,
        kinds=kinds,
        alphas=_ro(grid),
        alpha=alpha,
        runs=runs,
        seed=seed_label(seed),
        confidence=confidence,
        channel=spec["channel"],
        channels=tuple(scenarios[0].nominal.output_names),
        counts=_ro(out["det"].reshape(*shape, *out["det"].shape[1:])),
        counts_any=_ro(out["det_any"].reshape(*shape, *out["det_any"].shape[1:])),
    )
