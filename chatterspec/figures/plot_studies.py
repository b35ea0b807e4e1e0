"""Figures of the Monte Carlo studies (calibration, false alarms, power/ROC); matplotlib, Agg backend.

Imported on demand only (the numeric core never imports matplotlib).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import LogLocator, NullFormatter

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..studies.calibration.result import Calibration
    from ..studies.detection_rates import FalseAlarmResult, PowerResult

__all__ = ["calibration_figure", "far_figure", "power_figure", "save"]


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
