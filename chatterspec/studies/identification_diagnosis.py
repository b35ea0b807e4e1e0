"""Fault identification over many realizations, per segment of a scenario (``chatterspec diagnose``).

:class:`IdentificationTally` takes the same simulation chunks as the other diagnosis routes
(:mod:`chatterspec.studies.chattering_diagnosis`, :mod:`chatterspec.studies.mode_diagnosis`) and
identifies every realization inside every segment of the true plant (one STFT hop inside the
edges shared with another segment: a window that straddles a change mixes two regressions).
Per segment it keeps, per realization, the selected hypothesis and the estimate of the
hypothesis that explains the true plant; :meth:`IdentificationTally.result` gives the
isolation rate, the median relative error and the interval's coverage with Clopper-Pearson
intervals. Only per-run numbers are kept: memory does not grow with the number of runs, and the
result does not depend on the chunking.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..detection.identification import (
    NO_FAULT,
    IdentificationSetup,
    identify,
    true_hypothesis,
    true_parameters,
)
from ..plants.models import LinearModel
from ..plants.scenarios import Scenario
from ..plants.simulate import Simulation
from .intervals import clopper_pearson

__all__ = ["IdentificationTally", "SegmentIdentification", "segment_windows"]

#: Trim (s) at an edge shared with another segment: the monitor's default hop.
EDGE_TRIM_S = 0.2


def segment_windows(sc: Scenario, trim_s: float = EDGE_TRIM_S) -> list[tuple[int, tuple[float, float]]]:
    """``(segment index, (start, stop))`` windows inside each segment, ``trim_s`` inside shared edges.

    Parameters
    ----------
    sc : Scenario
        Its segments of true plant.
    trim_s : float
        Seconds left out on each side of an edge shared with another segment.
    """
    out = []
    last = len(sc.segments) - 1
    for i, s in enumerate(sc.segments):
        lo = s.start + (trim_s if i > 0 else sc.dt)
        hi = s.stop - (trim_s if i < last else 0.0)
        if hi - lo > 2 * trim_s:
            out.append((i, (lo, hi)))
    return out


@dataclass(frozen=True)
class SegmentIdentification:
    """Identification over the runs of one segment.

    Attributes
    ----------
    segment_s : (float, float)
        The segment; ``window_s`` the part identified.
    true_hypothesis : str or None
        The hypothesis that explains the segment's true plant ("no fault" when it matches the
        nominal model, None when no declared hypothesis does).
    true_values : dict
        Its parameters' true values.
    runs : int
    selection_rate : dict
        Fraction of runs selecting each name.
    isolation : (float, float, float)
        Fraction selecting the true hypothesis and its 99 % Clopper-Pearson interval.
    median_estimate, median_relative_error : dict
        Per parameter of the true hypothesis (NaN for "no fault").
    coverage : dict
        Per parameter: (fraction of intervals holding the true value, 99 % CP low, high).
    """

    segment_s: tuple[float, float]
    window_s: tuple[float, float]
    true_hypothesis: str | None
    true_values: dict[str, float]
    runs: int
    selection_rate: dict[str, float]
    isolation: tuple[float, float, float]
    median_estimate: dict[str, float] = field(default_factory=dict)
    median_relative_error: dict[str, float] = field(default_factory=dict)
    coverage: dict[str, tuple[float, float, float]] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""

        def r(x: float) -> float | None:
            return None if not np.isfinite(x) else float(f"{x:.6g}")

        return {
            "segment_s": list(self.segment_s),
            "window_s": [round(v, 9) for v in self.window_s],
            "true_hypothesis": self.true_hypothesis,
            "true_values": self.true_values,
            "runs": self.runs,
            "selection_rate": {k: round(v, 6) for k, v in self.selection_rate.items() if v},
            "isolation": [r(v) for v in self.isolation],
            "median_estimate": {k: r(v) for k, v in self.median_estimate.items()},
            "median_relative_error": {k: r(v) for k, v in self.median_relative_error.items()},
            "coverage": {k: [r(x) for x in v] for k, v in self.coverage.items()},
        }


class IdentificationTally:
    """Accumulates identification over simulation chunks (see the module docstring).

    Parameters
    ----------
    sc : Scenario
    setup : IdentificationSetup
    alpha, confidence : float
    """

    def __init__(
        self, sc: Scenario, setup: IdentificationSetup, *, alpha: float = 1e-3, confidence: float = 0.95
    ) -> None:
        self.sc, self.setup, self.alpha, self.confidence = sc, setup, alpha, confidence
        self.windows = segment_windows(sc)
        self.truth = []
        for i, _ in self.windows:
            model = cast(LinearModel, sc.segments[i].model)  # (the setup's linear plant, per segment)
            name = true_hypothesis(setup, model)
            values: dict[str, float] = {}
            if name not in (None, NO_FAULT):
                params = next(h.parameters for h in setup.hypotheses if h.name == name)
                values = dict(zip(params, map(float, true_parameters(setup, model)[name]), strict=True))
            self.truth.append((name, values))
        self._selected: list[list[str]] = [[] for _ in self.windows]
        self._est: list[list[np.ndarray]] = [[] for _ in self.windows]
        self._cover: list[list[np.ndarray]] = [[] for _ in self.windows]

    def add(self, sim: Simulation) -> None:
        """Identify every run of a simulation chunk in every segment window."""
        self.absorb(sim.t, self.compute(sim))

    def compute(self, sim: Simulation) -> list[tuple[list[str], np.ndarray | None, np.ndarray | None]]:
        """The heavy part of :meth:`add` (on a worker with ``diagnose --workers``): per window the
        selected names, the true hypothesis's estimates and whether its intervals cover the truth."""
        out = []
        for w, (_, window) in enumerate(self.windows):
            idn = identify(
                self.setup.model,
                sim.z,
                sim.u,
                hypotheses=self.setup.hypotheses,
                window_s=window,
                t0=float(sim.t[0]),
                alpha=self.alpha,
                confidence=self.confidence,
            )
            name, values = self.truth[w]
            est = cover = None
            if values:
                assert name is not None  # (values: a named hypothesis)
                est = np.stack([idn.estimate(name, p) for p in values], axis=1)
                lo_hi = [idn.interval(name, p) for p in values]
                tv = np.array(list(values.values()))
                cover = np.stack(
                    [(lo <= t) & (t <= hi) for (lo, hi), t in zip(lo_hi, tv, strict=True)], axis=1
                )
            out.append((idn.selected, est, cover))
        return out

    def absorb(
        self, t: np.ndarray, computed: list[tuple[list[str], np.ndarray | None, np.ndarray | None]]
    ) -> None:
        """Fold one chunk's :meth:`compute` in (chunks in order: the serial figures)."""
        for w, (selected, est, cover) in enumerate(computed):
            self._selected[w] += selected
            if est is not None:
                assert cover is not None  # (computed with est)
                self._est[w].append(est)
                self._cover[w].append(cover)

    def result(self) -> list[SegmentIdentification]:
        """One :class:`SegmentIdentification` per segment window."""
        out = []
        for w, (i, window) in enumerate(self.windows):
            seg = self.sc.segments[i]
            name, values = self.truth[w]
            sel = self._selected[w]
            n = len(sel)
            names = [NO_FAULT, *(h.name for h in self.setup.hypotheses), "unexplained"]
            rate = {k: sel.count(k) / n for k in names} if n else {}
            hit = sel.count(name) if name is not None else 0
            lo, hi = clopper_pearson(hit, n, 0.99) if n else (np.nan, np.nan)
            med, rel, cov = {}, {}, {}
            if values and self._est[w]:
                est = np.concatenate(self._est[w])
                cv = np.concatenate(self._cover[w])
                for j, (p, t) in enumerate(values.items()):
                    med[p] = float(np.nanmedian(est[:, j]))
                    rel[p] = float(np.nanmedian(np.abs(est[:, j] - t) / abs(t))) if t != 0 else float("nan")
                    k = int(cv[:, j].sum())
                    cl, ch = clopper_pearson(k, n, 0.99)
                    cov[p] = (k / n, cl, ch)
            out.append(
                SegmentIdentification(
                    segment_s=(seg.start, seg.stop),
                    window_s=window,
                    true_hypothesis=name,
                    true_values=values,
                    runs=n,
                    selection_rate=rate,
                    isolation=(hit / n if n else np.nan, lo, hi),
                    median_estimate=med,
                    median_relative_error=rel,
                    coverage=cov,
                )
            )
        return out
