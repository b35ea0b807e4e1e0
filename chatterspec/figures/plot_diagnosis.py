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
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = ["DIAGNOSIS_HEADER", "diagnosis_rows", "diagnosis_table_figure"]

#: Column titles of :func:`diagnosis_rows`.
DIAGNOSIS_HEADER = (
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


def _isolation(r: object, i: int) -> str:
    if r.method == "chattering":  # type: ignore[attr-defined]
        onset = r.onsets[i]  # type: ignore[attr-defined]
        s = next(
            (j for j, span in enumerate(r.segment_span_s) if abs(span[0] - onset) < 1e-9),  # type: ignore[attr-defined]
            None,
        )
        if s is None or r.flagged_channel[s] is None:  # type: ignore[attr-defined]
            return "nothing flagged"
        c = r.channels.index(r.flagged_channel[s])  # type: ignore[attr-defined]
        frac = r.flag_fraction[s, c]  # type: ignore[attr-defined]
        return f"{r.flagged_channel[s]} @ {r.peak_hz[s]:.1f} Hz ({100 * frac:.0f}% frames)"  # type: ignore[attr-defined]
    k = r.new_modes[i]  # type: ignore[attr-defined]
    mode = r.modes[k]  # type: ignore[attr-defined]
    return (
        f"{mode} {r.confusion[k, k]:.1f}%, argmax after "  # type: ignore[attr-defined]
        f"{_ms(r.isolation_median[i])}/{_ms(r.isolation_p90[i])} ms"  # type: ignore[attr-defined]
    )


def diagnosis_rows(results: Sequence[object]) -> tuple[tuple[str, ...], list[tuple[str, ...]]]:
    """The comparison table as strings.

    Parameters
    ----------
    results : sequence of ModeDiagnosis or ChatteringDiagnosis
        Results of :func:`~chatterspec.studies.mode_diagnosis.diagnose_modes` and
        :func:`~chatterspec.studies.chattering_diagnosis.diagnose_chattering` on the same simulation.

    Returns
    -------
    (header, rows)
        :data:`DIAGNOSIS_HEADER` and one row per (method, onset); the false-alarm and cost cells are
        filled on a method's first row only.
    """
    rows = []
    for r in results:
        lo, hi = r.false_alarm_ci  # type: ignore[attr-defined]
        fa = f"{r.false_alarm_runs}/{r.runs} [{lo:.3f}, {hi:.3f}]"  # type: ignore[attr-defined]
        if not np.isfinite(r.healthy_alarm_fraction):  # type: ignore[attr-defined]
            fa = "n/a (no healthy part)"  # faulty from the start: no false alarm can be counted
        for i, onset in enumerate(r.onsets):  # type: ignore[attr-defined]
            rows.append(
                (
                    r.method if i == 0 else "",  # type: ignore[attr-defined]
                    fa if i == 0 else "",
                    f"{onset:.2f}",
                    f"{_ms(r.detection_median[i])}/{_ms(r.detection_p90[i])}",  # type: ignore[attr-defined]
                    _isolation(r, i),
                    str(r.missed[i]),  # type: ignore[attr-defined]
                    f"{r.steps_per_second:.3g}" if i == 0 else "",  # type: ignore[attr-defined]
                )
            )
    return DIAGNOSIS_HEADER, rows


def diagnosis_table_figure(results: Sequence[object], title: str = "") -> Figure:
    """The comparison table drawn as a matplotlib table.

    Parameters
    ----------
    results : sequence of ModeDiagnosis or ChatteringDiagnosis
        As for :func:`diagnosis_rows`.
    title : str
        Figure title (e.g. scenario, runs and seed).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    header, rows = diagnosis_rows(results)
    fig, ax = plt.subplots(figsize=(12, 0.45 * (len(rows) + 1) + 0.8))
    ax.axis("off")
    table = ax.table(cellText=rows or [[""] * len(header)], colLabels=header, loc="center", cellLoc="left")
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.auto_set_column_width(list(range(len(header))))
    table.scale(1.0, 1.4)
    for (row, _col), cell in table.get_celld().items():
        if row == 0:
            cell.set_text_props(weight="bold")
            cell.set_facecolor("#e8e8e8")
    if title:
        ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return fig
