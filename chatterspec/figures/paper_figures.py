"""The core paper's figures, recomputed with chatterspec (Figs 2, 4-12).

One function per figure computes its data through the public API
(:func:`chatterspec.detection.pipeline.scenario_chattering`, :mod:`chatterspec.detection.spectral`,
:mod:`chatterspec.detection.thresholds`, :mod:`chatterspec.detection.detect`,
:func:`chatterspec.studies.boundary_layer.boundary_layer_study`) and draws it with
:mod:`chatterspec.figures.plotting`. :data:`FIGURES` maps ``"fig2" .. "fig12"`` to a
:class:`FigureSpec`; ``chatterspec figures`` renders them all.

Thresholds are drawn the way the paper draws them **and** the way chatterspec
detects by default (``docs/design.md`` §6):

* the paper's flat bound of eq 58-62, ``Sigma_Gamma_ii chi2_{1-alpha}(2) / 2``,
  where ``alpha`` is a **per-bin** false-alarm probability (dashed, red shades);
* the exact chi-squared bound on the expected spectrum of eq 56 (finite-N form),
  ``E[S_i(f)] chi2_{1-alpha/n}(2) / 2`` with a Bonferroni correction over the
  ``n`` tested bins, so that ``alpha`` is a **family-wise** false-alarm
  probability for the whole spectrum (solid, green shades).

Each builder returns a :class:`PaperFigure` with the figure and one-line notes
(peak frequency and peak ratio ``max S / threshold`` over the tested bins, DC
and Nyquist excluded, for each threshold).

The figures' data (:class:`PaperFigure`, :func:`peak_summary`, :func:`averaged_paper_threshold`):
spectra, thresholds, peak ratios, natural-frequency lines, panels; the scenarios run through the public
API and their results turned into the plain panel records of :mod:`chatterspec.figures.plotting`.

The overlay figures (Figs 7, 10-12): fault levels of one family on one axes. Each of these figures shows
one realization (same seed) of several fault levels of a scenario family over the healthy spectrum, with
the thresholds at alpha = 0.1 % built from the shared nominal model. They differ only in data (which
scenarios, labels, colours, channel and title), held by one :class:`OverlaySpec` per figure in
:data:`OVERLAYS`; :func:`overlay_figure` draws any of them, and :func:`overlay_builder` turns a spec into
the ``builder(runs, seed)`` of the paper-figure registry.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.stats
from matplotlib.figure import Figure

from ..detection.pipeline import ChatteringRecord, iter_chattering, scenario_chattering
from ..detection.spectral import STFTConfig, periodogram, spectrogram, spectrum_model
from ..detection.thresholds import Correction, Threshold, exact_threshold, frame_threshold, paper_threshold
from ..errors import ParameterError
from ..montecarlo import SeedLike
from ..plants.nonlinear import Model
from ..plants.scenarios import Scenario, scenario
from . import plotting as pl

__all__ = [
    "FIGURES",
    "OVERLAYS",
    "OVERLAY_FMAX_HZ",
    "FigureSpec",
    "OverlaySpec",
    "PaperFigure",
    "averaged_paper_threshold",
    "fig2",
    "fig4",
    "fig5",
    "fig6",
    "fig7",
    "fig8",
    "fig9",
    "fig10",
    "fig11",
    "fig12",
    "figure_names",
    "overlay_builder",
    "overlay_figure",
    "peak_summary",
    "render",
    "scenario_spectrum",
]


#: Alphas the paper draws in Figs 4, 5 and 9 (error probability 1 % and 0.1 %).
PAPER_ALPHAS: tuple[float, ...] = (1e-2, 1e-3)
#: Alpha of the fault figures (the paper detects at 0.1 %).
FAULT_ALPHA: float = 1e-3
#: Fig 2 boundary layers psi1: too small, the paper's 5e-4, chatterspec's proposal (None), too large.
FIG2_PSIS: tuple[float | None, ...] = (1e-4, 5e-4, None, 2e-3)
#: Healthy per-sample chattering probability behind the proposed psi1 of Fig 2.
FIG2_PROBABILITY: float = 1e-3
#: Zoom of the inset on the second-order fault figures (Hz): the peaks sit at 9-15 Hz.
SO_INSET_HZ: tuple[float, float] = (0.0, 40.0)
#: Upper frequency (Hz) of the fault-level overlays (Figs 7, 10-12): the faults' footprints lie below it
#: (EHA chirp 10-100 Hz, natural frequencies 9-48 Hz); above it the chattering is healthy noise.
OVERLAY_FMAX_HZ: float = 150.0

_THRESHOLD_NOTE = (
    "dashed = paper's flat bound (eq 58-62), α = false-alarm probability PER BIN;\n"
    "solid = exact χ² bound on E[S] (eq 56), α = FAMILY-WISE false-alarm probability of the whole "
    "spectrum (Bonferroni over the tested bins; DC and Nyquist not tested)"
)


@dataclass(frozen=True)
class PaperFigure:
    """A rendered paper figure.

    Attributes
    ----------
    name : str
        Registry key (``"fig5"``).
    figure : matplotlib.figure.Figure
    notes : tuple of str
        One line per panel with what it shows (peak frequency in Hz, peak ratios).
    """

    name: str
    figure: Figure
    notes: tuple[str, ...]


# --------------------------------------------------------------------------- data helpers
@dataclass(frozen=True)
class _Spectrum:
    """Spectrum of one scenario: single realization (or average) plus thresholds."""

    scenario: Scenario
    record: ChatteringRecord
    freqs_hz: np.ndarray
    power: np.ndarray  # (bins, m): realization 0, or the mean over runs when averaged
    single: np.ndarray  # (bins, m): realization 0
    expected: np.ndarray  # (bins, m)
    averaged: int


def _spectrum(name: str, runs: int = 1, seed: SeedLike = 0, *, average: bool = False) -> _Spectrum:
    sc = scenario(name)
    if not average:
        runs = 1  # only realization 0 is drawn: simulate nothing else
    # chunk by chunk (memory independent of runs): sum of the periodograms + realization 0
    total, rec, pg = None, None, None
    for chunk in iter_chattering(sc, runs, seed):
        pg = periodogram(chunk.values, chunk.dt)
        part = pg.power.reshape(-1, *pg.power.shape[-2:]).sum(axis=0)
        total = part if total is None else total + part
        if rec is None:
            rec = replace(chunk, values=np.array(chunk.values[:1]))  # a copy: frees the chunk
            single = np.array(pg.power[0])
    assert total is not None and rec is not None and pg is not None  # (runs >= 1 records)
    power = total / runs if average else single
    th = exact_threshold(spectrum_model(sc.nominal), pg.freqs_hz, pg.n_samples, 0.5, "none")
    return _Spectrum(
        scenario=sc,
        record=rec,
        freqs_hz=np.asarray(pg.freqs_hz),
        power=power,
        single=single,
        expected=np.asarray(th.expected),
        averaged=runs if average else 1,
    )


def _thresholds(
    sp: _Spectrum, alphas: Sequence[float], kinds: Sequence[str] = ("paper", "exact")
) -> list[Threshold]:
    """Thresholds for ``sp``: for each kind, one per alpha (paper per-bin, exact Bonferroni family-wise)."""
    model, f, n = spectrum_model(sp.scenario.nominal), sp.freqs_hz, sp.record.n_samples
    out: list[Threshold] = []
    for kind in kinds:
        for a in alphas:
            if kind == "paper":
                out.append(paper_threshold(model, f, a))
            elif kind == "exact":
                out.append(exact_threshold(model, f, n, a, "bonferroni", averaged=sp.averaged))
            elif kind == "exact-per-bin":
                out.append(exact_threshold(model, f, n, a, "none", averaged=sp.averaged))
            else:
                raise ParameterError(
                    f"unknown threshold kind {kind!r}; choose 'paper', 'exact', 'exact-per-bin'"
                )
    return out


def peak_summary(power: np.ndarray, threshold: Threshold, channel: int) -> tuple[float, float, int]:
    """``(peak_hz, peak_ratio, n_over)`` of one channel over the threshold's tested bins.

    ``peak_ratio = max_f S(f) / threshold(f)`` (``docs/design.md`` §6; > 1 means
    detected), ``peak_hz`` its frequency and ``n_over`` the number of tested bins above.

    Parameters
    ----------
    power : (bins, m) array_like
        Periodogram of the chattering (eq 51), in squared output units per bin
        (e.g. Pa^2 for pressure), on the threshold's frequency grid.
    threshold : Threshold
        Threshold on the same bins; only its ``tested`` bins (DC and Nyquist
        excluded) are considered.
    channel : int
        Index of the output channel (column of ``power``).

    Returns
    -------
    peak_hz : float
        Frequency in Hz of the largest ratio.
    peak_ratio : float
        Largest ``S / threshold`` over the tested bins.
    n_over : int
        Number of tested bins with ``S > threshold``.
    """
    p = np.asarray(power, dtype=float)[:, channel]
    v = np.asarray(threshold.values, dtype=float)[:, channel]
    tested = np.asarray(threshold.tested, dtype=bool)
    ratio = np.where(tested, p / v, -np.inf)
    i = int(np.argmax(ratio))
    return float(threshold.freqs_hz[i]), float(ratio[i]), int(np.count_nonzero(ratio > 1.0))


def _short(th: Threshold) -> str:
    kind = "paper" if th.kind == "paper" else "exact"
    meaning = "FW" if th.alpha_meaning == "family-wise" else "per-bin"
    avg = f" K={th.averaged}" if th.averaged > 1 else ""
    return f"{kind} {pl.format_alpha(th.alpha)} {meaning}{avg}"


def _note(
    power: np.ndarray, ths: Sequence[Threshold], channel: int, *, prefix: str = ""
) -> tuple[list[str], str]:
    """(panel text lines, one-line summary): each threshold's own maximum ratio ``S / threshold``.

    For every threshold: its largest ``S(f) / threshold(f)`` over its tested bins
    (DC and Nyquist excluded), the frequency of that bin and the number of tested
    bins above it -- each threshold is compared with the spectrum on its own, so
    a ratio above 1 always comes with at least one bin over.
    """
    if not ths:
        return [], ""
    width = max(len(_short(t)) for t in ths)
    lines, summary = [], []
    for th in ths:
        f, r, n_over = peak_summary(power, th, channel)
        lines.append(
            f"{prefix}{_short(th):<{width}}  max S/thr {r:7.3g} at {f:6.2f} Hz, {n_over:4d} bins over"
        )
        summary.append(f"{_short(th)}: max S/threshold {r:.3g} at {f:.2f} Hz, {n_over} bins over")
    return lines, "; ".join(summary)


def _true_model(sc: Scenario) -> Model:
    """The true plant of a whole-record scenario (the nominal model when healthy)."""
    return sc.plant if sc.plant is not None else sc.nominal


def _context(
    sc: Scenario, *, true_color: str = "tab:red", true_label: str | None = None, nominal: bool = True
) -> tuple[tuple[pl.FrequencyLine, ...], tuple[float, float] | None, str]:
    """Frequency lines (nominal and true natural frequency, Hz) and the chirp band of ``sc``.

    The true natural frequency is drawn only where it differs from the nominal by
    more than 0.05 Hz (about a fifth of a 4 s record's 0.25 Hz bin).
    """
    lines = []
    f_nom, z_nom = sc.nominal.natural_frequency_hz, sc.nominal.damping_ratio
    if nominal and f_nom is not None:
        label = f"nominal natural frequency {f_nom:.1f} Hz (ζ = {z_nom:.2f})"
        lines.append(pl.FrequencyLine(f_nom, label, "black", ":"))
    true = _true_model(sc)
    f_true, z_true = true.natural_frequency_hz, true.damping_ratio
    if f_true is not None and z_true is not None:  # (a natural frequency comes with its damping)
        if f_nom is None or z_nom is None or abs(f_true - f_nom) > 0.05 or abs(z_true - z_nom) > 0.01:
            label = true_label or f"true natural frequency {f_true:.1f} Hz (ζ = {z_true:.2f})"
            lines.append(pl.FrequencyLine(f_true, label, true_color, (0, (4, 2))))
    lo, hi = getattr(sc.input, "f_start_hz", None), getattr(sc.input, "f_stop_hz", None)
    if lo is not None and hi is not None:
        return tuple(lines), (float(lo), float(hi)), f"chirp input band {lo:g}-{hi:g} Hz"
    return tuple(lines), None, ""


def _channel_index(sc: Scenario, channel: str | int | None) -> int:
    names = sc.nominal.output_names
    if channel is None:
        channel = sc.fault_channel or names[-1]
    if isinstance(channel, int | np.integer):
        if not 0 <= int(channel) < len(names):
            raise ParameterError(f"channel index {channel} out of range for outputs {names}")
        return int(channel)
    if channel not in names:
        raise ParameterError(
            f"unknown channel {channel!r} for scenario {sc.name!r}; valid: {', '.join(names)}"
        )
    return names.index(channel)


def _panel(
    sp: _Spectrum,
    channel: int,
    ths: Sequence[Threshold],
    title: str,
    *,
    curve_label: str | None = None,
    background: bool = False,
    inset: tuple[float, float] | None = None,
    fmax_hz: float | None = None,
) -> tuple[pl.SpectrumPanel, str]:
    model = sp.scenario.nominal
    curves = []
    if background:
        curves.append(
            pl.SpectrumCurve(
                sp.single[:, channel], "one realization", color="0.65", linewidth=0.6, alpha=0.8, mark=False
            )
        )
    label = curve_label or (
        f"S(f) averaged over K = {sp.averaged} realizations"
        if sp.averaged > 1
        else "S(f), one realization (eq 49)"
    )
    curves.append(pl.SpectrumCurve(sp.power[:, channel], label, color="tab:blue"))
    text, line = _note(sp.power, ths, channel)
    lines, band, band_label = _context(sp.scenario)
    if sp.scenario.is_healthy:  # a healthy spectrum has no footprint for a natural-frequency line to explain
        lines = ()
    panel = pl.SpectrumPanel(
        freqs_hz=sp.freqs_hz,
        curves=tuple(curves),
        expected=sp.expected[:, channel],
        thresholds=tuple(pl.threshold_curve(t, channel) for t in ths),
        title=title,
        channel=model.output_names[channel],
        unit=model.output_units[channel],
        fmax_hz=fmax_hz,
        note="\n".join(text),
        inset_hz=inset,
        lines=lines,
        band_hz=band,
        band_label=band_label,
    )
    return panel, f"{title}: {line}"


def _overlay(
    name: str,
    title: str,
    levels: Sequence[tuple[str, str, str]],
    channel: str,
    seed: SeedLike,
    *,
    healthy: str,
    fmax_hz: float,
    inset: tuple[float, float] | None = None,
) -> PaperFigure:
    """Fault levels overlaid on one axes (with the healthy spectrum in grey), as the paper compares them.

    ``levels`` holds ``(scenario, legend label, colour)``. Every scenario shares the
    nominal model and record length, so one set of thresholds (built from the
    healthy scenario's nominal model) applies to all curves. Each curve's true
    natural frequency is drawn in its colour, the nominal one in black.
    """
    base = _spectrum(healthy, 1, seed)
    ch = _channel_index(base.scenario, channel)
    ths = _thresholds(base, (FAULT_ALPHA,))
    curves = [pl.SpectrumCurve(base.power[:, ch], f"{healthy} (healthy)", color="0.6", linewidth=0.7)]
    text, _ = _note(base.power, ths, ch, prefix=f"{'healthy':<10}")
    notes = [f"{name} {healthy}: {_note(base.power, ths, ch)[1]}"]
    context, band, band_label = _context(base.scenario)
    lines = list(context)
    for i, (sc_name, label, color) in enumerate(levels):
        sp = _spectrum(sc_name, 1, seed)
        if sp.scenario.nominal.fingerprint() != base.scenario.nominal.fingerprint():
            raise ParameterError(f"{sc_name} and {healthy} must share the nominal model to share thresholds")
        # earlier levels wider underneath, later ones thinner on top: where the levels coincide (outside the
        # excited band) every colour stays visible
        width = 0.8 + 0.35 * (len(levels) - 1 - i)
        curves.append(pl.SpectrumCurve(sp.power[:, ch], f"{sc_name} ({label})", color=color, linewidth=width))
        t, line = _note(sp.power, ths, ch, prefix=f"{label[:10]:<10}")
        text += t
        notes.append(f"{name} {sc_name}: {line}")
        true = _true_model(sp.scenario)
        lines += _context(
            sp.scenario,
            true_color=color,
            true_label=f"true natural frequency {true.natural_frequency_hz:.1f} Hz, "
            f"ζ = {true.damping_ratio:.2f} ({label})",
            nominal=False,
        )[0]
    model = base.scenario.nominal
    panel = pl.SpectrumPanel(
        freqs_hz=base.freqs_hz,
        curves=tuple(curves),
        expected=base.expected[:, ch],
        thresholds=tuple(pl.threshold_curve(t, ch) for t in ths),
        channel=model.output_names[ch],
        unit=model.output_units[ch],
        fmax_hz=fmax_hz,
        note="\n".join(text),
        inset_hz=inset,
        lines=tuple(lines),
        band_hz=band,
        band_label=band_label,
    )
    fig = pl.spectrum_figure(
        [panel],
        ncols=1,
        suptitle=f"{title}\n{_THRESHOLD_NOTE}",
        panel_size=(12.0, 5.6),
        legend_cols=2,
    )
    return PaperFigure(name, fig, tuple(notes))


def averaged_paper_threshold(single: Threshold, averaged: int) -> Threshold:
    """The paper's flat bound (eq 58-62) carried over to the mean of K independent periodograms.

    A single record's bin obeys ``2 S / Sigma_Gamma_ii ~ chi2(2)`` (eq 62); the
    mean of K independent records then obeys ``2K S_bar / Sigma_Gamma_ii ~ chi2(2K)``,
    so the per-bin bound at level alpha is
    ``Sigma_Gamma_ii chi2.ppf(1 - alpha, 2K) / (2K)`` (the paper's scale with
    the averaged quantile; ``docs/design.md`` §6). This is chatterspec's extension:
    the paper draws no averaged bound. ``alpha`` stays a per-bin level.

    Parameters
    ----------
    single : Threshold
        The single-record paper threshold (:func:`chatterspec.detection.thresholds.paper_threshold`).
    averaged : int
        Number K >= 1 of independent records averaged.

    Returns
    -------
    Threshold
        ``kind="paper"``, ``averaged=K``, ``dof = 2K`` (K at DC and Nyquist, not tested).

    Raises
    ------
    ParameterError
        ``single`` is not a single-record paper threshold, or K < 1.
    """
    if single.kind != "paper" or single.averaged != 1:
        raise ParameterError("averaged_paper_threshold needs the single-record paper threshold")
    if isinstance(averaged, bool) or int(averaged) != averaged or averaged < 1:
        raise ParameterError(f"averaged must be an integer >= 1; got {averaged!r}")
    k = int(averaged)
    a = single.alpha
    scale = scipy.stats.chi2.isf(a, 2 * k) / (2 * k) / (scipy.stats.chi2.isf(a, 2) / 2.0)
    values = np.asarray(single.values, dtype=float) * scale
    dof = np.asarray(single.dof) * k
    return replace(
        single,
        values=values,
        averaged=k,
        dof=dof,
        effective_dof=np.broadcast_to(dof[:, None].astype(float), values.shape).copy(),
    )


def _timeline_lines(sc: Scenario) -> tuple[pl.FrequencyLine, ...]:
    """Nominal natural frequency and each fault window's differing natural frequency (Hz), for Fig 8."""
    f_nom, z_nom = sc.nominal.natural_frequency_hz, sc.nominal.damping_ratio
    if f_nom is None:
        return ()
    lines = [
        pl.FrequencyLine(f_nom, f"nominal natural frequency {f_nom:.1f} Hz (ζ = {z_nom:.2f})", "white", ":")
    ]
    for seg in sc.segments:
        f_seg = seg.model.natural_frequency_hz
        if f_seg is not None and abs(f_seg - f_nom) > 0.05:
            label = f"true natural frequency {f_seg:.1f} Hz on [{seg.start:g}, {seg.stop:g}) s"
            lines.append(pl.FrequencyLine(f_seg, label, "tab:red", (0, (4, 2)), (seg.start, seg.stop)))
    return tuple(lines)


# ------------------------------------------------------------------------------ the overlay figures

#: Second half of the title of the EHA overlays: what the shown range leaves out.
_NYQUIST_NOTE = (
    f"one realization each (same seed), 0-{OVERLAY_FMAX_HZ:g} Hz shown (all bins up to Nyquist are tested)"
)


@dataclass(frozen=True)
class OverlaySpec:
    """What one overlay figure shows.

    Attributes
    ----------
    name : str
        Registry key and output file stem (``"fig10"``).
    title : str
        First part of the figure title: figure number, scenario family, fault sizes
        (with units) and channel; also the first line of the builder's docstring.
    levels : tuple of (str, str, str)
        ``(scenario, legend label, colour)`` per fault level, drawn in this order.
    channel : str
        Output channel shown (``"velocity"``, ``"pressure"``).
    healthy : str
        Healthy scenario drawn in grey; its nominal model gives the thresholds (default ``eha-healthy``).
    title_tail : str
        Second part of the title, after a comma (default: one realization each, range shown).
    inset : (float, float), optional
        Zoom window in Hz, or None for no zoom.
    """

    name: str
    title: str
    levels: tuple[tuple[str, str, str], ...]
    channel: str
    healthy: str = "eha-healthy"
    title_tail: str = _NYQUIST_NOTE
    inset: tuple[float, float] | None = None


OVERLAYS: dict[str, OverlaySpec] = {
    s.name: s
    for s in (
        OverlaySpec(
            "fig7",
            "Fig 7 — mismatch levels f0 = 9 / 12 / 15 Hz (nominal 10 Hz), low noise, velocity chattering",
            (
                ("so-f9-low", "f0 9 Hz", "tab:blue"),
                ("so-f12-low", "f0 12 Hz", "tab:purple"),
                ("so-f15-low", "f0 15 Hz", "tab:brown"),  # not red: the paper's bound is red
            ),
            "velocity",
            healthy="so-healthy-low",
            title_tail="one realization each (same seed); the footprint moves with the true f0",
            inset=SO_INSET_HZ,
        ),
        OverlaySpec(
            "fig10",
            "Fig 10 — EHA leakage (L = 3e-11 / 6e-11 / 9e-11 m³/(s·Pa)), pressure chattering",
            (
                ("eha-leak-minor", "minor", "plum"),
                ("eha-leak-medium", "medium", "mediumorchid"),
                ("eha-leak-major", "major", "indigo"),
            ),
            "pressure",
        ),
        OverlaySpec(
            "fig11",
            "Fig 11 — EHA friction (a = 4000 / 7000 N·s/m), velocity chattering",
            (("eha-friction-minor", "minor", "tab:cyan"), ("eha-friction-major", "major", "teal")),
            "velocity",
        ),
        OverlaySpec(
            "fig12",
            "Fig 12 — EHA bulk-modulus mismatch (βe × 0.5 / 0.75 / 1.25 / 1.5), pressure chattering",
            (
                ("eha-bulk-50down", "βe × 0.5", "navy"),
                ("eha-bulk-25down", "βe × 0.75", "cornflowerblue"),
                ("eha-bulk-25up", "βe × 1.25", "salmon"),
                ("eha-bulk-50up", "βe × 1.5", "darkred"),
            ),
            "pressure",
        ),
    )
}

_BUILDER_DOC = """{title}: one realization per level, alpha 0.1 %.

Parameters
----------
runs : int, optional
    Ignored: accepted for the uniform ``builder(runs, seed)`` signature of
    :data:`chatterspec.figures.paper_figures.FIGURES`; the figure shows a single
    realization, as in the paper.
seed : int, SeedSequence, Generator or None
    Root seed of the simulation; realization 0 of this seed is shown in
    every panel (each fault level is a separate scenario with the same seed).

Returns
-------
PaperFigure
    The matplotlib figure and one note line per curve (peak ratios ``S / threshold``).
"""


def overlay_figure(spec: OverlaySpec, seed: SeedLike = 0) -> PaperFigure:
    """Draw the overlay figure ``spec`` (realization 0 of ``seed`` for every level).

    Parameters
    ----------
    spec : OverlaySpec
        The figure's data (an entry of :data:`OVERLAYS` or a new one).
    seed : int, SeedSequence, Generator or None
        Root seed shared by every scenario of the figure.

    Returns
    -------
    PaperFigure
        The figure (one axes, zoom optional) and one note line per curve.

    Raises
    ------
    ParameterError
        A level's nominal model differs from the healthy scenario's (no shared thresholds).
    UnknownScenarioError
        A scenario name is not in the catalogue.
    """
    return _overlay(
        spec.name,
        f"{spec.title}, {spec.title_tail}",
        spec.levels,
        spec.channel,
        seed,
        healthy=spec.healthy,
        fmax_hz=OVERLAY_FMAX_HZ,
        inset=spec.inset,
    )


def overlay_builder(spec: OverlaySpec) -> Callable[[int | None, SeedLike], PaperFigure]:
    """The registry builder ``builder(runs=None, seed=0)`` of ``spec`` (``runs`` is ignored).

    Parameters
    ----------
    spec : OverlaySpec

    Returns
    -------
    callable
        Named after ``spec.name``, with a docstring made from ``spec.title``.
    """

    def builder(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
        return overlay_figure(spec, seed)

    builder.__name__ = builder.__qualname__ = spec.name
    builder.__doc__ = _BUILDER_DOC.format(title=spec.title.replace(" — ", ": ", 1))
    return builder


# ------------------------------------------------------------------------------------- the registry


@dataclass(frozen=True)
class FigureSpec:
    """Registry entry of one paper figure.

    Attributes
    ----------
    name : str
        Registry key and output file stem.
    caption : str
        What the figure shows (from the paper's caption).
    builder : callable
        ``builder(runs, seed) -> PaperFigure``; ``runs=None`` selects ``default_runs``.
    default_runs : int
        Monte Carlo realizations used by default (1 = the single realization the paper shows).
    """

    name: str
    caption: str
    builder: Callable[[int | None, SeedLike], PaperFigure]
    default_runs: int = 1


# --------------------------------------------------------------------------- figures
_SINGLE_REALIZATION_DOC = """
    Parameters
    ----------
    runs : int, optional
        Ignored: accepted for the uniform ``builder(runs, seed)`` signature of
        :data:`FIGURES`; the figure shows a single realization, as in the paper.
    seed : int, SeedSequence, Generator or None
        Root seed of the simulation; realization 0 of this seed is shown in every panel.

    Returns
    -------
    PaperFigure
        The matplotlib figure and {returns}.
"""

_Builder = Callable[[int | None, SeedLike], PaperFigure]


def _single_realization(
    returns: str = "one note line per panel (peak ratios ``S / threshold``)",
) -> Callable[[_Builder], _Builder]:
    """Decorator: append the Parameters/Returns shared by the single-realization figures to the docstring."""

    def decorate(builder: _Builder) -> _Builder:
        doc = _SINGLE_REALIZATION_DOC.format(returns=returns)
        builder.__doc__ = (builder.__doc__ or "").rstrip() + "\n" + doc
        return builder

    return decorate


def fig2(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Fig 2: boundary-layer study on ``so-boundary-layer`` (reduced-order SVSF, x1 measured).

    Normalized estimation errors ``(x - x_hat) / rms_t(x)`` (mean over ``runs``
    realizations) of the measured (a) and unmeasured (b) states and the eq-13
    chattering of x1 for realization 0 (c), for the paper's three boundary layers
    psi1 = 1e-4 (too small), 5e-4 (the paper's choice) and 2e-3 (too large), plus
    chatterspec's proposal ``sigma Phi^-1(1 - p/2)`` at p = 0.1 % from the measured
    healthy chattering (:func:`chatterspec.studies.boundary_layer.estimate_boundary_layer`;
    sigma = 2.45e-4, not the 1.42e-4 of eq 34, ``docs/design.md`` C7).

    Parameters
    ----------
    runs : int, optional
        Monte Carlo realizations averaged in the error panels (a, b); default 20.
    seed : int, SeedSequence, Generator or None
        Root seed of the simulation (and of the healthy runs behind the
        proposed boundary layer).

    Returns
    -------
    PaperFigure
        The figure and, per boundary layer, a note with the chattering rate
        inside/outside the mismatch windows (Fisher exact test p-value) and the
        rms normalized error of x2.
    """
    from ..studies.boundary_layer import boundary_layer_study

    runs = 20 if runs is None else runs
    st = boundary_layer_study(FIG2_PSIS, runs=runs, seed=seed, probability=FIG2_PROBABILITY)
    kinds = ("too small", "paper's choice", f"proposed, p = {pl.format_alpha(FIG2_PROBABILITY)}", "too large")
    labels = tuple(f"ψ₁ = {p:.2g} ({k})" for p, k in zip(st.psis, kinds, strict=True))
    sc = scenario("so-boundary-layer")
    win_labels = tuple(s.label for s in sc.segments if (s.start, s.stop) in st.windows)
    panel = pl.BoundaryLayerPanel(
        t=st.t,
        psi=st.psis,
        labels=labels,
        error_measured=st.normalized_error[:, :, 0],
        error_unmeasured=st.normalized_error[:, :, 1],
        chattering=st.chattering,
        fault_intervals=st.windows,
        fault_labels=win_labels,
        error_label=f"(x − x̂)/rms(x), mean of {st.runs} runs",
    )
    fig = pl.boundary_layer_figure(
        panel,
        suptitle=(
            "Fig 2 — boundary-layer study, so-boundary-layer (f0 2 Hz nominal; f0 3 Hz on [1,2) s, ζ 0.1 on "
            f"[3,4) s)\nψ₂ (unmeasured) = {st.psi_lower:.3g} fixed; (c) shows realization 0"
        ),
    )
    notes = tuple(
        f"Fig 2 ψ1={p:.3g}: chattering rate inside mismatch {ri:.3g}, outside {ro:.3g} "
        f"(Fisher p {pv:.2g}); rms norm. error x2 inside {e_in:.3g} / outside {e_out:.3g}"
        for p, ri, ro, pv, e_in, e_out in zip(
            st.psis,
            st.rate_inside,
            st.rate_outside,
            st.p_value,
            st.rms_error_inside[:, 1],
            st.rms_error_outside[:, 1],
            strict=True,
        )
    )
    return PaperFigure("fig2", fig, notes)


def _paper_alpha_panels(
    figure: str,
    cells: Sequence[tuple[str, str, int]],
    seed: SeedLike,
    *,
    inset: tuple[float, float] | None = None,
) -> tuple[list[pl.SpectrumPanel], list[str]]:
    """One spectrum panel per ``(tag, scenario, channel)`` cell: realization 0, the paper's two alphas.

    Each scenario is simulated once (its spectrum and thresholds serve all its cells); panel
    titles read ``"{figure}{tag}: {scenario}, {channel name}"``. Shared by Figs 4, 5 and 9.
    """
    spectra: dict[str, tuple[_Spectrum, list[Threshold]]] = {}
    panels, notes = [], []
    for tag, name, ch in cells:
        if name not in spectra:
            sp = _spectrum(name, 1, seed)
            spectra[name] = (sp, _thresholds(sp, PAPER_ALPHAS))
        sp, ths = spectra[name]
        title = f"{figure}{tag}: {name}, {sp.scenario.nominal.output_names[ch]}"
        p, n = _panel(sp, ch, ths, title, inset=inset)
        panels.append(p)
        notes.append(n)
    return panels, notes


@_single_realization()
def fig4(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Fig 4: healthy spectra of both channels at (a) low and (b) high measurement noise.

    Thresholds at alpha = 1 % and 0.1 % (paper per-bin, exact family-wise).
    """
    cells = [
        (tag, name, ch) for tag, name in (("a", "so-healthy-low"), ("b", "so-healthy-high")) for ch in (0, 1)
    ]
    panels, notes = _paper_alpha_panels("Fig 4", cells, seed)
    fig = pl.spectrum_figure(
        panels,
        ncols=2,
        suptitle="Fig 4 — healthy chattering spectra, one 4 s realization\n" + _THRESHOLD_NOTE,
        panel_size=(5.6, 4.3),
    )
    return PaperFigure("fig4", fig, tuple(notes))


@_single_realization()
def fig5(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Fig 5: velocity spectrum with a true f0 of 11 Hz (nominal 10 Hz) at (a) low and (b) high noise.

    At high noise the 11 Hz peak stays below the paper's flat threshold while the
    exact family-wise threshold, much lower at low frequency, can still find it.
    """
    cells = (("a", "so-f11-low", 1), ("b", "so-f11-high", 1))  # channel 1: velocity
    panels, notes = _paper_alpha_panels("Fig 5", cells, seed, inset=SO_INSET_HZ)
    fig = pl.spectrum_figure(
        panels,
        ncols=1,
        suptitle="Fig 5 — mismatch f0 = 11 Hz (nominal 10 Hz), velocity chattering\n" + _THRESHOLD_NOTE,
        panel_size=(12.0, 4.4),
        legend_cols=2,
    )
    return PaperFigure("fig5", fig, tuple(notes))


def fig6(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Fig 6: spectrum averaged over K realizations of ``so-f11-high`` (velocity).

    Both thresholds are those of the average of K independent periodograms
    (chi-squared with 2K degrees of freedom per bin): the paper's flat bound
    ``Sigma_Gamma_ii chi2_{1-a}(2K) / (2K)`` (:func:`averaged_paper_threshold`)
    and the exact bound ``E[S] chi2_{1-a'}(2K) / (2K)``. Realization 0 is drawn
    in grey for comparison; the thresholds do not apply to it.

    Parameters
    ----------
    runs : int, optional
        Number K of realizations averaged (default 100); the thresholds use 2K
        degrees of freedom per bin.
    seed : int, SeedSequence, Generator or None
        Root seed of the K realizations.

    Returns
    -------
    PaperFigure
        The figure and a note with each threshold's maximum ratio ``S / threshold``.
    """
    K = 100 if runs is None else runs
    sp = _spectrum("so-f11-high", K, seed, average=True)
    model = spectrum_model(sp.scenario.nominal)
    ths = [
        averaged_paper_threshold(paper_threshold(model, sp.freqs_hz, FAULT_ALPHA), sp.averaged),
        exact_threshold(
            model,
            sp.freqs_hz,
            sp.record.n_samples,
            FAULT_ALPHA,
            averaged=sp.averaged,
        ),
    ]
    p, n = _panel(
        sp, 1, ths, f"Fig 6: so-f11-high, velocity, mean of K = {K}", background=True, inset=SO_INSET_HZ
    )
    fig = pl.spectrum_figure(
        [p],
        suptitle=f"Fig 6 — averaging K = {K} realizations: both bounds are for the mean of K records "
        f"(χ² with 2K = {2 * K} dof per bin; the paper's bound scaled by χ²₀.₉₉₉(2K)/(2K) "
        f"÷ χ²₀.₉₉₉(2)/2)\n" + _THRESHOLD_NOTE,
        panel_size=(12.0, 5.2),
        legend_cols=2,
    )
    return PaperFigure("fig6", fig, (n,))


@_single_realization(
    "one note per panel with the detected and true fault intervals (s) and the number of flagged frames"
)
def fig8(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Fig 8: STFT spectrograms (1 s Hamming, 0.2 s hop) of the velocity chattering.

    (a) ``so-timeline-constant`` (u = 1), (b) ``so-timeline-step`` (unit step at
    5 s). True fault windows (f0 8 Hz on [0, 2) s, zeta 0.1 on [4, 6) s) and the
    intervals detected by the per-frame exact threshold (alpha 0.1 % per frame,
    Bonferroni over the frame's bins) are marked above each spectrogram.
    """
    from ..detection.verdicts import detect_frames, frame_intervals, frame_statistic, healthy_frame_level

    config = STFTConfig(1.0, 0.2, "hamming")
    panels, notes = [], []
    for tag, name in (("a", "so-timeline-constant"), ("b", "so-timeline-step")):
        sc = scenario(name)
        rec = scenario_chattering(sc, 1, seed)
        sg = spectrogram(rec.values[0], rec.dt, config, t0=float(rec.t[0]))
        th = frame_threshold(
            spectrum_model(sc.nominal), sg.freqs_hz, config, rec.dt, FAULT_ALPHA, "bonferroni"
        )
        ch = _channel_index(sc, "velocity")
        flags = np.asarray(detect_frames(sg, th))[:, ch]
        # the window-extent estimates of `detect --json` and of the recording's lanes
        stat = np.asarray(frame_statistic(sg, th))[:, ch]
        found = frame_intervals(flags, sg.times_s, config, rec.dt, stat, healthy_frame_level(th))
        intervals = tuple((float(a), float(b)) for a, b in found)
        panels.append(
            pl.SpectrogramPanel(
                times_s=sg.times_s,
                freqs_hz=sg.freqs_hz,
                power=np.asarray(sg.power)[:, :, ch],
                title=f"Fig 8{tag}: {name} ({sc.input.describe() if hasattr(sc.input, 'describe') else ''})",
                channel="velocity",
                unit=sc.nominal.output_units[ch],
                fault_intervals=tuple(sc.fault_intervals),
                detected_intervals=intervals,
                flags=flags,
                fmax_hz=50.0,
                detector_label=f"detected (exact, α = {pl.format_alpha(FAULT_ALPHA)} per frame)",
            )
        )
        panels[-1] = replace(panels[-1], lines=_timeline_lines(sc))
        iv = ", ".join(f"[{a:.2f}, {b:.2f}] s" for a, b in intervals) or "none"
        tw = ", ".join(f"[{a:g}, {b:g}) s" for a, b in sc.fault_intervals)
        notes.append(
            f"Fig 8{tag} {name}: detected {iv}; true {tw}; {int(flags.sum())}/{flags.size} frames flagged"
        )
    fig = pl.spectrogram_figure(
        panels,
        suptitle="Fig 8 — spectrogram of the velocity chattering (1 s Hamming window, 0.2 s hop); "
        "amber: true fault windows, white: detected",
    )
    return PaperFigure("fig8", fig, tuple(notes))


@_single_realization()
def fig9(runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Fig 9: healthy EHA spectra of position, velocity and pressure, alpha 1 % and 0.1 %."""
    panels, notes = _paper_alpha_panels(
        "Fig 9", [(tag, "eha-healthy", ch) for ch, tag in enumerate("abc")], seed
    )
    fig = pl.spectrum_figure(
        panels,
        ncols=3,
        suptitle="Fig 9 — EHA, healthy, chirp 10-100 Hz, one 4 s realization\n" + _THRESHOLD_NOTE,
    )
    return PaperFigure("fig9", fig, tuple(notes))


# Figs 7 and 10-12 differ only in data: one builder per entry of the overlay table.
fig7 = overlay_builder(OVERLAYS["fig7"])
fig10 = overlay_builder(OVERLAYS["fig10"])
fig11 = overlay_builder(OVERLAYS["fig11"])
fig12 = overlay_builder(OVERLAYS["fig12"])

FIGURES: dict[str, FigureSpec] = {
    s.name: s
    for s in (
        FigureSpec("fig2", "boundary-layer study (errors and chattering for three psi)", fig2, 20),
        FigureSpec("fig4", "healthy second-order spectra, low and high noise", fig4),
        FigureSpec("fig5", "f0 11 Hz mismatch, velocity, low and high noise", fig5),
        FigureSpec("fig6", "f0 11 Hz, high noise, spectrum averaged over K realizations", fig6, 100),
        FigureSpec("fig7", "f0 9 / 12 / 15 Hz mismatch, velocity", fig7),
        FigureSpec("fig8", "spectrograms of the timeline scenarios", fig8),
        FigureSpec("fig9", "healthy EHA spectra", fig9),
        FigureSpec("fig10", "EHA leakage, pressure", fig10),
        FigureSpec("fig11", "EHA friction, velocity", fig11),
        FigureSpec("fig12", "EHA bulk modulus, pressure", fig12),
    )
}


def figure_names() -> tuple[str, ...]:
    """Registry keys in paper order."""
    return tuple(FIGURES)


def render(name: str, runs: int | None = None, seed: SeedLike = 0) -> PaperFigure:
    """Build the paper figure ``name`` (``"fig2"`` .. ``"fig12"``).

    Parameters
    ----------
    name : str
        Registry key.
    runs : int, optional
        Monte Carlo realizations for the figures that average (Fig 2: study runs,
        Fig 6: K); ``None`` uses the figure's default. Ignored by single-realization figures.
    seed : int, SeedSequence, Generator or None
        Seed of every simulation in the figure.

    Raises
    ------
    ParameterError
        Unknown figure name (the message lists the valid ones) or ``runs`` < 1.
    """
    spec = FIGURES.get(name)
    if spec is None:
        raise ParameterError(f"unknown figure {name!r}; valid figures: {', '.join(FIGURES)}")
    if runs is not None and (isinstance(runs, bool) or int(runs) != runs or runs < 1):
        raise ParameterError(f"runs must be an integer >= 1; got {runs!r}")
    return spec.builder(runs, seed)


# --------------------------------------------------------------------------- one scenario
def scenario_spectrum(
    name: str,
    *,
    channel: str | int | None = None,
    alpha: float = FAULT_ALPHA,
    threshold: str = "both",
    correction: Correction = "bonferroni",
    runs: int = 1,
    seed: SeedLike = 0,
) -> PaperFigure:
    """Spectrum of one catalogue scenario with its expected value and thresholds (``chatterspec spectrum``).

    Parameters
    ----------
    name : str
        Catalogue scenario.
    channel : str, int or "all", optional
        Output channel; default the scenario's fault channel (all channels for healthy scenarios).
    alpha : float
        False-alarm probability in (0, 1): per bin for ``paper``, family-wise for
        ``exact`` with a correction, per bin with ``correction="none"``.
    threshold : {"both", "exact", "paper"}
        Which threshold(s) to draw.
    correction : {"bonferroni", "sidak", "none"}
        Multiple-testing correction of the exact threshold.
    runs : int
        Realizations; with ``runs > 1`` the mean periodogram is drawn (over the first
        realization in grey) with the thresholds of a K-record mean (chi2 with 2K dof):
        the exact bound and the paper's bound scaled by :func:`averaged_paper_threshold`.
    seed : int, SeedSequence, Generator or None

    Raises
    ------
    UnknownScenarioError, ParameterError
    """
    if threshold not in ("both", "exact", "paper"):
        raise ParameterError(f"threshold must be 'exact', 'paper' or 'both'; got {threshold!r}")
    if correction not in ("bonferroni", "sidak", "none"):
        raise ParameterError(f"correction must be 'bonferroni', 'sidak' or 'none'; got {correction!r}")
    sc = scenario(name)
    if isinstance(runs, bool) or int(runs) != runs or runs < 1:
        raise ParameterError(f"runs must be an integer >= 1; got {runs!r}")
    if not 0.0 < float(alpha) < 1.0:
        raise ParameterError(f"alpha must be in (0, 1) (a probability, not a percentage); got {alpha!r}")
    if channel == "all" or (channel is None and sc.fault_channel is None):
        channels = list(range(sc.nominal.n_outputs))
    else:
        channels = [_channel_index(sc, channel)]
    sp = _spectrum(name, runs, seed, average=runs > 1)
    model, f, n = spectrum_model(sc.nominal), sp.freqs_hz, sp.record.n_samples
    ths: list[Threshold] = []
    if threshold in ("both", "paper"):
        ths.append(averaged_paper_threshold(paper_threshold(model, f, alpha), sp.averaged))
    if threshold in ("both", "exact"):
        ths.append(exact_threshold(model, f, n, alpha, correction, averaged=sp.averaged))
    panels, notes = [], []
    inset = SO_INSET_HZ if sc.family == "second-order" and not sc.is_healthy else None
    for ch in channels:
        p, note = _panel(sp, ch, ths, f"{name}, {model.output_names[ch]}", background=runs > 1, inset=inset)
        panels.append(p)
        notes.append(note)
    what = f"mean of {runs} realizations" if runs > 1 else "one realization"
    fig = pl.spectrum_figure(
        panels,
        ncols=min(len(panels), 3),
        suptitle=f"{name}: {sc.description} ({what}, seed {seed})\n{_THRESHOLD_NOTE}",
        panel_size=((12.0 if inset else 8.0), 4.8) if len(panels) == 1 else (5.2, 4.3),
    )
    return PaperFigure(f"spectrum-{name}", fig, tuple(notes))
