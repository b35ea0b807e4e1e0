"""Power spectra of the chattering signal: periodogram, expected healthy spectrum, STFT.

Conventions (``docs/design.md`` §4 and §6, ``docs/internal-contracts.md``): time is the
second-to-last axis and channels the last, ``(..., N, m)``; realizations (any
number of leading axes) are handled by vectorized numpy/scipy calls. Frequencies
are in **Hz**, times in **seconds**.

Healthy chattering model
------------------------
For a full-measurement auxiliary (sgn) SVSF with zero initial error, the healthy
chattering is the vector MA(1) process (eq 23 and 52-53 with the index
corrections of ``docs/design.md`` C6)::

    e(k+1|k) = C v(k) + w(k+1) + M w(k),        M = -C A C^-1

so channel ``i`` has lag-0 and lag-1 autocovariances::

    gamma0_i = (C Q C^T + R + M R M^T)_ii,      gamma1_i = (M R)_ii

and its periodogram has the exact finite-N expectation
``gamma0 + 2 (1 - 1/N) gamma1 cos(2 pi f dt)``. The exact finite-N *law* of a
bin is ``l1 Z1^2 + l2 Z2^2`` (Z iid standard normal) with ``(l1, l2)`` the
eigenvalues of the covariance of ``(Re X, Im X)`` divided by the normalisation
(:func:`periodogram_eigenvalues`, :func:`frame_eigenvalues`); ``l1 + l2`` is
the expectation and ``l1 = l2`` gives the chi2(2)/2 law of Lemma 2. The asymptotic form (N -> inf)
is eq (56) read index-wise; for diagonal Q and R it equals
``sum_j C_ij^2 q_j + sum_j |e^{i w} delta_ij + M_ij|^2 r_j``.

STFT column engine
------------------
The engine of :func:`frame_columns`, the online monitor and the alarm budget: :class:`FrameEngine`
computes the frame spectra of :class:`Spectrogram` for one ``(config, dt)`` with reusable
scratch buffers; :func:`_taper_kernel` and :func:`_power_kernel` are its compiled loops (same
operations as the numpy form, same bits: tests/test_spectral.py).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import numpy as np
import numpy.typing as npt
import scipy.fft

from .. import _jit
from .._repr import short_repr
from .._stft import DEFAULT_STFT, STFTConfig, cached_taper
from .._validate import finite_array, positive, positive_int, readonly
from ..errors import ParameterError, ShapeError, SingularMatrixError
from ..plants.models import LinearModel
from ..plants.nonlinear import Model, NonlinearModel, require_linear

__all__ = [
    "DEFAULT_STFT",
    "FrameEngine",
    "Periodogram",
    "STFTConfig",
    "Spectrogram",
    "chattering_autocovariance",
    "expected_frame_spectrum",
    "expected_spectrum",
    "frame_columns",
    "frame_eigenvalues",
    "mean_periodogram",
    "periodogram",
    "periodogram_eigenvalues",
    "periodogram_freqs",
    "power_step",
    "spectrogram",
    "window_overlap_ratio",
]


# STFTConfig is defined in the package base (model files check it without importing this module);
# this module is its public home (reprs, pickles and the API docs name it here).
STFTConfig.__module__ = __name__


SpectrumForm = Literal["exact", "asymptotic"]


def _time_series(name: str, x: npt.ArrayLike) -> np.ndarray:
    arr = finite_array(name, x)
    if arr.ndim < 2:
        raise ShapeError(
            f"{name} must have shape (..., N, channels) with time on axis -2; got shape {arr.shape} "
            "(use x[:, None] for a single channel)"
        )
    return arr


# ---------------------------------------------------------------------------
# Periodogram (eq 49)
# ---------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Periodogram:
    """Raw periodogram of eq (49).

    Attributes
    ----------
    freqs_hz : (n_bins,) array
        ``f_n = n / (N dt)`` Hz, ``n = 0 .. N // 2`` (all ``rfft`` bins, DC to Nyquist).
    power : (..., n_bins, m) array
        ``S(f_n) = |sum_k x(k) e^{-i 2 pi n k / N}|^2 / N`` per channel (units of x squared).
    n_samples : int
        Record length N.
    dt : float
        Sampling time (s).
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    freqs_hz: np.ndarray
    power: np.ndarray
    n_samples: int
    dt: float

    @property
    def n_bins(self) -> int:
        """Number of frequency bins."""
        return self.freqs_hz.shape[0]

    def mean(self) -> Periodogram:
        """Average over every leading (realization) axis: the Monte Carlo spectrum of Fig 6."""
        p = self.power.reshape(-1, *self.power.shape[-2:]).mean(axis=0)
        return Periodogram(self.freqs_hz, readonly(p), self.n_samples, self.dt)


