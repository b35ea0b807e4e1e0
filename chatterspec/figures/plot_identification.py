"""Figure of fault identification over a sweep of fault sizes (matplotlib, Agg backend).

Imported on demand only (the numeric core never imports matplotlib).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..studies.identification_study import IdentificationValidation

__all__ = ["identification_sweep_figure"]

#: Axis labels of the catalogue parameters (unit in brackets).
LABELS = {
    "leakage": "leakage L [m^3/(s Pa)]",
    "friction": "friction a [N s/m]",
    "bulk_modulus": "bulk modulus be [Pa]",
    "natural_frequency": "natural frequency f0 [Hz]",
}


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
        top.plot(true, true, color="0.6", lw=1, label="estimate = true")
        top.errorbar(true, med, yerr=[med - q05, q95 - med], fmt="o", ms=4, capsize=3, label="median, 5-95 %")
        top.set_title(f"{family} ({rows[0].runs} records of 4 s per size)", fontsize=9)
        top.set_ylabel("estimate")
        top.set_xlabel("true value")
        rel = 100 * (med - true) / true
        rlo, rhi = 100 * (q05 - true) / true, 100 * (q95 - true) / true
        bot.axhline(0, color="0.6", lw=1)
        bot.fill_between(true, rlo, rhi, alpha=0.25, label="5-95 % of records")
        bot.plot(true, rel, "o-", ms=4, label="median")
        bot.plot(
            true,
            100 * half / true,
            "--",
            color="C3",
            lw=1,
            label=f"mean {rows[0].confidence:.0%} CI half-width",
        )
        bot.plot(true, -100 * half / true, "--", color="C3", lw=1)
        for x, r in zip(true, rows, strict=True):
            bot.annotate(
                f"{r.isolation()[0]:.0%}",
                (x, 0),
                textcoords="offset points",
                xytext=(0, 4),
                ha="center",
                fontsize=7,
            )
        bot.set_xlabel(LABELS.get(rows[0].parameter or "", "true value"))
        bot.set_ylabel("relative error [%]")
        if j == 0:
            top.legend(fontsize=7, loc="upper left")
            bot.legend(fontsize=7, loc="lower left")
    fig.suptitle(
        title
        or "fault identification from the chattering: estimate vs true parameter (percentages: records "
        "selecting the true hypothesis, 'no fault' at the nominal size)",
        fontsize=10,
    )
    fig.tight_layout()
    return fig
