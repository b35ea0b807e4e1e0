"""Chi-squared thresholds for the chattering power spectrum (eq 57-64, ``DESIGN.md`` section 5).

Every threshold is an array ``(bins, m)`` with a :class:`Threshold` record of
what its ``alpha`` means:

``paper`` (eq 58-62)
    The flat bound ``Sigma_Gamma_ii chi2.ppf(1 - alpha, 2) / 2`` with
    ``Sigma_Gamma = C Q C^T + Lambda R Lambda^T``; ``alpha`` is a **per-bin**
    level (and the bound is conservative: it dominates the true spectrum).
``exact``
    ``E[S_i(f)] chi2.ppf(1 - a, nu) / nu`` per bin with the exact expected
    spectrum (:func:`chatterspec.spectral.expected_spectrum`); ``nu = 2`` for
    bins ``1 .. ceil(N/2) - 1`` and ``nu = 1`` for DC and the Nyquist bin
    (real-valued DFT there, ``DESIGN.md`` 8.8). Averaging K independent
    periodograms multiplies ``nu`` by K.
``frame`` (STFT)
    The same with the expected frame spectrum, family-wise over the bins of
    **one frame** (``alpha_meaning = "per-frame"``).

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
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.stats

from ._validate import finite_array, open_unit, positive, positive_int
from .errors import ParameterError, ShapeError
from .models import LinearModel
from .spectral import STFTConfig, chattering_autocovariance, expected_frame_spectrum, expected_spectrum

__all__ = [
    "AlphaMeaning",
    "Correction",
    "Threshold",
    "ThresholdKind",
    "bin_layout",
    "exact_threshold",
    "frame_threshold",
    "paper_gamma_matrix",
    "paper_threshold",
    "per_test_alpha",
    "threshold",
]

ThresholdKind = Literal["paper", "exact", "empirical"]
AlphaMeaning = Literal["per-bin", "family-wise", "per-frame"]
Correction = Literal["none", "bonferroni", "sidak"]
_CORRECTIONS = ("none", "bonferroni", "sidak")


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a)
    a.setflags(write=False)
    return a


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
        Chi-squared degrees of freedom of ``nu S / E[S]`` per bin (2K, or K at DC/Nyquist).
    averaged : int
        Number K of independent spectra averaged (1 for a single record).
    per_test_alpha : float
        Level ``a`` applied to each tested bin after the correction.
    expected : (bins, m) array or None
        Expected healthy spectrum the threshold was built from (None for ``paper``).
    """

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

    @property
    def n_tested(self) -> int:
        """Number of bins in the family (bins used for the verdict)."""
        return int(np.count_nonzero(self.tested))

    @property
    def n_channels(self) -> int:
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

    def describe(self) -> str:
        """One sentence saying what ``alpha`` guarantees for this threshold."""
        avg = f" for the average of {self.averaged} independent spectra" if self.averaged > 1 else ""
        band = f"{self.n_tested} tested bins (DC and Nyquist excluded)"
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


def _chi2_threshold(
    expected: np.ndarray,
    freqs: np.ndarray,
    dt: float,
    alpha: float,
    correction: Correction,
    averaged: int,
    kind: ThresholdKind,
    meaning_if_corrected: AlphaMeaning,
) -> Threshold:
    is_dc, is_nyq = bin_layout(freqs, dt)
    tested = ~(is_dc | is_nyq)
    n_tested = int(np.count_nonzero(tested))
    if n_tested == 0:
        raise ShapeError("no frequency bin left to test (need bins other than DC and Nyquist)")
    a = per_test_alpha(alpha, n_tested, correction)
    dof = np.where(is_dc | is_nyq, averaged, 2 * averaged)
    quant = scipy.stats.chi2.isf(a, dof) / dof
    values = expected * quant[:, None]
    return Threshold(
        values=_readonly(values),
        freqs_hz=_readonly(np.array(freqs)),
        kind=kind,
        alpha=alpha,
        alpha_meaning="per-bin" if correction == "none" else meaning_if_corrected,
        correction=correction,
        tested=_readonly(tested),
        dof=_readonly(dof.astype(int)),
        averaged=averaged,
        per_test_alpha=a,
        expected=_readonly(np.array(expected)),
    )


