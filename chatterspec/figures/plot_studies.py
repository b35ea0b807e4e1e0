"""Figures of the Monte Carlo studies and benches; matplotlib, Agg backend.

The studies (calibration, false alarms, power/ROC: :func:`calibration_figure`, :func:`far_figure`,
:func:`power_figure`); the realistic bench (:mod:`chatterspec.online.realistic_bench`,
:func:`bench_figure`): false alarms and detection per plant and monitor, from the bench's JSON document;
the summary figure of ``chatterspec demo`` (:func:`summary_figure`): peak ratio per scenario and channel,
faults against healthy. :func:`summary_figure` draws plain data (:class:`RatioRow`); :func:`demo_summary`
reads the per-scenario JSON documents ``chatterspec demo`` builds
(:meth:`chatterspec.detection.detect.DetectionReport.to_dict` plus ``healthy`` and ``fault_channel``) and
writes the PNG.

Imported on demand only (the numeric core never imports matplotlib).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.artist import Artist
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import LogLocator, NullFormatter

from ..errors import ParameterError, ShapeError
from ..palette import MODE_COLORS, NEUTRAL, mpl
from .style import _CURVE_COLORS, format_alpha, save_figure

if TYPE_CHECKING:  # pragma: no cover
    from ..studies.calibration.result import Calibration
    from ..studies.detection_rates import FalseAlarmResult, PowerResult

__all__ = [
    "RatioRow",
    "bench_figure",
    "calibration_figure",
    "demo_summary",
    "far_figure",
    "power_figure",
    "rows_from_reports",
    "save",
    "summary_figure",
]


def save(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Save ``fig`` to ``path`` and close it.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Figure to write; it is closed afterwards (``plt.close``) to free memory.
    path : str or Path
        Output file; the format follows its suffix (``.png``, ``.pdf``, ``.svg``, ...).
    dpi : int
        Resolution in dots per inch for raster formats (default 120).

    Returns
    -------
    Path
        ``path`` as a :class:`~pathlib.Path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return path


def calibration_figure(cal: Calibration) -> Figure:
    """Per channel: empirical per-bin quantile of S/E[S] with its interval vs the analytic exact factor.

    One log-scale panel per output channel over the tested bins (Hz), also
    showing the paper's flat threshold divided by E[S], the empirical
    family-wise factor and the analytic Bonferroni factor.

    Parameters
    ----------
    cal : Calibration
        Result of :func:`chatterspec.studies.calibration.thresholds.calibrate` (or
        :func:`~chatterspec.studies.calibration.result.load_calibration`).

    Returns
    -------
    matplotlib.figure.Figure
    """
    m = len(cal.channels)
    fig, axes = plt.subplots(m, 1, figsize=(8, 2.4 * m), sharex=True, squeeze=False)
    f, t = cal.freqs_hz, cal.tested
    for c, ax in enumerate(axes[:, 0]):
        ax.fill_between(
            f[t],
            cal.per_bin_low[t, c],
            cal.per_bin_high[t, c],
            color="C0",
            alpha=0.25,
            lw=0,
            label=f"empirical {cal.confidence:.0%} interval",
        )
        ax.plot(f[t], cal.per_bin[t, c], color="C0", lw=0.5, label="empirical quantile")
        if cal.analytic:  # none for an empirical normalization (nonlinear model)
            ax.plot(f[t], cal.exact_factor[t, c], color="k", lw=1.2, label="exact (analytic)")
            ax.plot(
                f[t], (cal.analytic["paper"] / cal.expected)[t, c], color="C3", lw=1, label="paper (flat)"
            )
        q = cal.family_wise[c]
        ax.axhline(q.value, color="C2", ls="--", lw=1, label="empirical family-wise")
        if cal.family_wise_analytic:
            ax.axhline(cal.family_wise_analytic["bonferroni"], color="C2", ls=":", lw=1, label="Bonferroni")
        ax.set_yscale("log")
        ax.set_ylabel(f"{cal.channels[c]}\nthreshold / E[S]")
    axes[0, 0].set_title(f"{cal.scenario}: thresholds at alpha = {cal.alpha:g} ({cal.runs} healthy runs)")
    axes[0, 0].legend(fontsize=7, ncol=3, loc="upper right")
    axes[-1, 0].set_xlabel("frequency (Hz)")
    fig.tight_layout()
    return fig


def far_figure(res: FalseAlarmResult, kinds: tuple[str, ...] = ("paper", "exact")) -> Figure:
    """Per-bin false-alarm rate vs frequency (per channel) for record kinds, with the nominal level.

    Rates are smoothed by a moving average over about 1 % of the band; DC and
    Nyquist are left out. Solid lines are the first alpha, dashed the second.

    Parameters
    ----------
    res : FalseAlarmResult
        Result of :func:`chatterspec.studies.detection_rates.false_alarm_study`.
    kinds : tuple of str
        Threshold kinds to draw (default ``("paper", "exact")``); kinds absent
        from ``res`` at an alpha are skipped.

    Returns
    -------
    matplotlib.figure.Figure
    """
    m = len(res.channels)
    fig, axes = plt.subplots(m, 1, figsize=(8, 2.4 * m), sharex=True, squeeze=False)
    alphas = sorted({r.alpha for r in res.rates if r.kind in kinds})
    for c, ax in enumerate(axes[:, 0]):
        for i, a in enumerate(alphas):
            for j, k in enumerate(kinds):
                try:
                    r = res.get(k, a)
                except ValueError:
                    continue
                f, rate = r.freqs_hz[1:-1], r.rate_vs_freq[1:-1, c]
                w = max(1, len(f) // 100)  # smooth over ~1 % of the band for readability
                kern = np.ones(w) / w
                ax.plot(
                    f,
                    np.convolve(rate, kern, mode="same"),
                    color=f"C{j}",
                    lw=1,
                    ls="-" if i == 0 else "--",
                    label=f"{k}, alpha {a:g}",
                )
            ax.axhline(a, color="k", lw=0.8, ls="-" if i == 0 else "--")
        ax.set_yscale("symlog", linthresh=min(alphas) / 10)
        ax.set_ylim(bottom=0)
        ax.set_ylabel(f"{res.channels[c]}\nper-bin rate")
    axes[0, 0].set_title(f"{res.scenario}: per-bin false-alarm rate ({res.runs} runs; black = nominal alpha)")
    axes[0, 0].legend(fontsize=7, ncol=2)
    axes[-1, 0].set_xlabel("frequency (Hz)")
    fig.tight_layout()
    return fig


def power_figure(res: PowerResult) -> Figure:
    """Left: detection probability vs fault size per kind and noise; right: ROC curves (exact Bonferroni).

    Parameters
    ----------
    res : PowerResult
        Result of :func:`chatterspec.studies.detection_rates.power_study`. The left panel
        shows Clopper-Pearson error bars at ``res.alpha`` on the fault channel;
        the right panel sweeps ``res.alphas`` for every non-healthy size
        (false-alarm rates of 0 are drawn at ``0.5 / runs`` on the log axis).

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(res.sizes))
    for i, nz in enumerate(res.noise):
        for j, k in enumerate(res.kinds):
            est = [res.estimate(i, s, k) for s in range(len(res.sizes))]
            y = np.array([e.rate for e in est])
            lo = y - np.array([e.ci_low for e in est])
            hi = np.array([e.ci_high for e in est]) - y
            ax1.errorbar(
                x + 0.05 * j,
                y,
                yerr=[lo, hi],
                color=f"C{j}",
                ls="-" if i == 0 else "--",
                marker="o",
                ms=3,
                capsize=2,
                label=f"{k}, noise x{nz:g}",
            )
    ax1.set_xticks(x, [f"{s:.3g}" for s in res.sizes], rotation=30)
    ax1.set_xlabel(f"{res.family} ({res.sizes[0]:.3g} = healthy)")
    ax1.set_ylabel(f"detection probability ({res.channel})")
    ax1.set_title(f"power at alpha = {res.alpha:g}, {res.runs} runs/point")
    ax1.legend(fontsize=7)
    for i, nz in enumerate(res.noise):
        for j in range(1, len(res.sizes)):
            far, det = res.roc(i, j)
            ax2.plot(
                np.maximum(far, 0.5 / res.runs),
                det,
                marker=".",
                ls="-" if i == 0 else "--",
                color=f"C{j % 10}",
                label=f"size {res.sizes[j]:.3g}, noise x{nz:g}",
            )
    ax2.set_xscale("log")
    # at least two decades, labels on the decades only: minor-tick labels (1.4e-1, 1.6e-1, ...) overlap
    ax2.set_xlim(min(0.4 / res.runs, 1e-2), 1.0)
    ax2.xaxis.set_major_locator(LogLocator(base=10.0))
    ax2.xaxis.set_minor_formatter(NullFormatter())
    ax2.set_xlabel("false-alarm rate (healthy records)")
    ax2.set_ylabel("detection rate")
    ax2.set_title("ROC, exact Bonferroni, alpha swept")
    ax2.legend(fontsize=6)
    fig.tight_layout()
    return fig


# ------------------------------------------------------------------------------ the realistic bench


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


# ------------------------------------------------------------------------------- the demo's summary


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
