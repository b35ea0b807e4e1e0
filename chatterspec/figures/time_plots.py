"""Matplotlib figures over time: STFT spectrograms (Fig 8) and the boundary-layer study (Fig 2).

Plain data in (:class:`SpectrogramPanel`, :class:`BoundaryLayerPanel`), a
:class:`matplotlib.figure.Figure` out; re-exported by :mod:`chatterspec.figures.plotting`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..errors import ParameterError, ShapeError
from ..palette import fault_level_color, mpl
from .style import _WINDOW_SHADES, FrequencyLine, _wrap, plt, power_unit

__all__ = ["BoundaryLayerPanel", "SpectrogramPanel", "boundary_layer_figure", "spectrogram_figure"]


@dataclass(frozen=True)
class SpectrogramPanel:
    """One axes of a spectrogram figure (Fig 8).

    Attributes
    ----------
    times_s : (frames,) array
        Frame-centre times in seconds.
    freqs_hz : (bins,) array
        Frequencies in Hz.
    power : (frames, bins) array
        STFT power of one chattering channel (unit²).
    title, channel, unit : str
        Axes title, channel name and channel unit.
    fault_intervals : tuple of (start_s, stop_s)
        True fault windows (drawn as a bar above the spectrogram).
    detected_intervals : tuple of (onset_s, offset_s)
        Detected intervals from the STFT detector (drawn as a second bar).
    flags : (frames,) bool array, optional
        Frames flagged by the detector (drawn as ticks on the detection bar).
    fmax_hz : float, optional
        Upper limit of the frequency axis.
    detector_label : str
        Says which threshold and alpha produced ``detected_intervals``.
    lines : tuple of FrequencyLine
        Horizontal frequency lines (e.g. nominal and true natural frequencies, Hz).
    """

    times_s: np.ndarray
    freqs_hz: np.ndarray
    power: np.ndarray
    title: str = ""
    channel: str = ""
    unit: str = ""
    fault_intervals: tuple[tuple[float, float], ...] = ()
    detected_intervals: tuple[tuple[float, float], ...] = ()
    flags: np.ndarray | None = None
    fmax_hz: float | None = None
    detector_label: str = "detected"
    lines: tuple[FrequencyLine, ...] = ()


@dataclass(frozen=True)
class BoundaryLayerPanel:
    """Data of the boundary-layer study (Fig 2), one row per boundary layer psi.

    Attributes
    ----------
    t : (T,) array
        Time in seconds.
    psi : (k,) array
        Boundary layers of the measured state (unit of x1).
    labels : tuple of str
        Legend text per psi (e.g. ``"ψ₁ = 1e-4 (too small)"``).
    error_measured, error_unmeasured : (k, T) arrays
        Normalized estimation errors of x1 and x2 (dimensionless).
    chattering : (k, T) array
        Boundary-layer chattering of the measured state (eq 13, unit of x1).
    fault_intervals : tuple of (start_s, stop_s)
        True model-mismatch windows (shaded).
    fault_labels : tuple of str
        One label per fault window.
    error_label : str
        Y-axis text of the normalized errors (how they were normalized).
    colors : tuple of str
        Matplotlib colours of the psi rows, reused cyclically (default black,
        blue, green, purple).
    """

    t: np.ndarray
    psi: np.ndarray
    labels: tuple[str, ...]
    error_measured: np.ndarray
    error_unmeasured: np.ndarray
    chattering: np.ndarray
    fault_intervals: tuple[tuple[float, float], ...] = ()
    fault_labels: tuple[str, ...] = ()
    error_label: str = "normalized error"
    # no red: red means a fault verdict (chatterspec.palette), and a boundary layer is not one
    colors: tuple[str, ...] = field(default=("black", "tab:blue", "tab:green", "tab:purple"))


# --------------------------------------------------------------------------- spectrograms
def _interval_bar(
    ax: Axes, intervals: Sequence[tuple[float, float]], y: float, color: str | Sequence[object]
) -> None:
    """One bar per interval at height ``y`` (axes fraction); ``color`` one colour or one per interval."""
    colors = [color] * len(intervals) if isinstance(color, str) else list(color)
    for (a, b), c in zip(intervals, colors, strict=True):
        ax.plot([a, b], [y, y], color=c, lw=6, solid_capstyle="butt", transform=ax.get_xaxis_transform())


def spectrogram_figure(
    panels: Sequence[SpectrogramPanel],
    *,
    suptitle: str = "",
    db_range: float = 80.0,
    panel_size: tuple[float, float] = (6.4, 4.6),
) -> Figure:
    """Spectrograms (STFT power in dB) with true fault windows and detected intervals (Fig 8).

    Each panel shows ``10 log10(power)`` over time (s) and frequency (Hz), clipped
    to ``db_range`` dB below the largest value of all panels (one colour scale for the
    figure). Above the image two bars mark the true fault windows (one amber per fault,
    as the recordings' truth lane) and the detected intervals (white, with flagged frames
    as ticks).

    Parameters
    ----------
    panels : sequence of SpectrogramPanel
        One panel per column (at least one; :class:`ParameterError` otherwise);
        each ``power`` must have shape (frames, bins).
    suptitle : str
        Figure title, wrapped to the figure width; empty for none.
    db_range : float
        Dynamic range of the colour scale in dB below the maximum over all panels (default 80).
    panel_size : (width, height)
        Size of one panel in inches; the figure is ``len(panels)`` panels wide.

    Returns
    -------
    matplotlib.figure.Figure
        One spectrogram axes per panel plus one colorbar axes per panel.
    """
    panels = list(panels)
    if not panels:
        raise ParameterError("a figure needs at least one panel")
    fig, axes = plt.subplots(
        1,
        len(panels),
        figsize=(panel_size[0] * len(panels), panel_size[1] + (0.5 if suptitle else 0.0)),
        squeeze=False,
        layout="constrained",
    )
    handles: dict[str, Artist] = {}
    tiny = np.finfo(float).tiny
    top = max(10.0 * np.log10(max(float(np.max(np.asarray(p.power, dtype=float))), tiny)) for p in panels)
    for ax, p in zip(axes[0], panels, strict=True):
        t = np.asarray(p.times_s, dtype=float)
        f = np.asarray(p.freqs_hz, dtype=float)
        s = np.asarray(p.power, dtype=float)
        if s.shape != (t.size, f.size):
            raise ShapeError(
                f"spectrogram power must have shape (frames, bins) = {(t.size, f.size)}; got {s.shape}"
            )
        db = 10.0 * np.log10(np.maximum(s, tiny))
        # dark grey where no frame covers the time (before the first frame centre): the white
        # detected bar stays visible there (a detected onset at 0 s is drawn from 0 s)
        ax.set_facecolor("0.3")
        mesh = ax.pcolormesh(t, f, db.T, shading="nearest", cmap="viridis", vmin=top - db_range, vmax=top)
        cb = fig.colorbar(mesh, ax=ax, pad=0.01)
        ref = f"dB re 1 {power_unit(p.unit)}" if p.unit else "dB; S dimensionless"
        cb.set_label(f"10 log10 S [{ref}]")
        ax.set_ylim(0.0, p.fmax_hz if p.fmax_hz is not None else float(f[-1]))
        ax.set_xlabel("time (frame centre) [s]")
        ax.set_ylabel(f"frequency [Hz] ({p.channel} chattering)" if p.channel else "frequency [Hz]")
        if p.title:
            ax.set_title(p.title, fontsize=10)
        # true windows in the fault-level ambers of the recordings' truth lane (red is a verdict)
        levels = [mpl(fault_level_color(j)) for j in range(len(p.fault_intervals))]
        _interval_bar(ax, p.fault_intervals, 0.97, levels)
        _interval_bar(ax, p.detected_intervals, 0.92, "white")
        if p.flags is not None:
            flags = np.asarray(p.flags, dtype=bool)
            ax.plot(
                t[flags],
                np.full(int(flags.sum()), 0.87),
                "|",
                color="white",
                ms=5,
                transform=ax.get_xaxis_transform(),
            )
        for fl in p.lines:
            if fl.span_s is None:
                ax.axhline(fl.hz, color=fl.color, ls=fl.linestyle, lw=1.2, label=fl.label)
            else:
                ax.hlines(fl.hz, *fl.span_s, color=fl.color, ls=fl.linestyle, lw=1.6, label=fl.label)
        for j, (a, b) in enumerate(p.fault_intervals):  # one swatch per amber (per true fault)
            what = f"true fault {j + 1}: {a:g}-{b:g} s (bar)"
            handles.setdefault(what, Patch(fc=levels[j], ec="none", label=what))
        det = f"{p.detector_label} (bar; ticks = flagged frames)"
        handles.setdefault(det, Patch(fc="white", ec="none", label=det))
        for fl in p.lines:
            handles.setdefault(
                fl.label, Line2D([], [], color=fl.color, ls=fl.linestyle, lw=1.2, label=fl.label)
            )
    # one legend below the images, out of the data (dark, so the white marks show)
    leg = fig.legend(
        handles=list(handles.values()),
        loc="outside lower center",
        ncols=2,
        fontsize=8,
        facecolor="0.35",
        framealpha=1.0,
    )
    for text in leg.get_texts():
        text.set_color("white")
    if suptitle:
        fig.suptitle(_wrap(suptitle, fig.get_figwidth()), fontsize=10)
    return fig


# --------------------------------------------------------------------------- boundary layer
def boundary_layer_figure(panel: BoundaryLayerPanel, *, suptitle: str = "", unit: str = "") -> Figure:
    """Fig 2: estimation errors and measured-state chattering for several boundary layers.

    Stacked axes sharing time: (a) normalized estimation error of the measured
    state x1, (b) of the unmeasured state x2, one line per psi, drawn largest
    excursion first so the smaller traces stay visible on top; (c) the
    boundary-layer chattering of x1 (eq 13), one thin axes per psi so no trace
    hides another. Each true mismatch window is shaded in its own colour.

    Parameters
    ----------
    panel : BoundaryLayerPanel
        Time axis (s), boundary layers, labels, error and chattering arrays of
        shape (len(psi), T) (:class:`ShapeError` otherwise), fault windows.
    suptitle : str
        Figure title; empty for none.
    unit : str
        Unit of x1, used in the chattering axis label (default: dimensionless,
        as the paper's benchmark has no unit).

    Returns
    -------
    matplotlib.figure.Figure
        ``2 + len(panel.psi)`` axes: (a), (b) with ``len(psi)`` lines each, then
        one chattering axes per psi with one line.
    """
    t = np.asarray(panel.t, dtype=float)
    k = len(panel.psi)
    for name in ("error_measured", "error_unmeasured", "chattering"):
        arr = np.asarray(getattr(panel, name))
        if arr.shape != (k, t.size):
            raise ShapeError(f"{name} must have shape (len(psi), T) = {(k, t.size)}; got {arr.shape}")
    if len(panel.labels) != k:
        raise ShapeError(f"labels must have {k} entries; got {len(panel.labels)}")
    fig, axes = plt.subplots(
        2 + k,
        1,
        figsize=(9.5, 6.0 + 1.0 * k),
        sharex=True,
        layout="constrained",
        gridspec_kw={"height_ratios": (3.0, 3.0) + (1.0,) * k},
    )
    colors = [panel.colors[i % len(panel.colors)] for i in range(k)]
    spans: list[Artist] = []
    for j, (a, b) in enumerate(panel.fault_intervals):
        lab = panel.fault_labels[j] if j < len(panel.fault_labels) else "model mismatch"
        shade = _WINDOW_SHADES[j % len(_WINDOW_SHADES)]
        for ax in axes:
            span = ax.axvspan(a, b, color=shade, alpha=0.22, lw=0, zorder=0, label=f"true mismatch: {lab}")
        spans.append(span)
    for ax, arr, ylab in zip(
        axes[:2],
        (panel.error_measured, panel.error_unmeasured),
        (f"(a) x1 (measured)\n{panel.error_label}", f"(b) x2 (unmeasured)\n{panel.error_label}"),
        strict=True,
    ):
        arr = np.asarray(arr, dtype=float)
        # roughest trace (largest sample-to-sample variation) first: the smoother ones stay visible on top
        rough = np.nanstd(np.diff(arr, axis=1), axis=1) if t.size > 1 else np.zeros(k)
        for i in np.argsort(-rough, kind="stable"):
            ax.plot(t, arr[i], lw=0.6, color=colors[i], label=panel.labels[i])
        ax.set_ylabel(ylab, fontsize=9)
        ax.grid(True, alpha=0.3)
    chat = np.asarray(panel.chattering, dtype=float)
    lim = float(np.nanmax(np.abs(chat))) if chat.size and np.any(np.isfinite(chat)) else 1.0
    for i, ax in enumerate(axes[2:]):
        ax.plot(t, chat[i], lw=0.6, color=colors[i])
        ax.set_ylim(-1.1 * lim if lim > 0 else -1.0, 1.1 * lim if lim > 0 else 1.0)
        ax.text(
            1.005,
            0.5,
            panel.labels[i],
            transform=ax.transAxes,
            fontsize=7,
            va="center",
            ha="left",
            color=colors[i],
        )
        ax.tick_params(labelsize=7)
        ax.grid(True, alpha=0.3)
    if k:
        axes[2].set_title(
            f"(c) x1 chattering (eq 13) [{unit or 'dimensionless'}], one row per ψ₁, common scale",
            fontsize=9,
            loc="left",
        )
    line_handles = [Line2D([], [], color=colors[i], lw=1.5, label=panel.labels[i]) for i in range(k)]
    fig.legend(handles=line_handles + spans, loc="outside lower center", ncols=3, fontsize=8, frameon=False)
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(float(t[0]), float(t[-1]))
    if suptitle:
        fig.suptitle(suptitle, fontsize=11)
    return fig
