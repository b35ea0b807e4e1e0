"""Is a fitted model adequate? Three tests on held-out healthy data, per channel (goes beyond the papers).

The held-out chattering ``e`` (eq 23 at the fitted model, from the held-out measurements only) is
tested three ways; ``alpha`` is shared equally among the three (Bonferroni), and within the first
two among the channels, so that data of a plant the fitted model describes fail the whole check with
probability at most ``alpha`` (union bound):

1. **Whiteness beyond lag 1.** Under the model each channel's chattering is a scalar MA(1): its
   autocorrelations vanish beyond lag 1. With ``r`` the sample autocorrelations at lags ``2 .. h + 1``
   (Ljung-Box's finite-sample weights ``(n + 2) / (n - l)``), Bartlett's formula gives under an
   MA(1) ``n Cov(r_i, r_j) = c(j - i)``, ``c(0) = 1 + 2 rho^2``, ``c(+-1) = 2 rho``, ``c(+-2) = rho^2``
   (``rho`` the lag-1 autocorrelation, taken from these data), and ``Q = n r' C^-1 r`` is
   chi-squared with ``h`` degrees of freedom: the portmanteau test after removing the MA(1)
   structure. Weighting by ``C^-1`` puts the power where the MA(1) spectrum is quiet (a pressure
   chattering that is nearly a first difference shows a low-frequency mismatch clearly). Lag 1 is not
   tested: its level is the MA(1) coefficient, which the noise fit estimated on other data
   (whitening with that coefficient makes the test reject sound models: a 1 % error in the pressure
   channel's ``gamma0``, inside the fit's interval, moves a whitened Ljung-Box statistic by tens).
   Checked: at ``rho`` from 0 to -0.4999995 (the EHA position channel, almost a first difference)
   the statistic's null mean is ``h`` and its level holds (``tests/test_commissioning.py``).
2. **Spectrum.** The held-out chattering is cut into ``K`` non-overlapping segments of one STFT
   window; their raw periodograms (eq 49) are averaged and compared bin by bin with the exact
   threshold of an average of ``K`` records (:func:`~chatterspec.detection.thresholds.exact_threshold`
   with ``averaged=K``, Welch-Satterthwaite), family-wise over the tested bins (the model file's
   band, if any). Adjacent segments share one lag-1 pair of the MA(1) chattering: independent for
   this purpose. Bins over the threshold are reported as bands (Hz).
3. **Alarms.** The monitor's frames (its STFT window and hop, its per-frame threshold and frame
   score) go through its alarm rule at its default budget (CUSUM, one false alarm per day, the
   threshold calibrated in-call as ``chatterspec monitor`` does:
   :func:`~chatterspec.studies.alarm_budget.alarm_settings`);
   the alarm starts on the held-out span are compared with the budget: the check fails when
   ``P(N >= starts)`` under a Poisson law of mean ``budget x hours`` is at most ``alpha / 3``.
   The frames, score and rule are the online monitor's own components, started at the held-out
   span's first sample, so the count is what ``chatterspec monitor`` reports on these data
   (``tests/test_commissioning.py`` checks it against :class:`~chatterspec.online.monitor.ChatteringMonitor`).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.signal
import scipy.special

from ...plants.models import LinearModel

__all__ = ["AdequacyCheck", "ChannelCheck", "check_model", "ma1_portmanteau"]

#: Tests that share the check's alpha (whiteness, spectrum, alarms).
N_TESTS = 3


@dataclass(frozen=True)
class ChannelCheck:
    """The held-out tests of one output channel.

    Attributes
    ----------
    channel : str
    whiteness : float
        Portmanteau statistic of the chattering's autocorrelations at lags 2 .. ``lags`` + 1.
    lags : int
        Lags tested: the statistic's chi-squared degrees of freedom.
    whiteness_p : float
        Its p-value.
    white : bool
        ``whiteness_p`` above the channel's share of alpha.
    peak_ratio : float
        Largest averaged-spectrum power over its threshold (> 1: over).
    peak_hz : float
        Frequency (Hz) of that bin.
    bands_hz : tuple of (float, float)
        Frequency ranges (Hz) of the bins over the threshold (adjacent bins merged).
    spectrum_ok : bool
        No tested bin over the threshold.
    alarm_starts : int
        Alarm starts of the monitor's rule on this channel.
    alarm_times_s : tuple of float
        Their frame-centre times (s).
    """

    channel: str
    whiteness: float
    lags: int
    whiteness_p: float
    white: bool
    peak_ratio: float
    peak_hz: float
    bands_hz: tuple[tuple[float, float], ...]
    spectrum_ok: bool
    alarm_starts: int
    alarm_times_s: tuple[float, ...]

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: every field (bands as ``[lo, hi]`` pairs)."""
        out = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["bands_hz"] = [list(b) for b in self.bands_hz]
        out["alarm_times_s"] = list(self.alarm_times_s)
        return out


