"""Estimator comparison figures (DETC2015 Figs 3-5 analogue); matplotlib, Agg backend, imported on demand.

:func:`estimation_error_figure` draws, per state, the estimation error ``x - x_hat`` of one
realization for every filter (left column, as DETC Fig 5 does for position) and the Monte Carlo
RMS error over time across realizations (right column, log scale), which shows where each filter
wins and when (e.g. after the plant switches to F2 at 0.5 s in ``detc-uncertain``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..errors import ParameterError
from ..filter_registry import ENTRIES
from ..palette import filter_color, mpl
from ..plants.models import state_units

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from ..studies.estimation import EstimateRecords

__all__ = ["estimation_error_figure"]


def _line(name: str, k: int) -> dict[str, object]:
    """Line keywords of filter ``name`` (the ``k``-th drawn) from its registry entry: colour (the shared
    palette, also used by the recordings), label and style. The stock entries draw the first filters wide
    and light underneath, the later ones thin on top, so that curves that coincide (the KF and the
    2nd-order SVSF often do) both stay visible."""
    entry = ENTRIES.get(name)
    style = {} if entry is None else dict(entry.style)
    return {
        "color": mpl(filter_color(name, k)),
        "ls": style.get("ls", "-"),
        "label": _label(name),
        "lw": style.get("lw", 1.0),
        "alpha": style.get("alpha", 1.0),
    }


def _label(name: str) -> str:
    entry = ENTRIES.get(name)
    return name if entry is None or not entry.label else entry.label


def estimation_error_figure(records: EstimateRecords, *, run: int = 0, title: str | None = None) -> Figure:
    """Per-state estimation error of one realization and the RMS error over realizations vs time.

    Parameters
    ----------
    records : EstimateRecords
        From :func:`chatterspec.studies.estimation.estimate_records` (several runs for the RMS column).
    run : int
        Realization shown in the left column (index into ``records``).
    title : str, optional
        Figure title (default: the scenario name and the number of runs).

    Returns
    -------
    matplotlib.figure.Figure
    """
    runs = records.x.shape[0]
    if not 0 <= run < runs:
        raise ParameterError(f"run must be in [0, {runs}); got {run}")
    model = records.scenario.nominal
    names = list(records.outputs)
    states = tuple(model.state_names)
    units = state_units(model)
    t = records.t[1:]
    fig, axes = plt.subplots(len(states), 2, figsize=(12, 2.6 * len(states)), sharex=True, squeeze=False)
    for k, name in enumerate(names):
        err = records.error(name)
        rms = np.sqrt(np.mean(err**2, axis=0))
        for i in range(len(states)):
            kw = {**_line(name, k), "zorder": 2 + k}
            axes[i, 0].plot(t, err[run, :, i], **kw)
            axes[i, 1].semilogy(t, rms[:, i], **kw)
    for i, s in enumerate(states):
        unit = f"[{units[i] or 'model units'}]"  # "model units": the model declares none for this state
        axes[i, 0].set_ylabel(f"{s} error\n{unit}")
        axes[i, 1].set_ylabel(f"{s} RMS error\n{unit}")
        for j, ax in enumerate(axes[i]):
            ax.grid(True, alpha=0.3)
            for seg in records.scenario.windows:
                # labelled once: the legend is taken from the top-left axes
                label = f"true plant {seg.label} from {seg.start:g} s" if i == j == 0 else None
                ax.axvline(seg.start, color="k", ls=":", lw=0.8, label=label)
    axes[0, 0].set_title(f"estimation error x - x_hat, realization {records.first_run + run}")
    axes[0, 1].set_title(f"RMS over {runs} realizations at each time")
    axes[-1, 0].set_xlabel("time [s]")
    axes[-1, 1].set_xlabel("time [s]")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    who = ", ".join(_label(n) for n in names)
    default = f"{records.scenario.name}: {who}; {runs} realizations\n{records.scenario.description}"
    fig.suptitle(title or default, fontsize=10)
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.03, 1, 1))
    return fig