def periodogram_freqs(n_samples: int, dt: float) -> np.ndarray:
    """Frequencies (Hz) of the ``rfft`` bins of an N-sample record: ``n / (N dt)``, ``n = 0 .. N//2``.

    Parameters
    ----------
    n_samples : int
        Record length N.
    dt : float
        Sampling time (s).
    """
    n_samples = positive_int("n_samples", n_samples)
    dt = positive("dt", dt, unit="s")
    return scipy.fft.rfftfreq(n_samples, dt)


def periodogram(x: np.ndarray, dt: float) -> Periodogram:
    """Periodogram of eq (49): ``S(f_n) = |rfft(x)|^2 / N`` over the time axis, no window.

    Parameters
    ----------
    x : (..., N, m) array
        Chattering (or any signal); time on axis -2, channels on axis -1.
    dt : float
        Sampling time in seconds.

    Returns
    -------
    Periodogram
        ``power`` has shape ``(..., N // 2 + 1, m)``. No window is applied: the
        chi-squared law of Lemma 2 (eq 43) holds for the raw DFT. Bins
        ``1 .. ceil(N/2) - 1`` are chi2(2)/2 times their mean; DC (and the
        Nyquist bin for even N) are chi2(1) times their mean (``docs/design.md`` C8).

    See Also
    --------
    spectrogram : frame spectra (STFT) of the same signal.
    expected_spectrum : the healthy expectation of this periodogram.

    Examples
    --------
    >>> import numpy as np
    >>> p = periodogram(np.ones((8, 1)), dt=1e-3)
    >>> float(p.power[0, 0])  # |8|^2 / 8
    8.0
    """
    x = _time_series("x", x)
    dt = positive("dt", dt, unit="s")
    n = x.shape[-2]
    X = scipy.fft.rfft(x, axis=-2)
    # (X.real**2 + X.imag**2) / n, squaring in X's own memory: one new array instead of three
    # (page faults on fresh memory cost as much as the arithmetic in the Monte Carlo loop)
    Xf = np.ascontiguousarray(X).view(np.float64).reshape(*X.shape, 2)
    np.square(Xf, out=Xf)
    power = np.add(Xf[..., 0], Xf[..., 1])
    power /= n
    return Periodogram(readonly(periodogram_freqs(n, dt)), readonly(power), n, dt)


def mean_periodogram(x: np.ndarray, dt: float) -> Periodogram:
    """Monte Carlo averaged periodogram (Fig 6): :func:`periodogram` averaged over all leading axes.

    Parameters
    ----------
    x : (..., N, m) array
        Realizations of the chattering; time on axis -2.
    dt : float
        Sampling time (s).
    """
    return periodogram(x, dt).mean()


# ---------------------------------------------------------------------------
# Expected healthy spectrum (eq 56, exact finite-N form)
# ---------------------------------------------------------------------------
def spectrum_model(model: Model) -> LinearModel:
    """``model`` itself when linear: the closed-form chattering spectrum (eq 56-58) needs A and B.

    Raises
    ------
    ModelKindError
        For a nonlinear model (the message says to calibrate a threshold on healthy runs instead).
    """
    return require_linear(model, "the expected chattering spectrum (eq 56-58)")


