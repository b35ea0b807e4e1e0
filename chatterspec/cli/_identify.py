"""Fault identification in the command line: options, JSON documents and table lines.

Shared by ``detect``, ``demo``, ``monitor`` and ``diagnose``. A scenario's whole record is
identified for every realization as the chunks stream past the detector (pooled estimate
and per-record selection rates with ``--runs R > 1``); when the STFT found fault intervals,
each interval of run 0 is identified on its own, one hop inside its edges.
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.identification import IdentificationSetup, IdentificationStream
    from ..plants.models import LinearModel
    from ..plants.scenarios import Scenario


def confidence_arg(text: str) -> float:
    """argparse type: a confidence level in (0, 1)."""
    from ._common import alpha_arg

    try:
        return alpha_arg(text)  # the same open interval
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"confidence must be a number in (0, 1); got {text!r}") from None


def add_identification_args(p: argparse.ArgumentParser) -> None:
    """``--no-identify`` and ``--confidence``."""
    p.add_argument(
        "--no-identify",
        action="store_true",
        help="skip fault identification (which parameter changed, in physical units)",
    )
    p.add_argument(
        "--confidence",
        type=confidence_arg,
        default=0.95,
        help="confidence level of the identified parameters' intervals (default 0.95); the hypothesis "
        "tests use --alpha",
    )


def setup_or_reason(
    model: LinearModel, args: argparse.Namespace
) -> tuple[IdentificationSetup | None, str | None]:
    """The identification setup of ``model``, or why there is none (``--no-identify``, reduced order, ...)."""
    if getattr(args, "no_identify", False):
        return None, "skipped (--no-identify)"
    from ..detection.identification import identification_setup
    from ..errors import IdentifiabilityError

    try:
        return identification_setup(model), None
    except IdentifiabilityError as exc:
        return None, str(exc)


def stream(setup: IdentificationSetup, args: argparse.Namespace) -> IdentificationStream:
    """The identification stream of ``setup`` at the ``--alpha`` / ``--confidence`` of ``args``."""
    from ..detection.identification import IdentificationStream

    return IdentificationStream(setup, alpha=args.alpha, confidence=args.confidence)


def truth(
    setup: IdentificationSetup, sc: Scenario, window: tuple[float, float] | None
) -> dict[str, Any] | None:
    """The true hypothesis and parameter values of the segment covering most of ``window`` (simulations)."""
    from ..detection.identification import NO_FAULT, true_hypothesis, true_parameters
    from ..plants.nonlinear import is_linear

    lo, hi = window if window is not None else (0.0, sc.duration)
    inside = [s for s in sc.segments if min(s.stop, hi) - max(s.start, lo) > sc.dt]
    if len({id(s.model) for s in inside}) != 1 and len({s.model.fingerprint() for s in inside}) != 1:
        return {"hypothesis": None, "note": "the window spans segments with different plants"}
    seg = inside[0]
    if not is_linear(seg.model) or not seg.model.full_measurement:
        return None
    name = true_hypothesis(setup, seg.model)
    out: dict[str, Any] = {"hypothesis": name, "segment_s": [seg.start, seg.stop]}
    if name not in (None, NO_FAULT):
        names = next(h.parameters for h in setup.hypotheses if h.name == name)
        values = true_parameters(setup, seg.model)[name]
        out["parameters"] = {p: float(v) for p, v in zip(names, values, strict=True)}
    return out


def record_doc(
    ident: IdentificationStream, runs: int, setup: IdentificationSetup, sc: Scenario | None
) -> dict[str, Any]:
    """Whole-record identification: run 0 (one run) or the pooled estimate with selection rates."""
    rep = ident.pooled() if runs > 1 else ident.result().report(0)
    doc = rep.to_dict()
    doc["scope"] = "pooled over runs" if runs > 1 else "run 0"
    if sc is not None:
        doc["true"] = truth(setup, sc, None)
    return doc


def interval_docs(
    setup: IdentificationSetup,
    z: Any,
    u: Any,
    intervals: list[tuple[float, float]],
    duration: float,
    hop_s: float,
    args: argparse.Namespace,
    sc: Scenario | None,
) -> list[dict[str, Any]]:
    """Identification of run 0 inside each STFT interval, one hop inside its interior edges.

    A window that straddles a change of the plant mixes two regressions (one sample on the
    wrong side is enough for the test to reject the right hypothesis), so the window starts a
    hop after the estimated onset and ends a hop before the estimated offset, unless the
    interval touches the record's start or end, or the trimmed window would be shorter than
    two hops.
    """
    from ..detection.identification import identify
    from ..errors import ParameterError

    out = []
    for on, off in intervals:
        lo = on if on <= hop_s else on + hop_s
        hi = off if off >= duration - hop_s else off - hop_s
        if hi - lo < 2 * hop_s:
            lo, hi = on, off
        doc: dict[str, Any] = {"interval_s": [on, off]}
        try:
            rep = identify(
                setup.model,
                z,
                u,
                hypotheses=setup.hypotheses,
                window_s=(lo, hi),
                alpha=args.alpha,
                confidence=args.confidence,
            ).report(0)
            doc.update(rep.to_dict())
        except ParameterError as exc:  # e.g. a window too short to hold two samples
            doc.update({"selected": None, "reason": str(exc)})
        if sc is not None:
            doc["true"] = truth(setup, sc, (lo, hi))
        out.append(doc)
    return out


def _selected_rows(doc: dict[str, Any]) -> list[dict[str, Any]]:
    return [h for h in doc.get("hypotheses", []) if h["hypothesis"] == doc.get("selected")]


def _num(x: float | None, se: float | None = None) -> str:
    """A number of the JSON document; with its standard error, the digits that keep two of it."""
    if x is None:
        return "-"
    if se is None:
        return f"{x:.6g}"
    from ..detection.identification_results import format_with_error

    return format_with_error(x, se)


def summary_line(doc: dict[str, Any]) -> str:
    """``leakage = 8.96e-11 [8.90e-11, 9.02e-11] m^3/(s Pa)`` (or the selected name without a parameter)."""
    sel = doc.get("selected")
    rows = _selected_rows(doc)
    if not rows or rows[0]["parameter"] is None:
        return str(sel)
    parts = []
    for h in rows:
        if h["estimate"] is None:
            parts.append(f"{h['parameter']}: no estimate ({h.get('reason', '')})")
        else:
            unit = f" {h['unit']}" if h["unit"] else ""
            se = h["std_error"]
            parts.append(
                f"{h['parameter']} = {_num(h['estimate'], se)} [{_num(h['ci_low'], se)}, "
                f"{_num(h['ci_high'], se)}]{unit}"
            )
    return f"{sel}: " + "; ".join(parts)


def true_text(doc: dict[str, Any]) -> str:
    """The true fault of an identification JSON ``doc`` as text (empty when it has none)."""
    t = doc.get("true")
    if not t or t.get("hypothesis") is None:
        return ""
    params = t.get("parameters")
    if not params:
        return str(t["hypothesis"])
    return ", ".join(f"{k} = {v:.6g}" for k, v in params.items())


def print_identification(doc: dict[str, Any]) -> None:
    """The ``detect`` text block: the table of the whole record, then each interval's line."""
    ident = doc.get("identification")
    if ident is None:
        return
    if "reason" in ident and "hypotheses" not in ident:
        print(f"identification: not available: {ident['reason']}")
        return
    scope = ident.get("scope", "")
    conf = f"{ident['confidence']:.0%}"
    w0, w1 = ident["window_s"]
    print(
        f"identification ({scope}, {w0:.3f}-{w1:.3f} s, {conf} intervals, tests at alpha = "
        f"{ident['alpha']:g}; estimate = the plant's value):"
    )
    header = (
        f"{'hypothesis':<18} {'parameter':<18} {'estimate':>12} {conf + ' interval':>28} {'unit':<11} "
        f"{'p-value':>9}"
    )
    print(header)
    for h in ident["hypotheses"]:
        mark = "  <- selected" if h["hypothesis"] == ident["selected"] else ""
        se = h.get("std_error")
        ci = "-" if h["ci_low"] is None else f"[{_num(h['ci_low'], se)}, {_num(h['ci_high'], se)}]"
        print(
            f"{h['hypothesis']:<18} {h['parameter'] or '-':<18} {_num(h['estimate'], se):>12} {ci:>28} "
            f"{h['unit'] or '-':<11} {_num(h['p_value']):>9}{mark}"
        )
    rate = ident.get("selection_rate")
    if rate:
        print("selected per record: " + ", ".join(f"{k} {v:.3f}" for k, v in rate.items() if v))
    tt = true_text(ident)
    print(f"selected: {summary_line(ident)}" + (f"   (true: {tt})" if tt else ""))
    for iv in doc.get("identification_intervals", []):
        a, b = iv["interval_s"]
        tt = true_text(iv)
        what = summary_line(iv) if iv.get("selected") is not None else f"no estimate ({iv.get('reason')})"
        print(f"  interval [{a:.1f}, {b:.1f}] s, run 0: {what}" + (f"   (true: {tt})" if tt else ""))


