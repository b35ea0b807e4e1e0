"""Verdicts of the chattering spectra: whole records, STFT frames and the frames' ``-log p`` score.

Whole-record spectra (``docs/design.md`` §6)
--------------------------------------------
A channel is flagged when its spectrum exceeds the threshold at any **tested**
bin (DC and Nyquist excluded; the DC ratio is reported separately because a
step input puts a large DC term into any mismatch). The default detector is the
``exact`` threshold with Bonferroni correction at family-wise alpha = 0.1 %.

Where the fault is (two frequencies, both over the tested bins):

``peak_hz``
    Frequency (Hz) of the largest **excess power** ``S(f_n) - E[S(f_n)]``: the
    spectrum's peak above the healthy expectation, the fault footprint the paper
    reads off its figures (e.g. 34-36 Hz for EHA leakage). When some bins exceed
    the threshold, the largest excess among those bins (on one noisy record the
    largest excess overall often sits on a healthy high-frequency bin where
    ``E[S]`` and its spread are largest).
``most_significant_hz``
    Frequency (Hz) of the largest ``S(f_n) / threshold(f_n)``: the bin that decides
    the verdict (``peak_ratio`` is its ratio). Where the healthy spectrum is small
    this can sit far from ``peak_hz`` (14-22 Hz for EHA leakage).

Severity scores (both grow with fault size within a fault family):

``peak_ratio``
    ``max_n S(f_n) / threshold(f_n)`` over the tested bins (the paper's peak
    height relative to its bound; > 1 means detected).
``excess_power``
    ``sum_n (S(f_n) - E[S(f_n)]) / sum_n E[S(f_n)]`` over the tested bins: the
    fraction of power above the healthy expectation (about 0 when healthy,
    with standard deviation ``1 / sqrt(n_tested)`` for a single record).

STFT frames
-----------
STFT frame verdicts and fault intervals: one verdict rule for batch records and the online monitor.

:func:`frame_verdicts` (and its precomputed form :class:`FrameVerdicts`, which the online monitor
keeps between pushes) flags a frame on a channel when its spectrum exceeds the per-frame threshold
at any tested bin; :func:`detect_frames` and :func:`frame_statistic` are its flags and peak ratios
for a :class:`~chatterspec.detection.spectral.Spectrogram`. :func:`frame_intervals` turns flags
into onset/offset times, :func:`stft_detect` does all of it for one record.

Frame score
-----------
The chattering route's frame score: ``-log p`` of each STFT frame and channel.

``p`` is the Bonferroni p-value of the frame's largest bin over the ``n`` tested bins,
``p = min(1, n * min_k p_k)``, with ``p_k = P(S_k > s_k)`` the p-value of bin ``k`` under
its healthy law, so the score is

    score = max(0, max_k (-log p_k) - log n)     (nats; 0 when the frame looks healthy)

and the per-frame rule at level ``alpha`` (:func:`chatterspec.detection.thresholds.frame_threshold`,
Bonferroni) flags exactly the frames with ``score >= -log(alpha)`` (up to the 1e-10 relative
tolerance of the threshold's quantile). Under the healthy law ``P(p <= x) <= x``, so a healthy
score exceeds ``h`` with probability at most ``exp(-h)``. The score feeds the alarm rules of
:mod:`chatterspec.detection.alarms.streams` (e.g. a CUSUM ``g = max(0, g + score - drift)``).

Laws
    ``exact`` (a threshold with ``eigenvalues``, i.e. a linear model): a healthy frame bin is
    ``S = l1 Z1^2 + l2 Z2^2`` (:func:`chatterspec.detection.spectral.frame_eigenvalues`). With
    ``Z = R (cos phi, sin phi)`` (``R^2`` exponential with mean 2, ``phi`` uniform)
    ``P(S > s) = (1 / pi) int_0^pi exp(-s / (2 lambda(phi))) dphi``,
    ``lambda = l1 cos^2 phi + l2 sin^2 phi``, hence, with ``u = s / (2 l1)`` and ``r = l2 / l1``,

        -log p_k = u - log J(u),   J(u) = (1 / pi) int_0^pi exp(-u c(phi)) dphi,
        c(phi) = (1 - r) sin^2 phi / (cos^2 phi + r sin^2 phi) >= 0.

    ``J`` is the mean of a smooth periodic function, which the trapezoid rule integrates with
    exponential accuracy; the node count of each bin is doubled at construction until ``log J``
    changes by less than 1e-13 at ``u = 200`` (``-log p_k`` about 200; larger scores keep the
    rule's bounds below and only ever raise alarms), 2 nodes for the ``r ~ 1`` bins that make up
    almost the whole band, up to 64 for the lowest bins. ``r = 1`` gives ``J = 1`` (``l chi2(2)``).
    ``exponential`` (a threshold without eigenvalues but with ``expected`` ``E``, e.g. the
    empirical normalization of a calibrated nonlinear model): every bin is taken as ``E chi2(2) / 2``,
    ``-log p_k = S / E``. This law is an approximation there, so the thresholds of the alarm rules
    on it must come from simulated healthy streams (they do: :mod:`chatterspec.detection.alarms.calibration`).

Cost
    A special function on every bin of every frame would cost more than the monitor's whole
    analysis. Since ``u <= -log p_k <= u / r`` (``c`` lies in ``[0, (1 - r) / r]``), one pass over
    the tested bins computes ``u`` (one product per bin) and keeps its two largest values; ``J`` is
    evaluated at the bin of largest ``u``, then at the few "low" bins (``r`` well below 1: the
    lowest frequencies, ``r`` down to 0.44 on the EHA position channel) whose bound ``u / r``
    exceeds the best exact value, and at the other bins only when the second largest ``u`` times
    their common bound ``max 1 / r <= 1 + LOW_GAP`` exceeds it (about 1 frame in 100): usually one
    special-function evaluation per frame and channel.

Paths
    :class:`FrameScore` runs the compiled kernel :func:`_score_kernel` when
    :func:`chatterspec._jit.enabled`, otherwise numpy for the bounds and the same scalar code
    (:func:`_exact_log_sf`, ``math.exp`` / ``math.log``, nodes summed in order) at the candidate
    bins; the two agree to rounding (``tests/test_frame_score.py``: relative 1e-13).

Compiled verdict
----------------
The compiled one-pass verdict of :func:`detect_spectrum`.

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

See Also
--------
chatterspec.detection.thresholds.frame_threshold : the per-frame threshold at a fixed alpha.
chatterspec.detection.thresholds.weighted_chi2_sf : the same law by Gauss-Legendre quadrature.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .. import _jit
from .._repr import short_repr
from .._validate import names_of
from ..errors import ModelKindError, ParameterError, ShapeError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model
from .spectral import DEFAULT_STFT, Spectrogram, STFTConfig, spectrogram, spectrum_model
from .thresholds import Band, Correction, Threshold, frame_threshold

__all__ = [
    "ChannelVerdict",
    "FrameDetection",
    "FrameScore",
    "FrameVerdicts",
    "SpectrumDetection",
    "detect_frames",
    "detect_spectrum",
    "frame_intervals",
    "frame_scores",
    "frame_statistic",
    "frame_verdicts",
    "healthy_frame_level",
    "peak_channel",
    "stft_detect",
]


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

    With ``FULL`` (:data:`verdict_kernel`, :func:`~chatterspec.detection.verdicts.detect_spectrum`)
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
    # a run of bins (the usual case): read through slices indexed from 0, which numba does not test
    # for wraparound per access as it does an index it loads (idx[j]): ~20 % of the pass
    run = idx[nt - 1] - b == nt - 1
    p_run, t_run, e_run = power[r, b : b + nt, c], thr[b : b + nt, c], expected[b : b + nt, c]
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
        if run:
            p, t, e = p_run[j], t_run[j], e_run[j]
        else:
            b = idx[j]
            p, t, e = power[r, b, c], thr[b, c], expected[b, c]
        ratio = p / t
        kr, vr, nr = argmax_update(j, ratio, kr, vr, nr)
        if FULL:
            ex = p - e
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


#: The one-pass verdict of :func:`~chatterspec.detection.verdicts.detect_spectrum`.
verdict_kernel = _jit.specialize(_verdict_loop, "full", CHANNEL=verdict_channel)
#: The same pass for the online monitor's frames: the bin of the largest ``S / threshold`` only.
peak_kernel = _jit.specialize(_verdict_loop, "peak", CHANNEL=peak_channel)


@dataclass(frozen=True)
class ChannelVerdict:
    """Verdict for one channel of one spectrum (scipy.stats-style named result).

    Attributes
    ----------
    channel : str
    detected : bool
        Any tested bin above the threshold.
    peak_hz : float
        Frequency (Hz) of the tested bin with the largest excess power ``S - E[S]``
        (among the bins over the threshold when there are any).
    most_significant_hz : float
        Frequency (Hz) of the tested bin with the largest ``S / threshold``.
    peak_ratio : float
        ``max S / threshold`` over the tested bins (at ``most_significant_hz``).
    excess_power : float
        ``sum (S - E[S]) / sum E[S]`` over the tested bins.
    dc_ratio : float
        ``S(0) / threshold(0)`` (not used for the verdict).
    threshold_kind : str
    alpha : float
    alpha_meaning : str
    """

    channel: str
    detected: bool
    peak_hz: float
    most_significant_hz: float
    peak_ratio: float
    excess_power: float
    dc_ratio: float
    threshold_kind: str
    alpha: float
    alpha_meaning: str

    def to_dict(self) -> dict[str, object]:
        """JSON-ready ``{"channel", "detected", "peak_hz", "most_significant_hz", "peak_ratio", ...}``."""
        return {
            "channel": self.channel,
            "detected": bool(self.detected),
            "peak_hz": float(self.peak_hz),
            "most_significant_hz": float(self.most_significant_hz),
            "peak_ratio": float(self.peak_ratio),
            "excess_power": float(self.excess_power),
            "dc_ratio": float(self.dc_ratio),
        }


@dataclass(frozen=True, eq=False)
class SpectrumDetection:
    """Verdicts for many spectra at once: every field is an array ``(..., m)``.

    Attributes
    ----------
    detected, peak_hz, most_significant_hz, peak_ratio, excess_power, dc_ratio : (..., m) arrays
        See :class:`ChannelVerdict`; the leading axes are those of the spectra.
    channels : tuple of str
    threshold : Threshold
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    detected: np.ndarray
    peak_hz: np.ndarray
    most_significant_hz: np.ndarray
    peak_ratio: np.ndarray
    excess_power: np.ndarray
    dc_ratio: np.ndarray
    channels: tuple[str, ...]
    threshold: Threshold

    @property
    def any_channel(self) -> np.ndarray | np.bool_:
        """``(...)`` bool: any channel detected."""
        return self.detected.any(axis=-1)

    @property
    def detection_rate(self) -> np.ndarray:
        """``(m,)`` fraction of the spectra (all leading axes pooled) detected per channel."""
        return self.detected.reshape(-1, self.detected.shape[-1]).mean(axis=0)

    def verdicts(self, index: int | tuple[int, ...] = ()) -> tuple[ChannelVerdict, ...]:
        """Per-channel :class:`ChannelVerdict` of the spectrum at leading ``index`` (``()`` if none)."""
        th = self.threshold
        return tuple(
            ChannelVerdict(
                channel=name,
                detected=bool(self.detected[index][i]),
                peak_hz=float(self.peak_hz[index][i]),
                most_significant_hz=float(self.most_significant_hz[index][i]),
                peak_ratio=float(self.peak_ratio[index][i]),
                excess_power=float(self.excess_power[index][i]),
                dc_ratio=float(self.dc_ratio[index][i]),
                threshold_kind=th.kind,
                alpha=th.alpha,
                alpha_meaning=th.alpha_meaning,
            )
            for i, name in enumerate(self.channels)
        )


