"""The diagnosis comparison table (``chatterspec diagnose``) as text rows and as a figure.

One row per (method, fault onset): false alarms on the healthy segments (runs with any alarm, 99 %
Clopper-Pearson interval), the onset (s), the detection delay (median / 90th percentile over runs, ms),
isolation (modes: the true mode's mean probability in the new segment and the argmax isolation delay;
chattering: the channel flagged most in the new segment, its median peak frequency and the fraction of
frames flagged), runs that miss the onset, and the cost (realization-steps per second). matplotlib, Agg
backend; imported on demand only.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

import numpy as np

from ..palette import filter_color, mpl

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..studies.budget_diagnosis import OnsetFigures, RouteBudget
    from ..studies.diagnosis import ChatteringDiagnosis, ModeDiagnosis

__all__ = [
    "BUDGET_HEADER",
    "DIAGNOSIS_HEADER",
    "DIAGNOSIS_NOTES",
    "budget_rows",
    "delay_far_figure",
    "diagnosis_rows",
    "diagnosis_table_figure",
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

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
