"""Chi-squared thresholds for the chattering power spectrum (eq 57-64, ``docs/design.md`` §6).

Every threshold is an array ``(bins, m)`` with a :class:`Threshold` record of
what its ``alpha`` means:

``paper`` (eq 58-62)
    The flat bound ``Sigma_Gamma_ii chi2.ppf(1 - alpha, 2) / 2`` with
    ``Sigma_Gamma = C Q C^T + Lambda R Lambda^T``; ``alpha`` is a **per-bin**
    level (and the bound is conservative: it dominates the true spectrum).
``exact``
    The ``1 - a`` quantile of the exact finite-N law of each bin (``law="exact"``,
    default): a healthy bin is ``S = l1 Z1^2 + l2 Z2^2`` with ``Z`` iid standard
    normal and ``(l1, l2)`` from :func:`chatterspec.detection.spectral.periodogram_eigenvalues`
    (``l2 = 0`` at DC and Nyquist). ``law="chi2"`` is the previous approximation
    ``E[S_i(f)] chi2.ppf(1 - a, nu) / nu`` with the exact expected spectrum
    (:func:`chatterspec.detection.spectral.expected_spectrum`), ``nu = 2`` for bins
    ``1 .. ceil(N/2) - 1`` and ``nu = 1`` for DC and Nyquist (``docs/design.md`` C8);
    it assumes ``l1 = l2`` and under-estimates the tail where the spectrum is
    tiny compared with ``|gamma1| / N`` (EHA position channel, lowest bins:
    about twice the nominal per-bin rate there).
    Averaging K independent periodograms: ``law="chi2"`` multiplies ``nu`` by K;
    ``law="exact"`` uses the **Welch-Satterthwaite approximation**
    ``(c / K) chi2(nu_eff)`` with ``c = (l1^2 + l2^2) / (l1 + l2)`` and
    ``nu_eff = K (l1 + l2)^2 / (l1^2 + l2^2)`` (mean and variance matched; exact
    when ``l1 = l2``, giving ``E chi2(2K) / (2K)``, or ``l2 = 0``).
``frame`` (STFT)
    The same (exact law from :func:`chatterspec.detection.spectral.frame_eigenvalues`) for
    the Hamming-windowed frames, family-wise over the bins of **one frame**
    (``alpha_meaning = "per-frame"``).

Family-wise control
    The family is the set of bins **tested for the verdict**: ``1 .. ceil(N/2) - 1``
    (DC excluded because a step input puts a large DC term into any mismatch, the
    Nyquist bin excluded as in eq 43), ``n_tested = ceil(N/2) - 1``. DC is *not*
    counted in the family because it never contributes to the verdict; its
    threshold is computed at the same per-test level ``a`` and reported separately
    (``dc_ratio``). Bonferroni: ``a = alpha / n_tested`` (default); Sidak:
    ``a = 1 - (1 - alpha)^(1 / n_tested)`` (exact for independent bins; the DFT
    bins of the healthy MA(1) chattering are nearly independent). Eq (64) is the
    union bound: with per-bin alpha it gives ``n alpha``, which is vacuous for
    ``n alpha >= 1`` and is not a guarantee.

Frequency band (beyond the paper)
    Every builder takes ``band=(lo, hi)`` in Hz: only bins with ``lo <= f <= hi``
    are tested (DC and Nyquist stay excluded), and the family of the correction is
    those bins only (Bonferroni ``a = alpha / n_tested`` with ``n_tested`` the bins
    in the band). The paper's rule (eq 57-62) tests every bin; a band keeps, e.g.,
    near-Nyquist noise out of the verdict when the fault band is known.
    :meth:`Threshold.restricted` narrows a ready threshold (an empirical one) to
    a band; its level is then conservative (a sub-family of the calibrated one).

The threshold type
------------------
The threshold type, :class:`Threshold` (a spectral bound and the meaning of its false-alarm level),
and the bin bookkeeping every threshold shares (:func:`bin_layout`, :func:`band_mask`,
:func:`per_test_alpha`).

The law of one bin
------------------
The law of one periodogram bin, ``Y = l1 Z1^2 + l2 Z2^2`` (a weighted sum of two chi2(1)).

Its survival function, density and inverse (:func:`weighted_chi2_sf`, :func:`weighted_chi2_pdf`,
:func:`weighted_chi2_isf`) give the ``exact`` thresholds; ``l1 = l2`` is the chi2(2)/2 law of Lemma 2.

Empirical normalization (nonlinear models)
------------------------------------------
Empirical normalization spectrum and family-wise threshold, for models without a closed-form spectrum.

For a linear nominal model the healthy chattering spectrum ``E[S]`` is known in closed form
(eq 56; :func:`~chatterspec.detection.spectral.expected_spectrum`). For a nonlinear model
(:class:`~chatterspec.plants.nonlinear.NonlinearModel`) it is not, so it is *estimated* from
healthy runs (beyond the paper):

* ``normalization_spectrum``: the mean periodogram (eq 49) of ``P`` healthy "pilot" runs, then a
  moving average over ``2 h + 1`` neighbouring tested bins (the healthy spectrum is smooth; a
  periodogram bin has standard deviation about its mean, so the estimate's relative standard error
  is about ``1 / sqrt(P (2 h + 1))``). DC and Nyquist are kept unsmoothed (they are not tested).
* ``frame_normalization``: the same for STFT frames (mean over runs and frames).

The detector then tests ``S / E_hat`` against the empirical ``(1 - alpha)``-quantile of the
per-record maximum over tested bins, estimated on *other* healthy runs
(:func:`chatterspec.studies.calibration.thresholds.calibrate_empirical`). The false-alarm rate
of that family-wise threshold does not depend on how good ``E_hat`` is (it only shapes which
frequencies the detector is sensitive to); it is exact up to the order-statistic uncertainty
of the quantile, which the calibration reports as an interval.

Naming the bins of a verdict
----------------------------
Naming the bins behind a fault verdict: the most significant bin and the bin of largest excess.

A flagged frame has two bins worth naming, and they can differ:

- the **most significant** bin, the largest ``S / threshold`` (the detector's own peak: the bin whose
  test fails hardest);
- the bin of **largest excess**, the largest excess power ``S - E`` over the expected healthy spectrum
  ``E`` among the bins over the threshold (the batch report's ``peak_hz``): where the added power is.

They differ where the expected spectrum ``E`` is not flat (a linear model's closed-form chattering
spectrum rises towards its resonance). Where ``E`` is nearly flat they coincide: on the nonlinear EHA
leak (``eha4-leak-timeline``) the expected spectrum is within 2 % between 1 and 76 Hz, so the strongest
frame names 1.0 Hz both ways (the spectrogram's bright bottom row, in every fault frame), while the
wide band near 76 Hz, brighter to the eye because it spans ~28 bins, is weaker bin for bin (S = 38
against 230 at 1 Hz). Reports name both bins, each with its level in dB over the threshold
(``10 log10(S / threshold)``), with :func:`two_bins_text`, and say when they are one bin.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Literal, cast

import numpy as np
import numpy.typing as npt
import scipy.special

from .._repr import short_repr
from .._validate import check_band, finite_array, open_unit, positive, positive_int, readonly
from ..errors import ParameterError, ShapeError
from ..plants.models import LinearModel
from .spectral import (
    STFTConfig,
    chattering_autocovariance,
    expected_frame_spectrum,
    expected_spectrum,
    frame_eigenvalues,
    periodogram,
    periodogram_eigenvalues,
)
from .spectral import spectrogram as stft_spectrogram

if TYPE_CHECKING:  # pragma: no cover
    from ..plants.nonlinear import Model
    from .alarms.calibration import MonitorSettings

__all__ = [
    "NORMALIZATION_SMOOTH_BINS",
    "AlphaMeaning",
    "Band",
    "Correction",
    "Threshold",
    "ThresholdKind",
    "ThresholdLaw",
    "band_mask",
    "bin_layout",
    "check_band",
    "db_over_threshold",
    "empirical_family_wise_threshold",
    "exact_threshold",
    "frame_normalization",
    "frame_threshold",
    "monitor_threshold",
    "normalization_spectrum",
    "paper_gamma_matrix",
    "paper_threshold",
    "per_test_alpha",
    "smooth_spectrum",
    "threshold",
    "two_bins_text",
    "weighted_chi2_isf",
    "weighted_chi2_pdf",
    "weighted_chi2_sf",
]


def db_over_threshold(ratio: float) -> float:
    """``10 log10(S / threshold)`` (dB) of a ratio ``S / threshold`` (a ratio <= 1e-30 gives -300 dB).

    Parameters
    ----------
    ratio : float
        ``S / threshold`` of one bin.

    Returns
    -------
    float
    """
    return 10.0 * math.log10(max(float(ratio), 1e-30))


def two_bins_text(significant_hz: float, significant_db: float, excess_hz: float, excess_db: float) -> str:
    """The two bins of a flagged frame, labelled: ``"most significant 1.0 Hz +41 dB, largest excess
    76.0 Hz +24 dB"``, or ``"8.0 Hz +55 dB (most significant = largest excess)"`` when they are one bin.

    Parameters
    ----------
    significant_hz, significant_db : float
        The bin of largest ``S / threshold`` (Hz) and that ratio in dB (:func:`db_over_threshold`).
    excess_hz, excess_db : float
        The bin of largest excess ``S - E`` among the bins over the threshold (Hz) and its
        ``S / threshold`` in dB; a NaN ``excess_hz`` (not known) names the most significant bin only.

    Returns
    -------
    str
    """
    sig = f"{significant_hz:.1f} Hz {significant_db:+.0f} dB"
    if math.isnan(excess_hz):
        return f"most significant {sig}"
    if significant_hz == excess_hz:
        return f"{sig} (most significant = largest excess)"
    return f"most significant {sig}, largest excess {excess_hz:.1f} Hz {excess_db:+.0f} dB"


def _chi2_isf(p: npt.ArrayLike, dof: npt.ArrayLike) -> np.ndarray:
    """Inverse survival function of the chi-squared law: ``scipy.stats.chi2.isf(p, dof)``.

    The same function underneath (``scipy.special.chdtri``), without importing :mod:`scipy.stats`
    (a few hundred ms at every command start).
    """
    return scipy.special.chdtri(dof, p)


# ---------------------------------------------------------------------------
# Law of one bin: Y = l1 Z1^2 + l2 Z2^2 (weighted sum of two chi2(1))
# ---------------------------------------------------------------------------
_GL_X, _GL_W = np.polynomial.legendre.leggauss(64)
_ERFC_CUT = 12.0  # erfc(12) ~ 1e-64: the integrand beyond is negligible


def _eigen_pair(l1: npt.ArrayLike, l2: npt.ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(l1, dtype=float)
    b = np.asarray(l2, dtype=float)
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))) or np.any(a < 0) or np.any(b < 0):
        raise ParameterError("weights l1, l2 must be finite and >= 0")
    return np.maximum(a, b), np.minimum(a, b)


def _sf_unit(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """``P(Z1^2 + r Z2^2 > x)`` for ``0 <= r <= 1``, ``x >= 0`` (arrays of one shape).

    Conditioning on ``Z1``: ``erfc(z1 / sqrt 2) + int_{|z| < z1} phi(z) erfc(sqrt((x - z^2) / (2 r))) dz``
    with ``z1 = sqrt(x)``; the substitution ``z = z1 cos s`` gives
    ``2 z1 int_0^{pi/2} phi(z1 cos s) erfc(K sin s) sin s ds``, ``K = sqrt(x / (2 r))``, an entire
    integrand, cut where ``K sin s > 12`` and integrated by 64-point Gauss-Legendre (relative error
    ~1e-15 against direct quadrature of the density, whatever ``r``).
    """
    z1 = np.sqrt(x)
    first = scipy.special.erfc(z1 / np.sqrt(2.0))
    pos = r > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        K = np.where(pos, np.sqrt(x / (2.0 * np.where(pos, r, 1.0))), np.inf)
    Ks = np.where(np.isfinite(K) & (K > 0), K, 1.0)
    smax = np.where(K > _ERFC_CUT, np.arcsin(np.minimum(1.0, _ERFC_CUT / Ks)), 0.5 * np.pi)
    sn = smax[..., None] * (0.5 * (_GL_X + 1.0))
    sin_s = np.sin(sn)
    integrand = (
        np.exp(-0.5 * (z1[..., None] * np.cos(sn)) ** 2)
        * scipy.special.erfc(np.where(pos, Ks, 0.0)[..., None] * sin_s)
        * sin_s
    )
    second = z1 * smax * (integrand @ _GL_W) / np.sqrt(2.0 * np.pi)
    return first + np.where(pos & (x > 0), second, 0.0)


def _pdf_unit(x: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Density of ``Z1^2 + r Z2^2`` at ``x > 0``: ``exp(-x/2) I0(x (1 - r) / (4 r)) e^{...} / (2 sqrt r)``."""
    pos = r > 0
    rs = np.where(pos, r, 1.0)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        gen = np.exp(-0.5 * x) * scipy.special.i0e(x * (1.0 - rs) / (4.0 * rs)) / (2.0 * np.sqrt(rs))
        chi1 = np.exp(-0.5 * x) / np.sqrt(2.0 * np.pi * x)
    return np.where(pos, gen, chi1)


