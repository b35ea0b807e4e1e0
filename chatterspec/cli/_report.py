"""What the subcommands write: output paths checked before the computation, writes whose failures
are kept until the result is shown, the end of a command (JSON document or table, figure), and the
shared report blocks (the alarm rule in use, the fault identification).

Identification in the command line is shared by ``detect``, ``demo``, ``monitor`` and ``diagnose``. A
scenario's whole record is identified for every realization as the chunks stream past the detector
(pooled estimate and per-record selection rates with ``--runs R > 1``); when the STFT found fault
intervals, each interval of run 0 is identified on its own, one hop inside its edges.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, Protocol, TypeVar, overload

from ..errors import ParameterError

if TYPE_CHECKING:  # pragma: no cover
    import numpy as np

    from ..detection.alarms.calibration import MonitorSettings
    from ..detection.identification import IdentificationSetup, IdentificationStream
    from ..plants.scenarios import Scenario

R = TypeVar("R")
P = ParamSpec("P")


class StudyResult(Protocol):
    """A Monte Carlo study's result as :func:`report_study` takes it: its JSON document."""

    def to_dict(self) -> dict[str, Any]:
        """The result as a JSON-ready dict."""
        ...


def stderr_note(command: str) -> Any:
    """A function that prints one ``chatterspec COMMAND: note: TEXT`` line on stderr (library notes)."""

    def note(text: str) -> None:
        print(f"chatterspec {command}: note: {text}", file=sys.stderr, flush=True)

    return note


def quiet_stdout() -> None:
    """Send further output to stdout, and the flush at exit, to /dev/null (its reader went away)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # not a real file (e.g. captured in tests)
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, fd)
    os.close(devnull)


def print_json(doc: Any, *, allow_nan: bool = False) -> None:
    """Print ``doc`` as indented JSON on standard output (NaN refused unless ``allow_nan``: the JSON stays
    standard; the Monte Carlo studies write NaN where a rate has no trials)."""
    from ..jsonout import dumps

    sys.stdout.write(dumps(doc, indent=2, allow_nan=allow_nan) + "\n")


def check_record_path(path: str | os.PathLike | None) -> None:
    """``--record FILE.rrd``: a ``.rrd`` name whose file can be created (see :func:`check_output_path`)."""
    if path is not None and not str(path).endswith(".rrd"):
        raise ParameterError(f"--record expects a path ending in .rrd; got {str(path)!r}")
    check_output_path(path, "--record")


# --- output paths --------------------------------------------------------------------------------------
class OutputPathError(ParameterError):
    """An output path cannot be written (checked before the computation, or failed at the end)."""


def _nearest_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe_writable(folder: Path) -> str | None:
    """Create and remove one empty file in ``folder``; None when that works, else the reason."""
    import tempfile

    if not folder.is_dir():
        return f"{str(folder)!r} is not a folder"
    try:
        fd, name = tempfile.mkstemp(prefix=".chatterspec-probe-", dir=folder)
    except OSError as exc:
        return f"cannot create files in {str(folder)!r} ({exc.strerror or exc})"
    os.close(fd)
    try:
        os.unlink(name)
    except OSError:  # pragma: no cover - the probe file is empty; leaving it is harmless
        pass
    return None


@overload
def check_output_path(
    path: str | os.PathLike, option: str, *, folder: bool = False, suffixes: tuple[str, ...] | None = None
) -> Path: ...


@overload
def check_output_path(
    path: None, option: str, *, folder: bool = False, suffixes: tuple[str, ...] | None = None
) -> None: ...


@overload
def check_output_path(
    path: str | os.PathLike | None,
    option: str,
    *,
    folder: bool = False,
    suffixes: tuple[str, ...] | None = None,
) -> Path | None: ...


def check_output_path(
    path: str | os.PathLike | None,
    option: str,
    *,
    folder: bool = False,
    suffixes: tuple[str, ...] | None = None,
) -> Path | None:
    """Check, before any computation, that ``path`` can be written as a file (or used as a folder).

    Parameters
    ----------
    path : str or path-like or None
        The file the command will write, or with ``folder`` the folder it will write into (None:
        nothing to check).
    option : str
        The option that named it (e.g. ``"--plot"``), for the message.
    folder : bool
        ``path`` is a folder, existing or created at write time with any missing parents (default:
        a file, whose folder must exist: a mistyped folder is refused rather than created).
    suffixes : tuple of str, optional
        Accepted lower-case suffixes of a file (e.g. ``(".png",)``); None accepts any.

    Returns
    -------
    Path or None
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputPathError
        A file ``path`` is an existing folder, an existing read-only file, has a refused suffix or a
        folder that does not exist; a folder ``path`` is an existing file; or the folder written
        into (``path`` itself or its nearest existing parent for a folder, the file's folder for a
        file) is not writable.
    """
    if path is None:
        return None
    p = Path(path)
    if folder:
        if p.exists() and not p.is_dir():
            raise OutputPathError(f"{option} {str(p)!r} is an existing file; give a folder")
        base = _nearest_existing(p)
    else:
        if suffixes is not None and p.suffix.lower() not in suffixes:
            raise OutputPathError(f"{option} {str(p)!r}: the file name must end in {' or '.join(suffixes)}")
        if p.is_dir():
            raise OutputPathError(f"{option} {str(p)!r} is an existing folder; give a file name")
        if p.exists() and not os.access(p, os.W_OK):
            raise OutputPathError(f"{option} {str(p)!r}: the file exists and is not writable")
        base = p.parent if str(p.parent) else Path(".")
        if not base.exists():
            raise OutputPathError(
                f"{option} {str(p)!r} cannot be written: the folder {str(base)!r} does not exist (create it "
                "first)"
            )
    why = _probe_writable(base)
    if why is not None:
        raise OutputPathError(f"{option} {str(p)!r} cannot be written: {why}")
    return p


def figure_suffixes() -> tuple[str, ...]:
    """File suffixes matplotlib can write (``.png``, ``.pdf``, ``.svg``, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(f".{k}" for k in FigureCanvasBase.get_supported_filetypes()))