def _windows(r: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """The identification windows of one demo scenario: its STFT intervals if any, else the record."""
    ivs = r.get("identification_intervals")
    if ivs:  # the window identified: the STFT interval, a hop inside its interior edges
        out = []
        for iv in ivs:
            w0, w1 = iv.get("window_s", iv["interval_s"])
            out.append((f"{w0:.1f}-{w1:.1f}", iv))
        return out
    ident = r.get("identification")
    if not ident or "hypotheses" not in ident:
        return []
    w0, w1 = ident["window_s"]
    return [(f"{w0:.1f}-{w1:.1f}", ident)]


def print_demo_table(results: list[dict[str, Any]]) -> None:
    """The demo's identification table: per scenario (and STFT interval) the selected hypothesis,
    the parameter's estimate with its interval in physical units, and the true value."""
    rows = [(r, w, d) for r in results for w, d in _windows(r)]
    if not rows:
        why = next((r["identification"].get("reason") for r in results if r.get("identification")), None)
        print(f"identification: not available ({why})")
        return
    d0 = rows[0][2]
    conf = f"{d0['confidence']:.0%}"
    print(
        f"identification: which parameter changed, in physical units ({conf} intervals; hypothesis tests at "
        f"alpha = {d0['alpha']:g}; window: the STFT intervals of run 0 a hop inside, else the whole record"
        + (", pooled over runs" if d0.get("records", 1) > 1 else "")
        + ")"
    )
    head = (
        f"{'scenario':<22} {'window (s)':<10} {'selected':<18} {'estimate':>12} {conf + ' interval':>27} "
        f"{'unit':<11} {'true':>10}"
    )
    print(head)
    print("-" * len(head))
    for r, win, d in rows:
        sel = d.get("selected")
        picked = _selected_rows(d)
        true = d.get("true") or {}
        tv = (true.get("parameters") or {}) if isinstance(true, dict) else {}
        if not picked or picked[0]["parameter"] is None:
            t_name = true.get("hypothesis") if isinstance(true, dict) else None
            truth_s = "" if t_name in (None, sel) else str(t_name)
            print(
                f"{r['scenario']:<22} {win:<10} {sel or '-':<18} {'-':>12} {'-':>27} {'-':<11} {truth_s:>10}"
            )
            continue
        for h in picked:
            se = h["std_error"]
            est = _num(h["estimate"], se) if h["estimate"] is not None else "none"
            ci = "-" if h["ci_low"] is None else f"[{_num(h['ci_low'], se)}, {_num(h['ci_high'], se)}]"
            t = tv.get(h["parameter"])
            print(
                f"{r['scenario']:<22} {win:<10} {sel:<18} {est:>12} {ci:>27} {h['unit'] or '-':<11} "
                f"{'-' if t is None else f'{t:.6g}':>10}"
            )


class MonitorIdentification:
    """Online identification for ``chatterspec monitor``: per hop an ``identification`` event (JSON
    lines), a human line when the selected hypothesis changes, and a summary for ``--json``.

    The identification tests every hop at the monitor's per-frame alpha, which the alarm rule does not
    (it holds false alarms to a budget per hour). So that the human lines follow the alarms, with
    ``alarm_active`` set (a callable: is an alarm active now?) a fault or "unexplained" selection is
    said only while an alarm is active (at the first hop of the alarm if it was selected before), and
    "no fault" only after one was said; the JSON events and the summary's ``changes`` keep every change.

    Parameters
    ----------
    setup : IdentificationSetup
    hop_samples, window_hops : int
        The monitor's hop and the window in hops (default: the STFT window).
    t0 : float
        Time (s) of the first row.
    args : argparse.Namespace
        ``alpha`` (the monitor's per-frame alpha) and ``confidence``.
    emit : callable or None
        Writes one JSON line (``--events jsonl`` with ``--identification-events``); None: no events.
    say : callable
        Writes one human line.
    every_hop : bool
        An event per hop (``every-hop``), or only when the selected hypothesis changes (``changes``).
    """

    def __init__(
        self,
        setup: IdentificationSetup,
        hop_samples: int,
        window_hops: int,
        t0: float,
        alpha: float,
        confidence: float,
        emit: Any,
        say: Any,
        every_hop: bool = False,
    ) -> None:
        from ..detection.identification_online import OnlineIdentifier

        self.identifier = OnlineIdentifier(
            setup, hop_samples=hop_samples, window_hops=window_hops, t0=t0, alpha=alpha, confidence=confidence
        )
        self.emit, self.say, self.every_hop = emit, say, every_hop
        self.alarm_active: Any = None  # callable () -> bool, set once the monitor exists
        self.on_output: Any = None  # callable (OnlineIdentification) -> None: e.g. the recordings
        self.selected: str | None = None
        self.said: str | None = None  # the last selection said on the human line
        self.changes: list[dict[str, Any]] = []
        self.last: dict[str, Any] | None = None
        self.windows = 0

    def reset(self, t0: float) -> None:
        """A gap or restart: start over at ``t0``."""
        self.identifier.reset(t0)
        self.selected = None

    def push(self, z: Any, u: Any) -> None:
        """Identify on one chunk of measurements ``z`` and inputs ``u`` and hand the results on."""
        out = self.identifier.push(z, u)
        if self.on_output is not None:
            self.on_output(out)
        self.handle(out)

    def handle(self, out: Any) -> None:
        """Report the windows of one push."""
        from ..jsonout import dumps

        for i in range(out.n_windows):
            rep = out.report(i)
            self.windows += 1
            doc = {"sample_time_s": round(float(out.times_s[i]), 9), **rep.to_dict()}
            doc.pop("entries", None)
            doc.pop("method", None)
            changed = rep.selected != self.selected
            if self.emit is not None and (self.every_hop or changed):
                self.emit(dumps({"event": "identification", **doc}))
            line = summary_line(rep.to_dict()) if changed else None
            if changed:
                self.selected = rep.selected
                self.changes.append({"time_s": doc["sample_time_s"], "selected": rep.selected, "line": line})
            if rep.selected != self.said and self._worth_saying(rep.selected):
                # said when it changes, or later when the alarm that makes it worth saying starts
                self.said = rep.selected
                if line is None:
                    line = summary_line(rep.to_dict())
                self.say(
                    f"identified at t = {float(out.times_s[i]):.2f} s (window {rep.window_s[0]:.2f}-"
                    f"{rep.window_s[1]:.2f} s): {line}"
                )
            self.last = doc

    def _worth_saying(self, selected: str) -> bool:
        """Whether a change to ``selected`` gets a human line (see the class notes)."""
        from ..detection.identification import NO_FAULT

        if self.alarm_active is None:  # no alarm state known: every change
            return True
        if selected == NO_FAULT:
            return self.said not in (None, NO_FAULT)
        return bool(self.alarm_active())

    def to_dict(self) -> dict[str, Any]:
        """``windows`` identified, the ``changes`` of the selected hypothesis and the ``last`` window."""
        return {
            "window_s": self.identifier.window_s,
            "windows": self.windows,
            "changes": self.changes,
            "last": self.last,
        }


def print_diagnosis(doc: dict[str, Any]) -> None:
    """The ``diagnose`` block: per segment isolation rate, median estimate, relative error, coverage."""
    if "segments" not in doc:
        print(f"identification: not available: {doc.get('reason')}")
        return
    conf = f"{doc['confidence']:.0%}"
    print(
        f"identification per segment (tests at alpha = {doc['alpha']:g}; isolation and coverage with 99% "
        f"Clopper-Pearson intervals; {conf} parameter intervals):"
    )
    for seg in doc["segments"]:
        a, b = seg["segment_s"]
        iso = seg["isolation"]
        head = f"  [{a:g}, {b:g}) s: true {seg['true_hypothesis']}"
        if iso[0] is not None:
            head += f", selected in {iso[0]:.3f} [{iso[1]:.3f}, {iso[2]:.3f}] of {seg['runs']} runs"
        others = {k: v for k, v in seg["selection_rate"].items() if k != seg["true_hypothesis"]}
        if others:
            head += " (else " + ", ".join(f"{k} {v:.3f}" for k, v in others.items()) + ")"
        print(head)
        for p, t in seg["true_values"].items():
            cov = seg["coverage"].get(p, [None, None, None])
            med = seg["median_estimate"].get(p)
            rel = seg["median_relative_error"].get(p)

            def g(x: float | None) -> str:
                return "-" if x is None else f"{x:.4g}"

            print(
                f"    {p}: true {t:.6g}, median estimate {_num(med)}, median relative error {g(rel)}, "
                f"{conf} interval coverage {g(cov[0])} [{g(cov[1])}, {g(cov[2])}]"
            )