def weighted_chi2_sf(t: npt.ArrayLike, l1: npt.ArrayLike, l2: npt.ArrayLike) -> np.ndarray:
    """Survival function ``P(l1 Z1^2 + l2 Z2^2 > t)``, ``Z1, Z2`` iid standard normal (broadcasting).

    The exact law of a periodogram or frame bin of Gaussian data (see
    :func:`chatterspec.detection.spectral.periodogram_eigenvalues`). ``l1 = l2 = l`` gives
    ``exp(-t / (2 l))`` (``l chi2(2)``), ``l2 = 0`` gives ``l1 chi2(1)``. Computed by a
    one-dimensional integral (Gauss-Legendre, relative error ~1e-15) of non-negative terms,
    so it is accurate far in the tail.

    Parameters
    ----------
    t : array_like
        Thresholds (any real; ``sf = 1`` for ``t <= 0``).
    l1, l2 : array_like
        Non-negative weights (their order does not matter).

    See Also
    --------
    weighted_chi2_pdf : its density.
    weighted_chi2_isf : its inverse (the threshold at a level).
    """
    a, b = _eigen_pair(l1, l2)
    t = np.asarray(t, dtype=float)
    t, a, b = np.broadcast_arrays(t, a, b)
    out = np.ones(t.shape)
    ok = (t > 0) & (a > 0)
    if np.any(ok):
        out[ok] = _sf_unit(t[ok] / a[ok], b[ok] / a[ok])
    return out