class Outputs:
    """Write the outputs of a finished computation; failures are kept, not raised, until :meth:`finish`.

    A command computes, writes through :meth:`write`, prints its result (table
    or JSON) and then calls :meth:`finish`, so a study whose output cannot be
    written (disk full, folder removed meanwhile) is still shown before the
    one-line error (exit 2).
    """

    def __init__(self) -> None:
        self.failures: list[str] = []

    def write(
        self,
        option: str,
        target: str | os.PathLike[str],
        fn: Callable[P, R],
        /,
        *args: P.args,
        **kwargs: P.kwargs,
    ) -> R | None:
        """Call ``fn(*args, **kwargs)``; on ``OSError`` (or Rerun's file-sink ``RuntimeError``) note it.

        Returns ``fn``'s result, or None when the write failed.
        """
        try:
            result = fn(*args, **kwargs)
        except (OSError, RuntimeError) as exc:
            from ..viewer.sinks import file_error  # Rerun reports a full disk as a RuntimeError

            err = file_error(exc, target) if isinstance(exc, RuntimeError) else exc
            if err is None:
                raise
            reason = getattr(err, "strerror", None) or str(err).splitlines()[0]
            self.failures.append(f"{option} {str(target)!r} could not be written ({reason})")
            return None
        late = getattr(result, "write_error", None)  # a recording that failed after the run finished
        if late:
            self.failures.append(f"{option} {str(target)!r} could not be completed ({late})")
        return result

    def finish(self) -> None:
        """Raise :class:`OutputPathError` naming every failed write (after the result was printed)."""
        if self.failures:
            done = " -- the result above was computed but not saved"
            raise OutputPathError("; ".join(self.failures) + done)