def exact_threshold(
    model: LinearModel,
    freqs_hz: np.ndarray,
    n_samples: int,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    averaged: int = 1,
) -> Threshold:
    """Exact per-bin chi-squared threshold ``E[S(f)] chi2.ppf(1 - a, nu) / nu``.

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

    Returns
    -------
    Threshold
        ``kind="exact"``; bins ``1 .. ceil(N/2) - 1`` tested.
    """
    alpha = open_unit("alpha", alpha)
    averaged = positive_int("averaged", averaged)
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    E = expected_spectrum(model, freqs, n_samples, form="exact")
    return _chi2_threshold(E, freqs, model.dt, alpha, correction, averaged, "exact", "family-wise")


def frame_threshold(
    model: LinearModel,
    freqs_hz: np.ndarray,
    config: STFTConfig,
    dt: float | None = None,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
) -> Threshold:
    """Per-frame STFT threshold from :func:`chatterspec.spectral.expected_frame_spectrum`.

    ``alpha`` is the probability that one healthy frame has any tested bin
    (``1 .. W/2 - 1``) above the threshold (``alpha_meaning="per-frame"``);
    with ``correction="none"`` it is per bin. A Hamming-windowed frame of the
    MA(1) chattering is chi2(2)/2 times its mean to a very good approximation
    (exactly for white noise at bins >= 2).

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Frame frequencies (Hz), :attr:`chatterspec.spectral.Spectrogram.freqs_hz`.
    config : STFTConfig
        Window settings.
    dt : float, optional
        Sampling time (s); defaults to ``model.dt``.
    alpha : float
        Per-frame false-alarm probability in (0, 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise control over the tested bins of one frame.
    """
    alpha = open_unit("alpha", alpha)
    dt = model.dt if dt is None else positive("dt", dt, unit="s")
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    E = expected_frame_spectrum(model, freqs, config, dt)
    return _chi2_threshold(E, freqs, dt, alpha, correction, 1, "exact", "per-frame")


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


def paper_threshold(model: LinearModel, freqs_hz: np.ndarray, alpha: float = 1e-3) -> Threshold:
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
    """
    alpha = open_unit("alpha", alpha)
    freqs = finite_array("freqs_hz", freqs_hz, ndim=1)
    L = paper_gamma_matrix(model)
    sigma = np.diag(model.C @ model.Q @ model.C.T + L @ model.R @ L.T)
    is_dc, is_nyq = bin_layout(freqs, model.dt)
    values = np.broadcast_to(sigma * scipy.stats.chi2.isf(alpha, 2) / 2.0, (freqs.size, sigma.size))
    dof = np.where(is_dc | is_nyq, 1, 2)
    return Threshold(
        values=_readonly(np.array(values)),
        freqs_hz=_readonly(np.array(freqs)),
        kind="paper",
        alpha=alpha,
        alpha_meaning="per-bin",
        correction="none",
        tested=_readonly(~(is_dc | is_nyq)),
        dof=_readonly(dof),
        averaged=1,
        per_test_alpha=alpha,
        expected=None,
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
) -> Threshold:
    """Build a threshold by name: ``"exact"`` (default detector), ``"paper"`` or ``"frame"``.

    Parameters
    ----------
    kind : {"exact", "paper", "frame"}
        Threshold family (``"empirical"`` thresholds come from
        :mod:`chatterspec.calibration`).
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

    Raises
    ------
    ParameterError
        Unknown ``kind`` (the message lists the valid ones), missing argument, alpha outside (0, 1).
    """
    alpha = open_unit("alpha", alpha)
    if kind == "exact":
        if n_samples is None:
            raise ParameterError('threshold("exact", ...) needs n_samples (the record length N)')
        return exact_threshold(model, freqs_hz, n_samples, alpha, correction, averaged)
    if kind == "paper":
        if averaged != 1:
            raise ParameterError('the "paper" threshold is for a single record; use "exact" with averaged=K')
        return paper_threshold(model, freqs_hz, alpha)
    if kind == "frame":
        return frame_threshold(model, freqs_hz, config or STFTConfig(), None, alpha, correction)
    raise ParameterError(f"unknown threshold kind {kind!r}; choose one of 'exact', 'paper', 'frame'")