def weighted_chi2_pdf(t: npt.ArrayLike, l1: npt.ArrayLike, l2: npt.ArrayLike) -> np.ndarray:
    """Density of ``l1 Z1^2 + l2 Z2^2`` at ``t > 0`` (0 for ``t <= 0``; requires ``max(l1, l2) > 0``).

    See Also
    --------
    weighted_chi2_sf : the survival function.
    weighted_chi2_isf : the inverse survival function.
    """
    a, b = _eigen_pair(l1, l2)
    t = np.asarray(t, dtype=float)
    t, a, b = np.broadcast_arrays(t, a, b)
    if np.any(a <= 0):
        raise ParameterError("weighted_chi2_pdf needs max(l1, l2) > 0")
    out = np.zeros(t.shape)
    ok = t > 0
    out[ok] = _pdf_unit(t[ok] / a[ok], b[ok] / a[ok]) / a[ok]
    return out


def weighted_chi2_isf(
    p: npt.ArrayLike, l1: npt.ArrayLike, l2: npt.ArrayLike, rtol: float = 1e-10
) -> np.ndarray:
    """Inverse survival function of ``l1 Z1^2 + l2 Z2^2``: ``t`` with ``P(Y > t) = p`` (broadcasting).

    Safeguarded Newton iteration on ``log sf`` (vectorized over every bin and channel)
    inside the bracket ``l1 chi2.isf(p, 1) <= t <= l1 chi2.isf(p, 2)`` (``l1 Z1^2 <= Y <=
    l1 (Z1^2 + Z2^2)``), to relative accuracy ``rtol``. ``l2 = 0`` is exactly
    ``l1 chi2.isf(p, 1)``; ``l1 = l2 = 0`` gives 0.

    Parameters
    ----------
    p : array_like
        Exceedance probabilities in (0, 1).
    l1, l2 : array_like
        Non-negative weights (their order does not matter).
    rtol : float
        Relative tolerance on ``t``.

    See Also
    --------
    weighted_chi2_sf : the survival function it inverts.
    weighted_chi2_pdf : the density.
    """
    a, b = _eigen_pair(l1, l2)
    p = np.asarray(p, dtype=float)
    if not np.all((p > 0) & (p < 1)):
        raise ParameterError("p must lie in the open interval (0, 1)")
    p, a, b = np.broadcast_arrays(p, a, b)
    out = np.zeros(p.shape)
    ok = a > 0
    if not np.any(ok):
        return out
    pv, r = p[ok], b[ok] / a[ok]
    out[ok] = _unit_isf(pv, r, float(rtol)) * a[ok]
    return out