@dataclass(frozen=True)
class AdequacyCheck:
    """The held-out check of a fitted model (module docstring).

    Attributes
    ----------
    channels : tuple of ChannelCheck
    span_s : (float, float)
        Times (s) of the held-out measurements' first sample and one sample past the last.
    alpha : float
        Probability that data of a plant the model describes fail the check (at most).
    segments : int
        Spectra averaged (``K``), each ``segment_s`` long.
    segment_s : float
    rule : str
        The alarm rule (``cusum`` by default).
    false_alarms_per_hour : float
        Its budget (alarm starts per hour, all channels).
    rule_threshold : float
        The rule's threshold ``h``.
    hours : float
        Hours of held-out data the rule saw.
    expected_starts : float
        ``false_alarms_per_hour x hours``.
    alarm_p_value : float
        ``P(N >= starts)`` for a Poisson count of mean ``expected_starts``.
    rate_interval : (float, float)
        Exact 95 % Poisson interval of the alarm-start rate (per hour).
    adequate : bool
        Every test passed.
    """

    channels: tuple[ChannelCheck, ...]
    span_s: tuple[float, float]
    alpha: float
    segments: int
    segment_s: float
    rule: str
    false_alarms_per_hour: float
    rule_threshold: float
    hours: float
    expected_starts: float
    alarm_p_value: float
    rate_interval: tuple[float, float]
    adequate: bool

    @property
    def alarm_starts(self) -> int:
        """Alarm starts on every channel together."""
        return sum(c.alarm_starts for c in self.channels)

    def failures(self) -> list[str]:
        """One line per failed test: what failed, on which channel, in which band or when."""
        out = []
        for c in self.channels:
            if not c.white:
                out.append(
                    f"{c.channel}: the chattering is correlated beyond lag 1 (portmanteau {c.whiteness:.4g} "
                    f"over lags 2-{c.lags + 1}, p = {c.whiteness_p:.2g})"
                )
            if not c.spectrum_ok:
                bands = ", ".join(f"{lo:.4g}-{hi:.4g} Hz" for lo, hi in c.bands_hz)
                out.append(
                    f"{c.channel}: the spectrum is over its threshold at {bands} (peak {c.peak_ratio:.3g} x "
                    f"threshold at {c.peak_hz:.4g} Hz)"
                )
        if self.alarm_p_value <= self.alpha / N_TESTS:
            where = "; ".join(
                f"{c.channel} at {', '.join(f'{t:.2f}' for t in c.alarm_times_s)} s"
                for c in self.channels
                if c.alarm_starts
            )
            out.append(
                f"{self.alarm_starts} alarm start(s) in {self.hours:.3g} h ({where}) where the budget of "
                f"{self.false_alarms_per_hour:.3g} per hour expects {self.expected_starts:.2g} "
                f"(p = {self.alarm_p_value:.2g})"
            )
        return out

    def to_dict(self) -> dict[str, object]:
        """JSON-ready: the fields, ``channels`` as dicts, ``alarm_starts`` and ``failures``."""
        out: dict[str, object] = {k: getattr(self, k) for k in self.__dataclass_fields__}
        out["channels"] = [c.to_dict() for c in self.channels]
        out["span_s"], out["rate_interval"] = list(self.span_s), list(self.rate_interval)
        out["alarm_starts"] = self.alarm_starts
        out["failures"] = self.failures()
        return out


def ma1_portmanteau(e: np.ndarray, lags: int) -> tuple[float, float]:
    """Portmanteau test that ``e`` has no autocorrelation beyond lag 1 (an MA(1); module docstring).

    Parameters
    ----------
    e : (n,) array
        A series (here a channel's chattering).
    lags : int
        Number ``h`` of lags tested, ``2 .. h + 1`` (``h + 1 < n``): the chi-squared degrees of freedom.

    Returns
    -------
    (statistic, p_value)
    """
    import scipy.fft
    import scipy.linalg

    x = np.asarray(e, dtype=float) - float(np.mean(e))
    n = x.size
    size = scipy.fft.next_fast_len(n + lags + 1)
    X = scipy.fft.rfft(x, n=size)
    acov = scipy.fft.irfft(X.real**2 + X.imag**2, n=size)[: lags + 2]
    r = acov[1:] / acov[0]
    rho = float(np.clip(r[0], -0.5, 0.5))
    col = np.zeros(lags)
    col[: min(3, lags)] = [1 + 2 * rho * rho, 2 * rho, rho * rho][: min(3, lags)]
    rr = r[1:] * np.sqrt((n + 2.0) / (n - np.arange(2, lags + 2)))
    stat = float(n * rr @ scipy.linalg.solve(scipy.linalg.toeplitz(col), rr, assume_a="pos"))
    return stat, float(scipy.special.chdtrc(lags, stat))


def _bands(freqs: np.ndarray, over: np.ndarray, gap_bins: int = 2) -> tuple[tuple[float, float], ...]:
    """Frequency ranges of the ``True`` bins of ``over``, merging runs at most ``gap_bins`` bins apart."""
    idx = np.flatnonzero(over)
    if not idx.size:
        return ()
    runs, start = [], idx[0]
    for a, b in itertools.pairwise(idx):
        if b - a > gap_bins + 1:
            runs.append((start, a))
            start = b
    runs.append((start, idx[-1]))
    return tuple((float(freqs[lo]), float(freqs[hi])) for lo, hi in runs)


