"""Shared matplotlib set-up of chatterspec's figures: the Agg backend, labels, colours, saving.

Importing this module selects the non-interactive ``Agg`` backend, so figures
render on headless machines and in CI. :mod:`chatterspec.figures.plotting`
re-exports the public names.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from ..errors import ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.axes import Axes

__all__ = ["DEFAULT_DPI", "FrequencyLine", "format_alpha", "frequency_lines", "power_unit", "save_figure"]

#: Resolution of saved PNGs (dots per inch); keeps a 12 x 7 inch figure well under 300 kB.
DEFAULT_DPI: int = 110

#: Shades of the true mismatch windows of Fig 2, one per window.
_WINDOW_SHADES = ("tab:orange", "tab:purple", "tab:cyan")
_CURVE_COLORS = ("tab:blue", "tab:orange", "tab:purple", "tab:brown", "tab:cyan", "tab:pink")


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

    An empty unit gives ``"dimensionless"``: the paper gives its second-order
    benchmark (eq 63) no physical unit, so its spectra are dimensionless too.

    Parameters
    ----------
    unit : str
        Unit of the signal (``""`` for a dimensionless one).

    Returns
    -------
    str
    """
    if not unit:
        return "dimensionless"
    if "/" in unit or " " in unit:
        return f"({unit})²"
    return f"{unit}²"


@dataclass(frozen=True)
class FrequencyLine:
    """A vertical line at a frequency that explains the spectrum (e.g. a natural frequency).

    Attributes
    ----------
    hz : float
        Frequency in Hz (not rad/s).
    label : str
        Legend text, e.g. ``"nominal natural frequency 10 Hz"``.
    color : str
        Matplotlib colour (default black).
    linestyle : str or tuple
        Matplotlib line style (default dotted).
    span_s : (start_s, stop_s), optional
        Time window in seconds the line applies to (spectrograms draw it only
        there); None for the whole record.
    """

    hz: float
    label: str
    color: str = "black"
    linestyle: Any = ":"
    span_s: tuple[float, float] | None = None


def _wrap(text: str, width_in: float) -> str:
    """Wrap each line of ``text`` to the width of a ``width_in``-inch figure (10 pt font).

    A line too long for the figure is split into the fewest lines that fit, of balanced
    length (no short orphan such as ``on E[S] (eq 56),`` left on a line of its own).
    """
    chars = max(int(width_in * 12.5), 20)
    out: list[str] = []
    for line in text.split("\n"):
        n_lines = len(textwrap.wrap(line, chars)) if len(line) > chars else 1
        width = min(chars, -(-len(line) // n_lines))
        while len(textwrap.wrap(line, width)) > n_lines:  # ends at chars at the latest
            width += 1
        out.extend(textwrap.wrap(line, width) if n_lines > 1 else [line])
    return "\n".join(out)


# --------------------------------------------------------------------------- saving
def save_figure(fig: Figure, path: str | Path, *, dpi: int = DEFAULT_DPI, close: bool = True) -> Path:
    """Save ``fig`` as PNG at ``dpi`` (creating parent folders) and close it; return the path.

    The image is stored with a 256-colour adaptive palette (no dithering): line
    figures lose nothing visible and the files are 2-3 times smaller than RGBA,
    which keeps the committed figures small.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Figure to save.
    path : str or Path
        Output file; must end in ``.png``.
    dpi : int
        Resolution in dots per inch (default :data:`DEFAULT_DPI`).
    close : bool
        Close the figure after saving (default True).

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
    from PIL import Image, PngImagePlugin  # matplotlib's own dependency

    buf = io.BytesIO()
    fig.savefig(buf, dpi=dpi, format="png")
    buf.seek(0)
    with Image.open(buf) as img:
        pal = img.convert("RGB").quantize(
            colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
        )
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", "chatterspec")
    pal.save(path, format="PNG", optimize=True, pnginfo=info)
    if close:
        plt.close(fig)
    return path


def frequency_lines(ax: Axes, lines: Sequence[FrequencyLine]) -> list[Any]:
    """Draw frequency lines on ``ax`` and return one legend artist per entry.

    A line alone in its style (the nominal natural frequency) spans the whole height; lines sharing a
    style (the true natural frequencies of several curves) are short marks at the top in their own
    colours, under one legend entry, so that they cover no curve.

    Parameters
    ----------
    ax : matplotlib.axes.Axes
    lines : sequence of FrequencyLine

    Returns
    -------
    list of matplotlib.artist.Artist
    """
    from matplotlib.lines import Line2D

    by_style: dict[str, list[FrequencyLine]] = {}
    for fl in lines:
        by_style.setdefault(fl.linestyle, []).append(fl)
    out: list[Any] = []
    for group in by_style.values():
        if len(group) == 1:
            fl = group[0]
            out.append(ax.axvline(fl.hz, color=fl.color, ls=fl.linestyle, lw=1.1, zorder=2, label=fl.label))
            continue
        for fl in group:
            ax.axvline(fl.hz, ymin=0.88, color=fl.color, ls="-", lw=2.0, zorder=2, label=fl.label)
        hz = " / ".join(f"{fl.hz:.1f}" for fl in group)
        head = " ".join(group[0].label.split(" ")[:3])
        out.append(
            Line2D(
                [],
                [],
                color=group[0].color,
                lw=2.0,
                label=f"{head} {hz} Hz (marks at the top, curve colours)",
            )
        )
    return out