def _unit_isf(pv: np.ndarray, r: np.ndarray, rtol: float) -> np.ndarray:
    """The quantiles ``x`` of ``Z1^2 + r Z2^2`` with ``P(. > x) = pv`` (:func:`weighted_chi2_isf`), for
    float64 arrays of one shape (``r = l2 / l1``)."""
    lo = _chi2_isf(pv, 1)
    hi = _chi2_isf(pv, 2)
    # start from the Welch-Satterthwaite approximation, clipped into the bracket
    c = (1.0 + r * r) / (1.0 + r)
    x = np.clip(c * _chi2_isf(pv, (1.0 + r) ** 2 / (1.0 + r * r)), lo, hi)
    x = np.where(r > 0, x, lo)
    act = r > 0
    logp = np.log(pv)
    for _ in range(200):
        if not np.any(act):
            break
        xa, ra = x[act], r[act]
        sf = _sf_unit(xa, ra)
        h = np.log(sf) - logp[act]
        lo_a = np.where(h > 0, xa, lo[act])  # sf too large: the quantile is above x
        hi_a = np.where(h > 0, hi[act], xa)
        with np.errstate(divide="ignore", invalid="ignore"):
            step = h * sf / _pdf_unit(xa, ra)  # Newton: x - h / h', h' = -pdf / sf
        xn = xa + step
        conv = np.isfinite(step) & (np.abs(step) <= rtol * xa)  # converged (may sit on the bracket)
        bad = ~np.isfinite(xn) | (xn <= lo_a) | (xn >= hi_a)
        xn = np.where(conv | (h == 0), np.where(h == 0, xa, xn), np.where(bad, 0.5 * (lo_a + hi_a), xn))
        done = conv | (h == 0) | (hi_a - lo_a <= rtol * xa)
        lo[act], hi[act], x[act] = lo_a, hi_a, xn
        idx = np.flatnonzero(act)
        act[idx[done]] = False
    return x


ThresholdKind = Literal["paper", "exact", "empirical"]
AlphaMeaning = Literal["per-bin", "family-wise", "per-frame"]
Correction = Literal["none", "bonferroni", "sidak"]
ThresholdLaw = Literal["exact", "chi2"]
#: The tested band ``(lo, hi)`` in Hz: the bins a threshold tests (not a parameter's tolerance band,
#: ``ParameterBands``, nor the band a spectrogram displays, ``band_hz`` in :mod:`chatterspec.viewer`).
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
        tested = self.tested & _in_band(self.freqs_hz, (lo, hi))
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
    return np.ones(f.shape, dtype=bool) if band is None else _in_band(f, check_band(band))


def _in_band(freqs_hz: np.ndarray, band: Band) -> np.ndarray:
    """:func:`band_mask` of a checked band."""
    lo, hi = band
    tol = 1e-9 * max(1.0, hi)
    return (freqs_hz >= lo - tol) & (freqs_hz <= hi + tol)