def _spectrum(model: LinearModel, e: np.ndarray, settings: Any, alpha_channel: float) -> tuple[list, int]:
    """Averaged-periodogram verdicts per channel: ``[(ratio, peak_hz, bands, ok)]`` and the segment count."""
    from ...detection.spectral import mean_periodogram
    from ...detection.thresholds import exact_threshold

    W = settings.stft.n_window(model.dt)
    K = e.shape[0] // W
    per = mean_periodogram(e[: K * W].reshape(K, W, -1), model.dt)
    th = exact_threshold(
        model, per.freqs_hz, W, alpha_channel, settings.correction, averaged=K, band=settings.band
    )
    tested = np.asarray(th.tested)
    ratio = np.where(tested[:, None], per.power / th.values, 0.0)
    out = []
    for c in range(model.n_outputs):
        k = int(np.argmax(ratio[:, c]))
        over = ratio[:, c] > 1.0
        out.append((float(ratio[k, c]), float(per.freqs_hz[k]), _bands(per.freqs_hz, over), not over.any()))
    return out, K


def _alarms(model: LinearModel, e: np.ndarray, settings: Any, t_first: float) -> tuple[np.ndarray, list, Any]:
    """The monitor's alarm starts on ``e`` (chattering sample 0 at ``t_first`` s): ``(starts (F, m), frame
    times, settings)``."""
    from ... import _jit
    from ...detection.alarms.streams import run_rule
    from ...detection.spectral import FrameEngine
    from ...detection.thresholds import frame_threshold
    from ...detection.verdicts import FrameScore

    dt = model.dt
    th = frame_threshold(model, settings.stft.freqs_hz(dt), settings.stft, dt, settings.alpha,
                         settings.correction, band=settings.band)  # fmt: skip
    idx, power = FrameEngine(settings.stft, dt, compiled=_jit.enabled())(np.ascontiguousarray(e), 0)
    score = FrameScore(th, compiled=_jit.enabled())(power)
    starts = run_rule(settings.rule, score).starts
    W, H = settings.stft.n_window(dt), settings.stft.n_hop(dt)
    times = t_first + (idx * H + (W - 1) / 2.0) * dt
    return starts, times.tolist(), settings


def check_model(
    model: LinearModel,
    settings: Any,
    e: np.ndarray,
    *,
    t0: float,
    alpha: float = 0.01,
    lags: int = 20,
) -> AdequacyCheck:
    """The three held-out tests of the module docstring on the chattering ``e`` of ``model``.

    Parameters
    ----------
    model : LinearModel
        The fitted model (full measurement), at which ``e`` was computed.
    settings : MonitorSettings
        The monitor's detector settings with its alarm rule set for its budget
        (:func:`~chatterspec.studies.alarm_budget.alarm_settings`).
    e : (N, m) array
        Held-out chattering, eq (23) from the held-out measurements only.
    t0 : float
        Time (s) of the held-out span's first measurement (``e[0]`` is one sample later).
    alpha : float
        Probability (at most) that data the model describes fail the check.
    lags : int
        Ljung-Box lags.
    """
    from ...detection.alarms.calibration import poisson_interval

    m, dt = model.n_outputs, model.dt
    a_test = alpha / N_TESTS
    spectra, K = _spectrum(model, e, settings, a_test / m)
    starts, times, settings = _alarms(model, e, settings, t0 + dt)
    channels = []
    for c in range(m):
        stat, p = ma1_portmanteau(e[:, c], lags)
        ratio, peak_hz, bands, ok = spectra[c]
        when = tuple(float(times[j]) for j in np.flatnonzero(starts[:, c]))
        white = p > a_test / m
        name = model.output_names[c]
        channels.append(
            ChannelCheck(name, stat, int(lags), p, white, ratio, peak_hz, bands, ok, len(when), when)
        )
    hours = e.shape[0] * dt / 3600.0
    budget = float(settings.false_alarms_per_hour)
    n_starts = int(starts.sum())
    expected = budget * hours
    p_alarm = float(scipy.special.pdtrc(n_starts - 1, expected)) if n_starts > 0 else 1.0
    lo, hi = poisson_interval(n_starts, 0.95)
    adequate = all(c.white and c.spectrum_ok for c in channels) and p_alarm > a_test
    return AdequacyCheck(
        channels=tuple(channels),
        span_s=(float(t0), float(t0 + (e.shape[0] + 1) * dt)),
        alpha=float(alpha),
        segments=int(K),
        segment_s=settings.stft.n_window(dt) * dt,
        rule=settings.rule.name,
        false_alarms_per_hour=budget,
        rule_threshold=float(settings.rule.threshold),
        hours=hours,
        expected_starts=expected,
        alarm_p_value=p_alarm,
        rate_interval=(lo / hours, hi / hours),
        adequate=bool(adequate),
    )