def chattering_autocovariance(model: LinearModel) -> tuple[np.ndarray, np.ndarray]:
    """Lag-0 and lag-1 autocovariances ``(gamma0, gamma1)``, each ``(m,)``, of the healthy chattering.

    ``gamma0 = diag(C Q C^T + R + M R M^T)``, ``gamma1 = diag(M R)`` with
    ``M = -C A C^-1`` (eq 58); the chattering is the MA(1) process
    ``C v(k) + w(k+1) + M w(k)``.

    Raises
    ------
    SingularMatrixError
        If the model is not full-measurement (C square and invertible): the
        reduced-order chattering (eq 26-28) is not an MA(1) of this form.
    """
    if isinstance(model, NonlinearModel):
        spectrum_model(model)
    if not isinstance(model, LinearModel):
        raise ParameterError(
            f"model must be a chatterspec.plants.models.LinearModel; got {type(model).__name__}"
        )
    if not model.full_measurement:
        raise SingularMatrixError(
            "the expected chattering spectrum needs a full-measurement model (C square and invertible); "
            f"got C with shape {model.C.shape}. Calibrate a threshold empirically for reduced-order filters"
        )
    C, A, Q, R = model.C, model.A, model.Q, model.R
    M = -C @ A @ model.C_inv
    gamma0 = np.diag(C @ Q @ C.T + R + M @ R @ M.T).copy()
    gamma1 = np.diag(M @ R).copy()
    return gamma0, gamma1


def _freqs(freqs_hz: npt.ArrayLike) -> np.ndarray:
    return finite_array("freqs_hz", freqs_hz, ndim=1)


def expected_spectrum(
    model: LinearModel,
    freqs_hz: np.ndarray,
    n_samples: int | None = None,
    form: SpectrumForm = "exact",
) -> np.ndarray:
    """Expected healthy periodogram ``E[S_i(f)]``, shape ``(n_bins, m)`` (eq 56, corrected).

    Parameters
    ----------
    model : LinearModel
        Nominal model of the filter (full measurement).
    freqs_hz : (n_bins,) array
        Frequencies in Hz (usually :attr:`Periodogram.freqs_hz`).
    n_samples : int, optional
        Record length N; required for ``form="exact"``.
    form : {"exact", "asymptotic"}
        ``"exact"``: ``gamma0 + 2 (1 - 1/N) gamma1 cos(2 pi f dt)``, the exact
        expectation of eq (49) for an MA(1) record of N samples at the DFT
        frequencies (it matters where ``q_i`` is tiny, e.g. the EHA position
        channel at low frequency). ``"asymptotic"``: eq (56) read index-wise
        (``N -> inf``), ``gamma0 + 2 gamma1 cos(2 pi f dt)``.

    Returns
    -------
    (n_bins, m) array
    """
    f = _freqs(freqs_hz)
    if form == "exact":
        if n_samples is None:
            raise ParameterError('form="exact" needs n_samples (the record length N); or use "asymptotic"')
        rho = 1.0 - 1.0 / positive_int("n_samples", n_samples)
    elif form == "asymptotic":
        rho = 1.0
    else:
        raise ParameterError(f'form must be "exact" or "asymptotic"; got {form!r}')
    return _ma1_spectrum(model, f, rho)


def _ma1_spectrum(model: LinearModel, f: np.ndarray, rho: float) -> np.ndarray:
    gamma0, gamma1 = chattering_autocovariance(model)
    c = np.cos(2.0 * np.pi * f * model.dt)[:, None]
    return gamma0[None, :] + 2.0 * rho * gamma1[None, :] * c


# ---------------------------------------------------------------------------
# STFT
# ---------------------------------------------------------------------------
@lru_cache(maxsize=32)
def _stft_engine(window: str, n_window: int, n_hop: int, dt: float) -> scipy.signal.ShortTimeFFT:
    # cached: the online monitor calls frame_columns once per push (never mutate the result)
    import scipy.signal

    # scale_to=None keeps the raw sum_k w_k x_k e^{-i w k}; we divide |.|^2 by sum w_k^2 ourselves.
    return scipy.signal.ShortTimeFFT(
        cached_taper(window, n_window),
        n_hop,
        fs=1.0 / dt,
        fft_mode="onesided",
        mfft=n_window,
        phase_shift=None,
    )