def check_detector(
    alpha: float, correction: str = "none", band: Band | None = None
) -> tuple[float, Correction, Band | None]:
    """``alpha`` in (0, 1), a known ``correction``, the tested band in Hz (:func:`check_band`): the checks
    of the threshold constructors, ``DetectorOptions`` and ``MonitorSettings`` (one message per bad value;
    the internal callers of :func:`per_test_alpha` and :func:`band_mask` pass checked values)."""
    if correction not in _CORRECTIONS:
        raise ParameterError(f"correction must be 'none', 'bonferroni' or 'sidak'; got {correction!r}")
    return open_unit("alpha", alpha), cast(Correction, correction), None if band is None else check_band(band)


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
    alpha, correction, _ = check_detector(alpha, correction)
    return _per_test_alpha(alpha, positive_int("n_tests", n_tests), correction)


def _per_test_alpha(alpha: float, n: int, correction: Correction) -> float:
    """:func:`per_test_alpha` of checked values (the threshold constructors have checked them)."""
    if correction == "none":
        return alpha
    if correction == "bonferroni":
        return alpha / n
    return float(-np.expm1(np.log1p(-alpha) / n))  # sidak


def _check_law(law: str) -> ThresholdLaw:
    if law not in _LAWS:
        raise ParameterError(f"law must be one of {_LAWS}; got {law!r}")
    return cast(ThresholdLaw, law)


def _chi2_threshold(
    expected: np.ndarray,
    freqs: np.ndarray,
    dt: float,
    alpha: float,
    correction: Correction,
    averaged: int,
    kind: ThresholdKind,
    meaning_if_corrected: AlphaMeaning,
    eigen: tuple[np.ndarray, np.ndarray] | None = None,
    band: Band | None = None,
) -> Threshold:
    is_dc, is_nyq = bin_layout(freqs, dt)
    tested = ~(is_dc | is_nyq)
    if not tested.any():
        raise ShapeError("no frequency bin left to test (need bins other than DC and Nyquist)")
    tested = _band_tested(tested, freqs, band)
    n_tested = int(np.count_nonzero(tested))
    a = _per_test_alpha(alpha, n_tested, correction)
    dof = np.where(is_dc | is_nyq, averaged, 2 * averaged)
    eigenvalues = None
    if eigen is None:
        quant = _chi2_isf(a, dof) / dof
        values = expected * quant[:, None]
        eff = np.broadcast_to(dof[:, None].astype(float), expected.shape)
    else:
        l1, l2 = eigen
        eigenvalues = np.stack([l1, l2], axis=-1)
        s1, s2 = l1 + l2, l1 * l1 + l2 * l2
        with np.errstate(divide="ignore", invalid="ignore"):
            eff = np.where(s2 > 0, averaged * s1 * s1 / np.where(s2 > 0, s2, 1.0), 2.0 * averaged)
        if averaged == 1:
            values = weighted_chi2_isf(a, l1, l2)
        else:  # Welch-Satterthwaite: (c / K) chi2(nu_eff), c = (l1^2 + l2^2) / (l1 + l2)
            with np.errstate(divide="ignore", invalid="ignore"):
                c = np.where(s1 > 0, s2 / np.where(s1 > 0, s1, 1.0), 0.0)
            values = c * _chi2_isf(a, eff) / averaged
    return Threshold(
        values=readonly(values),
        freqs_hz=readonly(np.array(freqs)),
        kind=kind,
        alpha=alpha,
        alpha_meaning="per-bin" if correction == "none" else meaning_if_corrected,
        correction=correction,
        tested=readonly(tested),
        dof=readonly(dof.astype(int)),
        averaged=averaged,
        per_test_alpha=a,
        expected=readonly(np.array(expected)),
        law="chi2" if eigen is None else "exact",
        eigenvalues=None if eigenvalues is None else readonly(eigenvalues),
        effective_dof=readonly(np.array(eff, dtype=float)),
        band=band,
    )


def _band_tested(tested: np.ndarray, freqs: np.ndarray, band: Band | None) -> np.ndarray:
    """``tested`` restricted to ``band``; a band holding no tested bin is a ParameterError."""
    if band is None:
        return tested
    out = tested & _in_band(freqs, band)
    if not out.any():
        f = freqs[tested]
        raise ParameterError(
            f"band [{band[0]:g}, {band[1]:g}] Hz holds no tested bin: the tested bins span "
            f"{f.min():g} .. {f.max():g} Hz (DC and Nyquist are never tested)"
        )
    return out


