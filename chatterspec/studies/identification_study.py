"""Validation of fault identification over many realizations: error, coverage, isolation.

:func:`identification_validation` runs one scenario's realizations through the simulation and
identification (the chunks of :func:`chatterspec.detection.pipeline.iter_chattering`, the
same numbers whatever the chunking) and compares each estimate with the true parameter of the
scenario's plant; :func:`identification_sweep` does it for every size of a power-study family
(:data:`chatterspec.studies.detection_rates.POWER_FAMILIES`). ``scripts/identification_study.py`` runs the
whole catalogue and draws ``figures/identification_sweep.png``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np

from ..detection.identification import (
    NO_FAULT,
    IdentificationStream,
    identification_setup,
    true_hypothesis,
    true_parameters,
)
from ..detection.pipeline import iter_chattering
from ..plants.models import LinearModel
from ..plants.scenarios import Scenario
from .detection_rates import POWER_FAMILIES, power_scenario
from .intervals import clopper_pearson

__all__ = [
    "FAMILY_HYPOTHESIS",
    "IdentificationValidation",
    "identification_sweep",
    "identification_validation",
]

#: The hypothesis of the catalogue models' parameter maps that each power-study family changes.
FAMILY_HYPOTHESIS = {
    "leakage": "leakage",
    "friction": "friction",
    "bulk-modulus": "bulk_modulus",
    "f0": "natural_frequency",
}


@dataclass(frozen=True)
class IdentificationValidation:
    """Identification of ``runs`` realizations of one single-segment scenario.

    Attributes
    ----------
    scenario : str
    runs : int
    true_hypothesis : str or None
    parameter : str or None
        The (first) parameter of the true hypothesis.
    true_value : float
        Its value in the scenario's plant (NaN for "no fault").
    estimates : (runs,) array
        Its estimate under the true hypothesis, per realization.
    ci_low, ci_high : (runs,) arrays
        Interval ends at ``confidence``.
    selected_true : int
        Realizations selecting the true hypothesis.
    selection_rate : dict
        Fraction of realizations per selected name.
    confidence, alpha : float
    """

    scenario: str
    runs: int
    true_hypothesis: str | None
    parameter: str | None
    true_value: float
    estimates: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    selected_true: int
    selection_rate: dict[str, float]
    confidence: float
    alpha: float

    @property
    def covered(self) -> int:
        """Intervals holding the true value."""
        return int(np.sum((self.ci_low <= self.true_value) & (self.true_value <= self.ci_high)))

    def coverage(self, level: float = 0.99) -> tuple[float, float, float]:
        """Fraction of intervals holding the true value and its Clopper-Pearson interval at ``level``."""
        return (self.covered / self.runs, *clopper_pearson(self.covered, self.runs, level))

    def isolation(self, level: float = 0.99) -> tuple[float, float, float]:
        """Fraction selecting the true hypothesis and its Clopper-Pearson interval at ``level``."""
        return (self.selected_true / self.runs, *clopper_pearson(self.selected_true, self.runs, level))

    @property
    def median_relative_error(self) -> float:
        """Median of ``|estimate - true| / |true|`` (NaN when the true value is 0 or unknown)."""
        if not np.isfinite(self.true_value) or self.true_value == 0:
            return float("nan")
        return float(np.nanmedian(np.abs(self.estimates - self.true_value) / abs(self.true_value)))

    def row(self) -> dict[str, object]:
        """One JSON-ready row: median estimate, relative error, coverage and isolation with 99 % CIs."""
        cov = self.coverage() if self.parameter else (np.nan,) * 3
        iso = self.isolation()

        def f(x: float) -> float | None:
            return None if not np.isfinite(x) else float(f"{x:.5g}")

        return {
            "scenario": self.scenario,
            "runs": self.runs,
            "true_hypothesis": self.true_hypothesis,
            "parameter": self.parameter,
            "true_value": f(self.true_value),
            "median_estimate": f(float(np.nanmedian(self.estimates))) if self.parameter else None,
            "median_relative_error": f(self.median_relative_error),
            "coverage": [f(x) for x in cov],
            "isolation": [f(x) for x in iso],
            "selection_rate": {k: round(v, 5) for k, v in self.selection_rate.items() if v},
        }


def identification_validation(
    sc: Scenario,
    runs: int,
    seed: int,
    *,
    alpha: float = 1e-3,
    confidence: float = 0.95,
    chunk_runs: int = 256,
    hypothesis: str | None = None,
) -> IdentificationValidation:
    """Identify ``runs`` realizations of a single-segment scenario and compare with its true plant.

    Parameters
    ----------
    sc : Scenario
        Linear, full measurement, with a parameter map; the whole record is one plant.
    runs : int
        Realizations.
    seed : int
        Root seed (realization r is the same whatever ``chunk_runs``).
    alpha, confidence : float
        Test level and interval level.
    chunk_runs : int
        Realizations simulated together (memory only).
    hypothesis : str, optional
        Whose estimate to compare with the plant's value (default: the true hypothesis; give one
        for a healthy plant, whose true value is then the nominal one).
    """
    setup = identification_setup(sc.nominal)
    st = IdentificationStream(setup, alpha=alpha, confidence=confidence)
    for _ in st.tap(iter_chattering(sc, runs, seed, chunk_runs=min(chunk_runs, runs), measurements=True)):
        pass
    idn = st.result()
    plant = cast(LinearModel, sc.segments[0].model)  # (the setup's linear plant)
    name = true_hypothesis(setup, plant)
    param, value = None, float("nan")
    est = lo = hi = np.full(runs, np.nan)
    compare = hypothesis or name
    if compare not in (None, NO_FAULT):
        param = next(h.parameters for h in setup.hypotheses if h.name == compare)[0]
        value = float(true_parameters(setup, plant)[compare][0])
        est = idn.estimate(compare, param)
        lo, hi = idn.interval(compare, param)
    sel = idn.selected
    return IdentificationValidation(
        scenario=sc.name,
        runs=runs,
        true_hypothesis=name,
        parameter=param,
        true_value=value,
        estimates=est,
        ci_low=lo,
        ci_high=hi,
        selected_true=sum(s == name for s in sel),
        selection_rate=idn.selection_rate(),
        confidence=confidence,
        alpha=alpha,
    )


def identification_sweep(
    family: str,
    sizes: Sequence[float] | None = None,
    *,
    noise: float = 1.0,
    runs: int = 200,
    seed: int = 0,
    alpha: float = 1e-3,
    confidence: float = 0.95,
) -> list[IdentificationValidation]:
    """:func:`identification_validation` at every size of a power-study family (the healthy size included).

    Parameters
    ----------
    family : {"leakage", "bulk-modulus", "friction", "f0"}
        See :data:`chatterspec.studies.detection_rates.POWER_FAMILIES`.
    sizes : sequence of float, optional
        Default: the family's sizes.
    noise : float
        Measurement-noise multiplier (see :func:`chatterspec.studies.detection_rates.power_scenario`).
    runs, seed, alpha, confidence
        As in :func:`identification_validation`.
    """
    sizes = POWER_FAMILIES[family]["sizes"] if sizes is None else sizes
    return [
        identification_validation(
            power_scenario(family, s, noise),
            runs,
            seed,
            alpha=alpha,
            confidence=confidence,
            hypothesis=FAMILY_HYPOTHESIS[family],
        )
        for s in sizes
    ]
