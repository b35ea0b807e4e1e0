"""Threshold calibration: thresholds read from healthy runs, the result, its file, and recordings.

The calibration of the chi-squared thresholds (as opposed to the alarm rules' calibration,
:mod:`chatterspec.detection.alarms.calibration`) lives in this package, in five modules:

* :mod:`.healthy` -- the healthy Monte Carlo runs everything is read from: scenarios of a model
  or a model file (:func:`~chatterspec.plants.simulate.as_scenario`), :class:`~.healthy.HealthyStudy` (the
  streaming summary of a chunk of healthy runs: top-k tails, compiled exceedance counts) and the
  bounded-memory tail histograms used above a memory budget.
* :mod:`.thresholds` -- :func:`~.thresholds.calibrate` (analytic ``paper`` / ``exact`` thresholds
  beside the empirical per-bin, per-frame and family-wise quantiles of simulated healthy runs,
  each with its order-statistic interval), :func:`~.thresholds.calibrate_empirical` (nonlinear
  models: empirical normalization) and the quantile fields both share.
* :mod:`.result` -- :class:`~.result.Calibration` and its file format (JSON, or ``.npz`` arrays
  with a JSON header; :func:`~.result.load_calibration`).
* :mod:`.support` -- whether a calibration's number of healthy runs supports its alpha (the
  minimum and the refusal; pure arithmetic, light enough for the command line's early checks).
* :mod:`.recorded` -- the same ``Calibration`` read from a recorded healthy run of the user's own
  plant (the plan, the tally and the result; the monitor that reads the recording is driven by
  :mod:`chatterspec.online.recorded_calibration`).

This ``__init__`` imports nothing, so that :mod:`.support` stays light; import from the modules.
"""