def window_overlap_ratio(config: STFTConfig, dt: float) -> float:
    """``rho_w = sum_k w_k w_{k+1} / sum_k w_k^2``: the lag-1 weight of a frame's expected spectrum.

    Parameters
    ----------
    config : STFTConfig
        Window settings.
    dt : float
        Sampling time (s).
    """
    w = config.taper(dt)
    return float(np.dot(w[:-1], w[1:]) / np.dot(w, w))


@dataclass(frozen=True, eq=False)
class Spectrogram:
    """Frame power spectra of the chattering.

    Attributes
    ----------
    times_s : (frames,) array
        Frame-centre times ``t0 + (j H + (W - 1) / 2) dt`` (s).
    freqs_hz : (bins,) array
        ``n / (W dt)`` Hz, ``n = 0 .. W // 2``.
    power : (..., frames, bins, m) array
        ``|sum_k w_k x(jH + k) e^{-i 2 pi n k / W}|^2 / sum_k w_k^2``: a white frame of
        variance sigma^2 has mean sigma^2 and (away from DC/Nyquist) the chi2(2)/2 law.
    config : STFTConfig
    dt : float
        Sampling time (s).
    frame_starts : (frames,) int array
        Index (in the analysed sample stream) of each frame's first sample.
    """

    __repr__ = short_repr  # shapes and key figures, never whole arrays

    times_s: np.ndarray
    freqs_hz: np.ndarray
    power: np.ndarray
    config: STFTConfig
    dt: float
    frame_starts: np.ndarray

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return self.times_s.shape[0]


