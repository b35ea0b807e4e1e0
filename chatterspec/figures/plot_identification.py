"""Figure of fault identification over a sweep of fault sizes (matplotlib, Agg backend).

Imported on demand only (the numeric core never imports matplotlib).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..palette import NEUTRAL, channel_color, mpl

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..studies.identification_study import IdentificationValidation

__all__ = ["identification_sweep_figure"]

#: Names and units of the catalogue parameters: (axis label, unit).
LABELS = {
    "leakage": ("leakage L", "m³/(s·Pa)"),
    "friction": ("friction a", "N·s/m"),
    "bulk_modulus": ("bulk modulus βe", "Pa"),
    "natural_frequency": ("natural frequency f0", "Hz"),
}
#: Colour of the interval half-width lines (neutral: red is kept for fault verdicts).
CI_COLOR = mpl(NEUTRAL)


def identification_sweep_figure(
    sweeps: Mapping[str, Sequence[IdentificationValidation]], title: str | None = None
) -> Figure:
    """Estimate vs true parameter over fault sizes, one column per family.

    Top row: the median estimate of single records against the true value, with the 5-95 %
    range of the estimates and the identity line. Bottom row: the relative error in % (median,
    5-95 % range) and the mean half-width of the records' intervals; each size is annotated
    with the fraction of records selecting the true hypothesis ("no fault" at the healthy size).

    Parameters
    ----------
    sweeps : mapping of family name -> list of IdentificationValidation
        From :func:`chatterspec.studies.identification_study.identification_sweep`.
    title : str, optional
        Figure title.
    """
    n = len(sweeps)
    fig, axes = plt.subplots(2, n, figsize=(4.2 * n, 6.4), squeeze=False, height_ratios=[1.2, 1])
    for j, (family, rows) in enumerate(sweeps.items()):
        top, bot = axes[0, j], axes[1, j]
        true = np.array([r.true_value for r in rows])
        med = np.array([np.nanmedian(r.estimates) for r in rows])
        q05 = np.array([np.nanquantile(r.estimates, 0.05) for r in rows])
        q95 = np.array([np.nanquantile(r.estimates, 0.95) for r in rows])
        half = np.array([np.nanmean(r.ci_high - r.ci_low) / 2 for r in rows])
        name, unit = LABELS.get(rows[0].parameter or "", ("parameter", ""))
        unit = f" [{unit}]" if unit else ""
        color = mpl(channel_color(0))
        top.plot(true, true, color="0.6", lw=1, label="estimate = true")
        bars = [med - q05, q95 - med]
        top.errorbar(true, med, yerr=bars, fmt="o", ms=4, capsize=3, color=color, label="median, 5-95 %")
        top.set_title(f"{family} ({rows[0].runs} records of 4 s per size)", fontsize=9, pad=14)
        top.set_ylabel(f"estimated {name}{unit}")
        top.set_xlabel(f"true {name}{unit}")
        rel = 100 * (med - true) / true
        rlo, rhi = 100 * (q05 - true) / true, 100 * (q95 - true) / true
        bot.axhline(0, color="0.6", lw=1)
        bot.fill_between(true, rlo, rhi, alpha=0.25, color=color, label="5-95 % of records")
        bot.plot(true, rel, "o-", ms=4, color=color, label="median")
        bot.plot(
            true,
            100 * half / true,
            "--",
            color=CI_COLOR,
            lw=1,
            label=f"mean {rows[0].confidence:.0%} CI half-width",
        )
        bot.plot(true, -100 * half / true, "--", color=CI_COLOR, lw=1)
        iso = [r.isolation()[0] for r in rows]
        # one line at the top instead of a label per size (close sizes' labels ran into each other)
        below = [f"{v:.1%} at {x:.4g}" for x, v in zip(true, iso, strict=True) if v < 0.9995]
        note = "100 % select the true hypothesis at every size"
        if below:
            note = (
                "true hypothesis: "
                + "; ".join(below)
                + ("; 100 % elsewhere" if len(below) < len(iso) else "")
            )
        bot.text(
            0.5, 0.97, textwrap.fill(note, 46), transform=bot.transAxes, ha="center", va="top", fontsize=7,
            bbox={"facecolor": "white", "alpha": 0.85, "lw": 0, "pad": 1.5},
        )  # fmt: skip
        bot.set_xlabel(f"true {name}{unit}")
        bot.set_ylabel("relative error [%]")
        if j == 0:  # legends below the panels, out of the data and the band
            handles = top.get_legend_handles_labels()[0] + bot.get_legend_handles_labels()[0]
            fig.legend(handles=handles, loc="lower center", ncol=len(handles), fontsize=7, frameon=False)
    fig.suptitle(
        title
        or "fault identification from the chattering: estimate vs true parameter (percentages: records "
        "selecting the true hypothesis, 'no fault' at the nominal size)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    return fig
