"""Threshold calibration from healthy runs and calibration files (JSON / NPZ)."""

from __future__ import annotations

from pathlib import Path
from typing import Unpack

import numpy as np
import scipy.stats

from .._validate import open_unit, positive_int
from ..detection.spectral import STFTConfig
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions, SeedLike
from ..plants.models import LinearModel
from ..plants.nonlinear import is_linear
from ..plants.scenarios import Scenario
from .calibration_result import CALIBRATION_FORMAT, Calibration, _ro, load_calibration
from .calibration_tails import calibration_fields, frame_counts
from .healthy import HealthyStudy, _analytic_thresholds, _frame_thresholds, resolve_scenario
from .tail_histogram import DEFAULT_TAIL_BUDGET

__all__ = [
    "CALIBRATION_FORMAT",
    "Calibration",
    "calibrate",
    "load_calibration",
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
        Memory budget in bytes (default :data:`~.tail_histogram.DEFAULT_TAIL_BUDGET`, 128 MiB)
        of the exact order-statistic tails, which grow like ``runs x alpha``. At or below it
        the quantiles are exact order statistics; above it they are read from per-bin tail
        histograms of fixed size (:mod:`~.tail_histogram`: point at most one fine bucket above
        the exact value, intervals widened outward to bucket edges); ``0`` forces the histograms.
        ``Calibration.tails`` records which path ran.
    **execution
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

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
    sc = resolve_scenario(source)
    if not sc.is_healthy:
        raise ParameterError(
            f"calibrate needs a healthy scenario; {sc.name!r} has faults at {sc.fault_intervals}"
        )
    config = STFTConfig() if config is None else config
    if not is_linear(sc.nominal):  # no closed-form spectrum: empirical normalization (docs/design.md §6)
        from .empirical_calibration import calibrate_empirical

        return calibrate_empirical(
            sc, alpha, runs, seed, config, confidence, tail_budget=tail_budget, **execution
        )
    model = sc.nominal
    N = sc.n_samples - 1
    freqs, thr = _analytic_thresholds(model, N, alpha)
    ffreqs, fthr = _frame_thresholds(model, config, alpha)
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
        freqs_hz=_ro(freqs),
        tested=_ro(thr["exact"].tested),
        expected=_ro(E),
        analytic={k: _ro(t.values) for k, t in thr.items()},
        family_wise_analytic={
            "bonferroni": float(scipy.stats.chi2.isf(thr["exact-bonferroni"].per_test_alpha, 2) / 2),
            "sidak": float(scipy.stats.chi2.isf(thr["exact-sidak"].per_test_alpha, 2) / 2),
            "n_tested": thr["exact"].n_tested,
        },
        frame_freqs_hz=_ro(ffreqs),
        frame_tested=_ro(fthr["frame"].tested),
        frame_expected=_ro(Ef),
        frame_analytic={k: _ro(t.values) for k, t in fthr.items()},
    )