def frame_columns(
    x: np.ndarray, dt: float, config: STFTConfig = DEFAULT_STFT, first_sample: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Frame spectra of every frame lying completely inside the samples ``x``.

    Frames live on a global grid: frame ``j`` covers the global samples
    ``[j H, j H + W)``. ``first_sample`` is the global index of ``x[..., 0, :]``
    (an online monitor passes the global index of the oldest sample in its ring
    buffer). Each frame's column is computed from its own W samples only, by the
    same operations as :meth:`scipy.signal.ShortTimeFFT.stft` (taper product and
    ``scipy.fft.rfft``, vectorized over frames) whatever the buffer, so the values
    of a frame are identical whether computed from the whole record
    (:func:`spectrogram`) or from any buffer that contains it.

    Parameters
    ----------
    x : (..., n, m) array
        Samples (time on axis -2).
    dt : float
        Sampling time (s).
    config : STFTConfig
    first_sample : int
        Global sample index of ``x[..., 0, :]`` (>= 0).

    Returns
    -------
    frame_index : (frames,) int array
        Global frame numbers ``j`` (frame start ``j H``); empty if no frame fits.
    power : (..., frames, W // 2 + 1, m) array
        Scaled as in :class:`Spectrogram`.
    """
    x = _time_series("x", x)
    dt = positive("dt", dt, unit="s")
    if isinstance(first_sample, bool) or not isinstance(first_sample, int | np.integer) or first_sample < 0:
        raise ParameterError(f"first_sample must be an integer >= 0; got {first_sample!r}")

    return FrameEngine(config, dt)(x, int(first_sample))


def spectrogram(x: np.ndarray, dt: float, config: STFTConfig = DEFAULT_STFT, t0: float = 0.0) -> Spectrogram:
    """Spectrogram of complete frames (paper section IV-C) via :class:`scipy.signal.ShortTimeFFT`.

    Parameters
    ----------
    x : (..., N, m) array
        Chattering; time on axis -2.
    dt : float
        Sampling time (s).
    config : STFTConfig
        Window (default 1 s Hamming) and hop (default 0.2 s).
    t0 : float
        Time (s) of ``x``'s first sample (``record.t[0]`` for a ChatteringRecord).

    Returns
    -------
    Spectrogram
        Frame ``j`` covers samples ``[j H, j H + W)``; only complete frames
        (``(N - W) // H + 1`` of them). Columns equal those of
        :func:`frame_columns` on any sample range containing the frame.

    Raises
    ------
    ShapeError
        If the record is shorter than one window.

    See Also
    --------
    periodogram : the whole-record spectrum.
    frame_columns : the frames from a given sample on (online use).
    """
    x = _time_series("x", x)
    dt = positive("dt", dt, unit="s")
    W = config.n_window(dt)
    if x.shape[-2] < W:
        raise ShapeError(
            f"record has {x.shape[-2]} samples, shorter than one STFT window of {W} samples "
            f"({config.window_s} s at dt = {dt} s); use a longer record or a shorter STFTConfig.window_s"
        )
    j, power = frame_columns(x, dt, config, 0)
    H = config.n_hop(dt)
    starts = j * H
    times = float(t0) + (starts + (W - 1) / 2.0) * dt
    return Spectrogram(
        readonly(times), readonly(config.freqs_hz(dt)), readonly(power), config, dt, readonly(starts)
    )


def expected_frame_spectrum(
    model: LinearModel, freqs_hz: np.ndarray, config: STFTConfig, dt: float | None = None
) -> np.ndarray:
    """Expected healthy frame spectrum ``gamma0 + 2 gamma1 rho_w cos(2 pi f dt)``, shape ``(bins, m)``.

    ``rho_w = sum_k w_k w_{k+1} / sum_k w_k^2`` (:func:`window_overlap_ratio`); exact
    for the MA(1) chattering at any frequency under the :class:`Spectrogram` scaling.

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Frame frequencies (Hz), usually :attr:`Spectrogram.freqs_hz`.
    config : STFTConfig
        Window settings.
    dt : float, optional
        Sampling time (s); defaults to ``model.dt``.

    Returns
    -------
    (bins, m) array
    """
    f = _freqs(freqs_hz)
    dt = model.dt if dt is None else positive("dt", dt, unit="s")
    return _ma1_spectrum(model, f, window_overlap_ratio(config, dt))


# ---------------------------------------------------------------------------
# Exact finite-N law of a bin: eigenvalues of the (Re, Im) covariance
# ---------------------------------------------------------------------------
def _bin_eigenvalues(
    gamma0: np.ndarray, gamma1: np.ndarray, w: np.ndarray, f: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues ``l1 >= l2 >= 0`` (each ``(bins, m)``) of ``|sum_k w_k x_k e^{-i omega k}|^2 / sum w_k^2``.

    For the MA(1) ``x`` (lag-0 ``gamma0``, lag-1 ``gamma1``), with ``P = sum w_k^2``,
    ``Q = sum w_k w_{k+1}``, ``A = sum w_k^2 e^{-2 i omega k}`` and
    ``B = e^{-i omega} sum_k w_k w_{k+1} e^{-2 i omega k}``, the covariance of
    ``(Re, Im)`` has trace ``T = gamma0 P + 2 gamma1 Q cos(omega)`` and
    ``(Var Re - Var Im)^2 + 4 Cov^2 = |gamma0 A + 2 gamma1 B|^2 = D^2``, so
    ``l1,2 = (T +- D) / (2 P)``. A constant phase shift of the frame does not change them.
    """
    L = w.size
    omega = 2.0 * np.pi * f * dt
    P = float(np.dot(w, w))
    Q = float(np.dot(w[:-1], w[1:]))
    w2 = w * w
    u = np.zeros(L)
    u[:-1] = w[:-1] * w[1:]
    n = f * L * dt
    ni = np.rint(n)
    if np.all(np.abs(n - ni) <= 1e-6):  # DFT grid of length L: FFT, O(L log L)
        idx = (2 * ni.astype(np.int64)) % L
        A = scipy.fft.fft(w2)[idx]
        B = np.exp(-1j * omega) * scipy.fft.fft(u)[idx]
    else:  # arbitrary frequencies: direct sums, chunked to bound memory
        k = np.arange(L)
        A = np.empty(f.size, dtype=complex)
        B = np.empty(f.size, dtype=complex)
        step = max(1, 2_000_000 // L)
        for s in range(0, f.size, step):
            E = np.exp(-2j * np.outer(omega[s : s + step], k))
            A[s : s + step] = E @ w2
            B[s : s + step] = np.exp(-1j * omega[s : s + step]) * (E @ u)
    T = gamma0[None, :] * P + 2.0 * gamma1[None, :] * Q * np.cos(omega)[:, None]
    D = np.abs(gamma0[None, :] * A[:, None] + 2.0 * gamma1[None, :] * B[:, None])
    l1 = (T + D) / (2.0 * P)
    l2 = (T - D) / (2.0 * P)
    # rounding: a real DFT bin (DC, Nyquist) has l2 = 0 exactly
    scale = (np.abs(gamma0)[None, :] * P + 2.0 * np.abs(gamma1)[None, :] * abs(Q)) / (2.0 * P)
    l2 = np.where(l2 <= 64.0 * np.finfo(float).eps * scale, 0.0, l2)
    return l1, l2


def periodogram_eigenvalues(
    model: LinearModel, freqs_hz: np.ndarray, n_samples: int
) -> tuple[np.ndarray, np.ndarray]:
    """Exact finite-N law of each healthy periodogram bin: ``S_i(f) = l1 Z1^2 + l2 Z2^2``.

    ``Z1, Z2`` are independent standard normal; ``l1 >= l2 >= 0`` are the
    eigenvalues of the covariance of ``(Re X, Im X) / sqrt(N)`` for the MA(1)
    chattering. At the DFT frequencies ``0 < n < N/2``::

        l1,2 = gamma0 / 2 + (1 - 1/N) gamma1 cos(omega) +- |gamma1| / N

    (``l1 + l2`` is :func:`expected_spectrum` ``form="exact"``), and at DC and
    Nyquist ``l2 = 0`` (chi2(1) bin). ``l1 = l2`` would be the chi2(2)/2 law of
    Lemma 2; the difference matters where the spectrum is tiny compared with
    ``|gamma1| / N`` (EHA position channel at the lowest bins).

    Parameters
    ----------
    model : LinearModel
        Nominal (full-measurement) model.
    freqs_hz : (bins,) array
        Frequencies (Hz), usually :attr:`Periodogram.freqs_hz` (any frequency is accepted).
    n_samples : int
        Record length N.

    Returns
    -------
    (l1, l2) : two (bins, m) arrays
    """
    f = _freqs(freqs_hz)
    n = positive_int("n_samples", n_samples)
    if n < 2:
        raise ParameterError(f"n_samples must be at least 2; got {n}")
    gamma0, gamma1 = chattering_autocovariance(model)
    return _bin_eigenvalues(gamma0, gamma1, np.ones(n), f, model.dt)


def frame_eigenvalues(
    model: LinearModel, freqs_hz: np.ndarray, config: STFTConfig, dt: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Exact law ``l1 Z1^2 + l2 Z2^2`` of each healthy STFT frame bin (:class:`Spectrogram` scaling).

    The eigenvalues of the covariance of ``(Re, Im)`` of ``sum_k w_k x(k) e^{-i omega k}``
    (``w`` = :meth:`STFTConfig.taper`) divided by ``sum_k w_k^2``; ``l1 + l2`` is
    :func:`expected_frame_spectrum`. Only the window matters (the frame's phase
    convention in :func:`frame_columns` is a constant shift that leaves them unchanged).

    Parameters
    ----------
    model, freqs_hz, config, dt
        As in :func:`expected_frame_spectrum`.

    Returns
    -------
    (l1, l2) : two (bins, m) arrays
    """
    f = _freqs(freqs_hz)
    dt = model.dt if dt is None else positive("dt", dt, unit="s")
    gamma0, gamma1 = chattering_autocovariance(model)
    return _bin_eigenvalues(gamma0, gamma1, np.asarray(config.taper(dt), dtype=float), f, dt)


class FrameEngine:
    """:func:`frame_columns` for one ``(config, dt)``, unchecked, with reusable scratch buffers.

    ``ShortTimeFFT.stft(seg, k_offset=W // 2)`` computes ``rfft(seg[p H : p H + W] * win.conj(), n=W)``
    one frame per Python iteration; the same products and the same ``scipy.fft.rfft`` over a block of
    frames at once give bit-identical columns (tests/test_spectral.py) with much less CPU per frame.
    ``|Y|^2 / sum w^2`` is evaluated as ``(Re Y * Re Y + Im Y * Im Y) / scale``, the same correctly
    rounded operations as ``(Y.real**2 + Y.imag**2) / scale`` (numpy's ``x**2`` is ``x * x``), written
    straight into the ``(..., frames, bins, m)`` output. Blocks of frames keep the windowed copy
    cache-sized (2^15 values, 256 kB) whatever the runs axes.

    ``compiled=True`` (the online monitor, when :func:`chatterspec._jit.enabled`) does the taper
    product and the power in the compiled kernels :func:`_taper_kernel` and :func:`_power_kernel`
    (one pass each instead of a strided view and four ufunc passes; the same operations, hence
    the same bits: tests/test_spectral.py) for inputs with at most one runs axis; the FFT is
    ``scipy.fft.rfft`` either way. :func:`frame_columns` uses the numpy form (no numba import).

    The online monitor keeps one engine per monitor, so that a push allocates only its output
    (the windowed frames and the spectrum's real part live in buffers kept between calls):
    one engine must not be shared between threads. :func:`frame_columns` makes a new one per call.
    The caller has validated ``x`` (a float array, time on axis -2) and ``first_sample`` (int >= 0).

    Parameters
    ----------
    config : STFTConfig
        Window, hop and taper (seconds).
    dt : float
        Sampling time (s).
    compiled : bool
        Use the compiled taper and power loops (same bits as the numpy form).

    See Also
    --------
    chatterspec.detection.spectral.frame_columns : the checked public form.
    """

    def __init__(self, config: STFTConfig, dt: float, compiled: bool = False) -> None:
        self.W, self.H = config.n_window(dt), config.n_hop(dt)
        self.n_bins = self.W // 2 + 1
        w = config.taper(dt)  # the taper the batch STFT (ShortTimeFFT) is built with: the same bits
        self.win = np.ascontiguousarray(w.conj())
        self.scale = float(np.dot(w, w))
        self.compiled = compiled
        self._work: dict[tuple[int, ...], tuple[np.ndarray, np.ndarray]] = {}

    def _buffers(self, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
        bufs = self._work.get(shape)
        if bufs is None:
            if len(self._work) > 4:  # a handful of shapes (full blocks, the last block, one per push size)
                self._work.clear()
            bufs = (np.empty(shape), np.empty((*shape[:-1], self.n_bins)))
            self._work[shape] = bufs
        return bufs

    def grid(self, n: int, first_sample: int) -> tuple[int, int, int]:
        """``(j_first, n_frames, offset)``: the complete global frames of ``n`` samples from ``first_sample``.

        Frame ``j_first + f`` starts at sample ``offset + f H`` of those samples.
        """
        H = self.H
        j_first = -(-first_sample // H)  # first global frame starting at or after first_sample
        j_last = (first_sample + n - self.W) // H  # last global frame ending inside x
        return j_first, max(j_last - j_first + 1, 0), j_first * H - first_sample

    def transforms(self, x: np.ndarray, offset: int, n_frames: int) -> Iterator[tuple[int, int, np.ndarray]]:
        """The compiled path's windowed transforms: ``(lo, hi, Y)`` per block of frames ``lo .. hi - 1``.

        ``x`` (n, m) or (runs, n, m); ``Y`` (runs, m, hi - lo, bins) complex, ``rfft`` of the
        tapered frames (:func:`_taper_kernel`); frame f starts at sample ``offset + f H``.
        """
        W, H = self.W, self.H
        # C-contiguous input: one compiled specialization (a copy only for strided input)
        x3 = np.ascontiguousarray(x) if x.ndim == 3 else np.ascontiguousarray(x)[None]
        m = x3.shape[2]
        block = max(1, (1 << 15) // max(1, x3.shape[0] * m * W))
        for lo in range(0, n_frames, block):
            hi = min(lo + block, n_frames)
            tapered = self._buffers((x3.shape[0], m, hi - lo, W))[0]
            _taper_kernel(x3, offset + lo * H, H, self.win, tapered)
            yield lo, hi, scipy.fft.rfft(tapered, n=W, axis=-1)

    def __call__(self, x: np.ndarray, first_sample: int) -> tuple[np.ndarray, np.ndarray]:
        W, H, n_bins = self.W, self.H, self.n_bins
        j_first, n_frames, offset = self.grid(x.shape[-2], first_sample)
        lead, m = x.shape[:-2], x.shape[-1]
        if n_frames == 0:
            return np.arange(0), np.zeros((*lead, 0, n_bins, m))
        j_last = j_first + n_frames - 1
        per_frame = max(1, math.prod(lead) * m * W)
        block = max(1, (1 << 15) // per_frame)
        power = np.empty((*lead, n_frames, n_bins, m))
        if self.compiled and x.ndim <= 3:
            p3 = power if x.ndim == 3 else power[None]
            for lo, hi, Y in self.transforms(x, offset, n_frames):
                _power_kernel(Y, self.scale, p3[:, lo:hi])
            return np.arange(j_first, j_last + 1), power
        seg = x[..., offset : offset + (n_frames - 1) * H + W, :]
        s_t, s_c = seg.strides[-2], seg.strides[-1]
        # (..., m, F, W) view: frame f of channel c is seg[..., f H : f H + W, c]
        frames = np.lib.stride_tricks.as_strided(
            seg, (*lead, m, n_frames, W), (*seg.strides[:-2], s_c, H * s_t, s_t), writeable=False
        )
        pv = np.moveaxis(power, -1, -3)  # (..., m, F, bins) view of the output
        for lo in range(0, n_frames, block):
            hi = min(lo + block, n_frames)
            tapered, re2 = self._buffers((*lead, m, hi - lo, W))
            np.multiply(frames[..., lo:hi, :], self.win, out=tapered)
            Y = scipy.fft.rfft(tapered, n=W, axis=-1)  # (..., m, f, bins)
            out = pv[..., lo:hi, :]
            np.multiply(Y.real, Y.real, out=re2)
            np.multiply(Y.imag, Y.imag, out=out)
            np.add(re2, out, out=out)
            np.divide(out, self.scale, out=out)
        return np.arange(j_first, j_last + 1), power


@_jit.njit
def _taper_kernel(
    x: np.ndarray, start: int, hop: int, win: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_spectral.py)
    """``out[r, c, f, k] = x[r, start + f hop + k, c] * win[k]``: the windowed frames (one product each).

    ``x`` (runs, n, m); ``out`` (runs, m, F, W). Compiled form of the strided view times the taper
    in :class:`FrameEngine` (same products, same bits).
    """
    runs, m, F, W = out.shape
    for r in range(runs):
        for c in range(m):
            for f in range(F):
                s = start + f * hop
                for k in range(W):
                    out[r, c, f, k] = x[r, s + k, c] * win[k]


@_jit.njit
def _power_kernel(
    Y: np.ndarray, scale: float, out: np.ndarray
) -> None:  # pragma: no cover - compiled (its Python form is tested in tests/test_spectral.py)
    """``out[r, f, b, c] = (Re Y[r, c, f, b]^2 + Im Y[r, c, f, b]^2) / scale`` in that order.

    ``Y`` (runs, m, F, bins) complex; ``out`` (runs, F, bins, m), any strides. No FMA contraction
    without fastmath, so each element is ``fl(fl(fl(re * re) + fl(im * im)) / scale)``, as numpy's
    ``(Y.real**2 + Y.imag**2) / scale`` (tests/test_spectral.py compares the bits).
    """
    runs, m, F, B = Y.shape
    row = np.empty(B)  # one contiguous line of bins, then scattered to the (bins, m) layout
    for r in range(runs):
        for c in range(m):
            for f in range(F):
                power_step(Y[r, c, f], scale, row, out[r, f], c, B)


@_jit.step
def power_step(y: np.ndarray, scale: float, row: np.ndarray, out: np.ndarray, c: int, B: int) -> None:
    """One frame and channel of :func:`_power_kernel`: ``out[b, c] = (Re y_b^2 + Im y_b^2) / scale``.

    ``y`` (B,) complex, ``row`` (B,) scratch (the contiguous line, then scattered to ``out`` (B, m)).
    """
    for b in range(B):
        v = y[b]
        row[b] = (v.real * v.real + v.imag * v.imag) / scale
    for b in range(B):
        out[b, c] = row[b]