def _compiled_verdict(
    power: np.ndarray, values: np.ndarray, expected: np.ndarray, idx: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(k, peak_ratio, k_excess, p_sum)`` of :func:`detect_spectrum` by :func:`verdict_kernel`."""
    lead, (bins, m) = power.shape[:-2], power.shape[-2:]
    p3 = power.reshape(-1, bins, m)  # a view for the usual (runs, bins, m) spectra
    k = np.empty((p3.shape[0], m), dtype=np.intp)
    peak_ratio = np.empty((p3.shape[0], m))
    k_excess = np.empty((p3.shape[0], m), dtype=np.intp)
    p_sum = np.empty((p3.shape[0], m))
    verdict_kernel(p3, values, expected, idx, k, peak_ratio, k_excess, p_sum)
    return (
        k.reshape(*lead, m),
        peak_ratio.reshape(*lead, m),
        k_excess.reshape(*lead, m),
        p_sum.reshape(*lead, m),
    )


def detect_spectrum(
    power: np.ndarray,
    threshold: Threshold,
    expected: np.ndarray | None = None,
    channels: Sequence[str] | None = None,
) -> SpectrumDetection:
    """Compare spectra ``(..., bins, m)`` with a threshold, vectorized over the leading axes.

    Parameters
    ----------
    power : (..., bins, m) array
        Periodograms (or averaged periodograms) on the threshold's frequency grid.
    threshold : Threshold
    expected : (bins, m) array, optional
        Healthy expectation for ``excess_power``; defaults to ``threshold.expected``
        (required for the ``paper`` threshold, which carries none).
    channels : sequence of str, optional
        Channel names (default ``z1..zm``).

    Raises
    ------
    ShapeError
        If ``power`` or ``expected`` does not match the threshold's ``(bins, m)``.
    """
    power = threshold.check_spectrum(power)
    if expected is None:
        expected = threshold.expected
    if expected is None:
        raise ParameterError(
            f"the {threshold.kind!r} threshold carries no expected spectrum: pass expected= "
            "(chatterspec.detection.spectral.expected_spectrum) to compute excess_power"
        )
    expected = np.asarray(expected, dtype=float)
    if expected.shape != threshold.values.shape:
        raise ShapeError(f"expected must have shape {threshold.values.shape}; got {expected.shape}")
    tested = threshold.tested
    idx = np.flatnonzero(tested)
    f_tested = threshold.freqs_hz[tested]
    if _jit.enabled() and idx.size:
        # one compiled pass, bit-identical to the numpy lines below (chatterspec.detection.verdicts)
        k, peak_ratio, k_excess, p_sum = _compiled_verdict(power, threshold.values, expected, idx)
        if not (power.flags.c_contiguous and power.shape[-1] > 1):  # numpy may sum pairwise
            p_sum = power[..., tested, :].sum(axis=-2)
    else:
        p_tested = power[..., tested, :]
        ratio = p_tested / threshold.values[tested]
        k = np.argmax(ratio, axis=-2)  # (..., m)
        peak_ratio = np.take_along_axis(ratio, k[..., None, :], axis=-2)[..., 0, :]
        # largest excess power S - E[S]; among the bins over the threshold when there are any, so that
        # on a single noisy record the footprint is not taken from a healthy bin where E[S] is large
        excess_bins = p_tested - expected[tested]
        over = ratio > 1.0
        k_excess = np.where(
            over.any(axis=-2),
            np.argmax(np.where(over, excess_bins, -np.inf), axis=-2),
            np.argmax(excess_bins, axis=-2),
        )
        p_sum = p_tested.sum(axis=-2)
    most_significant_hz = f_tested[k]
    peak_hz = f_tested[k_excess]
    e_sum = expected[tested].sum(axis=0)
    excess = (p_sum - e_sum) / e_sum
    dc = np.flatnonzero(threshold.freqs_hz == 0.0)
    if dc.size:
        dc_ratio = power[..., dc[0], :] / threshold.values[dc[0]]
    else:
        dc_ratio = np.full(peak_ratio.shape, np.nan)
    return SpectrumDetection(
        detected=peak_ratio > 1.0,
        peak_hz=peak_hz,
        most_significant_hz=most_significant_hz,
        peak_ratio=peak_ratio,
        excess_power=excess,
        dc_ratio=dc_ratio,
        channels=names_of("channels", channels, power.shape[-1], "z"),
        threshold=threshold,
    )


def _require_empirical(model: Model, threshold: Threshold | str) -> np.ndarray:
    """A nonlinear nominal model needs a calibrated threshold carrying its normalization (returned)."""
    if not (isinstance(threshold, Threshold) and threshold.expected is not None):
        raise ModelKindError(
            "the 'exact'/'paper' thresholds: detection needs a linear model (closed-form chattering "
            "spectrum, eq 56); "
            f"{getattr(model, 'name', 'the model')!r} is nonlinear. Calibrate a threshold on healthy runs "
            "(chatterspec calibrate <healthy scenario> --out FILE, then detect --calibration FILE)"
        )
    return threshold.expected


_VERDICT_FIELDS = ("detected", "peak_hz", "most_significant_hz", "peak_ratio", "excess_power", "dc_ratio")


class FrameVerdicts:
    """:func:`frame_verdicts` with the tested bins and their threshold precomputed (the monitor's per-push
    cost).

    Parameters
    ----------
    threshold : Threshold
        Per-frame threshold (:func:`chatterspec.detection.thresholds.frame_threshold`).
    compiled : bool
        Take the compiled one-pass loop (:data:`chatterspec.detection.verdicts.peak_kernel`) for
        ``(frames, bins, m)`` spectra when the tested bins are contiguous (same numbers).

    See Also
    --------
    frame_verdicts : the checked function form.
    """

    def __init__(self, threshold: Threshold, compiled: bool = False) -> None:
        tested = np.flatnonzero(threshold.tested)
        contiguous = tested.size > 0 and bool(np.all(np.diff(tested) == 1))
        # a slice is a view (no copy of the spectra); fancy indexing otherwise
        self.sel: slice | np.ndarray = slice(int(tested[0]), int(tested[-1]) + 1) if contiguous else tested
        self.values = np.ascontiguousarray(threshold.values[tested])
        self.freqs = np.ascontiguousarray(threshold.freqs_hz[tested], dtype=float)
        # the one-pass flag rule below needs finite normal thresholds > 0 (else: the direct comparison)
        tiny = np.finfo(float).tiny
        self.one_pass = bool(np.all((self.values >= tiny) & np.isfinite(self.values)))
        # the monitor's case (contiguous tested bins, one-pass rule) in one compiled pass when enabled:
        # the detection verdict's loop without the excess and the sum (detection.verdicts.peak_kernel)
        self.compiled = compiled and self.one_pass and isinstance(self.sel, slice)
        self._positions = np.arange(tested.size, dtype=np.int64)
        self._no_expected = np.empty((0, 0))

    def __call__(self, power: np.ndarray, finite: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(flags, peak_hz, peak_ratio)`` of frame spectra ``power`` ``(..., F, bins, m)``, unchecked.

        ``finite``: ``power`` holds no NaN / inf (always so in the monitor: its input is checked).
        """
        if self.compiled and finite and power.ndim == 3:
            F, m = power.shape[0], power.shape[2]
            k, peak_ratio = np.empty((F, m), dtype=np.int64), np.empty((F, m))
            peak_kernel(
                power[:, self.sel],
                self.values,
                self._no_expected,
                self._positions,
                k,
                peak_ratio,
                k,
                peak_ratio,
            )
            return peak_ratio > 1.0, self.freqs[k], peak_ratio
        p = power[..., self.sel, :]
        ratio = p / self.values
        k = np.argmax(ratio, axis=-2)
        peak_ratio = np.take_along_axis(ratio, k[..., None, :], axis=-2)[..., 0, :]
        # flags = any(p > threshold) (detect_frames' rule) without a second pass over the bins: for
        # a normal v > 0 and finite p >= 0, p > v means p >= v + ulp(v), so p / v >= 1 + ulp(v) / v
        # > 1 + 2^-53 rounds to > 1; p <= v gives fl(p / v) <= 1. Hence fl(p / v) > 1 <=> p > v,
        # and max_k fl(p / v) > 1 <=> any(p > v) (checked at exact ties in tests/test_monitor.py).
        if not (self.one_pass and finite):
            return np.any(p > self.values, axis=-2), self.freqs[k], peak_ratio
        flags = peak_ratio > 1.0
        return flags, self.freqs[k], peak_ratio


def frame_verdicts(power: np.ndarray, threshold: Threshold) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-frame verdicts from frame spectra.

    Parameters
    ----------
    power : (..., F, bins, m) array
        Frame spectra (see :func:`chatterspec.detection.spectral.frame_columns`).
    threshold : Threshold
        Per-frame threshold (:func:`chatterspec.detection.thresholds.frame_threshold`).

    Returns
    -------
    (flags, peak_hz, peak_ratio)
        Each ``(..., F, m)``: a frame is flagged on a channel when any tested bin
        exceeds the threshold, i.e. when the largest ``S / threshold`` over the
        tested bins is > 1; ``peak_hz`` is that bin's frequency (Hz).

    See Also
    --------
    detect_frames : the flags of a :class:`~chatterspec.detection.spectral.Spectrogram`.
    frame_statistic : the peak ratios of a spectrogram.
    chatterspec.online.monitor.ChatteringMonitor : the same verdicts, frame by frame.
    """
    power = threshold.check_spectrum(power)
    return FrameVerdicts(threshold)(power, finite=bool(np.isfinite(power).all()))


def detect_frames(spec: Spectrogram, frame_threshold: Threshold) -> np.ndarray:
    """``(..., frames, m)`` bool: frame spectrum above the per-frame threshold at any tested bin.

    DC and Nyquist are excluded (``frame_threshold.tested``).

    Parameters
    ----------
    spec : Spectrogram
        Frame spectra ``(..., frames, bins, m)``.
    frame_threshold : Threshold
        Per-frame threshold on the same frequency grid
        (:func:`chatterspec.detection.thresholds.frame_threshold`).

    Raises
    ------
    ShapeError
        If the spectrogram's ``(bins, m)`` does not match the threshold.

    See Also
    --------
    frame_statistic : the peak ratio of each frame (flagged when > 1).
    frame_verdicts : flags, peak frequencies and ratios in one pass.
    """
    return frame_verdicts(spec.power, frame_threshold)[0]


def frame_statistic(spec: Spectrogram, frame_threshold: Threshold) -> np.ndarray:
    """``(..., frames, m)``: the per-frame statistic ``max_n S(f_n) / threshold(f_n)`` over the tested bins.

    A frame is flagged by :func:`detect_frames` exactly when this exceeds 1.

    Parameters
    ----------
    spec : Spectrogram
        Frame spectra ``(..., frames, bins, m)``.
    frame_threshold : Threshold
        Per-frame threshold on the same frequency grid.

    See Also
    --------
    detect_frames : the flags.
    frame_verdicts : flags, peak frequencies and ratios in one pass.
    """
    return frame_verdicts(spec.power, frame_threshold)[2]


def healthy_frame_level(frame_threshold: Threshold) -> float:
    """Median of the per-frame statistic (:func:`frame_statistic`) on a healthy frame.

    With ``n`` tested bins, each at per-bin level ``a`` (after the correction), and the
    chi2(2)/2 law of a healthy bin (``P(S / t > x) = a^x``; bins independent),
    ``P(max <= x) = (1 - a^x)^n``, so the median is ``m0 = ln(1 - 2^(-1/n)) / ln a``
    (0.50 for 499 bins at family-wise 0.1 % Bonferroni; the exact-law value is close:
    0.50 observed over healthy frames). Clipped to ``(0, 1]``; 1 (the threshold) when the
    threshold has no per-bin level (empirical thresholds).

    Parameters
    ----------
    frame_threshold : Threshold
        Per-frame threshold.
    """
    a, n = frame_threshold.per_test_alpha, frame_threshold.n_tested
    if not np.isfinite(a) or not 0.0 < a < 1.0:
        return 1.0
    m0 = float(np.log(-np.expm1(-np.log(2.0) / n)) / np.log(a))
    return float(min(1.0, max(m0, 1e-12)))


def frame_intervals(
    flags: np.ndarray,
    times_s: np.ndarray,
    config: STFTConfig,
    dt: float,
    statistic: np.ndarray | None = None,
    level: float = 1.0,
) -> list[tuple[float, float]]:
    """Merge runs of contiguous flagged frames into ``(onset_s, offset_s)`` estimates.

    **Window-extent estimator** (with ``statistic``, used by :func:`stft_detect`):
    a frame whose window ``[s_j, s_j + W dt)`` overlaps the fault can flag, one that
    does not has the healthy law. So the onset of a run whose first flagged frame is
    ``f`` lies in ``[s_{f-1} + W dt, s_f + W dt]`` (end of the last unflagged window, end
    of the first flagged one) and the offset of a run whose last flagged frame is ``l``
    in ``[s_l, s_{l+1}]``. Inside each bracket the per-frame statistic ``r_j``
    (:func:`frame_statistic`) locates the edge: ``log r`` is interpolated linearly
    between the two frames and the crossing of ``log level`` (the healthy median
    :func:`healthy_frame_level`, the value of a window that just touches the fault)
    gives the position ``s*`` (clipped to the bracket) of the window that just touches
    the fault: ``onset = s* + W dt`` (its end), ``offset = s*`` (its start). A run
    shorter than a window whose estimates cross (onset > offset) is reported as a
    zero-length interval at their mean. A run touching the start (end) of the record
    gets the start of the first (end of the last) window: the fault may predate
    (outlast) it. Resolution: a strong fault edge is found within the bracket of one
    hop ``H dt``; a fault whose signature fades before it ends (a decaying transient)
    is ended where it becomes invisible (``docs/paper-notes.md``, STFT onset/offset).

    **Frame-centre estimator** (``statistic=None``, the online monitor's): a frame is
    assumed flagged once its centre lies inside the fault, ``onset = c_first - H dt / 2``,
    ``offset = c_last + H dt / 2``; strong faults flag frames that overlap them by a
    single hop, which biases it outward by up to ``(W - H) dt / 2``.

    Parameters
    ----------
    flags : (frames,) bool array
        One channel (or the any-channel combination) of :func:`detect_frames` for one run.
    times_s : (frames,) array
        Frame-centre times (:attr:`Spectrogram.times_s`).
    config : STFTConfig
    dt : float
        Sampling time (s).
    statistic : (frames,) array, optional
        Per-frame statistic ``max S / threshold`` (:func:`frame_statistic`, same channel);
        selects the window-extent estimator.
    level : float
        Healthy median of the statistic (:func:`healthy_frame_level`), in (0, 1].
    """
    flags = np.asarray(flags, dtype=bool)
    times = np.asarray(times_s, dtype=float)
    if flags.ndim != 1 or times.shape != flags.shape:
        raise ShapeError(
            f"flags and times_s must be 1-D of equal length (one run, one channel); got {flags.shape} "
            f"and {times.shape}"
        )
    if statistic is not None:
        stat = np.asarray(statistic, dtype=float)
        if stat.shape != flags.shape:
            raise ShapeError(f"statistic must have the shape of flags {flags.shape}; got {stat.shape}")
        if not 0.0 < float(level) <= 1.0:
            raise ParameterError(
                f"level must lie in (0, 1] (a healthy median of max S / threshold); got {level}"
            )
    if not flags.any():
        return []
    hop = config.n_hop(dt) * dt
    half_hop = hop / 2.0
    half_win = (config.n_window(dt) - 1) * dt / 2.0
    padded = np.concatenate(([False], flags, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    out = []
    if statistic is None:
        for start, stop in zip(edges[::2], edges[1::2], strict=True):
            last = stop - 1
            onset = times[start] - (half_win if start == 0 else half_hop)
            offset = times[last] + (half_win + dt if last == flags.size - 1 else half_hop)
            out.append((float(onset), float(offset)))
        return out
    win = config.n_window(dt) * dt
    starts = times - half_win  # first sample of each window
    logr = np.log(np.maximum(stat, 1e-300))
    lvl = np.log(level)

    def crossing(inside: int, outside: int) -> float:
        """Fraction (0..1) of the way from frame ``inside`` to ``outside`` where log r reaches lvl."""
        drop = logr[inside] - logr[outside]
        return float(np.clip((logr[inside] - lvl) / drop, 0.0, 1.0)) if drop > 0 else 1.0

    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        last = stop - 1
        if start == 0:
            onset = starts[0]
        else:
            onset = starts[start] - crossing(start, start - 1) * hop + win
        if last == flags.size - 1:
            offset = starts[last] + win
        else:
            offset = starts[last] + crossing(last, last + 1) * hop
        if onset > offset:
            onset = offset = 0.5 * (onset + offset)
        out.append((float(onset), float(offset)))
    return out


@dataclass(frozen=True, eq=False)
class FrameDetection:
    """STFT detection of one record: spectrogram, per-frame threshold, flags and intervals.

    Attributes
    ----------
    spectrogram : Spectrogram
    threshold : Threshold
        Per-frame threshold (``alpha_meaning="per-frame"``).
    flags : (..., frames, m) bool array
    intervals : dict of str -> list of (onset_s, offset_s)
        Per channel and under ``"any"`` (any channel flagged), for run 0
        (window-extent estimator of :func:`frame_intervals`).
    statistic : (..., frames, m) array or None
        Per-frame statistic ``max S / threshold`` (:func:`frame_statistic`).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    spectrogram: Spectrogram
    threshold: Threshold
    flags: np.ndarray
    intervals: dict[str, list[tuple[float, float]]]
    statistic: np.ndarray | None = None


def stft_detect(
    x: np.ndarray,
    model: Model,
    *,
    t0: float = 0.0,
    config: STFTConfig = DEFAULT_STFT,
    alpha: float = 1e-3,
    correction: Correction = "bonferroni",
    channels: Sequence[str] | None = None,
    band: Band | None = None,
    threshold: Threshold | None = None,
) -> FrameDetection:
    """Spectrogram + per-frame threshold + flags + intervals for chattering ``x`` (..., N, m).

    Parameters
    ----------
    x : (..., N, m) array
        Chattering; time on axis -2.
    model : LinearModel
        Nominal model (expected frame spectrum, sampling time).
    t0 : float
        Time (s) of ``x``'s first sample.
    config : STFTConfig
        Window settings (default 1 s Hamming, 0.2 s hop).
    alpha : float
        Per-frame false-alarm probability in (0, 1).
    correction : {"bonferroni", "sidak", "none"}
        Family-wise control over the bins of one frame.
    channels : sequence of str, optional
        Channel names (default ``model.output_names``).
    band : (float, float), optional
        ``(lo, hi)`` in Hz: frame bins tested (the correction counts only these).
    threshold : Threshold, optional
        Per-frame threshold to use instead of the analytic one (``alpha`` and ``correction`` are
        then ignored), e.g. a calibration's ``threshold("frame-family-wise")``; required for a
        nonlinear model, which has no closed-form frame spectrum.

    Raises
    ------
    ShapeError
        If the record is shorter than one window.
    """
    spec = spectrogram(x, model.dt, config, t0=t0)
    if threshold is not None:
        th = threshold.restricted(band)
        if th.values.shape != spec.power.shape[-2:]:
            raise ShapeError(
                f"the per-frame threshold covers {th.values.shape} (bins, channels); these frames have "
                f"{spec.power.shape[-2:]}: it was made for another STFT window or model"
            )
    else:
        th = frame_threshold(
            spectrum_model(model), spec.freqs_hz, config, model.dt, alpha, correction, band=band
        )
    flags, _, stat = frame_verdicts(spec.power, th)
    level = healthy_frame_level(th)
    names = names_of("channels", channels or model.output_names, flags.shape[-1], "z")
    first = flags.reshape(-1, *flags.shape[-2:])[0]
    first_stat = stat.reshape(-1, *stat.shape[-2:])[0]
    times, dt = spec.times_s, model.dt
    intervals = {
        n: frame_intervals(first[:, i], times, config, dt, first_stat[:, i], level)
        for i, n in enumerate(names)
    }
    # any channel: the frame's largest statistic over the channels
    intervals["any"] = frame_intervals(first.any(axis=-1), times, config, dt, first_stat.max(axis=-1), level)
    return FrameDetection(spec, th, flags, intervals, stat)


#: ``u`` (about ``-log p_k``) at which the trapezoid rule is converged to 1e-13 in ``log J``.
U_CONVERGED = 200.0
#: Bins with ``l1 / l2 > 1 + LOW_GAP`` are checked one by one; the others share one bound.
LOW_GAP = 1e-3
_TOL = 1e-13
_MAX_NODES = 4096


def _half_nodes(r: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Trapezoid nodes on ``[0, pi)`` folded by the symmetry ``phi -> pi - phi``: ``(c, w)``.

    ``r`` (q,) -> ``c`` (q, N/2 + 1) = ``c(phi_j)``, ``phi_j = pi j / N``, and weights ``w``
    (N/2 + 1,) = ``(1, 2, ..., 2, 1) / N`` summing to 1.
    """
    phi = np.pi * np.arange(N // 2 + 1) / N
    s2, c2 = np.sin(phi) ** 2, np.cos(phi) ** 2
    r = r[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(s2 > 0, (1.0 - r) * s2 / (c2 + r * s2), 0.0)
    w = np.full(N // 2 + 1, 2.0 / N)
    w[0] = w[-1] = 1.0 / N
    return c, w


def _log_j(u: float, c: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``log J(u)`` by the folded trapezoid rule, rows of ``c``."""
    with np.errstate(invalid="ignore"):
        t = np.where(np.isinf(c), 0.0, np.exp(-u * np.where(np.isinf(c), 0.0, c)))
    return np.log(t @ w)


def _node_tables(r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per element of ``r`` (flat, ``0 <= r <= 1``): converged node tables, ragged.

    Returns ``(offset, count, c_values, weights)``: element ``i`` uses ``c_values[offset[i] :
    offset[i] + count[i]]`` with the matching ``weights``; ``count = 0`` means ``J = 1``
    (``r = 1``, the plain exponential law).
    """
    q = r.size
    count = np.zeros(q, dtype=np.int64)
    tables: list[tuple[np.ndarray, np.ndarray] | None] = [None] * q
    todo = np.flatnonzero(r < 1.0)
    N = 2
    prev_c, prev_w = _half_nodes(r[todo], N)
    prev = _log_j(U_CONVERGED, prev_c, prev_w)
    while todo.size:
        if N > _MAX_NODES:  # pragma: no cover - r -> 0 only (a bin with one degree of freedom)
            for i, row in enumerate(todo):
                tables[row] = (prev_c[i], prev_w)
            break
        c2, w2 = _half_nodes(r[todo], 2 * N)
        cur = _log_j(U_CONVERGED, c2, w2)
        done = np.abs(cur - prev) <= _TOL * np.maximum(1.0, np.abs(cur))
        for j in np.flatnonzero(done):
            tables[todo[j]] = (prev_c[j], prev_w)  # N nodes already agree with 2N
        keep = ~done
        todo, prev_c, prev, prev_w = todo[keep], c2[keep], cur[keep], w2
        N *= 2
    offset = np.zeros(q, dtype=np.int64)
    cs: list[np.ndarray] = []
    ws: list[np.ndarray] = []
    pos = 0
    for i, table in enumerate(tables):
        offset[i] = pos
        if table is not None:
            count[i] = table[0].size
            cs.append(table[0])
            ws.append(table[1])
            pos += table[0].size
    cvals = np.concatenate(cs) if cs else np.zeros(0)
    wvals = np.concatenate(ws) if ws else np.zeros(0)
    return offset, count, np.ascontiguousarray(cvals), np.ascontiguousarray(wvals)


@_jit.njit
def _exact_log_sf(u: float, off: int, cnt: int, cvals: np.ndarray, wvals: np.ndarray) -> float:
    """``-log p_k = u - log J(u)`` of one bin from its node table (``cnt = 0``: ``J = 1``)."""
    if cnt == 0 or u <= 0.0:
        return u
    acc = 0.0
    for t in range(off, off + cnt):
        x = u * cvals[t]
        if x < 745.2:  # exp(-x) underflows to 0 beyond (and c = inf at r = 0)
            acc += wvals[t] * math.exp(-x)
    return u - math.log(acc)


@_jit.njit
def _score_kernel(
    power: np.ndarray,
    idx: np.ndarray,
    inv1: np.ndarray,
    invr: np.ndarray,
    off: np.ndarray,
    cnt: np.ndarray,
    cvals: np.ndarray,
    wvals: np.ndarray,
    low: np.ndarray,
    n_low: np.ndarray,
    is_low: np.ndarray,
    hi_invr: np.ndarray,
    inv1T: np.ndarray,
    log_n: float,
    out: np.ndarray,
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_frame_score.py)
    """Frame scores of ``power`` (F, bins, m) over the tested bins ``idx`` into ``out`` (F, m).

    ``inv1`` = 1 / (2 l1), ``invr`` = l1 / l2 (>= 1, inf for l2 = 0), ``off`` / ``cnt`` the node
    tables of :func:`_node_tables`, ``is_low`` (bool), all (n_tested, m). The "low" bins of channel
    ``c`` (``r < 1 / (1 + LOW_GAP)``, a handful at the lowest frequencies) are ``low[c, :n_low[c]]``;
    every other bin has ``invr <= hi_invr[c]``; ``inv1T`` is ``inv1`` channel-major (m, n_tested).
    One pass takes ``u = S inv1``, its largest value ``A``
    (bin ``kA``) and the second largest ``U2``; the exact value at ``kA`` is then compared with the
    upper bounds ``u invr`` of the low bins and, only when ``U2 hi_invr`` exceeds it (rare), of every
    other bin: the maximum of the exact values over the bins that can hold it.
    """
    F = power.shape[0]
    m = power.shape[2]
    for f in range(F):
        for c in range(m):
            e = score_step(
                power, f, c, idx, inv1, invr, off, cnt, cvals, wvals, low, n_low, is_low, hi_invr, inv1T
            )
            out[f, c] = max(e - log_n, 0.0)


@_jit.step
def score_step(
    power: np.ndarray,
    f: int,
    c: int,
    idx: np.ndarray,
    inv1: np.ndarray,
    invr: np.ndarray,
    off: np.ndarray,
    cnt: np.ndarray,
    cvals: np.ndarray,
    wvals: np.ndarray,
    low: np.ndarray,
    n_low: np.ndarray,
    is_low: np.ndarray,
    hi_invr: np.ndarray,
    inv1T: np.ndarray,
) -> float:  # pragma: no cover - compiled (inlined into _score_kernel and the monitor's hop loop)
    """``max_k -log p_k`` of frame ``f``, channel ``c`` (arguments of :func:`_score_kernel`)."""
    nt = idx.shape[0]
    lo = idx[0]
    contiguous = idx[nt - 1] - lo == nt - 1  # the usual case: a slice of bins, no index loads
    A = -1.0
    kA = 0
    U2 = -1.0
    w = inv1T[c]
    run = power[f, lo : lo + nt, c]  # (indexed from 0: no wraparound test per bin, as in _verdict_channel)
    for j in range(nt):
        u = (run[j] if contiguous else power[f, idx[j], c]) * w[j]
        if u > U2:
            if u > A:
                U2 = A
                A = u
                kA = j
            else:
                U2 = u
    e = _exact_log_sf(A, off[kA, c], cnt[kA, c], cvals, wvals)
    for t in range(n_low[c]):
        j = low[c, t]
        if j != kA:
            u = power[f, idx[j], c] * inv1[j, c]
            if u * invr[j, c] > e:
                ej = _exact_log_sf(u, off[j, c], cnt[j, c], cvals, wvals)
                if ej > e:
                    e = ej
    if U2 * hi_invr[c] > e:
        for j in range(nt):
            if j != kA and not is_low[j, c]:
                u = power[f, idx[j], c] * inv1[j, c]
                if u * invr[j, c] > e:
                    ej = _exact_log_sf(u, off[j, c], cnt[j, c], cvals, wvals)
                    if ej > e:
                        e = ej
    return e


class FrameScore:
    """``-log`` Bonferroni p-value of each frame and channel (see the module docstring).

    Parameters
    ----------
    threshold : Threshold
        A per-frame threshold that says which bins are tested (its ``tested``, hence its
        ``band``) and carries the healthy law: ``eigenvalues`` (``law="exact"``, from
        :func:`~chatterspec.detection.thresholds.frame_threshold`) or, failing that,
        ``expected`` (the exponential law; e.g. a calibration's ``threshold("frame-family-wise")``).
        Its ``values`` and ``alpha`` are not used.
    compiled : bool, optional
        Use the compiled kernel (default: :func:`chatterspec._jit.enabled` at each call).

    Attributes
    ----------
    law : {"exact", "exponential"}
    n_tested : int
        ``n`` of the Bonferroni correction.
    freqs_hz : (bins,) array
    tested : (bins,) bool array

    Raises
    ------
    ParameterError
        A threshold without ``eigenvalues`` and ``expected``, or a tested bin whose healthy
        power is 0 (no law to test against).

    Examples
    --------
    >>> import numpy as np
    >>> from chatterspec.plants.models import eha_linear
    >>> from chatterspec.detection.spectral import STFTConfig
    >>> from chatterspec.detection.thresholds import frame_threshold
    >>> m, cfg = eha_linear(), STFTConfig()
    >>> th = frame_threshold(m, cfg.freqs_hz(m.dt), cfg, m.dt, alpha=1e-3)
    >>> score = FrameScore(th)
    >>> power = th.values[None].copy()     # one frame exactly at the 0.1 % per-frame threshold
    >>> bool(np.allclose(score(power), -np.log(1e-3), rtol=1e-7))
    True
    """

    def __init__(self, threshold: Threshold, compiled: bool | None = None) -> None:
        if not isinstance(threshold, Threshold):
            raise ParameterError(f"threshold must be a Threshold; got {type(threshold).__name__}")
        tested = np.asarray(threshold.tested, dtype=bool)
        idx = np.flatnonzero(tested)
        if threshold.eigenvalues is not None:
            ev = np.asarray(threshold.eigenvalues, dtype=float)[idx]
            l1, l2 = np.maximum(ev[..., 0], ev[..., 1]), np.minimum(ev[..., 0], ev[..., 1])
            self.law = "exact"
        elif threshold.expected is not None:
            l1 = l2 = 0.5 * np.asarray(threshold.expected, dtype=float)[idx]
            self.law = "exponential"
        else:
            raise ParameterError(
                "the frame score needs the healthy law of each bin: a threshold with eigenvalues "
                "(frame_threshold of a linear model) or an expected spectrum (a calibration)"
            )
        if not (np.all(np.isfinite(l1)) and np.all(l1 > 0) and np.all(l2 >= 0)):
            raise ParameterError(
                "every tested bin needs a positive, finite healthy power for the frame score"
            )
        self.freqs_hz = np.asarray(threshold.freqs_hz, dtype=float)
        self.tested = tested
        self.n_tested = int(idx.size)
        self.n_channels = int(l1.shape[1])
        self.log_n = math.log(self.n_tested)
        self._idx = np.ascontiguousarray(idx, dtype=np.int64)
        self._inv1 = np.ascontiguousarray(0.5 / l1)
        with np.errstate(divide="ignore"):
            self._invr = np.ascontiguousarray(np.where(l2 > 0, l1 / np.where(l2 > 0, l2, 1.0), np.inf))
        r = np.where(l1 > 0, l2 / l1, 1.0)
        r = np.where(l2 == l1, 1.0, np.clip(r, 0.0, 1.0))
        off, cnt, self._cvals, self._wvals = _node_tables(r.ravel())
        self._off = np.ascontiguousarray(off.reshape(r.shape))
        self._cnt = np.ascontiguousarray(cnt.reshape(r.shape))
        invr = self._invr
        is_low = invr > 1.0 + LOW_GAP
        self._is_low = np.ascontiguousarray(is_low)
        self._n_low = np.ascontiguousarray(is_low.sum(axis=0).astype(np.int64))
        self._low = np.zeros((self.n_channels, max(1, int(self._n_low.max()))), dtype=np.int64)
        for c in range(self.n_channels):
            js = np.flatnonzero(is_low[:, c])
            self._low[c, : js.size] = js
        self._hi_invr = np.ascontiguousarray(
            np.array([invr[~is_low[:, c], c].max(initial=1.0) for c in range(self.n_channels)])
        )
        self._kernel_args = (
            self._idx, self._inv1, self._invr, self._off, self._cnt, self._cvals, self._wvals,
            self._low, self._n_low, self._is_low, self._hi_invr, np.ascontiguousarray(self._inv1.T),
            self.log_n,
        )  # fmt: skip
        self._compiled = compiled
        self._exact_py = getattr(_exact_log_sf, "py_func", _exact_log_sf)

    @classmethod
    def from_model(
        cls,
        model: LinearModel,
        config: STFTConfig,
        band: tuple[float, float] | None = None,
    ) -> FrameScore:
        """The exact-law score of a linear model's STFT frames (``config``: an ``STFTConfig``)."""
        from .thresholds import frame_threshold

        dt = model.dt
        th = frame_threshold(model, config.freqs_hz(dt), config, dt, 0.5, band=band)
        return cls(th)

    def bin_scores(self, power: np.ndarray) -> np.ndarray:
        """``-log p_k`` of every tested bin ``(..., frames, n_tested, m)`` (for tests and plots; slow)."""
        p = np.asarray(power, dtype=float)[..., self._idx, :]
        u = p * self._inv1
        out = np.empty(u.shape)
        it = np.nditer(u, flags=["multi_index"])
        for _ in it:
            j, c = it.multi_index[-2], it.multi_index[-1]
            out[it.multi_index] = self._exact_py(
                float(u[it.multi_index]), int(self._off[j, c]), int(self._cnt[j, c]), self._cvals, self._wvals
            )
        return out

    def __call__(self, power: np.ndarray) -> np.ndarray:
        """Scores ``(..., frames, m)`` of frame spectra ``power`` ``(..., frames, bins, m)`` (finite, >= 0).

        Raises
        ------
        ParameterError
            If the last two axes are not this score's ``(bins, m)``.
        """
        p = np.asarray(power, dtype=float)
        if p.ndim < 3 or p.shape[-2] != self.tested.size or p.shape[-1] != self.n_channels:
            raise ParameterError(
                f"power must have shape (..., frames, {self.tested.size}, {self.n_channels}); got {p.shape}"
            )
        compiled = _jit.enabled() if self._compiled is None else self._compiled
        lead = p.shape[:-2]
        flat = p.reshape(-1, *p.shape[-2:])
        out = np.empty((flat.shape[0], self.n_channels))
        if compiled and _jit.HAVE_NUMBA:
            _score_kernel(flat, *self._kernel_args, out)
        else:
            self._numpy(flat, out)
        return out.reshape(*lead, self.n_channels)

    def _unchecked(self, power: np.ndarray) -> np.ndarray:
        """:meth:`__call__` for ``(F, bins, m)`` float arrays of the right shape (the monitor calls it)."""
        out = np.empty((power.shape[0], self.n_channels))
        if self._compiled and _jit.HAVE_NUMBA:
            _score_kernel(power, *self._kernel_args, out)
        elif self._compiled is None:
            return self(power)
        else:
            self._numpy(power, out)
        return out

    def _numpy(self, power: np.ndarray, out: np.ndarray) -> None:
        """Bounds vectorized; the exact value at the candidate bins by the kernel's scalar code."""
        u = power[:, self._idx, :] * self._inv1  # (F, nt, m)
        kA = np.argmax(u, axis=1)  # (F, m): first maximum, as the kernel's strict '>'
        A = np.take_along_axis(u, kA[:, None, :], axis=1)[:, 0, :]
        ex, cv, wv, off, cnt = self._exact_py, self._cvals, self._wvals, self._off, self._cnt
        F, m = A.shape
        e = np.empty((F, m))
        for f in range(F):
            for c in range(m):
                k = int(kA[f, c])
                e[f, c] = ex(float(A[f, c]), int(off[k, c]), int(cnt[k, c]), cv, wv)
        v = u * self._invr
        cand = v > e[:, None, :]
        cand[np.arange(F)[:, None], kA, np.arange(m)[None, :]] = False
        for f, j, c in zip(*np.nonzero(cand), strict=True):
            ej = ex(float(u[f, j, c]), int(off[j, c]), int(cnt[j, c]), cv, wv)
            if ej > e[f, c]:
                e[f, c] = ej
        np.maximum(e - self.log_n, 0.0, out=out)


def frame_scores(power: np.ndarray, threshold: Threshold) -> np.ndarray:
    """``-log`` Bonferroni p-value ``(..., frames, m)`` of frame spectra (one-off :class:`FrameScore`).

    Parameters
    ----------
    power : (..., frames, bins, m) array
        Frame spectra (:func:`chatterspec.detection.spectral.frame_columns`).
    threshold : Threshold
        Gives the tested bins and the healthy law (see :class:`FrameScore`).
    """
    return FrameScore(threshold)(power)
