"""The paper's overlay figures (Figs 7, 10-12): fault levels of one family on one axes.

Each of these figures shows one realization (same seed) of several fault levels of
a scenario family over the healthy spectrum, with the thresholds at alpha = 0.1 %
built from the shared nominal model. They differ only in data (which scenarios,
labels, colours, channel and title), held by one :class:`OverlaySpec` per figure in
:data:`OVERLAYS`; :func:`overlay_figure` draws any of them, and :func:`overlay_builder`
turns a spec into the ``builder(runs, seed)`` of the paper-figure registry.

See Also
--------
chatterspec.figures.paper_figures : the registry of all paper figures.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..montecarlo import SeedLike
from .figure_data import OVERLAY_FMAX_HZ, SO_INSET_HZ, PaperFigure, _overlay

__all__ = ["OVERLAYS", "OverlaySpec", "overlay_builder", "overlay_figure"]

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
