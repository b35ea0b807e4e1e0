"""Figures of the decisions on the identified parameters (matplotlib, Agg backend).

* :func:`tolerance_band_figure`: a parameter's joint estimate with its interval against its tolerance
  band over time, the true value, and the alarm;
* :func:`excitation_figure`: the detectable leakage change over a hold-move-hold cycle, with and
  without dither, against the not-excited limit.

Imported on demand only (the numeric core never imports matplotlib).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..palette import FAULT, NEUTRAL, NO_EVIDENCE, TAB10, TRUTH, fault_level_color, mpl

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = ["excitation_figure", "tolerance_band_figure"]


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