# --- the end of a command: figure, document or table, failed writes ------------------------------------
def check_figure_path(path: str | os.PathLike | None, option: str = "--plot") -> None:
    """Check, before any computation, that the figure file ``path`` can be written (a matplotlib suffix)."""
    if path:
        check_output_path(path, option, suffixes=figure_suffixes())


def write_plot(
    outputs: Outputs, args: argparse.Namespace, doc: dict[str, Any], figure: str, *figure_args: object
) -> None:  # (figure_args: whatever the named drawing function takes)
    """With ``--plot FILE``: save the figure there, noted as ``doc["figure"]`` (None: not saved).

    ``figure`` names the drawing function in :mod:`chatterspec.figures` as ``"module.function"``
    (e.g. ``"plot_studies.far_figure"``), called with ``figure_args``; it is imported only here, so
    a command without ``--plot`` never loads matplotlib.
    """
    if not args.plot:
        return
    import importlib

    from ..figures.plot_studies import save

    module, name = figure.rsplit(".", 1)
    draw = getattr(importlib.import_module(f"..figures.{module}", __package__), name)
    saved = outputs.write("--plot", args.plot, save, draw(*figure_args), args.plot)
    doc["figure"] = None if saved is None else str(saved)


def report(
    args: argparse.Namespace,
    doc: dict[str, Any],
    outputs: Outputs,
    print_text: Callable[[], None],
    *,
    allow_nan: bool = False,
) -> int:
    """Print the result and end the command: ``doc`` as JSON with ``--json`` (NaN written only with
    ``allow_nan``), else ``print_text()``; then :meth:`Outputs.finish`. Returns 0."""
    if args.json:
        print_json(doc, allow_nan=allow_nan)
    else:
        print_text()
    outputs.finish()
    return 0


def report_study(
    args: argparse.Namespace, res: StudyResult, figure: str, print_text: Callable[[dict[str, Any]], None]
) -> int:
    """The end of a Monte Carlo study command (``far``, ``power``, ``power --closed-loop``): the result
    ``res``'s document, its ``--plot`` figure (:func:`write_plot`, ``figure`` called with ``res``),
    then :func:`report` with ``print_text(doc)`` and the figure's path as the text (NaN kept in the JSON:
    a rate without trials)."""
    outputs = Outputs()
    doc = res.to_dict()
    write_plot(outputs, args, doc, figure, res)

    def text() -> None:
        print_text(doc)
        if doc.get("figure"):
            print(f"figure: {doc['figure']}")

    return report(args, doc, outputs, text, allow_nan=True)


# --- the alarm rule in use ----------------------------------------------------------------------------------
def alarm_doc(settings: MonitorSettings) -> dict:
    """The ``alarm`` entry of the JSON summary: rule, threshold, budget and how it was set."""
    import math

    b = getattr(settings, "budget", None)
    rule = getattr(settings, "rule", None)
    if rule is None:
        a = float(settings.alpha)
        return {
            "rule": {"rule": "frame", "threshold": -math.log(a)},
            "alpha": a,
            "false_alarms_per_hour": None,
            "calibration": None,
        }
    return {
        "rule": rule.to_dict(),
        "alpha": None,
        "false_alarms_per_hour": None if b is None else b.false_alarms_per_hour,
        "calibration": None if b is None else b.to_dict(),
    }


def alarm_short(settings: MonitorSettings) -> str:
    """The rule in use in a few words (its alarm label, or the frame rule's per-frame alpha)."""
    from ..detection.alarms.rules import alarm_label

    rule = getattr(settings, "rule", None)
    if rule is None:
        return f"frame rule, per-frame alpha {settings.alpha:g}"
    return alarm_label(rule.name, settings.false_alarms_per_hour)


