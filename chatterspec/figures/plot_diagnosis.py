"""Figures and tables of fault diagnosis: the comparison of the diagnosis routes, the multiple-model
filters' modes, and the identification of the changed parameter.

The diagnosis comparison table (``chatterspec diagnose``) as text rows (:func:`diagnosis_rows`,
:func:`budget_rows`) and as figures (:func:`diagnosis_table_figure`, :func:`delay_far_figure`). One row
per (method, fault onset): false alarms on the healthy segments (runs with any alarm, 99 %
Clopper-Pearson interval), the onset (s), the detection delay (median / 90th percentile over runs, ms),
isolation (modes: the true mode's mean probability in the new segment and the argmax isolation delay;
chattering: the channel flagged most in the new segment, its median peak frequency and the fraction of
frames flagged), runs that miss the onset, and the cost (realization-steps per second).

The multiple-model filters: mode weights over time (:func:`mode_weights_figure`, [SMM] Fig 5) and
confusion heatmaps (:func:`confusion_figure`, [IMM] Tables 5-7 as images).

Fault identification over a sweep of fault sizes (:func:`identification_sweep_figure`) and the
decisions on the identified parameters:

* :func:`tolerance_band_figure`: a parameter's joint estimate with its interval against its tolerance
  band over time, the true value, and the alarm;
* :func:`excitation_figure`: the detectable leakage change over a hold-move-hold cycle, with and
  without dither, against the not-excited limit.

matplotlib, Agg backend (:mod:`chatterspec.figures.style`), imported on demand only, and only inside the
figures: the text rows load no matplotlib.
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ..errors import ShapeError
from ..palette import (
    FAULT,
    NEUTRAL,
    NO_EVIDENCE,
    TAB10,
    TRUTH,
    channel_color,
    fault_level_color,
    filter_color,
    mode_color,
    mpl,
)

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..studies.budget_diagnosis import OnsetFigures, RouteBudget
    from ..studies.diagnosis import ChatteringDiagnosis, ModeDiagnosis
    from ..studies.identification_study import IdentificationValidation

__all__ = [
    "BUDGET_HEADER",
    "DIAGNOSIS_HEADER",
    "DIAGNOSIS_NOTES",
    "budget_rows",
    "confusion_figure",
    "delay_far_figure",
    "diagnosis_rows",
    "diagnosis_table_figure",
    "excitation_figure",
    "identification_sweep_figure",
    "mode_weights_figure",
    "tolerance_band_figure",
]


#: Column titles of :func:`diagnosis_rows`.
DIAGNOSIS_HEADER: tuple[str, ...] = (
    "method",
    "false alarms (runs) [99% CI]",
    "onset [s]",
    "detect med/p90 [ms]",
    "isolation",
    "missed",
    "steps/s",
)


def _ms(v: float) -> str:
    if not np.isfinite(v):
        return "-"
    return f"{1e3 * v:.0f}" if abs(v) >= 0.0995 else f"{1e3 * v:.1f}"


def _isolation(result: ModeDiagnosis | ChatteringDiagnosis, i: int) -> str:
    if result.method == "chattering":
        r = cast("ChatteringDiagnosis", result)
        onset = r.onsets[i]
        s = next(
            (j for j, span in enumerate(r.segment_span_s) if abs(span[0] - onset) < 1e-9),
            None,
        )
        if s is None or r.flagged_channel[s] is None:
            return "nothing flagged"
        c = r.channels.index(r.flagged_channel[s])
        frac = r.flag_fraction[s, c]
        return f"{r.flagged_channel[s]} @ {r.peak_hz[s]:.1f} Hz ({100 * frac:.0f}% frames)"
    m = cast("ModeDiagnosis", result)
    k = m.new_modes[i]
    mode = m.modes[k]
    return (
        f"{mode} {m.confusion[k, k]:.1f}%, argmax after "
        f"{_ms(m.isolation_median[i])}/{_ms(m.isolation_p90[i])} ms"
    )


def _delay_cell(median_s: float, p90_s: float, onset_index: int) -> str:
    """``"med/p90"`` in ms; a later onset whose delays are all 0 met runs already in alarm from the fault
    before it (not an instant detection): ``"already in alarm"``."""
    if onset_index > 0 and median_s == 0.0 and p90_s == 0.0:
        return "already in alarm"
    return f"{_ms(median_s)}/{_ms(p90_s)}"


def diagnosis_rows(
    results: Sequence[ModeDiagnosis | ChatteringDiagnosis],
) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """The comparison table as strings.

    Parameters
    ----------
    results : sequence of ModeDiagnosis or ChatteringDiagnosis
        Results of :func:`~chatterspec.studies.diagnosis.diagnose_modes` and
        :func:`~chatterspec.studies.diagnosis.diagnose_chattering` on the same simulation.

    Returns
    -------
    (header, rows)
        :data:`DIAGNOSIS_HEADER` and one row per (method, onset); the false-alarm and cost cells are
        filled on a method's first row only.
    """
    rows: list[tuple[str, ...]] = []
    for r in results:
        lo, hi = r.false_alarm_ci
        fa = f"{r.false_alarm_runs}/{r.runs} [{lo:.3f}, {hi:.3f}]"
        if not np.isfinite(r.healthy_alarm_fraction):
            fa = "n/a (no healthy part)"  # faulty from the start: no false alarm can be counted
        for i, onset in enumerate(r.onsets):
            rows.append(
                (
                    r.method if i == 0 else "",
                    fa if i == 0 else "",
                    f"{onset:.2f}",
                    _delay_cell(r.detection_median[i], r.detection_p90[i], i),
                    _isolation(r, i),
                    str(r.missed[i]),
                    f"{r.steps_per_second:.3g}" if i == 0 else "",
                )
            )
    return DIAGNOSIS_HEADER, rows


#: Footnotes of :func:`diagnosis_table_figure`: what the columns count.
DIAGNOSIS_NOTES = (
    "false alarms (runs): runs whose healthy part raised an alarm under the route's own per-record rule, "
    "of all runs, with its 99 % Clopper-Pearson interval (n/runs = every run; the routes are not at one "
    "budget: `chatterspec diagnose` without --per-record compares them at one)",
    "detect med/p90: delay from the onset to the first alarm, median / 90th percentile over the runs [ms]; "
    "'already in alarm': every run was still in alarm from the fault before at this onset (a delay of 0, "
    "not an instant detection); isolation: the true mode's share of the argmax after the onset and its "
    "delay [ms]; '-' = none",
    "steps/s: filter steps per second of wall time (one realization, one core)",
)


def diagnosis_table_figure(
    results: Sequence[ModeDiagnosis | ChatteringDiagnosis],
    title: str = "",
    notes: Sequence[str] = DIAGNOSIS_NOTES,
) -> Figure:
    """The comparison table drawn as a compact matplotlib table, with footnotes.

    The figure is sized to the table (no blank margins); numbers keep the formats of
    :func:`diagnosis_rows` (milliseconds without decimals from 100 ms on, probabilities with 3 decimals).

    Parameters
    ----------
    results : sequence of ModeDiagnosis or ChatteringDiagnosis
        As for :func:`diagnosis_rows`.
    title : str
        Figure title (e.g. scenario, methods, runs and seed).
    notes : sequence of str
        Footnotes under the table (default :data:`DIAGNOSIS_NOTES`).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import textwrap

    from .style import plt

    header, rows = diagnosis_rows(results)
    header = tuple(textwrap.fill(h, 16) for h in header)
    n = len(rows) + 1
    wrapped = [textwrap.fill(f"{k + 1}. {t}" if len(notes) > 1 else t, 150) for k, t in enumerate(notes)]
    note_lines = sum(w.count("\n") + 1 for w in wrapped)
    height = 0.3 * n + 0.45 + 0.17 * note_lines + (0.35 if title else 0.0)
    fig = plt.figure(figsize=(10.5, height))
    top = 1.0 - (0.35 / height if title else 0.05 / height)
    bottom = (0.17 * note_lines + 0.15) / height
    ax = fig.add_axes((0.01, bottom, 0.98, top - bottom))
    ax.axis("off")
    table = ax.table(
        cellText=rows or [[""] * len(header)], colLabels=header, loc="upper center", cellLoc="left"
    )
    table.auto_set_font_size(False)
    table.set_fontsize(8.5)
    table.auto_set_column_width(list(range(len(header))))
    for (row, _col), cell in table.get_celld().items():
        cell.set_height(1.0 / n)
        if row == 0:
            cell.set_text_props(weight="bold")
            cell.set_facecolor("#e8e8e8")
    if title:
        fig.suptitle(title, fontsize=10, y=1.0 - 0.08 / height, va="top")
    fig.text(0.01, 0.02 / height, "\n".join(wrapped), fontsize=7, va="bottom", ha="left")
    return fig


