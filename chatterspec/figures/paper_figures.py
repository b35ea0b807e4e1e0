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
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..detection.pipeline import scenario_chattering
from ..detection.spectral import STFTConfig, spectrogram, spectrum_model
from ..detection.threshold_type import Correction
from ..detection.thresholds import Threshold, exact_threshold, frame_threshold, paper_threshold
from ..errors import ParameterError
from ..montecarlo import SeedLike
from ..plants.scenarios import scenario
from . import plotting as pl
from .figure_data import (
    _THRESHOLD_NOTE,
    FAULT_ALPHA,
    FIG2_PROBABILITY,
    FIG2_PSIS,
    OVERLAY_FMAX_HZ,
    PAPER_ALPHAS,
    SO_INSET_HZ,
    PaperFigure,
    _channel_index,
    _panel,
    _Spectrum,
    _spectrum,
    _thresholds,
    _timeline_lines,
    averaged_paper_threshold,
    peak_summary,
)
from .overlay_figures import OVERLAYS, overlay_builder

__all__ = [
    "FIGURES",
    "OVERLAY_FMAX_HZ",
    "FigureSpec",
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
    "peak_summary",
    "render",
    "scenario_spectrum",
]


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
    from ..detection.frames import detect_frames, frame_intervals, frame_statistic, healthy_frame_level

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
