"""The threshold type, :class:`Threshold` (a spectral bound and the meaning of its false-alarm level),
and the bin bookkeeping every threshold shares (:func:`bin_layout`, :func:`band_mask`,
:func:`per_test_alpha`).

The constructors are in :mod:`chatterspec.detection.thresholds`, which re-exports every name here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from .._repr import short_repr
from .._validate import check_band, finite_array, open_unit, positive, positive_int, readonly
from ..errors import ParameterError, ShapeError

__all__ = [
    "AlphaMeaning",
    "Band",
    "Correction",
    "Threshold",
    "ThresholdKind",
    "ThresholdLaw",
    "band_mask",
    "bin_layout",
    "per_test_alpha",
]

ThresholdKind = Literal["paper", "exact", "empirical"]
AlphaMeaning = Literal["per-bin", "family-wise", "per-frame"]
Correction = Literal["none", "bonferroni", "sidak"]
ThresholdLaw = Literal["exact", "chi2"]
Band = tuple[float, float]
_CORRECTIONS = ("none", "bonferroni", "sidak")
_LAWS = ("exact", "chi2")


@dataclass(frozen=True, eq=False)
class Threshold:
    """A spectral threshold and the meaning of its false-alarm level.

    Attributes
    ----------
    values : (bins, m) array
        Threshold on the power of each bin and channel (units of the chattering squared).
    freqs_hz : (bins,) array
        Bin frequencies (Hz).
    kind : {"paper", "exact", "empirical"}
    alpha : float
        The false-alarm probability the user asked for.
    alpha_meaning : {"per-bin", "family-wise", "per-frame"}
        ``per-bin``: each tested bin exceeds with probability alpha (healthy);
        ``family-wise``: one record has any tested bin above with probability <= alpha;
        ``per-frame``: one STFT frame has any tested bin above with probability <= alpha.
    correction : {"none", "bonferroni", "sidak"}
    tested : (bins,) bool array
        Bins used for the verdict (DC and Nyquist excluded).
    dof : (bins,) int array
        Nominal chi-squared degrees of freedom of ``nu S / E[S]`` per bin (2K, or K at
        DC/Nyquist): the law used by ``law="chi2"``; see ``effective_dof`` for the exact law.
    averaged : int
        Number K of independent spectra averaged (1 for a single record).
    per_test_alpha : float
        Level ``a`` applied to each tested bin after the correction.
    expected : (bins, m) array or None
        Expected healthy spectrum the threshold was built from (None for ``paper``).
    law : {"exact", "chi2"} or None
        Distribution the quantiles come from: ``"exact"`` (weighted sum
        ``l1 Z1^2 + l2 Z2^2`` per bin), ``"chi2"`` (``E chi2(dof) / dof``), None
        for ``empirical`` thresholds.
    eigenvalues : (bins, m, 2) array or None
        ``(l1, l2)`` per bin and channel for ``law="exact"`` (single-record law).
    effective_dof : (bins, m) float array or None
        ``K (l1 + l2)^2 / (l1^2 + l2^2)``: the Welch-Satterthwaite degrees of freedom
        of the exact law (equals ``dof`` where ``l1 = l2`` or ``l2 = 0``); ``dof``
        broadcast for ``law="chi2"``; None for ``empirical``.
    band : (float, float) or None
        ``(lo, hi)`` in Hz: only bins with ``lo <= f <= hi`` are tested (None: every bin
        but DC and Nyquist).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    values: np.ndarray
    freqs_hz: np.ndarray
    kind: ThresholdKind
    alpha: float
    alpha_meaning: AlphaMeaning
    correction: Correction
    tested: np.ndarray
    dof: np.ndarray
    averaged: int = 1
    per_test_alpha: float = float("nan")
    expected: np.ndarray | None = None
    law: ThresholdLaw | None = None
    eigenvalues: np.ndarray | None = None
    effective_dof: np.ndarray | None = None
    band: Band | None = None

    @property
    def n_tested(self) -> int:
        """Number of bins in the family (bins used for the verdict)."""
        return int(np.count_nonzero(self.tested))

    @property
    def n_channels(self) -> int:
        """Number of channels."""
        return self.values.shape[1]

    def check_spectrum(self, power: np.ndarray) -> np.ndarray:
        """Return ``power`` as an array after checking its last two axes are ``(bins, m)``.

        Raises
        ------
        ShapeError
            If the spectrum does not match the threshold's bins and channels.
        """
        power = np.asarray(power, dtype=float)
        if power.ndim < 2 or power.shape[-2:] != self.values.shape:
            raise ShapeError(
                f"spectrum shape {power.shape} does not match the threshold "
                f"(..., {self.values.shape[0]} bins, {self.values.shape[1]} channels); "
                "build the threshold with the spectrum's freqs_hz and model"
            )
        return power

    def restricted(self, band: Band | None) -> Threshold:
        """This threshold with only the bins of ``band`` (Hz) tested; ``None`` returns it unchanged.

        The values are not recomputed: for a family-wise threshold the level over the
        narrower family is at most ``alpha`` (conservative). Builders that take
        ``band=`` (:func:`exact_threshold`, ...) recompute the correction for the band.

        Parameters
        ----------
        band : (float, float) or None
            ``(lo, hi)`` in Hz.

        Raises
        ------
        ParameterError
            If the band is malformed or holds no tested bin.
        """
        if band is None:
            return self
        lo, hi = check_band(band)
        tested = self.tested & band_mask(self.freqs_hz, (lo, hi))
        if not tested.any():
            raise ParameterError(
                f"band [{lo:g}, {hi:g}] Hz holds none of this threshold's tested bins "
                f"({self.freqs_hz[self.tested].min():g} .. {self.freqs_hz[self.tested].max():g} Hz)"
            )
        return replace(self, tested=readonly(tested), band=(lo, hi))

    def describe(self) -> str:
        """One sentence saying what ``alpha`` guarantees for this threshold."""
        avg = f" for the average of {self.averaged} independent spectra" if self.averaged > 1 else ""
        where = "" if self.band is None else f" in {self.band[0]:g}-{self.band[1]:g} Hz"
        band = f"{self.n_tested} tested bins{where} (DC and Nyquist excluded)"
        if self.alpha_meaning == "per-bin":
            return (
                f"{self.kind} threshold{avg}: each of the {band} exceeds it with probability "
                f"{'at most ' if self.kind == 'paper' else ''}{self.alpha:g} under healthy conditions; "
                f"no family-wise guarantee (the union bound of eq 64 gives {self.n_tested * self.alpha:g})"
            )
        unit = "one record" if self.alpha_meaning == "family-wise" else "one STFT frame"
        corr = f" with {self.correction} correction" if self.correction != "none" else ""
        level = f" (per-bin level {self.per_test_alpha:.3g})" if np.isfinite(self.per_test_alpha) else ""
        return (
            f"{self.kind} threshold{avg}{corr}: under healthy conditions "
            f"{unit} has any of its {band} above the threshold with probability at most {self.alpha:g}"
            f"{level}"
        )