# --------------------------------------------------------------------------- at one false-alarm budget
#: Column titles of :func:`budget_rows`.
BUDGET_HEADER: tuple[str, ...] = (
    "method",
    "threshold",
    "false alarms/h [99% CI] (count/hours)",
    "onset [s]",
    "delay med/p90 [ms]",
    "missed",
    "in alarm",
    "isolation at detection",
    "steps/s",
)

#: Line colour of each route in the budget figure.
METHOD_COLORS = {m: mpl(filter_color(m)) for m in ("chattering", "smm", "imm", "innovation")}  # palette


def _rate(v: float) -> str:
    if not np.isfinite(v):
        return "-"
    return f"{v:.3g}"


def _budget_isolation(o: OnsetFigures) -> str:
    iso = o.isolated
    parts = ", ".join(f"{k} {v}" for k, v in sorted(iso.items(), key=lambda kv: -kv[1])) or "-"
    if o.true_label is None:
        return parts
    return f"{parts}; {o.true_label} after {_ms(o.isolation_median_s)}/{_ms(o.isolation_p90_s)} ms"


def budget_rows(results: Sequence[RouteBudget]) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """The comparison at one false-alarm budget as strings (one row per route and onset).

    Parameters
    ----------
    results : sequence of RouteBudget
        :func:`~chatterspec.studies.budget_diagnosis.diagnose_at_budget`.

    Returns
    -------
    (header, rows)
        :data:`BUDGET_HEADER` and the rows; the threshold, false-alarm and cost cells are filled on a
        route's first row only.
    """
    rows: list[tuple[str, ...]] = []
    for r in results:
        lo, hi = r.rate_ci
        if r.healthy_hours > 0:
            fa = (
                f"{_rate(r.rate_per_hour)} [{_rate(lo)}, {_rate(hi)}] "
                f"({r.false_alarms}/{r.healthy_hours:.3g})"
            )
            fa += "" if r.budget_inside else " <- budget outside"
        else:
            fa = "n/a (no healthy part; --onset S gives one)"
        h = r.rule.get("threshold")
        for i, o in enumerate(r.onsets):
            rows.append(
                (
                    r.method if i == 0 else "",
                    ("never (not calibrated)" if h is None else f"{h:.4g}") if i == 0 else "",
                    fa if i == 0 else "",
                    f"{o.onset_s:.2f}",
                    f"{_ms(o.delay_median_s)}/{_ms(o.delay_p90_s)}",
                    str(o.missed),
                    str(o.in_alarm_at_onset),
                    _budget_isolation(o),
                    f"{r.steps_per_second:.3g}" if i == 0 else "",
                )
            )
    return BUDGET_HEADER, rows


