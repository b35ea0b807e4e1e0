"""Monte Carlo studies: threshold calibration, false-alarm statistics and detection power.

Threshold calibration, false-alarm statistics and detection power at Monte Carlo scale, and the
studies built on them. One concept per module:

* :mod:`.calibration` (a package) -- the threshold calibration: healthy runs, calibrated
  thresholds, the ``Calibration`` and its file, the support of its alpha, recorded healthy runs;
* :mod:`.intervals` -- Clopper-Pearson and order-statistic intervals;
* :mod:`.detection_rates` -- false-alarm and power studies, ROC curves;
* :mod:`.boundary_layer` -- the boundary-layer Monte Carlo and the Fig 2 study;
* :mod:`.estimation` -- error metrics, the estimator study, multiple-model mode outputs;
* :mod:`.diagnosis` -- the chattering, mode-based and identification diagnosis routes;
* :mod:`.alarm_budget` -- the monitor's alarm rule at a false-alarm budget, and its delays;
* :mod:`.budget_diagnosis` -- every diagnosis route at one false-alarm budget;
* :mod:`.closed_loop` -- excitation and footprint studies under a position loop;
* :mod:`.identification_study`, :mod:`.tolerance_study` -- identification and tolerance decisions;
* :mod:`.commissioning` (a package) -- a fitted, checked model from a healthy recording.

Three studies run on :mod:`chatterspec.montecarlo` (serial, local processes or
Dask, identical results for the same seed):

* :func:`~.calibration.thresholds.calibrate` -- analytic thresholds (``paper``, ``exact`` per-bin,
  ``exact`` family-wise) beside empirical ones from healthy runs: per-bin and
  per-frame quantiles of the normalized power ``S / E[S]`` and the family-wise
  quantile of the maximum normalized bin, each with a distribution-free
  order-statistic confidence interval. The result saves to a calibration file
  (JSON or NPZ) that detection can load instead of the analytic threshold.
* :func:`~.detection_rates.false_alarm_study` -- per-bin, per-frame and family-wise false-alarm
  rates of every threshold kind with exact (Clopper-Pearson) intervals and a
  verdict against the nominal alpha.
* :func:`~.detection_rates.power_study` -- detection probability vs fault size and noise level
  for each threshold kind, and ROC curves (false-alarm vs detection rate as
  alpha varies).

Nothing here reimplements a periodogram or a threshold: spectra come from
:mod:`chatterspec.detection.spectral`, thresholds from :mod:`chatterspec.detection.thresholds`.

Statistics
----------
Clopper-Pearson interval for ``k`` events in ``n`` trials at confidence ``c``:
``[B^-1((1-c)/2; k, n-k+1), B^-1((1+c)/2; k+1, n-k)]`` (beta quantiles).
Order-statistic interval for the ``q``-quantile of ``n`` iid samples:
``[X_(l), X_(u)]`` with ``l = Binom^-1((1-c)/2; n, q)`` and
``u = Binom^-1((1+c)/2; n, q) + 1``; its coverage is at least ``c`` for any
continuous law. Pooling the bins of one record treats them as independent
trials; periodogram bins of the MA(1) chattering are nearly independent
(their correlation is O(1/N)). STFT frames that overlap are not: per-frame
quantile intervals count only the non-overlapping frames as independent
samples (approximate, conservative), and per-frame false-alarm intervals,
which pool overlapping frames, are approximate.
"""