def exact_threshold(
    model: LinearModel,
    freqs_hz: np.ndarray,
    n_samples: int,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    averaged: int = 1,
    law: ThresholdLaw = "exact",
    band: Band | None = None,
) -> Threshold:
    """Per-bin threshold from the exact finite-N law of each healthy periodogram bin.

    ``law="exact"`` (default): the ``1 - a`` quantile of ``l1 Z1^2 + l2 Z2^2``
    (:func:`weighted_chi2_isf`, eigenvalues from
    :func:`chatterspec.detection.spectral.periodogram_eigenvalues`); for ``averaged = K > 1`` the
    Welch-Satterthwaite approximation ``(c / K) chi2(nu_eff)`` (module docstring).
    ``law="chi2"``: the approximation ``E[S(f)] chi2.ppf(1 - a, nu) / nu`` (Lemma 2).

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Periodogram frequencies (Hz) of an ``n_samples`` record.
    n_samples : int
        Record length N (for the exact finite-N expectation).
    alpha : float
        False-alarm probability in (0, 1): family-wise over the tested bins
        (``correction`` "bonferroni" or "sidak") or per-bin (``"none"``).
    correction : {"bonferroni", "sidak", "none"}
    averaged : int
        K independent periodograms averaged: ``nu = 2K`` (``K`` at DC/Nyquist).
    law : {"exact", "chi2"}
        Law of a healthy bin: exact weighted sum of two chi2(1) (default) or ``E chi2(nu) / nu``.
    band : (float, float), optional
        ``(lo, hi)`` in Hz: test only these bins; the correction counts only them.

    Returns
    -------
    Threshold
        ``kind="exact"``; bins ``1 .. ceil(N/2) - 1`` (within ``band``) tested.

    See Also
    --------
    paper_threshold : the paper's flat bound (eq 58-62).
    frame_threshold : the per-frame threshold of the STFT.
    """
    alpha, correction, band = check_detector(alpha, correction, band)
    averaged = positive_int("averaged", averaged)
    law = _check_law(law)
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    E = expected_spectrum(model, freqs, n_samples, form="exact")
    eigen = periodogram_eigenvalues(model, freqs, n_samples) if law == "exact" else None
    return _chi2_threshold(
        E, freqs, model.dt, alpha, correction, averaged, "exact", "family-wise", eigen, band
    )


def frame_threshold(
    model: LinearModel,
    freqs_hz: np.ndarray,
    config: STFTConfig,
    dt: float | None = None,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    law: ThresholdLaw = "exact",
    band: Band | None = None,
) -> Threshold:
    """Per-frame STFT threshold from the exact law of each healthy frame bin.

    ``alpha`` is the probability that one healthy frame has any tested bin
    (``1 .. W/2 - 1``) above the threshold (``alpha_meaning="per-frame"``);
    with ``correction="none"`` it is per bin. ``law="exact"`` (default): the
    quantile of ``l1 Z1^2 + l2 Z2^2`` with :func:`chatterspec.detection.spectral.frame_eigenvalues`.
    ``law="chi2"``: :func:`chatterspec.detection.spectral.expected_frame_spectrum` times
    ``chi2(2)/2`` (exact for white noise at bins >= 2, an approximation otherwise).

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Frame frequencies (Hz), :attr:`chatterspec.detection.spectral.Spectrogram.freqs_hz`.
    config : STFTConfig
        Window settings.
    dt : float, optional
        Sampling time (s); defaults to ``model.dt``.
    alpha : float
        Per-frame false-alarm probability in (0, 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise control over the tested bins of one frame.
    law : {"exact", "chi2"}
        Law of a healthy frame bin (see above).
    band : (float, float), optional
        ``(lo, hi)`` in Hz: test only these frame bins; the correction counts only them.

    See Also
    --------
    exact_threshold : the whole-record threshold.
    """
    alpha, correction, band = check_detector(alpha, correction, band)
    law = _check_law(law)
    dt = model.dt if dt is None else positive("dt", dt, unit="s")
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    E = expected_frame_spectrum(model, freqs, config, dt)
    eigen = frame_eigenvalues(model, freqs, config, dt) if law == "exact" else None
    return _chi2_threshold(E, freqs, dt, alpha, correction, 1, "exact", "per-frame", eigen, band)


def monitor_threshold(model: Model, settings: MonitorSettings) -> Threshold:
    """The per-frame threshold of the chattering monitor of ``model`` with ``settings``.

    The one place it is computed: the monitor and the calibration of its alarm rule both take it from
    here (a caller that needs it for both computes it once and passes it on).

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        The monitored model (a nonlinear one needs ``settings.threshold``).
    settings : MonitorSettings
        Without a threshold: the exact per-frame threshold of the model's chattering spectrum
        (:func:`frame_threshold` at the settings' STFT, ``alpha``, ``correction`` and ``band``); with one
        (e.g. a calibration's): that threshold restricted to the band.

    Returns
    -------
    Threshold

    Raises
    ------
    ShapeError
        The given threshold was made for another STFT window or model (other bins or channels).
    ModelKindError
        A nonlinear model without a given threshold.
    """
    from .spectral import spectrum_model

    dt = model.dt
    freqs_hz = settings.stft.freqs_hz(dt)
    th = settings.threshold
    if th is None:
        return frame_threshold(
            spectrum_model(model), freqs_hz, settings.stft, dt, settings.alpha, settings.correction,
            band=settings.band,
        )  # fmt: skip
    if th.values.shape != (freqs_hz.size, model.n_outputs) or not np.allclose(th.freqs_hz, freqs_hz):
        raise ShapeError(
            f"the given per-frame threshold has shape {th.values.shape} at other frequencies than "
            f"this monitor's frames ({freqs_hz.size} bins x {model.n_outputs} channels): it "
            "was made for another STFT window or model"
        )
    return th.restricted(settings.band)