def delay_far_figure(results: Sequence[RouteBudget], title: str = "") -> Figure:
    """Detection delay against false alarms per hour, thresholds swept on the same realizations.

    One panel per fault onset; per route, the median delay (line) and its 90th percentile (shaded)
    over the diagnosed runs that detect, at each threshold of the route's grid, against the alarm starts
    per hour of the healthy calibration streams at that threshold (thresholds without a start there are
    not drawn: their rate is below what the streams resolve, marked by the dotted line of one start
    in the calibration hours). The star is the threshold calibrated to the budget (vertical line).
    Delays are over the runs not in alarm before the onset; an onset whose delay no route defines at
    the budget (every run meets it in alarm: a second fault) has no panel.

    Parameters
    ----------
    results : sequence of RouteBudget
    title : str

    Returns
    -------
    matplotlib.figure.Figure
    """
    from .style import plt

    results = list(results)
    n_on = max((len(r.onsets) for r in results), default=0)
    # an onset that the runs meet already in alarm at the budget (a second fault) has no delay to draw
    panels = [
        i
        for i in range(n_on)
        if any(i < len(r.onsets) and np.isfinite(r.onsets[i].delay_median_s) for r in results)
    ] or [0]
    fig, axes = plt.subplots(1, len(panels), figsize=(5.6 * len(panels), 4.4), squeeze=False, sharey=True)
    budget = results[0].budget_per_hour if results else 1.0
    for col, i in enumerate(panels):
        ax = axes[0, col]
        for r in results:
            if i >= len(r.onsets):
                continue
            c = r.curve
            color = METHOD_COLORS.get(r.method, None)
            far = np.asarray(c["far_per_hour"][:-1], dtype=float)
            med = np.asarray(c["delay_median_s"][i][:-1], dtype=float)
            p90 = np.asarray(c["delay_p90_s"][i][:-1], dtype=float)
            ok = (far > 0) & np.isfinite(med)
            order = np.argsort(far[ok])
            x, y, y90 = far[ok][order], np.maximum(med[ok][order], 1e-4), np.maximum(p90[ok][order], 1e-4)
            ax.plot(x, y, "-o", ms=3, color=color, label=r.method)
            ax.fill_between(x, y, y90, color=color, alpha=0.15, lw=0)
            o = r.onsets[i]
            if np.isfinite(o.delay_median_s):
                ax.plot([budget], [max(o.delay_median_s, 1e-4)], "*", ms=13, color=color, mec="k", mew=0.6)
            hours = c.get("calibration_hours", 0.0)
            if hours:
                ax.axvline(1.0 / hours, color=color, ls=":", lw=0.8)
        ax.axvline(budget, color="k", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        onset = next((r.onsets[i].onset_s for r in results if i < len(r.onsets)), float("nan"))
        ax.set_title(f"onset at {onset:g} s", fontsize=10)
        ax.set_xlabel("false alarms per hour (healthy calibration streams)")
        if col == 0:
            ax.set_ylabel("detection delay [s] (median; shaded to p90)")
        ax.grid(True, which="both", alpha=0.3)
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles, _ = axes[0, 0].get_legend_handles_labels()
    handles += [  # the marks every route shares, in black: their colour is the route's
        Patch(fc="k", alpha=0.15, label="median to 90th percentile"),
        Line2D([], [], ls="none", marker="*", ms=11, color="w", mec="k", label="threshold at the budget"),
        Line2D([], [], color="k", lw=0.8, ls="--", label=f"budget {budget:g} false alarm(s)/h"),
        Line2D([], [], color="k", lw=0.8, ls=":", label="one start in the calibration hours"),
    ]
    fig.legend(handles=handles, loc="lower center", ncol=4, fontsize=8, frameon=False)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0.03 + 0.05 * ((len(handles) + 3) // 4), 1, 1))
    return fig


# ---------------------------------------------------------------- the multiple-model filters' modes


def mode_weights_figure(
    t: np.ndarray,
    mu: np.ndarray,
    modes: Sequence[str],
    true_mode: np.ndarray | None = None,
    run: int | None = None,
    title: str = "",
) -> Figure:
    """Mode weights / probabilities over time (the SMM paper's Fig 5), in the shared palette's mode colours
    (the recordings' colours; no red), legend below the axes (out of the data).

    Parameters
    ----------
    t : (T,) array
        Sample times in seconds.
    mu : (runs, T, r) array
        Mode probabilities (``MultipleModelOutput.mu``).
    modes : sequence of str
        Mode names (r).
    true_mode : (T,) int array, optional
        Actual mode per sample, drawn as a shaded background per segment.
    run : int, optional
        Plot this realization; default: the mean over runs.
    title : str
        Axes title (scenario, method and runs).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from .style import plt

    mu = np.asarray(mu, dtype=float)
    if mu.ndim != 3 or mu.shape[1] != len(t) or mu.shape[2] != len(modes):
        raise ShapeError(f"mu must have shape (runs, {len(t)}, {len(modes)}); got {mu.shape}")
    curve = mu.mean(axis=0) if run is None else mu[run]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    colors = [mpl(mode_color(j)) for j in range(len(modes))]
    if true_mode is not None:
        tm = np.asarray(true_mode)
        edges = np.flatnonzero(np.diff(tm)) + 1
        starts = np.r_[0, edges]
        ends = np.r_[edges, len(tm)]
        for a, b in zip(starts, ends, strict=True):
            if tm[a] >= 0:
                ax.axvspan(t[a], t[b - 1], color=colors[tm[a] % len(colors)], alpha=0.08, lw=0)
    for j, name in enumerate(modes):
        ax.plot(t, curve[:, j], color=colors[j % len(colors)], lw=1.2, label=name)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("time [s]" + ("; shaded: true mode" if true_mode is not None else ""))
    ax.set_ylabel("mode weight" + (" (mean over runs)" if run is None else f" (run {run})"))
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=len(modes), fontsize=8, frameon=False)
    ax.grid(alpha=0.3)
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig


def confusion_figure(confusion: np.ndarray, modes: Sequence[str], title: str = "") -> Figure:
    """Confusion matrix heatmap (percent; rows predicted, columns actual; columns sum to 100).

    Parameters
    ----------
    confusion : (r, r) array
        From :func:`chatterspec.studies.estimation.confusion_matrix`.
    modes : sequence of str
        Mode names (r).
    title : str
        Axes title (e.g. the bank type).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from .style import plt

    c = np.asarray(confusion, dtype=float)
    r = len(modes)
    if c.shape != (r, r):
        raise ShapeError(f"confusion must be ({r}, {r}); got {c.shape}")
    fig, ax = plt.subplots(figsize=(1.4 * r + 1.5, 1.2 * r + 1.0))
    im = ax.imshow(c, vmin=0, vmax=100, cmap="Blues")
    for i in range(r):
        for a in range(r):
            v = c[i, a]
            ax.text(
                a,
                i,
                "-" if np.isnan(v) else f"{v:.1f}",
                ha="center",
                va="center",
                color="white" if v > 60 else "black",
                fontsize=9,
            )
    ax.set_xticks(range(r), modes, rotation=20, fontsize=8)
    ax.set_yticks(range(r), modes, fontsize=8)
    ax.set_xlabel("actual mode")
    ax.set_ylabel("predicted (mean probability, %)")
    if title:
        ax.set_title(title, fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.046)
    fig.tight_layout()
    return fig


# ------------------------------------------------------- identification over a sweep of fault sizes

#: Names and units of the catalogue parameters: (axis label, unit).
LABELS = {
    "leakage": ("leakage L", "m³/(s·Pa)"),
    "friction": ("friction a", "N·s/m"),
    "bulk_modulus": ("bulk modulus βe", "Pa"),
    "natural_frequency": ("natural frequency f0", "Hz"),
}
#: Colour of the interval half-width lines (neutral: red is kept for fault verdicts).
CI_COLOR = mpl(NEUTRAL)


def identification_sweep_figure(
    sweeps: Mapping[str, Sequence[IdentificationValidation]], title: str | None = None
) -> Figure:
    """Estimate vs true parameter over fault sizes, one column per family.

    Top row: the median estimate of single records against the true value, with the 5-95 %
    range of the estimates and the identity line. Bottom row: the relative error in % (median,
    5-95 % range) and the mean half-width of the records' intervals; each size is annotated
    with the fraction of records selecting the true hypothesis ("no fault" at the healthy size).

    Parameters
    ----------
    sweeps : mapping of family name -> list of IdentificationValidation
        From :func:`chatterspec.studies.identification_study.identification_sweep`.
    title : str, optional
        Figure title.
    """
    from .style import plt

    n = len(sweeps)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 6.4), squeeze=False, height_ratios=[1.2, 1])
    for j, (family, rows) in enumerate(sweeps.items()):
        top, bot = axes[0, j], axes[1, j]
        true = np.array([r.true_value for r in rows])
        med = np.array([np.nanmedian(r.estimates) for r in rows])
        q05 = np.array([np.nanquantile(r.estimates, 0.05) for r in rows])
        q95 = np.array([np.nanquantile(r.estimates, 0.95) for r in rows])
        half = np.array([np.nanmean(r.ci_high - r.ci_low) / 2 for r in rows])
        name, unit = LABELS.get(rows[0].parameter or "", ("parameter", ""))
        unit = f" [{unit}]" if unit else ""
        color = mpl(channel_color(0))
        top.plot(true, true, color="0.6", lw=1, label="estimate = true")
        bars = [med - q05, q95 - med]
        top.errorbar(true, med, yerr=bars, fmt="o", ms=4, capsize=3, color=color, label="median, 5-95 %")
        top.set_title(f"{family} ({rows[0].runs} records of 4 s per size)", fontsize=9, pad=14)
        top.set_ylabel(f"estimated {name}{unit}")
        top.set_xlabel(f"true {name}{unit}")
        rel = 100 * (med - true) / true
        rlo, rhi = 100 * (q05 - true) / true, 100 * (q95 - true) / true
        bot.axhline(0, color="0.6", lw=1)
        bot.fill_between(true, rlo, rhi, alpha=0.25, color=color, label="5-95 % of records")
        bot.plot(true, rel, "o-", ms=4, color=color, label="median")
        bot.plot(
            true,
            100 * half / true,
            "--",
            color=CI_COLOR,
            lw=1,
            label=f"mean {rows[0].confidence:.0%} CI half-width",
        )
        bot.plot(true, -100 * half / true, "--", color=CI_COLOR, lw=1)
        iso = [r.isolation()[0] for r in rows]
        # one line at the top instead of a label per size (close sizes' labels ran into each other)
        below = [f"{v:.1%} at {x:.4g}" for x, v in zip(true, iso, strict=True) if v < 0.9995]
        note = "100 % select the true hypothesis at every size"
        if below:
            note = (
                "true hypothesis: "
                + "; ".join(below)
                + ("; 100 % elsewhere" if len(below) < len(iso) else "")
            )
        bot.text(
            0.5, 0.97, textwrap.fill(note, 46), transform=bot.transAxes, ha="center", va="top", fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.85, "lw": 0, "pad": 1.5},
        )  # fmt: skip
        bot.set_xlabel(f"true {name}{unit}")
        bot.set_ylabel("relative error [%]")
        if j == 0:  # legends below the panels, out of the data and the band
            handles = top.get_legend_handles_labels()[0] + bot.get_legend_handles_labels()[0]
            fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=7, frameon=False)
    fig.suptitle(
        title
        or "fault identification from the chattering: estimate vs true parameter (percentages: records "
        "selecting the true hypothesis, 'no fault' at the nominal size)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig


# ----------------------------------------------------------- decisions on the identified parameters


def _spans(ax: Any, t: np.ndarray, mask: np.ndarray, color: tuple, label: str, half: float) -> None:
    """Shade the runs of ``mask`` (one window per time ``t``, ``half`` a hop either side)."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(int), [0]])))
    for k, (a, b) in enumerate(zip(edges[::2], edges[1::2], strict=True)):
        ax.axvspan(
            t[a] - half, t[b - 1] + half, color=color, alpha=0.18, lw=0, label=label if k == 0 else None
        )


def tolerance_band_figure(
    record: Any, truth: Mapping[str, np.ndarray], parameters: tuple[str, ...], title: str | None = None
) -> Figure:
    """Per parameter, one panel over time: the joint estimate and its interval (one window per hop),
    the tolerance band and nominal value, the true value, the windows that give no evidence (they
    straddle a change) and the alarm.

    Parameters
    ----------
    record : ParameterDecisions
        One record's decisions (run 0 is drawn).
    truth : mapping
        ``times_s`` and the true value of each parameter from each time on (a staircase).
    parameters : tuple of str
        The parameters to draw (names of the record's bands).
    title : str, optional
    """
    from .style import plt

    b = record.settings.bands
    t = record.times_s
    hop = record.settings.hop_s
    fig, axes = plt.subplots(
        len(parameters), 1, figsize=(9.0, 2.9 * len(parameters)), sharex=True, squeeze=False
    )
    for ax, p in zip(axes[:, 0], parameters, strict=True):
        i = b.names.index(p)
        scale = abs(b.nominal[i])
        est = record.estimate[0, :, i] / scale
        lo, hi = record.ci_low[0, :, i] / scale, record.ci_high[0, :, i] / scale
        fits = record.fits[0]
        ax.fill_between(t, lo, hi, color=mpl(TAB10["orange"]), alpha=0.35, lw=0, label="95 % interval")
        ax.plot(t, np.where(fits, est, np.nan), color=mpl(TAB10["orange"]), lw=1.4, label="joint estimate")
        ax.plot(
            t[~fits], est[~fits], "x", color=mpl(NEUTRAL), ms=4, label="window across a change (no evidence)"
        )
        ax.step(
            truth["times_s"],
            np.asarray(truth[p]) / scale,
            where="post",
            color="k",
            lw=1.0,
            label="true value",
        )
        ax.axhspan(b.low[i] / scale, b.high[i] / scale, color=mpl(TAB10["blue"]), alpha=0.08, lw=0)
        for edge in (b.low[i], b.high[i]):
            ax.axhline(edge / scale, color=mpl(TAB10["blue"]), ls="--", lw=1.0)
        ax.axhline(1.0, color=mpl(NEUTRAL), lw=0.8, ls=":")
        _spans(ax, t, record.alarm[0, :, i], mpl(FAULT), "alarm (outside its tolerance)", hop / 2)
        unit = f" ({b.units[i]})" if b.units[i] else ""
        ax.set_ylabel(f"{p} / nominal\n{b.tolerances[i]}{unit}")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize=8, ncol=2)
    axes[-1, 0].set_xlabel("time (s): window centre")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return fig


def excitation_figure(
    records: Mapping[str, Any],
    parameter: str,
    reference: Mapping[str, float],
    moves: tuple[float, float],
    title: str | None = None,
) -> Figure:
    """The detectable change of ``parameter`` over time (median over the records, 10-90 % band), one line
    per record set (e.g. without and with dither), against the not-excited limit (the tolerance) and
    reference sizes; the windows where the median record is not excited are shaded per set.

    Parameters
    ----------
    records : mapping of str -> ParameterDecisions
        Label -> decisions (same times).
    parameter : str
    reference : mapping of str -> float
        Label -> a change size drawn as a horizontal line (e.g. the minor leak's).
    moves : (float, float)
        Start and end (s) of the moving part, shaded.
    title : str, optional
    """
    from .style import plt

    fig, ax = plt.subplots(figsize=(9.0, 4.2))
    colors = [mpl(TAB10["blue"]), mpl(TAB10["orange"]), mpl(TAB10["green"]), mpl(TAB10["purple"])]
    ax.axvspan(*moves, color=mpl(TRUTH), alpha=0.5, lw=0, label="moving")
    first = next(iter(records.values()))
    b = first.settings.bands
    i = b.names.index(parameter)
    for k, ((label, rec), c) in enumerate(zip(records.items(), colors, strict=False)):
        det = rec.detectable[:, :, i]
        med = np.median(det, axis=0)
        ax.fill_between(
            rec.times_s,
            np.quantile(det, 0.1, axis=0),
            np.quantile(det, 0.9, axis=0),
            color=c,
            alpha=0.2,
            lw=0,
        )
        ax.semilogy(rec.times_s, med, color=c, lw=1.6, label=f"{label}: detectable change")
        blind = med > b.limit[i]
        ax.plot(rec.times_s[blind], np.full(blind.sum(), b.limit[i] * 0.5 * 0.7**k), "s", color=c, ms=3)
    ax.axhline(
        b.limit[i],
        color=mpl(NO_EVIDENCE),
        ls="--",
        lw=1.2,
        label=f"tolerance {b.tolerances[i]}: not excited above",
    )
    for k, (label, size) in enumerate(reference.items()):
        ax.axhline(size, color=mpl(fault_level_color(k)), ls=":" if k else "-.", lw=1.2, label=label)
    unit = f" ({b.units[i]})" if b.units[i] else ""
    horizon = first.settings.horizon_hops * first.settings.hop_s
    ax.set_ylabel(f"smallest detectable {parameter} change{unit}")
    ax.set_xlabel(f"time (s): window centre; detectable over the last {horizon:g} s (squares: not excited)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8, loc="upper right")
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig
