"""Figures of the multiple-model filters: mode weights over time ([SMM] Fig 5) and confusion heatmaps
([IMM] Tables 5-7 as images); matplotlib, Agg backend. Imported on demand only."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..errors import ShapeError
from ..palette import mode_color, mpl

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

__all__ = ["confusion_figure", "mode_weights_figure"]


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
