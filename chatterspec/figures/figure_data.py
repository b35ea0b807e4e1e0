"""Data of the paper figures: spectra, thresholds, peak ratios, natural-frequency lines, panels.

Helpers of :mod:`chatterspec.figures.paper_figures` (which re-exports
:class:`PaperFigure`, :func:`peak_summary` and :func:`averaged_paper_threshold`):
they run the scenarios through the public API and turn the results into the
plain panel records of :mod:`chatterspec.figures.plotting`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.stats
from matplotlib.figure import Figure

from ..detection.pipeline import ChatteringRecord, iter_chattering
from ..detection.spectral import periodogram, spectrum_model
from ..detection.thresholds import Threshold, exact_threshold, paper_threshold
from ..errors import ParameterError
from ..montecarlo import SeedLike
from ..plants.nonlinear import Model
from ..plants.scenarios import Scenario, scenario
from . import plotting as pl

__all__ = ["PaperFigure", "averaged_paper_threshold", "peak_summary"]

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
