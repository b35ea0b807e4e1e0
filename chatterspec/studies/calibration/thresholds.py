"""Threshold calibration from simulated healthy runs: :func:`calibrate` and :func:`calibrate_empirical`.

The empirical quantiles of a calibration study (:func:`study_quantiles`): exact top-k tails, or tail
histograms above a budget. Shared by :func:`calibrate` (linear models) and
:func:`calibrate_empirical` (nonlinear models). Below
the memory budget the exact path keeps the largest normalized values (exact order statistics,
the numbers of every earlier chatterspec); above it the bounded path of
:mod:`~chatterspec.studies.calibration.healthy` is used (pilot windows + per-cell bucket counts).
:func:`calibration_fields` turns them into the fields of a
:class:`~chatterspec.studies.calibration.result.Calibration` that both normalizations share.

Calibration of a nonlinear model (:func:`calibrate_empirical`): empirical normalization + empirical
family-wise threshold. :func:`calibrate` dispatches to it when the scenario's nominal model
is nonlinear (no closed-form expected spectrum, eq 56 needs linearity). Two disjoint sets of
healthy realizations of the same root seed are used:

1. **pilot** realizations ``[runs, runs + pilot_runs)``: the normalization spectrum ``E_hat``
   (record periodogram and STFT frames; :mod:`chatterspec.detection.thresholds`);
2. **calibration** realizations ``[0, runs)``: the ``(1 - alpha)``-quantiles of ``S / E_hat`` --
   per bin, per frame, and the family-wise ones (maximum over the tested bins of a record, or of
   a frame) -- with their order-statistic intervals (:mod:`~chatterspec.studies.intervals`),
   exactly as for a linear model.

Because ``E_hat`` is fixed before the quantiles are estimated, the family-wise threshold
``E_hat * q`` has false-alarm probability ``alpha`` on new healthy runs up to the quantile's
order-statistic uncertainty. The resulting :class:`~chatterspec.studies.calibration.result.Calibration`
has ``normalization="empirical"``, no analytic thresholds, and ``expected`` = ``E_hat``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Unpack

import numpy as np
import scipy.stats

from ..._validate import open_unit, positive_int
from ...detection.pipeline import iter_chattering
from ...detection.spectral import STFTConfig, periodogram_freqs
from ...detection.thresholds import NORMALIZATION_SMOOTH_BINS, frame_normalization, normalization_spectrum
from ...errors import ParameterError
from ...montecarlo import BLOCK, Execution, ExecutionOptions, SeedLike, seed_label
from ...plants.models import LinearModel
from ...plants.nonlinear import is_linear
from ...plants.scenarios import Scenario
from ...plants.simulate import as_scenario
from ..intervals import QuantileEstimate, _quantile_from_top, _top_needed
from . import healthy as th
from .healthy import (
    DEFAULT_TAIL_BUDGET,
    HealthyStudy,
    _analytic_thresholds,
    _frame_thresholds,
    _n_frames,
)
from .result import Calibration, _interval_fields, _ro, _stft_dict

__all__ = [
    "DEFAULT_PILOT_RUNS",
    "calibrate",
    "calibrate_empirical",
]


def calibrate(
    source: str | Scenario | LinearModel | Path,
    alpha: float = 1e-2,
    runs: int = 1000,
    seed: SeedLike = 0,
    *,
    config: STFTConfig | None = None,
    confidence: float = 0.99,
    tail_budget: int = DEFAULT_TAIL_BUDGET,
    **execution: Unpack[ExecutionOptions],
) -> Calibration:
    """Calibrate thresholds on healthy Monte Carlo runs and compare them with the analytic ones.

    Parameters
    ----------
    source : str, Scenario, LinearModel or path
        A healthy catalogue scenario name, a scenario, a user model or a TOML model file.
    alpha : float
        False-alarm probability in (0, 1) (per bin, per frame or family-wise, by threshold).
    runs : int
        Healthy realizations (>= 1). The family-wise quantile needs ``runs * alpha``
        well above 1 to be informative.
    seed : int
        Root seed (identical results whatever ``workers``/``scheduler``).
    config : STFTConfig, optional
        STFT settings of the per-frame calibration (default 1 s Hamming, 0.2 s hop).
    confidence : float
        Level of the order-statistic intervals.
    tail_budget : int
        Memory budget in bytes (default :data:`~.healthy.DEFAULT_TAIL_BUDGET`, 128 MiB)
        of the exact order-statistic tails, which grow like ``runs x alpha``. At or below it
        the quantiles are exact order statistics; above it they are read from per-bin tail
        histograms of fixed size (:mod:`~.healthy`: point at most one fine bucket above
        the exact value, intervals widened outward to bucket edges); ``0`` forces the histograms.
        ``Calibration.tails`` records which path ran.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    Calibration

    Raises
    ------
    ParameterError
        alpha outside (0, 1), runs < 1, or a scenario that is not healthy.
    """
    ex = Execution(**execution)
    alpha = open_unit("alpha", alpha)
    runs = positive_int("runs", runs)
    confidence = open_unit("confidence", confidence)
    sc = as_scenario(source)
    if not sc.is_healthy:
        raise ParameterError(
            f"calibrate needs a healthy scenario; {sc.name!r} has faults at {sc.fault_intervals}"
        )
    config = STFTConfig() if config is None else config
    if not is_linear(sc.nominal):  # no closed-form spectrum: empirical normalization (docs/design.md §6)
        return calibrate_empirical(
            sc, alpha, runs, seed, config, confidence, tail_budget=tail_budget, **execution
        )
    model = sc.nominal
    N = sc.n_samples - 1
    _, thr = _analytic_thresholds(model, N, alpha)
    _, fthr = _frame_thresholds(model, config, alpha)
    E = thr["exact"].expected
    Ef = fthr["frame"].expected
    assert E is not None and Ef is not None  # (exact thresholds carry E[S])
    frames = frame_counts(N, config, model.dt)
    study = HealthyStudy(
        scenario=sc,
        thr_values=np.stack([t.values for t in thr.values()]),
        thr_tested=np.stack([t.tested for t in thr.values()]),
        expected=E,
        tested=thr["exact"].tested,
        config=config,
        fthr_values=np.stack([t.values for t in fthr.values()]),
        fthr_tested=np.stack([t.tested for t in fthr.values()]),
        fexpected=Ef,
        keep_max=True,
    )
    label = f"calibrate {sc.name}"
    shared = calibration_fields(study, sc, alpha, runs, seed, confidence, frames, tail_budget, ex, label)
    return Calibration(
        **shared,
        analytic={k: _ro(t.values) for k, t in thr.items()},
        family_wise_analytic={
            "bonferroni": float(scipy.stats.chi2.isf(thr["exact-bonferroni"].per_test_alpha, 2) / 2),
            "sidak": float(scipy.stats.chi2.isf(thr["exact-sidak"].per_test_alpha, 2) / 2),
            "n_tested": thr["exact"].n_tested,
        },
        frame_analytic={k: _ro(t.values) for k, t in fthr.items()},
    )


Triple = tuple[np.ndarray, np.ndarray, np.ndarray]


def frame_counts(n_samples: int, config: STFTConfig, dt: float) -> tuple[int, int]:
    """STFT frames per record, and how many of them do not overlap (the independent ones).

    Raises :class:`~chatterspec.errors.ParameterError` for records shorter than one window.
    """
    n_frames = _n_frames(n_samples, config, dt)
    if n_frames < 1:
        raise ParameterError(f"records of {n_samples} samples are shorter than one STFT window")
    # overlapping frames are dependent: count only non-overlapping ones as independent samples
    return n_frames, max(1, (n_samples - config.n_window(dt)) // config.n_window(dt) + 1)


def calibration_fields(
    study: HealthyStudy,
    sc: Scenario,
    alpha: float,
    runs: int,
    seed: SeedLike,
    confidence: float,
    frames: tuple[int, int],
    tail_budget: int,
    execution: Execution,
    label: str,
) -> dict[str, Any]:
    """Run ``study`` (:func:`study_quantiles`) and return the fields of its ``Calibration`` that do
    not depend on the normalization: what was calibrated, the frequencies, tested bins and expected
    spectra of the study, the empirical quantiles and their tails.

    ``study.config`` is the per-frame STFT and ``frames`` its :func:`frame_counts`; the caller adds
    the normalization's own fields (analytic thresholds, normalization).
    """
    model, config, ftested, fexpected = sc.nominal, study.config, study.fthr_tested, study.fexpected
    assert config is not None and ftested is not None and fexpected is not None  # (it has frame statistics)
    N = sc.n_samples - 1
    n_frames, frames_eff = frames
    q = 1 - alpha
    res, tails = study_quantiles(
        study, runs, seed, n_frames, frames_eff, q, confidence, tail_budget, execution, label
    )

    def per_channel(key: str, n: int) -> tuple[QuantileEstimate, ...]:
        v, lo, hi = res[key]
        return tuple(
            QuantileEstimate(q, float(v[c]), float(lo[c]), float(hi[c]), n, confidence)
            for c in range(v.shape[0])
        )

    return {
        "scenario": sc.name,
        "model_name": model.name,
        "model_fingerprint": model.fingerprint(),
        "dt": model.dt,
        "n_samples": N,
        "stft": _stft_dict(config),
        "alpha": alpha,
        "runs": runs,
        "seed": seed_label(seed),
        "confidence": confidence,
        "channels": tuple(model.output_names),
        "freqs_hz": _ro(periodogram_freqs(N, model.dt)),
        "tested": _ro(study.tested),
        "expected": _ro(study.expected),
        **_interval_fields("per_bin", res["bin"]),
        "family_wise": per_channel("max", runs),
        **_interval_fields("per_frame", res["frame"]),
        "frame_family_wise": per_channel("frame_max", runs * n_frames),
        "frame_freqs_hz": _ro(config.freqs_hz(model.dt)),
        "frame_tested": _ro(ftested[0]),  # the uncorrected frame threshold's (or only) row
        "frame_expected": _ro(fexpected),
        "tails": tails,
    }


def study_quantiles(
    study: HealthyStudy,
    runs: int,
    seed: SeedLike,
    n_frames: int,
    frames_eff: int,
    q: float,
    confidence: float,
    budget: int,
    execution: Execution,
    label: str,
) -> tuple[dict[str, Triple], dict[str, Any]]:
    """Run ``study`` and return the four empirical quantiles and how they were read.

    Returns ``({"bin", "frame", "max", "frame_max"} -> (value, low, high), tails_info)``;
    ``bin``: ``(bins, m)``, ``frame``: ``(fbins, m)``, ``max`` and ``frame_max``: ``(m,)``.
    ``study`` must have ``keep_max=True`` and frame statistics; its ``k_top``/``kf_top`` are set here.
    """
    nf, nf_eff = runs * n_frames, runs * frames_eff
    bins, m = study.expected.shape
    assert study.fexpected is not None  # (frame statistics: see above)
    fbins = study.fexpected.shape[0]
    k_top = _top_needed(runs, q, confidence)
    kf_top = _top_needed(nf, q, confidence, nf_eff)
    need = th.tail_bytes(k_top, kf_top, bins, fbins, m)
    if need <= budget:
        out = execution.run(dataclasses.replace(study, k_top=k_top, kf_top=kf_top), runs, seed, label)
        res: dict[str, Triple] = {
            "bin": _quantile_from_top(_desc(out["top_bin"]), runs, q, confidence),
            "frame": _quantile_from_top(_desc(out["top_frame"]), nf, q, confidence, nf_eff),
            "max": _quantile_from_top(_desc(out["runs_max"]), runs, q, confidence),
            "frame_max": _quantile_from_top(_desc(out["top_frame_max"]), nf, q, confidence, nf_eff),
        }
        return res, {"method": "exact", "budget_bytes": int(budget), "exact_bytes": int(need)}

    # ---- bounded path: a pilot histogram places each cell's fine window, then counts over every run
    P = th.pilot_runs(runs, 1 - q, BLOCK)
    pw_bin, pw_frame = th.pilot_window((bins, m)), th.pilot_window((fbins, m))
    pilot = execution.run(
        dataclasses.replace(
            study,
            k_top=0,
            kf_top=0,
            bin_window=pw_bin,
            frame_window=pw_frame,
            frame_max_window=th.pilot_window((m,)),
        ),
        P,
        seed,
        f"{label} (pilot)",
    )
    pf, pfe = P * n_frames, P * frames_eff
    win = {
        "bin": th.window(pilot["hist_bin"], P, P, runs, runs, q, confidence),
        "frame": th.window(pilot["hist_frame"], pf, pfe, nf, nf_eff, q, confidence),
        "frame_max": th.window(pilot["hist_frame_max"], pf, pfe, nf, nf_eff, q, confidence),
    }
    del pilot
    main = dataclasses.replace(
        study,
        k_top=0,
        kf_top=0,
        bin_window=win["bin"],
        frame_window=win["frame"],
        frame_max_window=win["frame_max"],
    )
    out = execution.run(main, runs, seed, label)
    res = {}
    outside = 0
    for key, n, n_eff in (("bin", runs, runs), ("frame", nf, nf_eff), ("frame_max", nf, nf_eff)):
        v, lo, hi, o = th.quantile_from_counts(out[f"hist_{key}"], *win[key], n, q, confidence, n_eff)
        res[key] = (v, lo, hi)
        outside += o
    res["max"] = _quantile_from_top(_desc(out["runs_max"]), runs, q, confidence)
    info = {
        "method": "histogram",
        "budget_bytes": int(budget),
        "exact_bytes": int(need),
        "pilot_runs": int(P),
        "fine_buckets": th.FINE_BUCKETS,
        "fine_rel_width": max(th.fine_rel_width(*w) for w in win.values()),
        "outside_window": outside,
    }
    return res, info


def _desc(a: np.ndarray) -> np.ndarray:
    return -np.sort(-a, axis=0)


DEFAULT_PILOT_RUNS = 200  # E_hat relative SE ~ 1/sqrt(200 * 11) ~ 2 % per bin (see detection.empirical)


def calibrate_empirical(
    sc: Scenario,
    alpha: float,
    runs: int,
    seed: SeedLike,
    config: STFTConfig,
    confidence: float,
    *,
    pilot_runs: int = DEFAULT_PILOT_RUNS,
    half_width: int = NORMALIZATION_SMOOTH_BINS,
    tail_budget: int = DEFAULT_TAIL_BUDGET,
    **execution: Unpack[ExecutionOptions],
) -> Calibration:
    """Empirical calibration of a healthy scenario (any nominal model the pipeline can filter).

    Parameters
    ----------
    sc : Scenario
        Healthy scenario (validated by the caller).
    alpha : float
        False-alarm probability in (0, 1).
    runs : int
        Calibration realizations (>= 1).
    seed : int, SeedSequence, Generator or None
        Root seed; pilot and calibration realizations are disjoint streams of it.
    config : STFTConfig
        STFT settings (window, hop in seconds) of the per-frame calibration.
    confidence : float
        Level of the order-statistic intervals.
    pilot_runs : int
        Realizations for the normalization spectrum (>= 2).
    half_width : int
        Smoothing half-width of the normalization in bins.
    tail_budget : int
        Memory budget in bytes of the exact quantile tails; above it the bounded tail
        histograms are used (see :func:`~.calibration.calibrate`).
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress`` (:class:`~chatterspec.montecarlo.Execution`).

    Returns
    -------
    Calibration
        ``normalization="empirical"``.
    """
    ex = Execution(**execution)
    if int(pilot_runs) < 2:
        raise ParameterError(f"pilot_runs must be >= 2; got {pilot_runs}")
    model = sc.nominal
    N = sc.n_samples - 1
    dt = model.dt
    frames = frame_counts(N, config, dt)
    pilot = [rec.values for rec in iter_chattering(sc, int(pilot_runs), seed, first_run=runs)]
    E, _ = normalization_spectrum(pilot, dt, half_width)
    Ef = frame_normalization(pilot, dt, config, half_width)
    del pilot
    freqs = periodogram_freqs(N, dt)
    ffreqs = config.freqs_hz(dt)
    tested, ftested = _tested(freqs.size, N), _tested(ffreqs.size, config.n_window(dt))
    m = E.shape[1]
    study = HealthyStudy(
        scenario=sc,
        thr_values=np.zeros((0, freqs.size, m)),  # no fixed threshold to count: quantiles only
        thr_tested=np.zeros((0, freqs.size), dtype=bool),
        expected=E,
        tested=tested,
        config=config,
        fthr_values=np.full((1, ffreqs.size, m), np.inf),  # never exceeded: frame quantiles only
        fthr_tested=ftested[None],
        fexpected=Ef,
        keep_max=True,
    )
    label = f"calibrate {sc.name} (empirical)"
    shared = calibration_fields(study, sc, alpha, runs, seed, confidence, frames, tail_budget, ex, label)
    return Calibration(
        **shared,
        analytic={},
        family_wise_analytic={},
        frame_analytic={},
        normalization="empirical",
        normalization_info={
            "pilot_runs": int(pilot_runs),
            "pilot_first_run": int(runs),
            "smooth_half_width_bins": int(half_width),
            "estimator": "mean healthy periodogram of the pilot runs, moving average over 2h+1 bins",
        },
    )


def _tested(n_bins: int, n: int) -> np.ndarray:
    """Tested ones of the ``n_bins`` one-sided bins of an ``n``-point DFT: DC and even-``n`` Nyquist out."""
    tested = np.ones(n_bins, dtype=bool)
    tested[0] = False
    if n % 2 == 0:
        tested[-1] = False
    return tested
