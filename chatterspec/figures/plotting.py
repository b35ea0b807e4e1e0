"""Matplotlib figures of chattering spectra, spectrograms and the boundary-layer study.

This module is the only place where chatterspec imports matplotlib; the numeric
core (:mod:`chatterspec.detection.spectral`, :mod:`chatterspec.detection.thresholds`, ...) never
does. It selects the non-interactive ``Agg`` backend on import, so figures can
be rendered on headless machines and in CI.

The functions here take plain data (small frozen "panel" records holding
arrays) and return a :class:`matplotlib.figure.Figure`; they compute nothing
statistical themselves. :mod:`chatterspec.figures.paper_figures` computes the data of
the core paper's figures and calls them.

Conventions (DESIGN.md section 2 and 5):

* frequencies in Hz on a linear axis, power spectra on a log axis;
* a power spectrum ``S(f) = |rfft(x)|^2 / N`` (eq 49) of a chattering channel in
  unit ``u`` has unit ``u^2``;
* every threshold line says in its legend entry which threshold it is (the
  paper's flat bound of eq 58-62 or the exact chi-squared bound built on the
  expected spectrum of eq 56) and what its ``alpha`` means (a per-bin false-alarm
  probability, or a family-wise one over all bins tested).
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ..errors import ParameterError, ShapeError

__all__ = [
    "DEFAULT_DPI",
    "BoundaryLayerPanel",
    "SpectrogramPanel",
    "SpectrumCurve",
    "SpectrumPanel",
    "ThresholdCurve",
    "boundary_layer_figure",
    "draw_spectrum",
    "format_alpha",
    "power_unit",
    "save_figure",
    "spectrogram_figure",
    "spectrum_figure",
    "threshold_curve",
    "threshold_label",
]

#: Resolution of saved PNGs (dots per inch); keeps a 12 x 7 inch figure well under 300 kB.
DEFAULT_DPI: int = 110

ThresholdKind = Literal["paper", "exact", "empirical"]

# Line styles per threshold kind; colours per alpha (larger alpha = lighter).
_KIND_STYLE: dict[str, dict[str, Any]] = {
    "paper": {"linestyle": (0, (6, 2)), "linewidth": 1.6},
    "exact": {"linestyle": "-", "linewidth": 1.6},
    "empirical": {"linestyle": ":", "linewidth": 1.8},
}
_KIND_COLORS: dict[str, tuple[str, ...]] = {
    "paper": ("tab:red", "tab:orange", "gold"),
    "exact": ("tab:green", "yellowgreen", "turquoise"),
    "empirical": ("tab:purple", "orchid", "pink"),
}
_CURVE_COLORS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:cyan", "tab:pink")


# --------------------------------------------------------------------------- labels
def format_alpha(alpha: float) -> str:
    """``0.001 -> "0.1 %"``, ``0.01 -> "1 %"``, ``1e-5 -> "0.001 %"``.

    Parameters
    ----------
    alpha : float
        False-alarm probability as a fraction (not validated); shown as a
        percentage with up to 4 significant digits.

    Returns
    -------
    str
    """
    return f"{100.0 * float(alpha):.4g} %"


def power_unit(unit: str) -> str:
    """Unit of a power spectrum (eq 49) of a signal in ``unit``: ``"m/s" -> "(m/s)²"``.

    An empty unit gives ``"unit²"`` (the second-order benchmark's states carry no
    physical unit).
    """
    if not unit:
        return "unit²"
    if "/" in unit or " " in unit:
        return f"({unit})²"
    return f"{unit}²"


def threshold_label(
    kind: str,
    alpha: float,
    alpha_meaning: str,
    *,
    correction: str = "none",
    averaged: int = 1,
    n_tested: int | None = None,
) -> str:
    """Legend text of a threshold: which bound, and what its ``alpha`` means.

    Parameters
    ----------
    kind : {"paper", "exact", "empirical"}
        ``"paper"`` is the flat bound ``Sigma_Gamma_ii chi2_{1-alpha}(2) / 2`` of
        eq 58-62; ``"exact"`` is ``E[S_i(f)] chi2_{1-alpha'}(2K) / (2K)`` with the
        expected spectrum of eq 56 (finite-N form); ``"empirical"`` is a quantile of
        healthy Monte Carlo spectra.
    alpha : float
        False-alarm probability (a fraction, not a percentage).
    alpha_meaning : {"per-bin", "family-wise", "per-frame"}
        Whether ``alpha`` bounds the false-alarm probability of one frequency bin,
        of the whole spectrum (all bins tested), or of one STFT frame.
    correction : {"none", "bonferroni", "sidak"}
        Multiple-testing correction that turns the family-wise alpha into a per-bin one.
    averaged : int
        Number K of independent spectra averaged (chi-squared with 2K degrees of freedom).
    n_tested : int, optional
        Number of bins tested, shown with the correction.
    """
    names = {
        "paper": "paper flat bound (eq 62)",
        "exact": "exact χ² on E[S] (eq 56)",
        "empirical": "empirical (Monte Carlo)",
    }
    name = names.get(kind, kind)
    if averaged > 1:
        name += f", mean of K={averaged}"
    text = f"{name}: α = {format_alpha(alpha)} {alpha_meaning}"
    if alpha_meaning != "per-bin" and correction not in ("none", ""):
        text += f" ({correction.capitalize()}"
        text += f", {n_tested} bins)" if n_tested else ")"
    return text


# --------------------------------------------------------------------------- panel records
@dataclass(frozen=True)
class ThresholdCurve:
    """One threshold line of a spectrum panel.

    Attributes
    ----------
    values : (bins,) array
        Threshold per frequency bin in the unit of the spectrum; NaN where the bin
        is not tested (e.g. the Nyquist bin, or DC for detection).
    label : str
        Legend text (see :func:`threshold_label`).
    kind : {"paper", "exact", "empirical"}
        Selects the line style.
    alpha : float
        False-alarm probability; selects the shade.
    """

    values: np.ndarray
    label: str
    kind: str = "exact"
    alpha: float = 1e-3


@dataclass(frozen=True)
class SpectrumCurve:
    """One power spectrum drawn in a panel: ``power`` (bins,) in the panel's unit.

    Attributes
    ----------
    power : (bins,) array
        Periodogram values (eq 51) on the panel's ``freqs_hz``, in the square of
        the channel unit (e.g. Pa^2); non-positive values are masked on the log axis.
    label : str
        Legend text.
    color : str, optional
        Matplotlib colour; default cycles through the panel's curve palette.
    linewidth : float
        Line width in points (default 0.8).
    alpha : float
        Line opacity in [0, 1] (matplotlib alpha, not a false-alarm level).
    """

    power: np.ndarray
    label: str
    color: str | None = None
    linewidth: float = 0.8
    alpha: float = 1.0


@dataclass(frozen=True)
class SpectrumPanel:
    """One axes of a spectrum figure (Figs 4-7, 9-12).

    Attributes
    ----------
    freqs_hz : (bins,) array
        Bin frequencies in Hz (``f_n = n / (N Ts)``, eq 50).
    curves : tuple of SpectrumCurve
        Spectra to draw (one realization, several fault levels, an average, ...).
    expected : (bins,) array, optional
        Expected healthy spectrum ``E[S(f)]`` (eq 56).
    thresholds : tuple of ThresholdCurve
        Detection thresholds.
    title : str
        Axes title.
    channel : str
        Chattering channel name (position, velocity, pressure, ...).
    unit : str
        Unit of the chattering channel (the spectrum is in its square).
    fmax_hz : float, optional
        Upper limit of the frequency axis (default: Nyquist).
    note : str
        Text drawn in the upper-left corner (e.g. peak frequency and ratios); the
        y axis gets headroom so it does not hide the data.
    inset_hz : (f_lo, f_hi), optional
        Draw an inset zooming on this frequency band (Hz), e.g. the 9-15 Hz peaks
        of the second-order mismatch figures.
    """

    freqs_hz: np.ndarray
    curves: tuple[SpectrumCurve, ...]
    expected: np.ndarray | None = None
    thresholds: tuple[ThresholdCurve, ...] = ()
    title: str = ""
    channel: str = ""
    unit: str = ""
    fmax_hz: float | None = None
    note: str = ""
    inset_hz: tuple[float, float] | None = None


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
        blue, green, red).
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
    colors: tuple[str, ...] = field(default=("black", "tab:blue", "tab:green", "tab:red"))


# --------------------------------------------------------------------------- thresholds
def threshold_curve(threshold: Any, channel: int, *, label: str | None = None) -> ThresholdCurve:
    """A :class:`ThresholdCurve` for one channel of a :class:`chatterspec.detection.thresholds.Threshold`.

    Bins the threshold does not test (``threshold.tested`` False) are set to NaN
    so they are not drawn. The label comes from :func:`threshold_label` unless given.
    """
    values = np.asarray(threshold.values, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    col = np.array(values[:, channel], dtype=float)
    tested = getattr(threshold, "tested", None)
    if tested is not None:
        tested = np.asarray(tested, dtype=bool)
        if tested.ndim == 2:
            tested = tested[:, channel]
        col[~tested] = np.nan
    col[~np.isfinite(col)] = np.nan
    kind = str(getattr(threshold, "kind", "exact"))
    alpha = float(threshold.alpha)
    if label is None:
        n_tested = int(np.count_nonzero(tested)) if tested is not None else None
        label = threshold_label(
            kind,
            alpha,
            str(getattr(threshold, "alpha_meaning", "per-bin")),
            correction=str(getattr(threshold, "correction", "none")),
            averaged=int(getattr(threshold, "averaged", 1) or 1),
            n_tested=n_tested,
        )
    return ThresholdCurve(values=col, label=label, kind=kind, alpha=alpha)


# --------------------------------------------------------------------------- spectra
def _positive(y: np.ndarray) -> np.ndarray:
    """NaN where a value cannot be drawn on a log axis."""
    y = np.array(y, dtype=float)
    y[~(y > 0)] = np.nan
    return y


def draw_spectrum(ax: Axes, panel: SpectrumPanel, *, legend: bool = True) -> list[Line2D]:
    """Draw one :class:`SpectrumPanel` into ``ax`` (log y, Hz on x); return the lines drawn.

    Draw order: spectra, expected spectrum ``E[S]`` (eq 56, black dashed), then
    thresholds (paper's flat bound dashed in red/orange, exact bound solid in
    green shades; the darkest shade is the smallest alpha, i.e. the highest line).

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes to draw into; its y axis is set to log scale.
    panel : SpectrumPanel
        Frequencies (Hz), spectra, optional expected spectrum and thresholds,
        note and inset band. Arrays must match ``freqs_hz`` in shape
        (:class:`ShapeError` otherwise); a scalar threshold is drawn flat.
    legend : bool
        Add a legend of the drawn lines in the upper-left corner (default True).

    Returns
    -------
    list of matplotlib.lines.Line2D
        Spectra, expected spectrum and thresholds, in draw order (inset lines excluded).
    """
    f = np.asarray(panel.freqs_hz, dtype=float)
    if f.ndim != 1:
        raise ShapeError(f"freqs_hz must be 1-D; got shape {f.shape}")
    lines: list[Line2D] = []
    for i, c in enumerate(panel.curves):
        p = np.asarray(c.power, dtype=float)
        if p.shape != f.shape:
            raise ShapeError(f"curve {c.label!r}: power has shape {p.shape}, freqs_hz {f.shape}")
        color = c.color or _CURVE_COLORS[i % len(_CURVE_COLORS)]
        (ln,) = ax.plot(f, _positive(p), color=color, lw=c.linewidth, alpha=c.alpha, label=c.label)
        lines.append(ln)
    if panel.expected is not None:
        e = np.asarray(panel.expected, dtype=float)
        if e.shape != f.shape:
            raise ShapeError(f"expected has shape {e.shape}, freqs_hz {f.shape}")
        (ln,) = ax.plot(f, _positive(e), color="black", ls="--", lw=1.3, label="expected E[S] (eq 56)")
        lines.append(ln)
    # shade rank per kind: the smallest alpha (highest threshold) gets the darkest colour
    ranks: dict[str, list[float]] = {}
    for th in panel.thresholds:
        ranks.setdefault(th.kind if th.kind in _KIND_STYLE else "exact", []).append(th.alpha)
    ranks = {k: sorted(set(v)) for k, v in ranks.items()}
    for th in panel.thresholds:
        v = np.asarray(th.values, dtype=float)
        if v.ndim == 0:
            v = np.full(f.shape, float(v))
        if v.shape != f.shape:
            raise ShapeError(f"threshold {th.label!r} has shape {v.shape}, freqs_hz {f.shape}")
        kind = th.kind if th.kind in _KIND_STYLE else "exact"
        palette = _KIND_COLORS[kind]
        color = palette[min(ranks[kind].index(th.alpha), len(palette) - 1)]
        (ln,) = ax.plot(f, _positive(v), color=color, label=th.label, **_KIND_STYLE[kind])
        lines.append(ln)
    ax.set_yscale("log")
    ax.set_xlim(0.0, panel.fmax_hz if panel.fmax_hz is not None else float(f[-1]))
    ax.set_xlabel("frequency [Hz]")
    sub = f", {panel.channel}" if panel.channel else ""
    ax.set_ylabel(f"power spectrum S(f){sub} [{power_unit(panel.unit)}]")
    if panel.title:
        ax.set_title(panel.title, fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    if panel.note or panel.inset_hz is not None:
        # the inset needs the upper half of the axes, a note about its upper third
        _make_headroom(ax, panel, lines, data_fraction=0.5 if panel.inset_hz is not None else 0.68)
    if panel.note:
        ax.text(
            0.025,
            0.975,
            panel.note,
            transform=ax.transAxes,
            ha="left",
            va="top",
            fontsize=6.5,
            family="monospace",
            bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "0.75", "alpha": 0.9},
        )
    if panel.inset_hz is not None:
        _draw_inset(ax, panel, lines)
    if legend and lines:
        ax.legend(handles=lines, fontsize=7, loc="upper left", framealpha=0.9)
    return lines


def _make_headroom(
    ax: Axes, panel: SpectrumPanel, lines: Sequence[Line2D], *, data_fraction: float = 0.5
) -> None:
    """Raise the top of the log y axis so the data (DC excluded) fills the lower ``data_fraction``.

    Leaves room for the note (upper left) and the inset (upper right).
    """
    f = np.asarray(panel.freqs_hz, dtype=float)
    right = f > 0
    hi = 0.0
    for ln in lines:
        y = np.asarray(ln.get_ydata(), dtype=float)
        if y.shape == f.shape:
            yr = y[right]
            yr = yr[np.isfinite(yr)]
            if yr.size:
                hi = max(hi, float(yr.max()))
    lo, top = ax.get_ylim()
    if hi > 0 and lo > 0:
        decades = np.log10(hi / lo) + 0.15
        ax.set_ylim(lo, max(top, lo * 10.0 ** (decades / data_fraction)))


def _draw_inset(ax: Axes, panel: SpectrumPanel, lines: Sequence[Line2D]) -> Axes:
    """Zoom on ``panel.inset_hz`` in the upper-right quarter of ``ax`` (same lines, same log scale)."""
    lo, hi = panel.inset_hz  # type: ignore[misc]
    if not hi > lo:
        raise ParameterError(f"inset_hz must be (f_lo, f_hi) with f_lo < f_hi; got {panel.inset_hz}")
    ins = ax.inset_axes((0.6, 0.56, 0.38, 0.4))
    f = np.asarray(panel.freqs_hz, dtype=float)
    band = (f >= lo) & (f <= hi)
    ymin, ymax = np.inf, 0.0
    for ln in lines:
        x, y = (np.asarray(a, dtype=float) for a in ln.get_data())
        ins.plot(
            x, y, color=ln.get_color(), ls=ln.get_linestyle(), lw=ln.get_linewidth(), alpha=ln.get_alpha()
        )
        yb = y[band] if y.shape == f.shape else y
        yb = yb[np.isfinite(yb) & (yb > 0)]
        if yb.size:
            ymin, ymax = min(ymin, float(yb.min())), max(ymax, float(yb.max()))
    ins.set_yscale("log")
    ins.set_xlim(lo, hi)
    if ymax > 0 and np.isfinite(ymin):
        ins.set_ylim(ymin / 2.0, ymax * 2.0)
    ins.tick_params(labelsize=6)
    ins.set_title(f"zoom {lo:g}-{hi:g} Hz", fontsize=7, pad=2)
    ins.grid(True, alpha=0.3)
    return ins


def _grid(n: int, ncols: int | None) -> tuple[int, int]:
    if n < 1:
        raise ParameterError("a figure needs at least one panel")
    ncols = min(n, 3) if ncols is None else int(ncols)
    if ncols < 1:
        raise ParameterError(f"ncols must be >= 1; got {ncols}")
    return -(-n // ncols), ncols


def spectrum_figure(
    panels: Sequence[SpectrumPanel],
    *,
    ncols: int | None = None,
    suptitle: str = "",
    panel_size: tuple[float, float] = (5.2, 3.9),
    sharey: bool = False,
    legend_cols: int | None = None,
) -> Figure:
    """A figure with one axes per :class:`SpectrumPanel` (row-major, ``ncols`` per row).

    Parameters
    ----------
    panels : sequence of SpectrumPanel
        One panel per axes.
    ncols : int, optional
        Axes per row (default ``min(len(panels), 3)``).
    suptitle : str
        Figure title (name the paper figure and the threshold conventions).
    panel_size : (width, height)
        Size of one axes cell in inches.
    sharey : bool
        Share the (log) power axis between panels.
    legend_cols : int, optional
        Columns of the figure legend (below the panels; one entry per distinct label).

    Returns
    -------
    matplotlib.figure.Figure
        ``len(panels)`` main axes (plus one inset axes per panel with ``inset_hz``);
        unused grid cells are removed.
    """
    panels = list(panels)
    nrows, ncols = _grid(len(panels), ncols)
    fig, axes = plt.subplots(
        nrows,
        ncols,
        figsize=(panel_size[0] * ncols, panel_size[1] * nrows + (0.5 if suptitle else 0.0)),
        squeeze=False,
        sharey=sharey,
        layout="constrained",
    )
    flat = axes.ravel()
    handles: dict[str, Line2D] = {}
    for ax, panel in zip(flat, panels, strict=False):
        for ln in draw_spectrum(ax, panel, legend=False):
            handles.setdefault(str(ln.get_label()), ln)
    for ax in flat[len(panels) :]:
        fig.delaxes(ax)
    # one legend for the whole figure: every panel uses the same conventions
    fig.legend(
        handles=list(handles.values()),
        loc="outside lower center",
        ncols=legend_cols if legend_cols else ncols,
        fontsize=8,
        frameon=False,
    )
    if suptitle:
        fig.suptitle(_wrap(suptitle, fig.get_figwidth()), fontsize=10)
    return fig


def _wrap(text: str, width_in: float) -> str:
    """Wrap each line of ``text`` to the width of a ``width_in``-inch figure (10 pt font)."""
    chars = max(int(width_in * 15), 20)
    return "\n".join(textwrap.fill(line, chars) for line in text.split("\n"))


# --------------------------------------------------------------------------- spectrograms
def _interval_bar(ax: Axes, intervals: Sequence[tuple[float, float]], y: float, color: str) -> None:
    for a, b in intervals:
        ax.plot([a, b], [y, y], color=color, lw=6, solid_capstyle="butt", transform=ax.get_xaxis_transform())


def spectrogram_figure(
    panels: Sequence[SpectrogramPanel],
    *,
    suptitle: str = "",
    db_range: float = 80.0,
    panel_size: tuple[float, float] = (6.4, 4.6),
) -> Figure:
    """Spectrograms (STFT power in dB) with true fault windows and detected intervals (Fig 8).

    Each panel shows ``10 log10(power)`` over time (s) and frequency (Hz), clipped
    to ``db_range`` dB below its maximum. Above the image two bars mark the true
    fault windows (red) and the detected intervals (white, with flagged frames as
    ticks).

    Parameters
    ----------
    panels : sequence of SpectrogramPanel
        One panel per column (at least one; :class:`ParameterError` otherwise);
        each ``power`` must have shape (frames, bins).
    suptitle : str
        Figure title, wrapped to the figure width; empty for none.
    db_range : float
        Dynamic range of the colour scale in dB below each panel's maximum (default 80).
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
    for ax, p in zip(axes[0], panels, strict=True):
        t = np.asarray(p.times_s, dtype=float)
        f = np.asarray(p.freqs_hz, dtype=float)
        s = np.asarray(p.power, dtype=float)
        if s.shape != (t.size, f.size):
            raise ShapeError(
                f"spectrogram power must have shape (frames, bins) = {(t.size, f.size)}; got {s.shape}"
            )
        db = 10.0 * np.log10(np.maximum(s, np.finfo(float).tiny))
        top = float(np.max(db))
        mesh = ax.pcolormesh(t, f, db.T, shading="nearest", cmap="viridis", vmin=top - db_range, vmax=top)
        cb = fig.colorbar(mesh, ax=ax, pad=0.01)
        cb.set_label(f"10 log10 S [dB re 1 {power_unit(p.unit)}]")
        ax.set_ylim(0.0, p.fmax_hz if p.fmax_hz is not None else float(f[-1]))
        ax.set_xlabel("time (frame centre) [s]")
        ax.set_ylabel(f"frequency [Hz] ({p.channel} chattering)" if p.channel else "frequency [Hz]")
        if p.title:
            ax.set_title(p.title, fontsize=10)
        _interval_bar(ax, p.fault_intervals, 0.97, "tab:red")
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
        handles = [
            Line2D([], [], color="tab:red", lw=6, label="true fault window"),
            Line2D([], [], color="white", lw=6, label=p.detector_label, markeredgecolor="k"),
        ]
        leg = ax.legend(handles=handles, fontsize=7, loc="center right", facecolor="0.35", framealpha=0.8)
        for text in leg.get_texts():
            text.set_color("white")
    if suptitle:
        fig.suptitle(_wrap(suptitle, fig.get_figwidth()), fontsize=10)
    return fig


# --------------------------------------------------------------------------- boundary layer
def boundary_layer_figure(panel: BoundaryLayerPanel, *, suptitle: str = "", unit: str = "") -> Figure:
    """Fig 2: estimation errors and measured-state chattering for several boundary layers.

    Three stacked axes sharing time: (a) normalized estimation error of the
    measured state x1, (b) of the unmeasured state x2, (c) boundary-layer
    chattering of x1 (eq 13), one line per psi. True mismatch windows are shaded.

    Parameters
    ----------
    panel : BoundaryLayerPanel
        Time axis (s), boundary layers, labels, error and chattering arrays of
        shape (len(psi), T) (:class:`ShapeError` otherwise), fault windows.
    suptitle : str
        Figure title; empty for none.
    unit : str
        Unit of x1, used in the chattering axis label (default ``"unit of x1"``).

    Returns
    -------
    matplotlib.figure.Figure
        Three axes, ``len(panel.psi)`` lines each.
    """
    t = np.asarray(panel.t, dtype=float)
    k = len(panel.psi)
    for name in ("error_measured", "error_unmeasured", "chattering"):
        arr = np.asarray(getattr(panel, name))
        if arr.shape != (k, t.size):
            raise ShapeError(f"{name} must have shape (len(psi), T) = {(k, t.size)}; got {arr.shape}")
    if len(panel.labels) != k:
        raise ShapeError(f"labels must have {k} entries; got {len(panel.labels)}")
    fig, axes = plt.subplots(3, 1, figsize=(9.0, 8.5), sharex=True, layout="constrained")
    data = (panel.error_measured, panel.error_unmeasured, panel.chattering)
    ylabels = (
        f"(a) x1 (measured)\n{panel.error_label}",
        f"(b) x2 (unmeasured)\n{panel.error_label}",
        f"(c) x1 chattering, eq 13\n[{unit or 'unit of x1'}]",
    )
    order = list(range(k))
    for ax, arr, ylab in zip(axes, data, ylabels, strict=True):
        for i in order:
            ax.plot(
                t,
                np.asarray(arr)[i],
                lw=0.8,
                color=panel.colors[i % len(panel.colors)],
                label=panel.labels[i],
            )
        for j, (a, b) in enumerate(panel.fault_intervals):
            lab = panel.fault_labels[j] if j < len(panel.fault_labels) else "model mismatch"
            ax.axvspan(a, b, color="0.85", zorder=0, label=f"true mismatch: {lab}")
        ax.set_ylabel(ylab, fontsize=9)
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right", ncols=2)
    axes[-1].set_xlabel("time [s]")
    axes[-1].set_xlim(float(t[0]), float(t[-1]))
    if suptitle:
        fig.suptitle(suptitle, fontsize=11)
    return fig


# --------------------------------------------------------------------------- saving
def save_figure(fig: Figure, path: str | Path, *, dpi: int = DEFAULT_DPI, close: bool = True) -> Path:
    """Save ``fig`` as PNG at ``dpi`` (creating parent folders) and close it; return the path.

    Raises
    ------
    ParameterError
        If ``path`` does not end in ``.png`` or ``dpi`` is not positive.
    """
    path = Path(path)
    if path.suffix.lower() != ".png":
        raise ParameterError(f"figures are written as PNG; the file name must end in .png, got {str(path)!r}")
    if not dpi > 0:
        raise ParameterError(f"dpi must be > 0; got {dpi!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(
        path, dpi=dpi, format="png", metadata={"Software": "chatterspec"}, pil_kwargs={"optimize": True}
    )
    if close:
        plt.close(fig)
    return path