def paper_gamma_matrix(model: LinearModel) -> np.ndarray:
    """``Lambda`` of eq (58): ``M = -C A C^-1`` with ``m_ii +- 1`` on the diagonal.

    The diagonal gets ``m_ii + 1`` where ``m_ii >= 0`` and ``m_ii - 1`` otherwise, so that
    ``|e^{i w} delta_ij + m_ij| <= |lambda_ij|`` at every frequency (the paper's bound, eq 59).

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    """
    chattering_autocovariance(model)  # validates full measurement
    M = -model.C @ model.A @ model.C_inv
    L = M.copy()
    d = np.diag(M)
    L[np.diag_indices_from(L)] = np.where(d >= 0, d + 1.0, d - 1.0)
    return L


def paper_threshold(
    model: LinearModel, freqs_hz: np.ndarray, alpha: float = 1e-3, band: Band | None = None
) -> Threshold:
    """The paper's flat threshold (eq 58-62): ``Sigma_Gamma_ii chi2.ppf(1 - alpha, 2) / 2``.

    ``Sigma_Gamma = C Q C^T + Lambda R Lambda^T`` with ``Lambda`` from
    :func:`paper_gamma_matrix`. ``alpha`` is a **per-bin** level (eq 57); the
    threshold is the same at every bin, including DC (where it is not a valid
    chi2(1) bound; DC is not tested anyway).

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Periodogram frequencies (Hz).
    alpha : float
        Per-bin false-alarm probability in (0, 1).
    band : (float, float), optional
        ``(lo, hi)`` in Hz: test only these bins (beyond the paper; the per-bin level is unchanged).

    See Also
    --------
    exact_threshold : each bin's own law (the default).
    frame_threshold : the per-frame threshold of the STFT.
    """
    alpha, _, band = check_detector(alpha, band=band)
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    L = paper_gamma_matrix(model)
    sigma = np.diag(model.C @ model.Q @ model.C.T + L @ model.R @ L.T)
    is_dc, is_nyq = bin_layout(freqs, model.dt)
    values = np.broadcast_to(sigma * _chi2_isf(alpha, 2) / 2.0, (freqs.size, sigma.size))
    dof = np.where(is_dc | is_nyq, 1, 2)
    return Threshold(
        values=readonly(np.array(values)),
        freqs_hz=readonly(np.array(freqs)),
        kind="paper",
        alpha=alpha,
        alpha_meaning="per-bin",
        correction="none",
        tested=readonly(_band_tested(~(is_dc | is_nyq), freqs, band)),
        dof=readonly(dof),
        averaged=1,
        per_test_alpha=alpha,
        expected=None,
        law="chi2",
        effective_dof=readonly(np.broadcast_to(dof[:, None].astype(float), values.shape).copy()),
        band=band,
    )


def threshold(
    kind: str,
    model: LinearModel,
    freqs_hz: np.ndarray,
    *,
    n_samples: int | None = None,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    averaged: int = 1,
    config: STFTConfig | None = None,
    law: ThresholdLaw = "exact",
    band: Band | None = None,
) -> Threshold:
    """Build a threshold by name: ``"exact"`` (default detector), ``"paper"`` or ``"frame"``.

    Parameters
    ----------
    kind : {"exact", "paper", "frame"}
        Threshold family (``"empirical"`` thresholds come from
        :mod:`chatterspec.studies`).
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Frequencies (Hz) of the spectra to test.
    n_samples : int, optional
        Record length N; required for ``"exact"``.
    alpha : float
        False-alarm probability in (0, 1).
    correction : {"bonferroni", "sidak", "none"}
        Ignored by ``"paper"`` (per-bin).
    averaged : int
        K averaged spectra (``"exact"`` only; ``"paper"`` requires 1).
    config : STFTConfig, optional
        Window settings for ``"frame"`` (default 1 s Hamming, 0.2 s hop).
    law : {"exact", "chi2"}
        Bin law for ``"exact"`` and ``"frame"`` (ignored by ``"paper"``).
    band : (float, float), optional
        ``(lo, hi)`` in Hz: bins tested (every kind); corrections count only these bins.

    Raises
    ------
    ParameterError
        Unknown ``kind`` (the message lists the valid ones), missing argument, alpha outside (0, 1).
    """
    if kind == "exact":  # (each constructor checks alpha, correction and band)
        if n_samples is None:
            raise ParameterError('threshold("exact", ...) needs n_samples (the record length N)')
        return exact_threshold(model, freqs_hz, n_samples, alpha, correction, averaged, law, band)
    if kind == "paper":
        if averaged != 1:
            raise ParameterError('the "paper" threshold is for a single record; use "exact" with averaged=K')
        return paper_threshold(model, freqs_hz, alpha, band)
    if kind == "frame":
        return frame_threshold(model, freqs_hz, config or STFTConfig(), None, alpha, correction, law, band)
    raise ParameterError(f"unknown threshold kind {kind!r}; choose one of 'exact', 'paper', 'frame'")


NORMALIZATION_SMOOTH_BINS = 5  # h: half-width of the moving average (11 bins = 2.75 Hz at N = 4000, 1 ms)


