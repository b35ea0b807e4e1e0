"""Results of fault identification: per-parameter estimates, hypothesis tests, reports.

:class:`Identification` holds every realization's numbers (arrays, realizations leading);
:meth:`Identification.report` gives the :class:`IdentificationReport` of one record (or of
the pooled sums of many), with ``.table()`` and ``.to_dict()`` (estimates rounded to two
significant digits of their standard error). See :mod:`chatterspec.detection.identification`
for the method.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.special

from ..errors import ParameterError
from ..plants.parameters import NO_FAULT, UNEXPLAINED
from ._identification_fit import REASONS, IdentificationSetup, selection_names
from ._identification_moments import IdentificationMoments

__all__ = ["METHOD", "HypothesisTest", "Identification", "IdentificationReport", "ParameterEstimate"]

#: Method name reported with every result.
METHOD = "instrumental variables (z(k-1)), lag-1 sandwich covariance, minimum-distance hypotheses"


@dataclass(frozen=True)
class ParameterEstimate:
    """One parameter of one hypothesis: the plant's value with its interval.

    Attributes
    ----------
    hypothesis, parameter : str
    estimate : float
        The plant's value (nominal + estimated deviation), in ``unit``; NaN without an estimate.
    ci_low, ci_high : float
        Delta-method Wald interval at ``confidence``.
    std_error : float
    unit : str
    nominal : float
        The nominal model's value.
    confidence : float
    reason : str
        Why there is no estimate (empty when there is one).
    """

    hypothesis: str
    parameter: str
    estimate: float
    ci_low: float
    ci_high: float
    std_error: float
    unit: str
    nominal: float
    confidence: float
    reason: str = ""

    def __repr__(self) -> str:
        if not np.isfinite(self.estimate):
            return f"ParameterEstimate({self.parameter}: no estimate, {self.reason})"
        u, se = (f" {self.unit}" if self.unit else ""), self.std_error
        lo, hi = format_with_error(self.ci_low, se), format_with_error(self.ci_high, se)
        return (
            f"ParameterEstimate({self.parameter} = {format_with_error(self.estimate, se)}{u}, "
            f"{self.confidence:.0%} [{lo}, {hi}])"
        )


@dataclass(frozen=True)
class HypothesisTest:
    """The test of one hypothesis: minimum distance (or the Wald statistic for "no fault").

    Attributes
    ----------
    hypothesis : str
    parameters : tuple of str
    statistic : float
        Chi-squared statistic (NaN when the hypothesis could not be fitted).
    dof : int
    p_value : float
    fits : bool
        Not rejected at ``alpha`` (``p_value > alpha``).
    """

    hypothesis: str
    parameters: tuple[str, ...]
    statistic: float
    dof: int
    p_value: float
    fits: bool


def _sig(x: float, se: float) -> int:
    """Significant digits that keep two of the standard error."""
    if not (np.isfinite(x) and np.isfinite(se)) or x == 0 or se <= 0:
        return 6
    return int(min(12, max(2, np.floor(np.log10(abs(x))) - np.floor(np.log10(se)) + 2)))


def format_with_error(x: float, se: float) -> str:
    """``x`` as text with the digits that keep two of the standard error ``se`` (trailing zeros kept).

    Parameters
    ----------
    x : float
        The value (any unit; ``"nan"`` when not finite).
    se : float
        Its standard error, same unit.
    """
    if not np.isfinite(x):
        return "nan"
    text = f"{x:#.{_sig(x, se)}g}"
    mant, _, exp = text.partition("e")
    return mant.rstrip(".") + (f"e{exp}" if exp else "")


def _round(x: float, se: float) -> float | None:
    return None if not np.isfinite(x) else float(f"{x:.{_sig(x, se)}g}")


def _round_stat(x: float) -> float | None:
    return None if not np.isfinite(x) else float(f"{x:.4g}")


@dataclass(frozen=True)
class IdentificationReport:
    """Identification of one record (or of many records pooled): estimates, tests, selection.

    Attributes
    ----------
    selected : str
        The selected hypothesis, ``"no fault"`` or ``"unexplained"``.
    estimates : tuple of ParameterEstimate
        One per (hypothesis, parameter), in hypothesis order.
    tests : tuple of HypothesisTest
        ``"no fault"`` first, then one per hypothesis.
    window_s : (float, float)
        Times (s) of the first and one past the last chattering sample used.
    n_samples : int
        Chattering samples per record.
    records : int
        Records pooled (1 for a single record).
    alpha, confidence : float
    entries : tuple of (str, float, float)
        Estimated matrix entries' deviations ``(label, estimate, std_error)``.
    selection_rate : dict or None
        Fraction of single records selecting each hypothesis (pooled reports of many runs).
    """

    selected: str
    estimates: tuple[ParameterEstimate, ...]
    tests: tuple[HypothesisTest, ...]
    window_s: tuple[float, float]
    n_samples: int
    records: int
    alpha: float
    confidence: float
    entries: tuple[tuple[str, float, float], ...] = ()
    selection_rate: dict[str, float] | None = None

    def estimate(self, hypothesis: str | None = None) -> tuple[ParameterEstimate, ...]:
        """The estimates of ``hypothesis`` (default: the selected one; empty for no fault)."""
        name = self.selected if hypothesis is None else hypothesis
        return tuple(e for e in self.estimates if e.hypothesis == name)

    def __repr__(self) -> str:
        sel = self.estimate()
        what = ", ".join(
            f"{e.parameter} = {format_with_error(e.estimate, e.std_error)} "
            f"[{format_with_error(e.ci_low, e.std_error)}, "
            f"{format_with_error(e.ci_high, e.std_error)}]{(' ' + e.unit) if e.unit else ''}"
            for e in sel
        )
        return f"IdentificationReport(selected={self.selected!r}{', ' + what if what else ''})"

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: ``selected``, ``hypotheses`` (one entry per hypothesis and parameter with
        ``hypothesis``, ``parameter``, ``estimate``, ``ci_low``, ``ci_high``, ``unit``, ``nominal``,
        ``std_error``, ``statistic``, ``dof``, ``p_value``, ``fits``, ``reason``; "no fault" first with
        ``parameter`` null), ``window_s``, ``n_samples``, ``records``, ``alpha``, ``confidence``,
        ``method``, ``entries`` and, for pooled runs, ``selection_rate``. Estimates keep two
        significant digits of their standard error; statistics four digits."""
        tests = {t.hypothesis: t for t in self.tests}
        rows: list[dict[str, object]] = []
        t0 = tests[NO_FAULT]
        rows.append(
            {
                "hypothesis": NO_FAULT,
                "parameter": None,
                "estimate": None,
                "ci_low": None,
                "ci_high": None,
                "unit": None,
                "statistic": _round_stat(t0.statistic),
                "dof": t0.dof,
                "p_value": _round_stat(t0.p_value),
                "fits": bool(t0.fits),
            }
        )
        for e in self.estimates:
            t = tests[e.hypothesis]
            rows.append(
                {
                    "hypothesis": e.hypothesis,
                    "parameter": e.parameter,
                    "estimate": _round(e.estimate, e.std_error),
                    "ci_low": _round(e.ci_low, e.std_error),
                    "ci_high": _round(e.ci_high, e.std_error),
                    "unit": e.unit,
                    "nominal": e.nominal,
                    "std_error": _round_stat(e.std_error),
                    "statistic": _round_stat(t.statistic),
                    "dof": t.dof,
                    "p_value": _round_stat(t.p_value),
                    "fits": bool(t.fits),
                    **({"reason": e.reason} if e.reason else {}),
                }
            )
        out: dict[str, object] = {
            "selected": self.selected,
            "hypotheses": rows,
            "window_s": [round(self.window_s[0], 9), round(self.window_s[1], 9)],
            "n_samples": self.n_samples,
            "records": self.records,
            "alpha": self.alpha,
            "confidence": self.confidence,
            "method": METHOD,
            "entries": [
                {"entry": lab, "deviation": _round(v, s), "std_error": _round_stat(s)}
                for lab, v, s in self.entries
            ],
        }
        if self.selection_rate is not None:
            out["selection_rate"] = {k: round(v, 6) for k, v in self.selection_rate.items()}
        return out

    def table(self) -> str:
        """A plain-text table: one row per hypothesis and parameter, "no fault" first."""
        pct = f"{self.confidence:.0%}"
        head = (
            f"{'hypothesis':<18} {'parameter':<18} {'estimate':>12} {pct + ' interval':>27} {'unit':<11} "
            f"{'nominal':>10} {'statistic':>10} {'dof':>4} {'p-value':>9}"
        )
        lines = [head]
        tests = {t.hypothesis: t for t in self.tests}

        def mark(name: str) -> str:
            return "  <- selected" if name == self.selected else ""

        t0 = tests[NO_FAULT]
        lines.append(
            f"{NO_FAULT:<18} {'-':<18} {'-':>12} {'-':>27} {'-':<11} {'-':>10} {t0.statistic:10.4g} "
            f"{t0.dof:4d} {t0.p_value:9.3g}{mark(NO_FAULT)}"
        )
        for e in self.estimates:
            t = tests[e.hypothesis]
            if np.isfinite(e.estimate):
                est = format_with_error(e.estimate, e.std_error)
                lo, hi = format_with_error(e.ci_low, e.std_error), format_with_error(e.ci_high, e.std_error)
                ci = f"[{lo}, {hi}]"
            else:
                est, ci = "none", "-"
            lines.append(
                f"{e.hypothesis:<18} {e.parameter:<18} {est:>12} {ci:>27} {e.unit:<11} {e.nominal:10.4g} "
                f"{t.statistic:10.4g} {t.dof:4d} {t.p_value:9.3g}{mark(e.hypothesis)}"
            )
            if e.reason:
                lines.append(f"{'':<18} ({e.reason})")
        lines.append(f"selected: {self.selected}")
        if self.selected == UNEXPLAINED:
            lines.append(
                "(every declared hypothesis is rejected: a fault outside the declared ones, or several)"
            )
        return "\n".join(lines)


