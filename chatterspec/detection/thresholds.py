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
"""

from __future__ import annotations

from typing import cast

import numpy as np

from .._validate import check_band, finite_array, open_unit, positive, positive_int, readonly
from ..errors import ParameterError, ShapeError
from ..plants.models import LinearModel
from .bin_law import _chi2_isf, weighted_chi2_isf, weighted_chi2_pdf, weighted_chi2_sf
from .spectral import (
    STFTConfig,
    chattering_autocovariance,
    expected_frame_spectrum,
    expected_spectrum,
    frame_eigenvalues,
    periodogram_eigenvalues,
)
from .threshold_type import (
    _LAWS,
    AlphaMeaning,
    Band,
    Correction,
    Threshold,
    ThresholdKind,
    ThresholdLaw,
    band_mask,
    bin_layout,
    per_test_alpha,
)
from .threshold_type import __all__ as _TYPE_NAMES

__all__ = [  # the threshold type's names (re-exported: their documented home) and the constructors
    *_TYPE_NAMES,
    "check_band",
    "exact_threshold",
    "frame_threshold",
    "paper_gamma_matrix",
    "paper_threshold",
    "threshold",
    "weighted_chi2_isf",
    "weighted_chi2_pdf",
    "weighted_chi2_sf",
]


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
    band = None if band is None else check_band(band)
    tested = _band_tested(tested, freqs, band)
    n_tested = int(np.count_nonzero(tested))
    a = per_test_alpha(alpha, n_tested, correction)
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
    out = tested & band_mask(freqs, band)
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
    alpha = open_unit("alpha", alpha)
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
    alpha = open_unit("alpha", alpha)
    law = _check_law(law)
    dt = model.dt if dt is None else positive("dt", dt, unit="s")
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    E = expected_frame_spectrum(model, freqs, config, dt)
    eigen = frame_eigenvalues(model, freqs, config, dt) if law == "exact" else None
    return _chi2_threshold(E, freqs, dt, alpha, correction, 1, "exact", "per-frame", eigen, band)


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
    alpha = open_unit("alpha", alpha)
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    band = None if band is None else check_band(band)
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
    alpha = open_unit("alpha", alpha)
    if kind == "exact":
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
