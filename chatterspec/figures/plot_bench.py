"""The realistic bench's figure (:mod:`chatterspec.online.realistic_bench`): false alarms and detection
per plant and monitor; matplotlib, Agg backend, from the bench's JSON document."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from ..palette import MODE_COLORS, NEUTRAL, mpl
from .style import save_figure as save

__all__ = ["bench_figure", "save"]


def bench_figure(doc: Mapping[str, Any]) -> Figure:
    """Per case (rows) and monitor (markers): false alarms per day with their 99 % interval against the
    budget's (left), detection rate of each catalogue fault (middle) and the minor leakage's median
    delay (right).

    Parameters
    ----------
    doc : mapping
        ``BenchResult.to_dict()`` (the JSON the bench script writes).
    """
    cases = list(doc["cases"])
    routes = [r["route"] for r in cases[0]["routes"]]
    n = len(cases)
    budget = float(doc["config"]["budget"])
    fig, axes = plt.subplots(1, 3, figsize=(13.5, 0.32 * n + 1.6), sharey=True,
                             gridspec_kw={"width_ratios": [1.3, 1.0, 0.8]})  # fmt: skip
    y = np.arange(n)[::-1].astype(float)
    off = np.linspace(-0.25, 0.25, len(routes)) if len(routes) > 1 else np.zeros(1)
    ax = axes[0]
    floor = 0.05  # per day: draw zero counts here (log axis)
    hours = max((r["hours"] for c in cases for r in c["routes"]), default=24.0)
    lo, hi = (v * 24 / hours for v in cases[0]["routes"][0]["count_interval_99"])
    ax.axvspan(
        max(lo, floor),
        max(hi, floor),
        color=mpl(NEUTRAL),
        alpha=0.18,
        lw=0,
        label="99 % interval at the budget",
    )
    ax.axvline(budget * 24, color="k", lw=0.8, ls="--", label=f"budget ({budget * 24:g} per day)")
    standing = 1e3  # per day: where a standing alarm (in alarm most of the time) is drawn
    for k, route in enumerate(routes):
        col = mpl(MODE_COLORS[k % len(MODE_COLORS)])
        for i, c in enumerate(cases):
            r = c["routes"][k]
            if r["note"]:
                ax.plot(floor, y[i] + off[k], "x", color=col, ms=4)  # not run
                continue
            if r.get("alarm_fraction", 0.0) > 0.01:
                ax.plot(standing, y[i] + off[k], ">", color=col, ms=5)
                continue
            per_day = 24 / r["hours"]
            v = max(r["starts"] * per_day, floor)
            a, b = (max(x * 24, floor) for x in r["rate_interval_99"])
            ax.plot([a, b], [y[i] + off[k]] * 2, color=col, lw=1.2)
            ax.plot(v, y[i] + off[k], "o", color=col, ms=4, mfc=col if r["holds"] else "white",
                    label=route if i == 0 else None)  # fmt: skip
    for k, route in enumerate(routes):  # legend entries even when the first case has no point
        ax.plot([], [], "o", color=mpl(MODE_COLORS[k % len(MODE_COLORS)]), label=route)
    ax.plot([], [], ">", color="k", label="in alarm > 1 % of the time")
    ax.plot([], [], "x", color="k", label="not run (refused: no threshold, no model)")
    ax.set_xscale("log")
    ax.set_xlim(floor / 2, 2 * standing)
    ax.set_xlabel("false alarms per day, 99 % interval (0 drawn at 0.05)")
    ax.set_yticks(y, [c["description"] for c in cases], fontsize=8)
    handles, labels = ax.get_legend_handles_labels()
    keep = dict(zip(labels, handles, strict=True))
    fig.legend(keep.values(), keep.keys(), fontsize=7, loc="lower center", ncol=4, bbox_to_anchor=(0.5, 0.0))
    ax.grid(axis="x", alpha=0.3)
    faults = (
        [f["fault"] for f in cases[0]["routes"][0]["faults"]] if not cases[0]["routes"][0]["note"] else []
    )
    ax = axes[1]
    markers = "osD^v<>"
    for k, _ in enumerate(routes):
        col = mpl(MODE_COLORS[k % len(MODE_COLORS)])
        for i, c in enumerate(cases):
            r = c["routes"][k]
            for j, f in enumerate(r["faults"]):
                ax.plot(100 * f["detected"] / f["runs"], y[i] + off[k], markers[j % len(markers)], color=col,
                        ms=3.5, mfc="none", alpha=1.0 if r["holds"] else 0.3)  # fmt: skip
    for j, f in enumerate(faults):
        ax.plot([], [], markers[j % len(markers)], color="k", mfc="none", label=f)
    ax.set_xlabel("onsets detected (%)")
    ax.set_xlim(-3, 103)
    ax.grid(axis="x", alpha=0.3)
    if faults:
        ax.legend(fontsize=7, loc="lower left", title="fault (marker)", title_fontsize=7)
    ax = axes[2]
    for k, _ in enumerate(routes):
        col = mpl(MODE_COLORS[k % len(MODE_COLORS)])
        for i, c in enumerate(cases):
            r = c["routes"][k]
            if not r["faults"]:
                continue
            med = r["faults"][0]["median_s"]
            if med is not None and math.isfinite(med):
                ax.plot(med, y[i] + off[k], "o", color=col, ms=4, alpha=1.0 if r["holds"] else 0.3)
    ax.set_xlabel(f"{faults[0] if faults else 'fault'}: median delay (s)")
    ax.grid(axis="x", alpha=0.3)
    ax.set_xlim(0, ax.get_xlim()[1] * 1.1 + 0.05)
    fig.suptitle(
        f"Realistic bench: {hours:g} h of healthy data per plant through the online monitor, "
        f"{doc['config']['rule']} rule at {budget * 24:g} false alarm per day "
        "(faint markers: budget not held)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0.0, 0.9 / fig.get_figheight(), 1.0, 1.0))  # room for the legend's rows below
    return fig
