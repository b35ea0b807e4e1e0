"""The one colour palette of chatterspec: figures (matplotlib) and recordings (Rerun) both use it.

Rules: **red only means fault** (a fault verdict, a flagged frame, a fault interval); channels,
filters and modes take their colours from lists without red; the true fault timeline draws each
fault level in its own shade of amber (never red: truth is not a verdict) and healthy segments grey.

Colours are ``(r, g, b)`` tuples of 0-255 integers; :func:`mpl` converts one for matplotlib and
:func:`rgba32` packs one for Rerun's ``StateConfiguration``. Pure data: no import of matplotlib or
rerun.
"""

from __future__ import annotations

from .filter_registry import ENTRIES

__all__ = [
    "CHANNEL_COLORS",
    "FAULT",
    "FAULT_LEVEL_COLORS",
    "FILTER_COLORS",
    "HEALTHY",
    "MODE_COLORS",
    "NEUTRAL",
    "NO_EVIDENCE",
    "TAB10",
    "TRUTH",
    "channel_color",
    "fault_level_color",
    "filter_color",
    "mode_color",
    "mpl",
    "rgba32",
]

RGB = tuple[int, int, int]

#: A fault (verdict, flagged frame, detected interval); nothing else is drawn in red.
FAULT: RGB = (229, 57, 53)
#: A healthy verdict (lanes).
HEALTHY: RGB = (46, 125, 50)
#: No evidence either way: a lane before its first verdict, a channel or parameter not excited (the data
#: cannot see a change of the size its tolerance allows); neither healthy nor fault, darker than the
#: truth lane's healthy grey.
NO_EVIDENCE: RGB = (84, 88, 110)
#: Reference lines and healthy truth segments.
NEUTRAL: RGB = (140, 140, 140)
#: The true state (drawn under the estimates): light grey on Rerun's dark background; figures use black.
TRUTH: RGB = (235, 235, 235)

#: matplotlib's ``tab10`` colours by name (its red and grey are not used: red only means fault).
TAB10: dict[str, RGB] = {
    "blue": (31, 119, 180),
    "orange": (255, 127, 14),
    "green": (44, 160, 44),
    "purple": (148, 103, 189),
    "brown": (140, 86, 75),
    "pink": (227, 119, 194),
    "olive": (188, 189, 34),
    "cyan": (23, 190, 207),
}

#: Output channels, in model order (tab10 without its red and grey).
CHANNEL_COLORS: tuple[RGB, ...] = tuple(
    TAB10[n] for n in ("blue", "orange", "green", "purple", "brown", "pink", "olive", "cyan")
)

#: Diagnosis methods by name; an estimator's colour is its registry entry's
#: (:attr:`chatterspec.filter_registry.FilterEntry.color`; the KF and EKF share one: one runs per plant).
FILTER_COLORS: dict[str, RGB] = {
    name: TAB10[tab]
    for name, tab in (
        ("smm", "purple"),
        ("imm", "cyan"),
        ("chattering", "orange"),
        ("innovation", "brown"),
    )
}

#: Modes of a multiple-model diagnosis, in mode order (no red).
MODE_COLORS: tuple[RGB, ...] = tuple(
    TAB10[n] for n in ("blue", "orange", "green", "purple", "cyan", "olive", "pink", "brown")
)

#: True fault levels in order of appearance: light to dark amber (distinct, never red).
FAULT_LEVEL_COLORS: tuple[RGB, ...] = (
    (255, 213, 79),
    (255, 160, 0),
    (230, 110, 0),
    (170, 80, 0),
    (255, 236, 150),
)


def channel_color(index: int) -> RGB:
    """Colour of output channel ``index`` (0-based; cycles after 8)."""
    return CHANNEL_COLORS[index % len(CHANNEL_COLORS)]


def filter_color(name: str, index: int = 0) -> RGB:
    """Colour of estimator / method ``name``; an unknown name gets channel colour ``index``."""
    entry = ENTRIES.get(name.lower())
    if entry is not None and entry.color is not None:
        return TAB10[entry.color]
    return FILTER_COLORS.get(name.lower(), channel_color(index))


def mode_color(index: int) -> RGB:
    """Colour of mode ``index`` of a multiple-model diagnosis."""
    return MODE_COLORS[index % len(MODE_COLORS)]


def fault_level_color(index: int) -> RGB:
    """Colour of the ``index``-th distinct true fault level of a timeline."""
    return FAULT_LEVEL_COLORS[index % len(FAULT_LEVEL_COLORS)]


def mpl(color: RGB) -> tuple[float, float, float]:
    """A palette colour as a matplotlib RGB tuple.

    Parameters
    ----------
    color : (int, int, int)
        0-255 components.

    Returns
    -------
    (float, float, float)
        0-1 components.
    """
    return (color[0] / 255.0, color[1] / 255.0, color[2] / 255.0)


def rgba32(color: RGB, alpha: int = 255) -> int:
    """A palette colour packed as Rerun's ``0xRRGGBBAA`` integer.

    Parameters
    ----------
    color : (int, int, int)
        0-255 components.
    alpha : int
        Opacity 0-255.

    Returns
    -------
    int
    """
    return (color[0] << 24) | (color[1] << 16) | (color[2] << 8) | alpha
