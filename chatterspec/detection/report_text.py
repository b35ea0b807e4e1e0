"""The text table of a detection report (``DetectionReport.table()`` and ``chatterspec detect``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

__all__ = ["detection_table"]


def detection_table(doc: Mapping[str, Any]) -> str:
    """The per-channel table of a detection report's :meth:`~DetectionReport.to_dict` document.

    Parameters
    ----------
    doc : mapping
        ``DetectionReport.to_dict()`` (``chatterspec detect --json`` adds ``seed`` and
        ``fault_intervals_true``, shown when present).

    Returns
    -------
    str
        Lines: the threshold, a legend, one row per channel (detected, peak Hz, most significant
        Hz, peak ratio, excess power; detection rate with runs > 1), the verdict and the STFT
        intervals (seconds) when the STFT ran. No trailing newline.
    """
    th = doc["threshold"]
    runs = doc["runs"]
    lines = []
    seed = f"  seed {doc['seed']}" if "seed" in doc else ""
    lines.append(f"scenario {doc['scenario']}  runs {runs}{seed}")
    lines.append(f"threshold: {th['description']}")
    head = (
        f"{'channel':<10} {'detected':<9} {'peak Hz':>8} {'signif Hz':>9} {'peak ratio':>11} "
        f"{'excess power':>13}"
    )
    if runs > 1:
        head += f" {'rate':>6}"
    if runs > 1 and "averaged_threshold" in doc:  # none for an empirical (nonlinear) calibration
        lines.append(f"averaged spectrum: {doc['averaged_threshold']['description']}")
        lines.append(
            "(detected, signif Hz and peak ratio: averaged spectrum vs the averaged threshold; "
            "rate: fraction of single runs detected by the single-record threshold)"
        )
    elif runs > 1:
        lines.append("(detected, signif Hz and peak ratio: run 0; rate: fraction of runs detected)")
    lines.append(
        "(peak Hz: largest excess power S - E[S]; signif Hz: largest S / threshold, ratio = peak ratio)"
    )
    lines.append(head)
    for c in doc["channels"]:
        line = (
            f"{c['channel']:<10} {'YES' if c['detected'] else 'no':<9} {c['peak_hz']:8.2f} "
            f"{c['most_significant_hz']:9.2f} {c['peak_ratio']:11.3f} {c['excess_power']:13.4f}"
        )
        if runs > 1:
            line += f" {c['detection_rate']:6.3f}"
        lines.append(line)
    lines.append(f"fault detected: {'YES' if doc['detected'] else 'no'}")
    if "intervals" in doc:
        ivs = [iv for iv in doc["intervals"] if iv["channel"] == "any"]
        shown = ", ".join(f"[{iv['onset_s']:.1f}, {iv['offset_s']:.1f}] s" for iv in ivs) or "none"
        lines.append(f"STFT intervals (any channel): {shown}")
        if "fault_intervals_true" in doc:
            true = ", ".join(f"[{a:g}, {b:g}) s" for a, b in doc["fault_intervals_true"]) or "none"
            lines.append(f"true fault windows: {true}")
    return "\n".join(lines)
