"""Matplotlib figures of chattering spectra, and over time: STFT spectrograms (Fig 8) and the
boundary-layer study (Fig 2).

Only :mod:`chatterspec.figures` imports matplotlib; the numeric core
(:mod:`chatterspec.detection.spectral`, :mod:`chatterspec.detection.thresholds`, ...) never
does. Importing it selects the non-interactive ``Agg`` backend
(:mod:`chatterspec.figures.style`), so figures can be rendered on headless
machines and in CI.

The functions here take plain data (small frozen "panel" records holding
arrays: :class:`SpectrumPanel`, :class:`SpectrogramPanel`, :class:`BoundaryLayerPanel`) and return a
:class:`matplotlib.figure.Figure`; they compute nothing statistical themselves.
:mod:`chatterspec.figures.paper_figures` computes the data of the core paper's figures and calls them.

Conventions (``docs/design.md`` §4 and §6):

* frequencies in Hz on a linear axis, power spectra on a log axis;
* a power spectrum ``S(f) = |rfft(x)|^2 / N`` (eq 49) of a chattering channel in
  unit ``u`` has unit ``u^2``;
* every threshold line says in its legend entry which threshold it is (the
  paper's flat bound of eq 58-62 or the exact chi-squared bound built on the
  expected spectrum of eq 56) and what its ``alpha`` means (a per-bin false-alarm
  probability, or a family-wise one over all bins tested).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from ..errors import ParameterError, ShapeError
from ..palette import fault_level_color, mpl
from .style import (
    _CURVE_COLORS,
    _WINDOW_SHADES,
    DEFAULT_DPI,
    FrequencyLine,
    _wrap,
    format_alpha,
    frequency_lines,
    plt,
    power_unit,
    save_figure,
)

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.thresholds import Threshold

__all__ = [
    "DEFAULT_DPI",
    "BoundaryLayerPanel",
    "FrequencyLine",
    "SpectrogramPanel",
    "SpectrumCurve",
    "SpectrumPanel",
    "ThresholdCurve",
    "boundary_layer_figure",
    "draw_spectrum",
    "format_alpha",
    "main_axes",
    "power_unit",
    "save_figure",
    "spectrogram_figure",
    "spectrum_axes",
    "spectrum_figure",
    "threshold_curve",
    "threshold_label",
    "zoom_axes",
]


ThresholdKind = Literal["paper", "exact", "empirical"]

# Line styles per threshold kind; colours per alpha (larger alpha = lighter).
_KIND_STYLE: dict[str, dict[str, Any]] = {
    "paper": {"linestyle": (0, (6, 2)), "linewidth": 1.6},
    "exact": {"linestyle": "-", "linewidth": 1.6},
    "empirical": {"linestyle": ":", "linewidth": 1.8},
}
# larger alphas (lower lines) of the same kind: a second dash pattern, so 1 % and 0.1 % differ twice
_KIND_STYLE_LIGHT: dict[str, dict[str, Any]] = {
    "paper": {"linestyle": (0, (1.5, 1.5)), "linewidth": 1.6},
    "exact": {"linestyle": (0, (7, 1.5, 1.5, 1.5)), "linewidth": 1.4},
    "empirical": {"linestyle": (0, (1, 3)), "linewidth": 1.8},
}
_KIND_COLORS: dict[str, tuple[str, ...]] = {
    "paper": ("tab:red", "darkorange", "gold"),
    "exact": ("darkgreen", "limegreen", "turquoise"),
    "empirical": ("tab:purple", "orchid", "pink"),
}


# --------------------------------------------------------------------------- labels
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
    mark : bool
        Mark the bins of this curve above each threshold (default True; False for
        a background curve the thresholds do not apply to, e.g. one record under
        a K-average threshold).
    """

    power: np.ndarray
    label: str
    color: str | None = None
    linewidth: float = 0.8
    alpha: float = 1.0
    mark: bool = True


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
        Text written below the axes (e.g. each threshold's maximum ratio), outside
        the data area.
    inset_hz : (f_lo, f_hi), optional
        Draw a zoom on this frequency band (Hz) beside the main axes, e.g. the
        9-15 Hz peaks of the second-order mismatch figures.
    lines : tuple of FrequencyLine
        Vertical frequency lines (nominal and true natural frequencies, ...).
    band_hz : (f_lo, f_hi), optional
        Frequency band shaded in grey (Hz), e.g. the 10-100 Hz chirp of the EHA input.
    band_label : str
        Legend text of the band.
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
    lines: tuple[FrequencyLine, ...] = ()
    band_hz: tuple[float, float] | None = None
    band_label: str = ""


# --------------------------------------------------------------------------- thresholds
def threshold_curve(threshold: Threshold, channel: int, *, label: str | None = None) -> ThresholdCurve:
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


def _threshold_styles(thresholds: Sequence[ThresholdCurve]) -> list[dict[str, Any]]:
    """Colour and line style of each threshold.

    Per kind, the smallest alpha (the highest line) gets the darkest colour and
    the kind's base style; larger alphas get lighter colours and a second dash
    pattern, so 1 % and 0.1 % lines differ in both colour and pattern.
    """
    ranks: dict[str, list[float]] = {}
    for th in thresholds:
        ranks.setdefault(th.kind if th.kind in _KIND_STYLE else "exact", []).append(th.alpha)
    ranks = {k: sorted(set(v)) for k, v in ranks.items()}
    styles = []
    for th in thresholds:
        kind = th.kind if th.kind in _KIND_STYLE else "exact"
        rank = ranks[kind].index(th.alpha)
        palette = _KIND_COLORS[kind]
        style = dict(_KIND_STYLE[kind] if rank == 0 else _KIND_STYLE_LIGHT[kind])
        style["color"] = palette[min(rank, len(palette) - 1)]
        styles.append(style)
    return styles


def _checked(panel: SpectrumPanel) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """Frequencies, curve powers and threshold values of ``panel`` as float arrays (shapes checked)."""
    f = np.asarray(panel.freqs_hz, dtype=float)
    if f.ndim != 1:
        raise ShapeError(f"freqs_hz must be 1-D; got shape {f.shape}")
    powers = []
    for c in panel.curves:
        p = np.asarray(c.power, dtype=float)
        if p.shape != f.shape:
            raise ShapeError(f"curve {c.label!r}: power has shape {p.shape}, freqs_hz {f.shape}")
        powers.append(p)
    if panel.expected is not None and np.shape(panel.expected) != f.shape:
        raise ShapeError(f"expected has shape {np.shape(panel.expected)}, freqs_hz {f.shape}")
    values = []
    for th in panel.thresholds:
        v = np.asarray(th.values, dtype=float)
        if v.ndim == 0:
            v = np.full(f.shape, float(v))
        if v.shape != f.shape:
            raise ShapeError(f"threshold {th.label!r} has shape {v.shape}, freqs_hz {f.shape}")
        values.append(v)
    return f, powers, values


def draw_spectrum(
    ax: Axes,
    panel: SpectrumPanel,
    *,
    legend: bool = True,
    xlim_hz: tuple[float, float] | None = None,
    note: bool = True,
) -> list[Artist]:
    """Draw one :class:`SpectrumPanel` into ``ax`` (log y, Hz on x); return the artists drawn.

    Draw order: the shaded input band, spectra, expected spectrum ``E[S]`` (eq 56,
    black dashed), thresholds (paper's flat bound dashed in red/orange, exact
    bound solid in green shades; the darkest shade is the smallest alpha, i.e.
    the highest line), the bins of each marked curve above each threshold (dots
    in the threshold's colour) and the frequency lines. The y axis is fitted to
    what is drawn inside the frequency range (no headroom); the panel's note is
    written **below** the axes, never over the data.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
        Axes to draw into; its y axis is set to log scale.
    panel : SpectrumPanel
        Frequencies (Hz), spectra, optional expected spectrum and thresholds,
        frequency lines, band and note. Arrays must match ``freqs_hz`` in shape
        (:class:`ShapeError` otherwise); a scalar threshold is drawn flat.
    legend : bool
        Add a legend of the drawn artists beside the axes (default True).
    xlim_hz : (f_lo, f_hi), optional
        Frequency range shown in Hz (default ``(0, panel.fmax_hz or Nyquist)``);
        the y range is fitted to the data inside it.
    note : bool
        Write ``panel.note`` below the axes (default True).

    Returns
    -------
    list of matplotlib.artist.Artist
        One artist per legend entry, in draw order: band, spectra, expected
        spectrum, thresholds, the "bins above a threshold" marker (if any bin is
        above) and the frequency lines.
    """
    f, powers, values = _checked(panel)
    if xlim_hz is None:
        xlim_hz = (0.0, panel.fmax_hz if panel.fmax_hz is not None else float(f[-1]))
    lo, hi = float(xlim_hz[0]), float(xlim_hz[1])
    if not hi > lo:
        raise ParameterError(f"frequency range must be (f_lo, f_hi) with f_lo < f_hi; got {xlim_hz}")
    shown = (f >= lo) & (f <= hi) & (f > 0)  # DC is never tested and not used for the y range
    artists: list[Artist] = []
    y_data: list[np.ndarray] = []
    if panel.band_hz is not None:
        b0, b1 = panel.band_hz
        artists.append(ax.axvspan(b0, b1, color="0.9", zorder=0, lw=0, label=panel.band_label or "band"))
    for i, (c, p) in enumerate(zip(panel.curves, powers, strict=True)):
        color = c.color or _CURVE_COLORS[i % len(_CURVE_COLORS)]
        (ln,) = ax.plot(f, _positive(p), color=color, lw=c.linewidth, alpha=c.alpha, label=c.label)
        artists.append(ln)
        y_data.append(p[shown])
    if panel.expected is not None:
        e = np.asarray(panel.expected, dtype=float)
        (ln,) = ax.plot(f, _positive(e), color="black", ls="--", lw=1.3, label="expected E[S] (eq 56)")
        artists.append(ln)
        y_data.append(e[shown])
    styles = _threshold_styles(panel.thresholds)
    for th, v, style in zip(panel.thresholds, values, styles, strict=True):
        (ln,) = ax.plot(f, _positive(v), label=th.label, zorder=3, **style)
        artists.append(ln)
        y_data.append(v[shown])
    # bins above each threshold, as ticks along the bottom (one row per marked curve, first curve lowest;
    # each tick in its CURVE's colour, so that a row is matched to its curve; taller where the bin is above
    # the higher thresholds too): nothing covers the curves
    order = np.argsort([np.nanmedian(v) if np.any(np.isfinite(v)) else np.inf for v in values])
    any_over = False
    row = 0
    for i, (c, p) in enumerate(zip(panel.curves, powers, strict=True)):
        if not c.mark:
            continue
        y = 0.02 + 0.035 * row
        row += 1
        color = c.color or _CURVE_COLORS[i % len(_CURVE_COLORS)]
        for rank, j in enumerate(order):
            over = shown & np.isfinite(values[j]) & (p > values[j])
            if np.any(over):
                any_over = True
                tick: dict[str, Any] = {
                    "ls": "none",
                    "marker": "|",
                    "ms": 4 + 3 * rank,
                    "mew": 1.0,
                    "zorder": 4,
                }
                ax.plot(f[over], np.full(int(over.sum()), y), color=color, **tick)
                ax.lines[-1].set_transform(ax.get_xaxis_transform())
    if any_over:
        label = (
            "bins above a threshold: ticks in the curve's colour, one row per curve "
            "(taller: above the higher threshold too)"
        )
        artists.append(Line2D([], [], ls="none", marker="|", ms=6, color="0.3", label=label))
    artists.extend(frequency_lines(ax, panel.lines))
    ax.set_yscale("log")
    ax.set_xlim(lo, hi)
    _fit_log_y(ax, y_data)
    ax.set_xlabel("frequency [Hz]")
    name = f"{panel.channel} " if panel.channel else ""
    ax.set_ylabel(f"{name}S(f) [{power_unit(panel.unit)}]")
    if panel.title:
        ax.set_title(panel.title, fontsize=10)
    ax.grid(True, which="major", alpha=0.3)
    if note and panel.note:
        # below the x label, in the layout: constrained layout makes room for it
        ax.annotate(
            panel.note,
            xy=(0.0, 0.0),
            xycoords=(ax.transAxes, ax.xaxis.label),
            xytext=(0.0, -4.0),
            textcoords="offset points",
            ha="left",
            va="top",
            fontsize=6.5,
            family="monospace",
        )
    if legend and artists:
        ax.legend(handles=artists, fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False)
    return artists


def _fit_log_y(ax: Axes, y_data: Sequence[np.ndarray]) -> None:
    """Fit the log y axis to the drawn values: top just above the largest, bottom at the 0.5 % quantile.

    Isolated deep dips of a periodogram (a bin near zero) would otherwise spend
    decades of the axis on nothing; the bottom is the 0.5 % quantile of the
    positive values divided by 3.
    """
    vals = np.concatenate([np.ravel(y) for y in y_data]) if y_data else np.array([])
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size:
        top = float(vals.max()) * 1.6
        bottom = float(np.quantile(vals, 0.005)) / 3.0
        ax.set_ylim(bottom, max(top, bottom * 10.0))


def _draw_zoom(ax: Axes, panel: SpectrumPanel) -> Axes:
    """Draw ``panel`` again into ``ax`` on the band ``panel.inset_hz`` (no note, no legend)."""
    assert panel.inset_hz is not None  # (drawn for a panel with an inset)
    lo, hi = panel.inset_hz
    if not hi > lo:
        raise ParameterError(f"inset_hz must be (f_lo, f_hi) with f_lo < f_hi; got {panel.inset_hz}")
    draw_spectrum(ax, replace(panel, title=""), legend=False, xlim_hz=(lo, hi), note=False)
    ax.set_title(f"zoom {lo:g}-{hi:g} Hz", fontsize=9)
    ax.set_ylabel("")
    ax.set_label("zoom")
    return ax


def _grid(n: int, ncols: int | None) -> tuple[int, int]:
    if n < 1:
        raise ParameterError("a figure needs at least one panel")
    ncols = min(n, 3) if ncols is None else int(ncols)
    if ncols < 1:
        raise ParameterError(f"ncols must be >= 1; got {ncols}")
    return -(-n // ncols), ncols


def spectrum_axes(fig: Figure) -> tuple[list[Axes], list[Axes]]:
    """The axes of a :func:`spectrum_figure`: main spectrum axes and zoom axes, each in panel order.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        A figure made by :func:`spectrum_figure`.

    Returns
    -------
    main, zoom : list of matplotlib.axes.Axes
        One main axes per panel; one zoom axes per panel with ``inset_hz``.

    See Also
    --------
    main_axes, zoom_axes : each list alone.
    """
    zoom = [ax for ax in fig.axes if ax.get_label() == "zoom"]
    return [ax for ax in fig.axes if ax.get_label() != "zoom"], zoom


def zoom_axes(fig: Figure) -> list[Axes]:
    """The zoom axes of ``fig``, made by :func:`spectrum_figure` (second list of :func:`spectrum_axes`)."""
    return spectrum_axes(fig)[1]


def main_axes(fig: Figure) -> list[Axes]:
    """The main axes of ``fig``, made by :func:`spectrum_figure` (first list of :func:`spectrum_axes`)."""
    return spectrum_axes(fig)[0]


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

    A panel with ``inset_hz`` gets a second axes to the right of its main axes
    that zooms on that band (drawn beside the data, not over it); its note goes
    below the axes.

    Parameters
    ----------
    panels : sequence of SpectrumPanel
        One panel per grid cell.
    ncols : int, optional
        Cells per row (default ``min(len(panels), 3)``).
    suptitle : str
        Figure title (name the paper figure and the threshold conventions).
    panel_size : (width, height)
        Size of one grid cell in inches.
    sharey : bool
        Share the (log) power axis between the main axes.
    legend_cols : int, optional
        Columns of the figure legend (below the panels; one entry per distinct label).

    Returns
    -------
    matplotlib.figure.Figure
        ``len(panels)`` main axes plus one zoom axes per panel with ``inset_hz``
        (see :func:`main_axes`, :func:`zoom_axes`).
    """
    panels = list(panels)
    nrows, ncols = _grid(len(panels), ncols)
    fig = plt.figure(
        figsize=(panel_size[0] * ncols, panel_size[1] * nrows + (0.5 if suptitle else 0.0)),
        layout="constrained",
    )
    gs = fig.add_gridspec(nrows, ncols)
    handles: dict[str, Artist] = {}
    first: Axes | None = None
    for k, panel in enumerate(panels):
        cell = gs[k // ncols, k % ncols]
        share = first if sharey else None
        if panel.inset_hz is not None:
            sub = cell.subgridspec(1, 2, width_ratios=(2.3, 1.0))
            ax = fig.add_subplot(sub[0], sharey=share)
            _draw_zoom(fig.add_subplot(sub[1]), panel)
        else:
            ax = fig.add_subplot(cell, sharey=share)
        first = first or ax
        for a in draw_spectrum(ax, panel, legend=False):
            handles.setdefault(str(a.get_label()), a)
    if sharey:  # each panel fitted its own range; the shared axis needs their union
        lims = np.array([ax.get_ylim() for ax in main_axes(fig)])
        assert first is not None  # (one panel at least)
        first.set_ylim(float(lims[:, 0].min()), float(lims[:, 1].max()))
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


# --------------------------------------------------------------------------- panel records over time


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
