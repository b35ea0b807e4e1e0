"""The y range of a recording's chattering views: a robust, symmetric extent of the record's chattering.

Rerun auto-ranges a time-series view from the data it shows; at 1600x1000 a small amplitude (the
chattering of a position in metres is ~1e-4) can leave a single "0" tick on the axis, with no amplitude
to read. A file's final blueprint therefore gives each chattering view a fixed symmetric range
``[-r, r]`` with ``r`` from :class:`ChatteringExtent`.

Which ticks the viewer labels: its plots (egui_plot, Rerun 0.41) put grid lines at powers of ten only
(``10^k``, no 2 or 5 steps) and label a step only when its lines are far enough apart on screen. Seen at
1600x1000 on the ~70 px high chattering views: ``±0.005`` in ``±0.00615`` is NOT labelled (its
``0.001`` lines are ~6 px apart and ``0.01`` is out of range), nor ``±1`` in ``±2.2``; ``±0.01`` in
``±0.011`` is. So ``r`` is not the extent itself but ``1.1 p`` for the smallest power of ten ``p``
with ``1.1 p`` at or above it (:func:`labelled_half_range`): the ``±p`` lines sit at 91 % of the
half-height and are labelled; the data then fill 10 % to 100 % of the half-height.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["QUANTILE", "STRIDE", "ChatteringExtent", "labelled_half_range"]

#: Quantile of ``|e(k|k-1)|`` taken per batch: a handful of samples (the filters' start, a glitch)
#: cannot set the range, a fault that lasts a fraction of a batch (20 s of 1 kHz data) still does.
QUANTILE = 0.999
#: Every STRIDE-th sample of a batch enters its quantile (5 000 of a 20 000-sample file batch): the
#: quantile of a 60 000-value batch cost ~0.6 ms, 13 % of a file's logging time
#: (``benchmarks/bench_monitor.py --cases d``); a quarter of it stays robust (the 5 largest of 5 000 are
#: ignored) and a fault lasting a second still holds ~250 of them.
STRIDE = 4
#: Headroom above the extent, so that the largest values and the ±psi lines are not drawn on the frame.
MARGIN = 1.15


def labelled_half_range(a: float) -> float:
    """``1.1 p`` for the smallest power of ten ``p`` with ``1.1 p >= a > 0``: a symmetric range whose
    ``±p`` grid lines the viewer labels (see the module docstring).

    Parameters
    ----------
    a : float
        Half-height the range must hold (> 0, output units).

    Returns
    -------
    float
    """
    p = 10.0 ** math.ceil(math.log10(a / 1.1) - 1e-12)
    return 1.1 * p


class ChatteringExtent:
    """Running robust extent of the chattering per channel, in bounded memory.

    Each batch of samples contributes its :data:`QUANTILE` of ``|e|`` per channel (over every
    :data:`STRIDE`-th sample of a batch of at least ``100 STRIDE`` samples); the extent is the largest
    of these over the record (so a fault late in a long record widens it).

    Parameters
    ----------
    n_channels : int
    """

    def __init__(self, n_channels: int) -> None:
        self._max = np.zeros(int(n_channels))
        self.n_samples = 0

    def add(self, chattering: np.ndarray) -> None:
        """Take one batch ``(samples, channels)`` of chattering ``e(k|k-1)`` (output units)."""
        e = np.asarray(chattering, dtype=float)
        n = e.shape[0]
        if n == 0:
            return
        a = np.abs(e[:: STRIDE if n >= 100 * STRIDE else 1])
        # np.quantile (one partition of every column) gives nanquantile's numbers where a column has no
        # NaN, in a third of its time (nanquantile goes column by column); a NaN makes its column's
        # quantile NaN, and only such batches take nanquantile
        q = np.quantile(a, QUANTILE, axis=0) if a.shape[0] > 1 else a[0]
        if np.isnan(q).any():
            with np.errstate(invalid="ignore"):
                q = np.nanquantile(a, QUANTILE, axis=0)
        np.fmax(self._max, q, out=self._max)
        self.n_samples += e.shape[0]

    def ranges(self, psi: Sequence[float] | None = None) -> list[float | None] | None:
        """Per channel the half-height ``r`` of the symmetric range ``[-r, r]``: :func:`labelled_half_range`
        of :data:`MARGIN` times the larger of the extent and the boundary layer ``psi`` (so that the ±psi
        lines are in view); a channel without any finite non-zero value gets None (auto range). None before
        any sample.

        Parameters
        ----------
        psi : sequence of float, optional
            The SVSF boundary layer per channel (output units).

        Returns
        -------
        list of (float or None), or None
        """
        if self.n_samples == 0:
            return None
        r = self._max.copy()
        if psi is not None:
            r = np.fmax(r, np.abs(np.asarray(psi, dtype=float)))
        return [labelled_half_range(MARGIN * float(x)) if np.isfinite(x) and x > 0 else None for x in r]
