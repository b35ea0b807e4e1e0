"""The summary figure of ``chatterspec demo``: peak ratio per scenario and channel, faults against healthy.

:func:`summary_figure` draws plain data (:class:`RatioRow`); :func:`demo_summary`
reads the per-scenario JSON documents ``chatterspec demo`` builds
(:meth:`chatterspec.detection.detect.DetectionReport.to_dict` plus ``healthy``
and ``fault_channel``) and writes the PNG.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.artist import Artist
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..errors import ParameterError, ShapeError
from .style import _CURVE_COLORS, format_alpha, plt, save_figure

__all__ = ["RatioRow", "demo_summary", "rows_from_reports", "summary_figure"]


@dataclass(frozen=True)
class RatioRow:
    """One scenario of the demo summary figure.

    Attributes
    ----------
    scenario : str
        Scenario name.
    channels : tuple of str
        Output channels, in model order.
    ratios : tuple of float
        Peak ratio ``max_f S(f) / threshold(f)`` per channel (dimensionless; > 1 = detected).
    healthy : bool
        True for a scenario without a fault.
    fault_channel : str, optional
        Channel the fault acts on (marked with a filled symbol).
    """

    scenario: str
    channels: tuple[str, ...]
    ratios: tuple[float, ...]
    healthy: bool = False
    fault_channel: str | None = None


def summary_figure(rows: Sequence[RatioRow], *, title: str = "", threshold_label: str = "") -> Figure:
    """Peak ratio per scenario and channel on a log axis, threshold at 1: faults against healthy.

    One row per scenario (healthy rows shaded green), one symbol per channel; the
    symbol is filled (and its value written) on the channel the fault acts on. A ratio above 1 means the
    channel's spectrum crosses the detection threshold somewhere.

    Parameters
    ----------
    rows : sequence of RatioRow
        Scenarios in display order (top to bottom); at least one
        (:class:`ParameterError` otherwise); ``ratios`` must match ``channels``
        (:class:`ShapeError`).
    title : str
        Axes title; empty for none.
    threshold_label : str
        What the threshold is (drawn as the legend entry of the line at 1).

    Returns
    -------
    matplotlib.figure.Figure
        One axes with a log x axis (peak ratio) and one y tick per scenario.
    """
    rows = list(rows)
    if not rows:
        raise ParameterError("the summary figure needs at least one scenario")
    for r in rows:
        if len(r.ratios) != len(r.channels):
            raise ShapeError(f"{r.scenario}: {len(r.ratios)} ratios for {len(r.channels)} channels")
    channels: list[str] = []
    for r in rows:
        channels += [c for c in r.channels if c not in channels]
    markers = dict(zip(channels, "osD^vP*X", strict=False))
    cmap = dict(zip(channels, _CURVE_COLORS, strict=False))
    fig, ax = plt.subplots(figsize=(8.5, 0.42 * len(rows) + 1.6), layout="constrained")
    n = len(rows)
    offsets = np.linspace(-0.22, 0.22, len(channels)) if len(channels) > 1 else np.zeros(1)
    vals = [v for r in rows for v in r.ratios if np.isfinite(v) and v > 0]
    for y, r in enumerate(rows):
        yy = n - 1 - y
        if r.healthy:
            ax.axhspan(yy - 0.5, yy + 0.5, color="tab:green", alpha=0.12, lw=0, zorder=0)
        for c, v in zip(r.channels, r.ratios, strict=True):
            if not (np.isfinite(v) and v > 0):
                continue
            filled = c == r.fault_channel
            ax.plot(
                v,
                yy + offsets[channels.index(c)],
                ls="none",
                marker=markers[c],
                ms=7,
                mec=cmap[c],
                mfc=cmap[c] if filled else "white",
                mew=1.4,
                zorder=3,
            )
            if filled:  # the number behind the fault channel's symbol
                ax.annotate(
                    f"{v:.3g}",
                    (v, yy + offsets[channels.index(c)]),
                    xytext=(7, 0),
                    textcoords="offset points",
                    va="center",
                    fontsize=7,
                    color=cmap[c],
                )
    ax.axvline(1.0, color="tab:red", lw=1.4, zorder=2)
    ax.set_xscale("log")
    if vals:
        ax.set_xlim(min(min(vals), 1.0) / 2.0, max(max(vals), 1.0) * 5.0)
    ax.set_yticks(range(n), [r.scenario for r in reversed(rows)], fontsize=8)
    ax.set_ylim(-0.6, n - 0.4)
    ax.set_xlabel("peak ratio max S(f) / threshold(f) over the tested bins (log; > 1 = detected)")
    ax.grid(True, axis="x", which="major", alpha=0.3)
    handles: list[Artist] = [
        Line2D([], [], ls="none", marker=markers[c], ms=7, mec=cmap[c], mfc="white", mew=1.4, label=c)
        for c in channels
    ]
    handles.append(
        Line2D([], [], ls="none", marker="o", ms=7, mec="0.3", mfc="0.3", label="channel the fault acts on")
    )
    handles.append(Line2D([], [], color="tab:red", lw=1.4, label=threshold_label or "threshold (ratio 1)"))
    handles.append(Patch(color="tab:green", alpha=0.2, label="healthy scenario (should stay left of 1)"))
    fig.legend(handles=handles, loc="outside lower center", ncols=3, fontsize=8, frameon=False)
    if title:
        ax.set_title(title, fontsize=10)
    return fig


def rows_from_reports(reports: Sequence[Mapping[str, Any]]) -> list[RatioRow]:
    """One :class:`RatioRow` per demo scenario document.

    Parameters
    ----------
    reports : sequence of mapping
        Documents with ``"scenario"``, ``"channels"`` (each with ``"channel"`` and
        ``"peak_ratio"``), ``"healthy"`` and ``"fault_channel"`` -- the entries of
        ``chatterspec demo --json``'s ``"scenarios"``.

    Returns
    -------
    list of RatioRow

    Raises
    ------
    ParameterError
        A document lacks one of those keys.
    """
    rows = []
    for doc in reports:
        try:
            chans = doc["channels"]
            rows.append(
                RatioRow(
                    scenario=str(doc["scenario"]),
                    channels=tuple(str(c["channel"]) for c in chans),
                    ratios=tuple(float(c["peak_ratio"]) for c in chans),
                    healthy=bool(doc["healthy"]),
                    fault_channel=doc["fault_channel"],
                )
            )
        except KeyError as exc:
            raise ParameterError(
                f"a demo scenario document needs 'scenario', 'channels' (channel, peak_ratio), 'healthy' "
                f"and 'fault_channel'; missing {exc}"
            ) from None
    return rows


def demo_summary(reports: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Write the demo's summary figure (:func:`summary_figure`) to ``path`` (PNG); return the path.

    Parameters
    ----------
    reports : sequence of mapping
        The demo's per-scenario documents (see :func:`rows_from_reports`); the
        threshold of the first one labels the line at 1.
    path : str or Path
        Output file ending in ``.png``.

    Returns
    -------
    Path
    """
    rows = rows_from_reports(reports)
    th = reports[0].get("threshold", {}) if reports else {}
    label = "threshold (ratio 1)"
    if th:
        label = (
            f"threshold: {th.get('kind', '')}, α = {format_alpha(th.get('alpha', float('nan')))} "
            f"{th.get('alpha_meaning', '')}"
        )
    runs = reports[0].get("runs", 1) if reports else 1
    what = "one realization per scenario" if runs == 1 else f"mean spectrum of {runs} realizations"
    fig = summary_figure(
        rows,
        title=f"chatterspec demo — largest S(f)/threshold(f) per channel ({what})",
        threshold_label=label,
    )
    return save_figure(fig, path)
