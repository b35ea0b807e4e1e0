"""Calibration of a nonlinear model: empirical normalization + empirical family-wise threshold.

:func:`chatterspec.studies.calibration.calibrate` dispatches here when the scenario's nominal model
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
order-statistic uncertainty. The resulting :class:`~chatterspec.studies.calibration.Calibration`
has ``normalization="empirical"``, no analytic thresholds, and ``expected`` = ``E_hat``.
"""

from __future__ import annotations

from typing import Unpack

import numpy as np

from ..detection.pipeline import iter_chattering
from ..detection.spectral import STFTConfig, periodogram_freqs
from ..detection.thresholds import NORMALIZATION_SMOOTH_BINS, frame_normalization, normalization_spectrum
from ..errors import ParameterError
from ..montecarlo import Execution, ExecutionOptions
from ..plants.scenarios import Scenario
from ..rng import SeedLike
from .calibration_result import Calibration, _ro
from .calibration_tails import calibration_fields, frame_counts
from .healthy import HealthyStudy
from .tail_histogram import DEFAULT_TAIL_BUDGET

__all__ = ["DEFAULT_PILOT_RUNS", "calibrate_empirical"]

DEFAULT_PILOT_RUNS = 200  # E_hat relative SE ~ 1/sqrt(200 * 11) ~ 2 % per bin (see detection.thresholds)


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
        ``workers``, ``scheduler``, ``chunk_runs``, ``progress``: how the runs execute
        (:class:`~chatterspec.montecarlo.Execution`).

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
        freqs_hz=_ro(freqs),
        tested=_ro(tested),
        expected=_ro(E),
        analytic={},
        family_wise_analytic={},
        frame_freqs_hz=_ro(ffreqs),
        frame_tested=_ro(ftested),
        frame_expected=_ro(Ef),
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
