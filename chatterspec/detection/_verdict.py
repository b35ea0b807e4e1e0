"""Compiled one-pass verdict of :func:`chatterspec.detection.spectrum_verdicts.detect_spectrum`.

The numpy path of ``detect_spectrum`` makes eight passes over the ``(runs, bins, m)``
spectra (a masked copy, the ratio, three ``argmax`` along the strided bin axis, ...);
at 4000-sample records they cost as much as the simulation itself. This kernel walks
each spectrum once and returns the same three things: the bin of the largest
``S / threshold`` (``most_significant_hz``, ``peak_ratio``), the bin of the largest
excess ``S - E[S]`` among the bins over the threshold, or over all tested bins when
none is over (``peak_hz``), and whether any bin is over. Every value is an element
of the arrays numpy computes (one correctly rounded ``/`` or ``-`` each, no sums),
and ``argmax`` is reproduced exactly: first occurrence of the maximum, or the first
NaN if there is one. The sum over the tested bins (``excess_power``) is added in bin
order, ``S_0 + S_1 + ...``: the order numpy uses for a C-contiguous ``(..., bins, m)``
array with m >= 2 channels (the reduced axis is not the innermost one, so numpy adds
bin after bin); for other layouts, where numpy may sum pairwise, the caller keeps
numpy's sum. The results are therefore bit-identical to the numpy path
(``tests/test_e2e_kernels.py``). The online monitor takes the same loop without the excess
and the sum (:data:`peak_kernel`); its frames hold no NaN, where ``argmax``'s rule is "the first
strictly larger ratio", and it flags a frame when the largest ratio exceeds 1.
"""

from __future__ import annotations

import numpy as np

from .. import _jit

__all__ = ["peak_channel", "peak_kernel", "verdict_channel", "verdict_kernel"]


@_jit.step
def argmax_update(j: int, v: float, k: int, best: float, nan: bool) -> tuple[int, float, bool]:
    """One element of numpy's ``argmax``: ``(k, best, nan)`` after value ``v`` at position ``j``.

    The first NaN wins for good; otherwise only a strictly larger value replaces the best one.
    """
    if nan:
        return k, best, nan
    if v != v:
        return j, v, True
    if v > best:
        return j, v, False
    return k, best, nan


#: Binding of :func:`_verdict_channel`: also the excess bin and the sum (False: only the ratio's argmax).
FULL = True


def _verdict_loop(
    power: np.ndarray,
    thr: np.ndarray,
    expected: np.ndarray,
    idx: np.ndarray,
    k_ratio: np.ndarray,
    peak_ratio: np.ndarray,
    k_excess: np.ndarray,
    p_sum: np.ndarray,
) -> None:  # pragma: no cover - compiled (a template: verdict_kernel, peak_kernel)
    """Per spectrum r and channel c, over the tested bins ``idx`` (positions j = 0 .. len(idx) - 1).

    With ``FULL`` (:data:`verdict_kernel`, :func:`~chatterspec.detection.spectrum_verdicts.detect_spectrum`)
    all four outputs; without (:data:`peak_kernel`, the online monitor's frames) only ``k_ratio``
    and ``peak_ratio`` (``expected``, ``k_excess``, ``p_sum`` unused).

    Parameters
    ----------
    power : (R, bins, m) array
        Spectra S (any strides).
    thr : (bins, m) array
        Threshold values.
    expected : (bins, m) array
        Healthy expectation E[S].
    idx : (n_tested,) int array
        Tested bins, increasing (at least one).
    k_ratio : (R, m) int array
        Output: position j of ``argmax_j S / thr`` (numpy ``argmax`` semantics).
    peak_ratio : (R, m) array
        Output: ``S / thr`` at ``k_ratio``.
    k_excess : (R, m) int array
        Output: position j of ``argmax_j (S - E[S])`` over the bins with ``S / thr > 1``
        (the others count as ``-inf``), or over every tested bin when none is over.
    p_sum : (R, m) array
        Output: ``sum_j S`` added in the order j = 0, 1, ... (``S_0 + S_1 + ...``).
    """
    b_ = _jit.borrow
    power, thr, expected, idx = b_(power), b_(thr), b_(expected), b_(idx)
    k_ratio, peak_ratio, k_excess, p_sum = b_(k_ratio), b_(peak_ratio), b_(k_excess), b_(p_sum)
    R = power.shape[0]
    m = power.shape[2]
    for r in range(R):
        for c in range(m):
            CHANNEL(power, thr, expected, idx, k_ratio, peak_ratio, k_excess, p_sum, r, c)


def _verdict_channel(
    power: np.ndarray,
    thr: np.ndarray,
    expected: np.ndarray,
    idx: np.ndarray,
    k_ratio: np.ndarray,
    peak_ratio: np.ndarray,
    k_excess: np.ndarray,
    p_sum: np.ndarray,
    r: int,
    c: int,
) -> None:  # pragma: no cover - compiled (a step template: verdict_channel, peak_channel)
    """:func:`_verdict_loop` for spectrum ``r`` and channel ``c`` (its arguments; ``FULL`` as there)."""
    nt = idx.shape[0]
    b = idx[0]
    p = power[r, b, c]
    ratio = p / thr[b, c]
    # argmax trackers: index, value, NaN seen (argmax returns the first NaN)
    kr, vr, nr = 0, ratio, ratio != ratio
    if FULL:
        ex = p - expected[b, c]
        over = ratio > 1.0
        ke, ve, ne = 0, ex, ex != ex
        wv = ex if over else -np.inf  # np.where(over, excess, -inf)
        kw, vw, nw = 0, wv, wv != wv
        any_over = over
        ps = p
    for j in range(1, nt):
        b = idx[j]
        p = power[r, b, c]
        ratio = p / thr[b, c]
        kr, vr, nr = argmax_update(j, ratio, kr, vr, nr)
        if FULL:
            ex = p - expected[b, c]
            ps += p
            ke, ve, ne = argmax_update(j, ex, ke, ve, ne)
            if ratio > 1.0:
                any_over = True
                kw, vw, nw = argmax_update(j, ex, kw, vw, nw)
    k_ratio[r, c] = kr
    peak_ratio[r, c] = vr
    if FULL:
        k_excess[r, c] = kw if any_over else ke
        p_sum[r, c] = ps


#: One spectrum and channel of the full verdict / of the monitor's peak (inlined steps).
verdict_channel = _jit.specialize(_verdict_channel, "full", inline=True, FULL=True)
peak_channel = _jit.specialize(_verdict_channel, "peak", inline=True, FULL=False)
CHANNEL = verdict_channel


#: The one-pass verdict of :func:`~chatterspec.detection.spectrum_verdicts.detect_spectrum`.
verdict_kernel = _jit.specialize(_verdict_loop, "full", CHANNEL=verdict_channel)
#: The same pass for the online monitor's frames: the bin of the largest ``S / threshold`` only.
peak_kernel = _jit.specialize(_verdict_loop, "peak", CHANNEL=peak_channel)