def smooth_spectrum(mean_power: np.ndarray, half_width: int = NORMALIZATION_SMOOTH_BINS) -> np.ndarray:
    """Moving average over ``2 h + 1`` bins of the interior (tested) bins; DC and Nyquist unchanged.

    Parameters
    ----------
    mean_power : (bins, m) array
        Mean periodogram or frame spectrum (power units, e.g. Pa^2 for pressure).
    half_width : int
        ``h >= 0`` bins on each side; the ends are mirrored (a real signal's spectrum is even
        about DC and Nyquist).

    Returns
    -------
    (bins, m) ndarray
    """
    P = finite_array("mean_power", mean_power, ndim=2)
    h = int(half_width)
    if h < 0:
        raise ParameterError(f"half_width must be >= 0 bins; got {half_width}")
    out = P.copy()
    if h and P.shape[0] > 3:
        import scipy.ndimage  # here, not at the top: the monitor imports this module at start-up (30 ms)

        out[1:-1] = scipy.ndimage.uniform_filter1d(P[1:-1], 2 * h + 1, axis=0, mode="reflect")
    if np.any(out[1:-1] <= 0):
        raise ParameterError("the healthy chattering has zero power in some bin: cannot normalize by it")
    return out


def normalization_spectrum(
    records: Iterable[np.ndarray], dt: float, half_width: int = NORMALIZATION_SMOOTH_BINS
) -> tuple[np.ndarray, int]:
    """Estimated healthy periodogram ``E_hat[S]`` from chunks of healthy chattering.

    Parameters
    ----------
    records : iterable of (runs, N, m) arrays
        Healthy chattering chunks (same N and m).
    dt : float
        Sampling time in seconds.
    half_width : int
        Smoothing half-width in bins (:func:`smooth_spectrum`).

    Returns
    -------
    (E_hat (bins, m), runs)
    """
    total, runs = None, 0
    for x in records:
        S = periodogram(x, dt).power
        s = S.sum(axis=0)
        if total is not None and s.shape != total.shape:
            raise ShapeError(f"chunk spectrum {s.shape} differs from the first chunk's {total.shape}")
        total = s if total is None else total + s
        runs += S.shape[0]
    if total is None:
        raise ParameterError("no healthy chattering to estimate the normalization from")
    return smooth_spectrum(total / runs, half_width), runs


def frame_normalization(
    records: Iterable[np.ndarray],
    dt: float,
    config: STFTConfig,
    half_width: int = NORMALIZATION_SMOOTH_BINS,
) -> np.ndarray:
    """Estimated healthy STFT frame spectrum (mean over runs and frames, then smoothed).

    Parameters
    ----------
    records : iterable of (runs, N, m) arrays
        Healthy chattering chunks.
    dt : float
        Sampling time in seconds.
    config : STFTConfig
        Window length and hop (s) and taper.
    half_width : int
        Smoothing half-width in frame bins (:func:`smooth_spectrum`).

    Returns
    -------
    (fbins, m) ndarray
    """
    total, count = None, 0
    for x in records:
        P = stft_spectrogram(x, dt, config).power  # (runs, F, fb, m)
        s = P.sum(axis=(0, 1))
        total = s if total is None else total + s
        count += P.shape[0] * P.shape[1]
    if total is None or count == 0:
        raise ParameterError("no complete STFT frame to estimate the frame normalization from")
    return smooth_spectrum(total / count, half_width)


def empirical_family_wise_threshold(
    normalization: np.ndarray,
    freqs_hz: np.ndarray,
    tested: np.ndarray,
    factor: np.ndarray,
    alpha: float,
    meaning: AlphaMeaning = "family-wise",
) -> Threshold:
    """Threshold ``E_hat * q`` per channel (``kind="empirical"``).

    Parameters
    ----------
    normalization : (bins, m) array
        Estimated healthy spectrum ``E_hat`` (power units).
    freqs_hz : (bins,) array
        Bin frequencies in Hz.
    tested : (bins,) bool array
        Bins the detector tests (DC and Nyquist excluded).
    factor : (m,) array
        Empirical ``(1 - alpha)``-quantile of ``max_tested S / E_hat`` per channel.
    alpha : float
        Its nominal false-alarm probability in (0, 1).
    meaning : {"family-wise", "per-frame"}
        Record-level family-wise, or per STFT frame (family-wise over the frame's bins).

    Returns
    -------
    Threshold
    """
    alpha = open_unit("alpha", alpha)
    if meaning not in ("family-wise", "per-frame"):
        raise ParameterError(f"meaning must be 'family-wise' or 'per-frame'; got {meaning!r}")
    E = finite_array("normalization", normalization, ndim=2)
    q = finite_array("factor", factor, ndim=1)
    if q.shape[0] != E.shape[1]:
        raise ShapeError(f"factor needs one value per channel ({E.shape[1]}); got {q.shape}")
    tested = np.asarray(tested, dtype=bool)
    values = E * q
    ro = [np.array(a) for a in (values, freqs_hz, tested, np.where(tested, 2, 1), E)]
    for a in ro:
        a.setflags(write=False)
    return Threshold(
        values=ro[0],
        freqs_hz=ro[1],
        kind="empirical",
        alpha=alpha,
        alpha_meaning=meaning,
        correction="none",
        tested=ro[2],
        dof=ro[3],
        averaged=1,
        per_test_alpha=float("nan"),
        expected=ro[4],
    )
