"""Naming the bins behind a fault verdict: the most significant bin and the bin of largest excess.

A flagged frame has two bins worth naming, and they can differ by far:

- the **most significant** bin, the largest ``S / threshold`` (the detector's own peak: the bin whose
  test fails hardest);
- the bin of **largest excess**, the largest excess power ``S - E`` over the expected healthy spectrum
  ``E`` among the bins over the threshold (the batch report's ``peak_hz``): where the added power is.

On a nonlinear EHA leak (``eha4-leak-timeline``) the most significant bin is 1 Hz, the bottom row of the
spectrogram, where the expected spectrum is tiny, while the eye goes to the bright band near 76 Hz,
the largest excess. Reports name both, each with its level in dB over the threshold
(``10 log10(S / threshold)``), with :func:`two_bins_text`.
"""

from __future__ import annotations

import math

__all__ = ["db_over_threshold", "two_bins_text"]


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