@dataclass(frozen=True, eq=False)
class Identification:
    """Identification of many realizations at once (arrays with realizations leading).

    Attributes
    ----------
    setup : IdentificationSetup
    moments : IdentificationMoments
        The sums it was computed from (``moments.total()`` gives the pooled estimate).
    alpha, confidence : float
    fit : dict of arrays
        ``theta (runs, H, P)`` (plant's values), ``se``, ``statistic (runs, H)``, ``dof``, ``p``,
        ``no_fault_statistic (runs,)``, ``no_fault_dof``, ``no_fault_p``, ``selected (runs,)``
        (-1 no fault, -2 unexplained, else the hypothesis index), ``entries (runs, D)``,
        ``entry_cov``, ``active``, ``reason``.
    """

    setup: IdentificationSetup
    moments: IdentificationMoments
    alpha: float
    confidence: float
    fit: dict[str, np.ndarray]

    @property
    def runs(self) -> int:
        """Number of realizations (the leading axis)."""
        return self.moments.runs

    @property
    def hypothesis_names(self) -> tuple[str, ...]:
        """Names of the tested hypotheses, in the setup's order."""
        return tuple(h.name for h in self.setup.hypotheses)

    @property
    def selected(self) -> list[str]:
        """Selected hypothesis name per realization."""
        return selection_names(self.setup, self.fit["selected"])

    def selection_rate(self) -> dict[str, float]:
        """Fraction of realizations selecting each name ("no fault", hypotheses, "unexplained")."""
        sel = self.fit["selected"]
        names = {NO_FAULT: -1, **{n: i for i, n in enumerate(self.hypothesis_names)}, UNEXPLAINED: -2}
        return {n: float(np.mean(sel == i)) for n, i in names.items()}

    def _index(self, hypothesis: str, parameter: str | None) -> tuple[int, int]:
        names = self.hypothesis_names
        if hypothesis not in names:
            raise ParameterError(f"no hypothesis {hypothesis!r}; tested: {', '.join(names)}")
        h = names.index(hypothesis)
        params = self.setup.hypotheses[h].parameters
        parameter = params[0] if parameter is None else parameter
        if parameter not in params:
            raise ParameterError(f"hypothesis {hypothesis!r} has parameters {params}; not {parameter!r}")
        return h, params.index(parameter)

    def estimate(self, hypothesis: str, parameter: str | None = None) -> np.ndarray:
        """``(runs,)`` plant's value of ``parameter`` under ``hypothesis`` (NaN where not estimated)."""
        h, i = self._index(hypothesis, parameter)
        return self.fit["theta"][:, h, i]

    def interval(self, hypothesis: str, parameter: str | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(low, high)`` arrays of the Wald interval at ``confidence``."""
        h, i = self._index(hypothesis, parameter)
        zq = scipy.special.ndtri(0.5 + self.confidence / 2)  # normal quantile
        th, se = self.fit["theta"][:, h, i], self.fit["se"][:, h, i]
        return th - zq * se, th + zq * se

    def report(self, run: int = 0, *, selection_rate: dict[str, float] | None = None) -> IdentificationReport:
        """The :class:`IdentificationReport` of realization ``run``."""
        f, s = self.fit, self.setup
        zq = scipy.special.ndtri(0.5 + self.confidence / 2)  # normal quantile
        pm = s.parameter_map
        estimates, tests = [], []
        tests.append(
            HypothesisTest(
                NO_FAULT,
                (),
                float(f["no_fault_statistic"][run]),
                int(f["no_fault_dof"][run]),
                float(f["no_fault_p"][run]),
                bool(f["no_fault_p"][run] > self.alpha),
            )
        )
        for h, hyp in enumerate(s.hypotheses):
            p = float(f["p"][run, h])
            tests.append(
                HypothesisTest(
                    hyp.name,
                    hyp.parameters,
                    float(f["statistic"][run, h]),
                    int(f["dof"][run, h]),
                    p,
                    bool(p > self.alpha),
                )
            )
            for i, name in enumerate(hyp.parameters):
                th, se = float(f["theta"][run, h, i]), float(f["se"][run, h, i])
                par = pm.parameter(name)
                estimates.append(
                    ParameterEstimate(
                        hypothesis=hyp.name,
                        parameter=name,
                        estimate=th,
                        ci_low=th - zq * se,
                        ci_high=th + zq * se,
                        std_error=se,
                        unit=par.unit,
                        nominal=par.value,
                        confidence=self.confidence,
                        reason=REASONS[int(f["reason"][run, h])] if not np.isfinite(th) else "",
                    )
                )
        entries = tuple(
            (lab, float(f["entries"][run, a]), float(np.sqrt(max(f["entry_cov"][run, a, a], 0.0))))
            for a, lab in enumerate(s.labels)
        )
        mom = self.moments
        return IdentificationReport(
            selected=selection_names(s, f["selected"][run : run + 1])[0],
            estimates=tuple(estimates),
            tests=tuple(tests),
            window_s=(mom.t_start, mom.t_stop),
            n_samples=mom.n_samples,
            records=mom.records,
            alpha=self.alpha,
            confidence=self.confidence,
            entries=entries,
            selection_rate=selection_rate,
        )
