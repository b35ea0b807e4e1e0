"""The text report of a commissioning: what was fitted, with intervals, and the held-out verdict."""

from __future__ import annotations

from typing import Any

import numpy as np

from ...detection.identification import format_with_error

__all__ = ["report_text"]


def _g(x: float) -> str:
    return f"{x:.5g}"


def _head(res: Any) -> list[str]:
    src = res.source
    what = "" if src is None else f" from {'standard input' if src.name == '-' else src.name}"
    dur = res.fit_span_s[1] - res.fit_span_s[0]
    lines = [f"commissioning {res.nominal.path}{what}"]
    if src is not None:
        lines.append(f"  data sha256 {src.sha256} ({src.n_bytes} bytes)")
    span = f"  fit on {res.fit_span_s[0]:.3f}-{res.fit_span_s[1]:.3f} s ({dur:.4g} s)"
    if res.check_span_s is not None:
        span += f", held-out check on {res.check_span_s[0]:.3f}-{res.check_span_s[1]:.3f} s"
    return [*lines, span]


def _parameters(res: Any) -> list[str]:
    pf = res.parameters
    if pf is None:
        return ["", "no physical parameters declared: A and B kept as given (only Q, R and psi fitted)"]
    pct = f"{res.confidence:.0%}"
    lines = [
        "",
        f"physical parameters (fitted jointly; {pct} intervals)",
        f"{'parameter':<16} {'nominal':>11} {'fitted':>14} {pct + ' interval':>30}  {'unit':<12} "
        f"{'change':>8}",
    ]
    for p in pf.parameters:
        ci = f"[{format_with_error(p.ci_low, p.std_error)}, {format_with_error(p.ci_high, p.std_error)}]"
        change = f"{100 * p.relative_change:+.2f} %" if np.isfinite(p.relative_change) else "-"
        lines.append(
            f"{p.name:<16} {p.nominal:>11.4g} {format_with_error(p.estimate, p.std_error):>14} {ci:>30}  "
            f"{p.unit:<12} {change:>8}"
        )
    explained = "explain" if pf.p_value > res.options["alpha"] else "do NOT explain"
    lines.append(
        f"(the declared parameters {explained} the estimated entries: chi2 {pf.statistic:.3g} on {pf.dof} "
        f"dof, p = {pf.p_value:.2g}; {res.passes} pass{'es' if res.passes > 1 else ''})"
    )
    return lines


def _covariance_cell(value: float, lo: float, hi: float, identified: bool, nominal: float) -> str:
    if identified:
        return f"{_g(value):>11} [{_g(lo)}, {_g(hi)}]"
    kept = "nominal kept" if value == nominal else "set to the bound"
    bound = f"<= {_g(hi)}" if np.isfinite(hi) else "unbounded"
    return f"{_g(value):>11} {bound} (not identified: {kept})"


def _noise(res: Any) -> list[str]:
    nf, model = res.noise, res.model
    pct = f"{res.confidence:.0%}"
    lines = ["", f"noise covariances (diagonals; {pct} intervals, or the bound the data give)"]
    lines.append(
        f"{'channel':<12} {'R nominal':>10} {'R fitted':>11} {'':<26} {'Q nominal':>10} {'Q fitted':>11}"
    )
    for c, name in enumerate(model.output_names):
        r = _covariance_cell(nf.r[c], nf.r_ci_low[c], nf.r_ci_high[c], nf.r_identified[c], nf.r_nominal[c])
        q = _covariance_cell(nf.q[c], nf.q_ci_low[c], nf.q_ci_high[c], nf.q_identified[c], nf.q_nominal[c])
        lines.append(f"{name:<12} {_g(nf.r_nominal[c]):>10} {r:<38} {_g(nf.q_nominal[c]):>10} {q}")
    lines.append(
        f"(autocovariances at lags 0 and 1 fitted: chi2 {nf.statistic:.3g} on {nf.dof} dof, "
        f"p = {nf.p_value:.2g})"
    )
    psi = ", ".join(f"{n} {_g(v)}" for n, v in zip(model.output_names, res.psi, strict=True))
    lines.append(f"psi ({res.PSI_SIGMAS:g} x the fitted chattering std): {psi}")
    return lines


def _check(res: Any) -> list[str]:
    ch = res.check
    if ch is None:
        return ["", "no held-out check (the whole recording was used for the fit)"]
    lines = [
        "",
        f"held-out check ({ch.span_s[0]:.1f}-{ch.span_s[1]:.1f} s; at most {ch.alpha:g} to fail on a "
        "plant the model describes)",
        f"{'channel':<12} {'whiteness (lags 2-' + str(ch.channels[0].lags + 1) + ')':<34} "
        f"{'spectrum (' + str(ch.segments) + ' x ' + _g(ch.segment_s) + ' s averaged)':<44} alarm starts",
    ]
    for c in ch.channels:
        white = f"{c.whiteness:.4g}, p = {c.whiteness_p:.2g} {'ok' if c.white else 'CORRELATED'}"
        where = ", ".join(f"{lo:.4g}-{hi:.4g} Hz" for lo, hi in c.bands_hz)
        spec = f"{c.peak_ratio:.3g} x threshold at {c.peak_hz:.4g} Hz " + (
            "ok" if c.spectrum_ok else f"OVER {where}"
        )
        times = "" if not c.alarm_starts else f" (at {', '.join(f'{t:.2f}' for t in c.alarm_times_s)} s)"
        lines.append(f"{c.channel:<12} {white:<34} {spec:<44} {c.alarm_starts}{times}")
    per = 1.0 / ch.false_alarms_per_hour
    lines.append(
        f"alarms ({ch.rule} rule, 1 false alarm per {per:.3g} h): {ch.alarm_starts} start(s) in "
        f"{ch.hours:.3g} h (expected {ch.expected_starts:.2g}; 95 % interval of the rate "
        f"{_g(ch.rate_interval[0])}-{_g(ch.rate_interval[1])} per hour)"
    )
    if ch.adequate:
        lines.append("verdict: ADEQUATE")
    else:
        lines.append("verdict: NOT ADEQUATE")
        lines += [f"  - {f}" for f in ch.failures()]
    return lines


def report_text(res: Any) -> str:
    """The report of a :class:`~chatterspec.studies.commissioning.result.Commissioning` as plain text.

    Parameters
    ----------
    res : Commissioning
    """
    return "\n".join(_head(res) + _parameters(res) + _noise(res) + _check(res))