def bin_layout(freqs_hz: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(is_dc, is_nyquist)`` boolean masks of a one-sided frequency grid (Hz).

    Parameters
    ----------
    freqs_hz : (bins,) array
        Frequencies (Hz).
    dt : float
        Sampling time (s); the Nyquist frequency is ``1 / (2 dt)``.
    """
    f = finite_array("freqs_hz", freqs_hz, ndim=1)
    dt = positive("dt", dt, unit="s")
    nyq = 0.5 / dt
    is_dc = np.abs(f) <= 1e-9 * nyq
    is_nyq = np.abs(f - nyq) <= 1e-9 * nyq
    return is_dc, is_nyq


def band_mask(freqs_hz: np.ndarray, band: Band | None) -> np.ndarray:
    """``(bins,)`` bool: bins with ``lo <= f <= hi`` (all True for ``band=None``).

    Parameters
    ----------
    freqs_hz : (bins,) array
        Frequencies (Hz).
    band : (float, float) or None
        ``(lo, hi)`` in Hz (validated by :func:`check_band`).
    """
    f = np.asarray(freqs_hz, dtype=float)
    if band is None:
        return np.ones(f.shape, dtype=bool)
    lo, hi = check_band(band)
    tol = 1e-9 * max(1.0, hi)
    return (f >= lo - tol) & (f <= hi + tol)


def per_test_alpha(alpha: float, n_tests: int, correction: Correction = "bonferroni") -> float:
    """Per-bin level ``a`` giving family-wise level ``alpha`` over ``n_tests`` bins.

    Parameters
    ----------
    alpha : float
        Family-wise false-alarm probability in (0, 1).
    n_tests : int
        Number of bins in the family.
    correction : {"bonferroni", "sidak", "none"}
        ``none``: ``a = alpha``; ``bonferroni``: ``alpha / n``; ``sidak``: ``1 - (1 - alpha)^(1/n)``.
    """
    alpha = open_unit("alpha", alpha)
    n = positive_int("n_tests", n_tests)
    if correction == "none":
        return alpha
    if correction == "bonferroni":
        return alpha / n
    if correction == "sidak":
        return float(-np.expm1(np.log1p(-alpha) / n))
    raise ParameterError(f"correction must be one of {_CORRECTIONS}; got {correction!r}")
