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
    for k, route in enumerate(routes):
        col = mpl(MODE_COLORS[k % len(MODE_COLORS)])
        for i, c in enumerate(cases):
            r = c["routes"][k]
            if r["note"]:
                continue
            per_day = 24 / r["hours"]
            v = max(r["starts"] * per_day, floor)
            a, b = (max(x * 24, floor) for x in r["rate_interval_99"])
            ax.plot([a, b], [y[i] + off[k]] * 2, color=col, lw=1.2)
            ax.plot(v, y[i] + off[k], "o", color=col, ms=4, mfc=col if r["holds"] else "white",
                    label=route if i == 0 else None)  # fmt: skip
    ax.set_xscale("log")
    ax.set_xlim(left=floor / 2)
    ax.set_xlabel("false alarms per day (hollow: budget not held; 0 drawn at 0.05)")
    ax.set_yticks(y, [c["description"] for c in cases], fontsize=8)
    ax.legend(fontsize=7, loc="lower right")
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
                        ms=3.5, mfc="none", label=f["fault"] if (i == 0 and k == 0) else None)  # fmt: skip
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
                ax.plot(med, y[i] + off[k], "o", color=col, ms=4)
    ax.set_xlabel(f"{faults[0] if faults else 'fault'}: median delay (s)")
    ax.grid(axis="x", alpha=0.3)
    ax.set_xlim(left=0)
    fig.suptitle(
        f"Realistic bench: {hours:g} h of healthy data per plant through the online monitor, "
        f"{doc['config']['rule']} rule at {budget * 24:g} false alarm per day",
        fontsize=10,
    )
    fig.tight_layout()
    return fig