def alarm_line(settings: MonitorSettings) -> str:
    """One stderr line on the rule in use and where its threshold comes from."""
    rule = getattr(settings, "rule", None)
    if rule is None:
        return f"alarms: {alarm_short(settings)} (every frame a test)"
    b = settings.budget
    return f"alarms: {b.describe()}" if b is not None else f"alarms: {rule.describe()}"


# --- fault identification: JSON documents and text blocks ---------------------------------------------------
def identification_stream(setup: IdentificationSetup, args: argparse.Namespace) -> IdentificationStream:
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


def tolerance_doc(ident: IdentificationStream, runs: int, args: argparse.Namespace) -> dict[str, Any] | None:
    """Whole-record decisions on the identified parameters when the model declares tolerances (None
    otherwise): per parameter run 0's estimate against its band and the fraction of records outside
    (99 % Clopper-Pearson interval); the fault verdict of run 0 and the detection rate."""
    import numpy as np
    import scipy.special

    from ..detection.parameter_decision import ParameterBands, band_position, record_decisions
    from ..studies.intervals import clopper_pearson

    res = ident.result()
    pm = res.setup.parameter_map
    if not pm.has_tolerances:
        return None
    dec = record_decisions(res, args.alpha)
    bands = ParameterBands.from_map(pm)
    zq = float(scipy.special.ndtri(0.5 + args.confidence / 2))
    rows = []
    for i, p in enumerate(bands.names):
        th, se = float(dec["estimate"][0, i]), float(dec["std_error"][0, i])
        k = int(dec["outside"][:, i].sum())
        rows.append(
            {
                "parameter": p,
                "unit": bands.units[i],
                "nominal": float(bands.nominal[i]),
                "tolerance": bands.tolerances[i] or None,
                "band": [float(bands.low[i]), float(bands.high[i])],
                "estimate": th,
                "std_error": se,
                "ci_low": th - zq * se,
                "ci_high": th + zq * se,
                "p_value": float(dec["p_value"][0, i]),
                "position": band_position(th - zq * se, th + zq * se, bands.low[i], bands.high[i]),
                "outside": bool(dec["outside"][0, i]),
                "outside_records": k,
                "outside_interval": list(clopper_pearson(k, runs)),
            }
        )
    det = np.any(dec["outside"], axis=1)
    return {
        "decision": "parameters (tolerances)",
        "test": "joint estimate of the whole record against each band, at alpha / parameters",
        "alpha": args.alpha,
        "confidence": args.confidence,
        "parameters": rows,
        "fault": bool(det[0]),
        "detected_records": int(det.sum()),
        "runs": runs,
        "detection_interval": list(clopper_pearson(int(det.sum()), runs)),
    }


def print_tolerance(doc: dict[str, Any]) -> None:
    """The ``detect`` block of the decision on the identified parameters (tolerances)."""
    t = doc.get("tolerance")
    if not t:
        return
    from ..detection.parameter_decision import status_text

    n = len(t["parameters"])
    print(
        f"decision on the identified parameters (tolerances; the spectral verdicts above report the model "
        f"mismatch): each whole-record joint estimate against its band at alpha/{n} = {t['alpha'] / n:.3g}"
    )
    for r in t["parameters"]:
        ci = (r["ci_low"], r["ci_high"])
        text = status_text(
            r["parameter"], r["estimate"], r["std_error"], ci, r["nominal"], r["unit"], r["tolerance"] or "",
            r["position"],
        )  # fmt: skip
        lo, hi = r["outside_interval"]
        print(f"  {text}; outside in {r['outside_records']} of {t['runs']} records [{lo:.3f}, {hi:.3f}]")
    lo, hi = t["detection_interval"]
    print(
        f"fault (run 0): {'YES' if t['fault'] else 'no'}; detected in {t['detected_records']} of {t['runs']} "
        f"records [{lo:.3f}, {hi:.3f}] (99 % Clopper-Pearson)"
    )


def interval_docs(
    setup: IdentificationSetup,
    z: np.ndarray,
    u: np.ndarray,
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
    from ..detection.identification import format_with_error

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
