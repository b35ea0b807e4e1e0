"""The empirical quantiles of a calibration study: exact top-k tails, or tail histograms above a budget.

Shared by :func:`~chatterspec.studies.calibration.calibrate` (linear models) and
:func:`~chatterspec.studies.empirical_calibration.calibrate_empirical` (nonlinear models). Below
the memory budget the exact path keeps the largest normalized values (exact order statistics,
the numbers of every earlier chatterspec); above it the bounded path of
:mod:`~chatterspec.studies.tail_histogram` is used (pilot windows + per-cell bucket counts).
:func:`calibration_fields` turns them into the fields of a
:class:`~chatterspec.studies.calibration_result.Calibration` that both normalizations share.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ..detection.spectral import STFTConfig
from ..errors import ParameterError
from ..montecarlo import BLOCK, Execution, SeedLike, seed_label
from ..plants.scenarios import Scenario
from . import tail_histogram as th
from .calibration_result import _ro, _stft_dict
from .healthy import HealthyStudy, _n_frames
from .intervals import QuantileEstimate, _quantile_from_top, _top_needed

__all__: list[str] = []

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
    not depend on the normalization: what was calibrated, the empirical quantiles and their tails.

    ``study.config`` is the per-frame STFT and ``frames`` its :func:`frame_counts`; the caller adds
    the normalization's own fields (frequencies, tested bins, expected spectra, analytic thresholds).
    """
    model, config = sc.nominal, study.config
    assert config is not None  # (a calibration study has frame statistics)
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
        **dict(zip(("per_bin", "per_bin_low", "per_bin_high"), map(_ro, res["bin"]), strict=True)),
        "family_wise": per_channel("max", runs),
        **dict(zip(("per_frame", "per_frame_low", "per_frame_high"), map(_ro, res["frame"]), strict=True)),
        "frame_family_wise": per_channel("frame_max", runs * n_frames),
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
