"""The spectrogram of a recording: its time and frequency geometry, its 2-D view and its images.

Geometry. One time rule (:func:`to_ns`), the span a file's spectrogram covers (:func:`record_span`,
:func:`pad_columns`), the spectrogram's band (:func:`default_band_hz`) and colour range
(:data:`DB_RANGE`). One time rule for everything logged: seconds are converted once to integer
nanoseconds by :func:`to_ns` (rounded to the nearest ns) and only integers reach Rerun, whether through
``send_columns`` or ``set_time``. (Rerun's own float paths differ: ``TimeColumn(duration=seconds)``
truncates, ``set_time(duration=seconds)`` rounds, which put a state logged "before" a frame 1 ns
after it.)

The view. Rerun draws tensors without axis ticks (its tensor view names the dimensions only), so
a recording's spectrogram is a ``DepthImage`` of ``10 log10(S / threshold)`` (dB, colour
map ``magma`` over :data:`DB_RANGE`) in a 2-D view, beside labelled points that carry the scale:

- frequency labels ("50 Hz", ...) at the image's left edge, at their rows;
- a colour key (a small gradient image) left of the spectrogram with its dB values, :data:`KEY_PX`
  wide, so that the image starts where the time series' plot areas start (after their y tick labels).

Lining up with the time axes. The image spans the same time as the time views (a file's record span,
:func:`record_span`: one column per frame, padded), and its right edge is
the view's right edge, as theirs (seen in the viewer: within 1 px). Its left edge cannot follow every
time view exactly: a time view's plot area starts after its y tick labels, whose width the viewer sets
from the label text (``0`` ~15 px, ``20`` / ``-10`` / ``100`` ~30 px, ``-0.01`` ~40 px at 1600x1000),
so the time views do not line up with each other either, and a blueprint cannot set that margin. The
key is therefore :data:`KEY_PX` = 30 logical px wide, the margin of two- and three-character labels
(the statistic, alarm and frequency views), whatever the number of channels (:func:`key_width`).

World coordinates: the image spans ``x`` in ``[0, width]`` and ``y`` in ``[0, 1]`` (top =
highest frequency); ``width`` (:func:`image_width`) is the view's aspect ratio at 1600x1000 in
the default layout, so the image fills its view there. Hovering a pixel shows its dB value.

Entities under ``/spectrogram/<channel>``: ``image`` (the dB image and its scale transform),
``freq_ticks``, ``key`` and ``key_ticks`` (static).

The images (:class:`SpectrogramImages`): ``10 log10(S / threshold)`` in dB over the band, as float16.
A live viewer gets a scrolling image of the last ``scroll_frames`` columns after every frame; a file
gets ONE image per channel for the whole record (blocks of ``file_block_frames`` columns on longer
streams), padded by :func:`pad_columns` blank columns on each side so that it covers the record's span
(:meth:`SpectrogramImages.covered_span`).

Per-frame peak frequency of the ``peak_hz`` series (:func:`peak_bins`, :class:`FramePeaks`, compiled
when numba is on): the same rule as the batch report's ``peak_hz`` (:mod:`chatterspec.detection.detect`),
applied to every frame of a batch in one pass.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np
import numpy.typing as npt

from .._jit import enabled, njit
from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor
from ..palette import FAULT

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

    from ..online.monitor import FrameBlock
    from .events import IntervalCollector

__all__ = [
    "DB_RANGE",
    "KEY_FRACTION",
    "KEY_PX",
    "FramePeaks",
    "SpectrogramImages",
    "default_band_hz",
    "image_width",
    "key_width",
    "log_axes",
    "log_image",
    "pad_columns",
    "peak_bins",
    "record_span",
    "spectrogram_view",
    "to_ns",
]


#: Colour range of the spectrogram, dB re the per-frame threshold (0 dB = threshold): healthy
#: frames (about -11 dB on average at alpha = 1e-3, Bonferroni over 499 bins) stay near black,
#: only excess lights up; fixed so that colours mean the same in every recording.
DB_RANGE = (-5.0, 30.0)


def to_ns(seconds: npt.ArrayLike) -> np.ndarray:
    """Seconds -> integer nanoseconds, rounded to the nearest ns: the one time rule of a recording.

    Parameters
    ----------
    seconds : float or array of float
        Times (s).

    Returns
    -------
    int64 array
        ``round(seconds * 1e9)`` (same shape; 0-d for a scalar).
    """
    return np.rint(np.asarray(seconds, dtype=float) * 1e9).astype(np.int64)


def pad_columns(monitor: ChatteringMonitor) -> int:
    """Blank columns added on each side of a file's spectrogram so that it covers the whole record: the
    first frame's window starts about ``(W - H) / 2`` samples before the first column's left edge
    (2 columns for a 1 s window at a 0.2 s hop).

    Parameters
    ----------
    monitor : ChatteringMonitor

    Returns
    -------
    int
        ``round((W - 1 - H) / (2 H))`` (>= 0) for window ``W`` and hop ``H`` in samples.
    """
    return max(0, round((monitor.n_window - 1 - monitor.n_hop) / (2.0 * monitor.n_hop)))


def record_span(monitor: ChatteringMonitor, total: int, *, raw: bool) -> tuple[float, float] | None:
    """The time span (s) of a file recording: the columns of its spectrogram, padded by
    :func:`pad_columns` on each side, which covers the whole record; every time view shows exactly it.

    Parameters
    ----------
    monitor : ChatteringMonitor
        A fresh monitor (no sample pushed yet).
    total : int
        Samples that will be pushed.
    raw : bool
        Raw measurements (``z(0)`` initializes the filters) rather than chattering.

    Returns
    -------
    (start_s, stop_s) or None
        None if no frame fits or the monitor is not fresh.
    """
    if monitor.n_samples or monitor.n_frames:
        return None  # not a fresh monitor: the record's extent is not known
    n_chat = total - 1 if raw else total
    if n_chat < monitor.n_window:
        return None
    last = (n_chat - monitor.n_window) // monitor.n_hop
    t_chat0 = monitor.t0 + (monitor.dt if raw else 0.0)
    hop = monitor.n_hop * monitor.dt
    edge = hop / 2.0 + pad_columns(monitor) * hop
    centre = (monitor.n_window - 1) / 2.0
    first_c = t_chat0 + centre * monitor.dt
    last_c = t_chat0 + (last * monitor.n_hop + centre) * monitor.dt
    return (first_c - edge, last_c + edge)


def _nice_ceil(x: float) -> float:
    """Smallest multiple of half a decade's unit >= x (125 -> 150, 15 -> 15, 12.5 -> 15)."""
    step = 10.0 ** np.floor(np.log10(x)) / 2.0
    return float(np.ceil(x / step - 1e-9) * step)


def default_band_hz(monitor: ChatteringMonitor, factor: float = 3.0) -> tuple[float, float]:
    """Default spectrogram band: the bins the detector tests, capped where the model has no content.

    The cap is ``factor`` times the model's highest natural frequency ``|ln(lambda)| / (2 pi dt)``
    over the eigenvalues ``lambda`` of ``A`` (Hz), rounded up to a multiple of half a decade's unit
    (EHA: 3 x 41.8 Hz -> 150 Hz; second-order 5 Hz plant -> 15 Hz). Without an oscillatory or
    decaying mode (all eigenvalues 1) the band is the whole tested band.

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the model, the STFT frequencies and the tested bins of the threshold.
    factor : float
        Multiple of the highest natural frequency kept (> 0).

    Returns
    -------
    (lo_hz, hi_hz) : tuple of float
        Lowest and highest tested bin frequency inside the band (Hz).
    """
    if not factor > 0:
        raise ParameterError(f"factor must be > 0; got {factor!r}")
    f = monitor.threshold.freqs_hz[monitor.threshold.tested]
    if f.size == 0:
        f = monitor.freqs_hz
    lo, hi = float(f.min()), float(f.max())
    A = getattr(monitor.model, "A", None)
    if A is None:  # nonlinear model: the natural frequency of its linearization at rest (Hz)
        fn = float(getattr(monitor.model, "natural_frequency_hz", None) or 0.0)
    else:
        with np.errstate(divide="ignore"):
            s = np.log(np.linalg.eigvals(np.asarray(A, dtype=float)).astype(complex))
        fn = float(np.max(np.abs(s[np.isfinite(s)]), initial=0.0)) / (2 * np.pi * monitor.dt)
    if fn > 0:
        cap = _nice_ceil(factor * fn)
        inside = f[f <= cap]
        hi = float(inside.max()) if inside.size else hi
    return lo, hi


# ----------------------------------------------------------------------------- the spectrogram view

#: Width of the colour key (and its labels) in world units, as a fraction of the image width, when no
#: ``key`` width is given (the layout of a single view, e.g. a notebook).
KEY_FRACTION = 0.07
_KEY = KEY_FRACTION
#: Width (logical px at 1600x1000) of the colour key: the left margin of a time view whose y tick labels
#: have two or three characters (measured in the Rerun 0.41 viewer), so that the image starts where their
#: plot areas start.
KEY_PX = 30.0


def key_width(width: float, view_px: float) -> float:
    """World width of the colour key: :data:`KEY_PX` of a view ``view_px`` wide whose image is ``width``.

    Parameters
    ----------
    width : float
        World width of the image (its height is 1), filling the view right of the key.
    view_px : float
        Width of the spectrogram view (logical px at 1600x1000).

    Returns
    -------
    float
        ``width * KEY_PX / (view_px - KEY_PX)``.
    """
    return float(width) * KEY_PX / max(float(view_px) - KEY_PX, 1.0)


def image_width(n_channels: int) -> float:
    """World width of the spectrogram image (its height is 1): the aspect ratio of one channel's
    spectrogram view in the default layout at 1600x1000 (~690 x 160 px for two channels).

    Parameters
    ----------
    n_channels : int
        Channel columns of the layout.

    Returns
    -------
    float
    """
    return 8.6 / max(int(n_channels), 1)


def _nice_ticks(lo: float, hi: float, n: int = 4) -> list[float]:
    """About ``n`` round frequencies (Hz) inside ``[lo, hi]``."""
    span = max(hi - lo, 1e-9)
    raw = span / n
    step = 10.0 ** np.floor(np.log10(raw))
    step *= min((m for m in (1, 2, 5, 10) if m * step >= raw), default=10)
    first = np.ceil(lo / step) * step
    return [float(f) for f in np.arange(first, hi + 1e-9, step)]


def _y(f: float, band_hz: tuple[float, float], df: float) -> float:
    """World y of frequency ``f`` (the centre of its row; 1 = top edge = highest bin's upper edge)."""
    lo, hi = band_hz
    return 1.0 - (f - lo + df / 2.0) / (hi - lo + df)


def log_axes(
    stream: RecordingStream,
    path: str,
    band_hz: tuple[float, float],
    df: float,
    db_range: tuple[float, float],
    width: float,
    key: float | None = None,
) -> None:
    """Log the static frequency labels and the dB colour key of the spectrogram at ``path``.

    Parameters
    ----------
    stream : rerun.RecordingStream
    path : str
        ``/spectrogram/<channel>``.
    band_hz : (float, float)
        Lowest and highest bin shown (Hz).
    df : float
        Bin spacing (Hz).
    db_range : (float, float)
        Colour range (dB).
    width : float
        World width of the image (:func:`image_width`).
    key : float, optional
        World width of the colour key (:func:`key_width`); default :data:`KEY_FRACTION` of ``width``.
    """
    import rerun as rr

    ticks = _nice_ticks(*band_hz)
    x = 0.012 * width
    stream.log(
        f"{path}/freq_ticks",
        rr.Points2D(
            [[x, _y(f, band_hz, df)] for f in ticks],
            labels=[f"{f:g} Hz" for f in ticks],
            radii=0.006,
            colors=[[220, 220, 220]],
            show_labels=True,
        ),
        static=True,
    )
    n = 64
    kw = _KEY * width if key is None else float(key)
    key_image = np.linspace(db_range[1], db_range[0], n, dtype=np.float32)[:, None].repeat(2, axis=1)
    stream.log(
        f"{path}/key",
        rr.Transform3D(translation=[-kw, 0.0, 0.0], scale=[0.3 * kw / 2, 1.0 / n, 1.0]),
        static=True,
    )
    stream.log(
        f"{path}/key",
        rr.DepthImage(key_image, meter=1.0, colormap="magma", depth_range=list(db_range)),
        static=True,
    )
    mid = round(0.5 * (db_range[0] + db_range[1]))
    # short labels (dB in the view's title): centred in the key, they stay inside the view and clear of
    # the frequency labels right of the key
    stream.log(
        f"{path}/key_ticks",
        rr.Points2D(
            [[-0.55 * kw, y] for y in (0.06, 0.5, 0.94)],
            labels=[f"{db_range[1]:g}", f"{mid:g}", f"{db_range[0]:g}"],
            radii=0.001,
            colors=[[220, 220, 220]],
            show_labels=True,
        ),
        static=True,
    )


def log_image(
    stream: RecordingStream, path: str, ns: int, img: np.ndarray, width: float, db_range: tuple[float, float]
) -> None:
    """Log one spectrogram image at time ``ns`` (integer nanoseconds).

    Parameters
    ----------
    stream : rerun.RecordingStream
    path : str
        ``/spectrogram/<channel>``; the image goes to ``<path>/image``.
    ns : int
        Time of the image (integer nanoseconds on the ``time`` timeline): a file's block start, or a
        live frame's centre.
    img : (bins, columns) float16 or float32 array
        dB values, row 0 = lowest frequency, one column per frame (oldest left).
    width : float
        World width of the image (:func:`image_width`).
    db_range : (float, float)
        Colour range (dB).
    """
    import rerun as rr

    from .sinks import TIMELINE

    stream.set_time(TIMELINE, duration=np.timedelta64(int(ns), "ns"))
    nb, nc = img.shape
    stream.log(
        f"{path}/image",
        rr.Transform3D(scale=[width / nc, 1.0 / nb, 1.0]),
        rr.DepthImage(
            np.ascontiguousarray(img[::-1]), meter=1.0, colormap="magma", depth_range=list(db_range)
        ),
    )


def spectrogram_view(path: str, name: str, width: float, key: float | None = None) -> Any:
    """The 2-D view of the spectrogram at ``path``: the image, its frequency labels and the colour key.

    Parameters
    ----------
    path : str
        ``/spectrogram/<channel>``.
    name : str
        View title.
    width : float
        World width of the image (:func:`image_width`).
    key : float, optional
        World width of the colour key left of it (:func:`key_width`); default :data:`KEY_FRACTION` of
        ``width``.

    Returns
    -------
    rerun.blueprint.Spatial2DView
    """
    import rerun.blueprint as rrb

    kw = _KEY * width if key is None else float(key)

    return rrb.Spatial2DView(
        origin=path,
        name=name,
        background=[0, 0, 0],
        visual_bounds=rrb.VisualBounds2D(x_range=(-kw, width), y_range=(0.0, 1.0)),
    )


# ------------------------------------------------------------------------- per-frame peak frequency


@njit
def _peak_bins_kernel(
    power: np.ndarray,
    tested: np.ndarray,
    expected: np.ndarray,
    thr: np.ndarray,
    out: np.ndarray,
    ratio: np.ndarray | None = None,
) -> None:  # pragma: no cover - compiled; its py_func is tested
    """:func:`peak_bins` in one pass over the tested bins of each frame and channel (first maximum
    wins, as ``np.argmax``; only subtractions and comparisons: the same bits as the numpy path), and
    the peak bin's ``S / threshold`` into ``ratio`` when given (one division, as the numpy path)."""
    n_frames, m, n_tested = power.shape[0], power.shape[2], tested.shape[0]
    for f in range(n_frames):
        for c in range(m):
            best, v_best, over, v_over = 0, -np.inf, -1, -np.inf
            for j in range(n_tested):
                p = power[f, tested[j], c]
                ex = p - expected[j, c]
                if ex > v_best:
                    best, v_best = j, ex
                if p > thr[j, c] and (over < 0 or ex > v_over):
                    over, v_over = j, ex
            k = over if over >= 0 else best
            out[f, c] = k
            if ratio is not None:
                ratio[f, c] = power[f, tested[k], c] / thr[k, c]


def _peak_bins_numpy(
    power: np.ndarray, tested: np.ndarray, expected: np.ndarray, thr: np.ndarray
) -> np.ndarray:
    """Numpy path of :func:`peak_bins` (channel-major, so every reduction runs over contiguous bins)."""
    p = np.ascontiguousarray(np.moveaxis(power[:, tested, :], 2, 0))  # (m, F, k)
    over = p > thr.T[:, None, :]
    excess = p - expected.T[:, None, :]
    k = excess.argmax(axis=2)
    rows = np.flatnonzero(over.any(axis=2))  # the (channel, frame) pairs with a bin over the threshold
    if rows.size:
        n = p.shape[2]
        masked = np.where(over.reshape(-1, n)[rows], excess.reshape(-1, n)[rows], -np.inf)
        k.reshape(-1)[rows] = masked.argmax(axis=1)
    return k.T


def peak_bins(
    power: np.ndarray,
    tested: np.ndarray,
    expected: np.ndarray,
    thr: np.ndarray,
    out: np.ndarray | None = None,
    ratio: np.ndarray | None = None,
) -> np.ndarray:
    """Index (into ``tested``) of each frame's largest excess power ``S - E`` among the bins over the
    threshold, or among all tested bins when none is over: the rule of the batch report's ``peak_hz``.

    Parameters
    ----------
    power : (F, bins, m) float array
        Frame spectra ``S`` (the monitor's frame power).
    tested : (k,) int array
        The tested bins (indices into ``bins``).
    expected : (k, m) float array
        Expected healthy spectrum ``E`` at the tested bins.
    thr : (k, m) float array
        Frame threshold at the tested bins (a bin is over when ``S > thr``).
    out : (F, m) int64 array, optional
        Written in place and returned (the logger fills one batch array block by block).
    ratio : (F, m) float array, optional
        Filled in place with ``S / threshold`` at each peak bin.

    Returns
    -------
    (F, m) int64 array
        Position in ``tested`` of the peak bin of each frame and channel.
    """
    power = np.asarray(power, dtype=float)
    if not enabled():
        k = _peak_bins_numpy(power, tested, expected, thr)
        if ratio is not None:
            cols = np.arange(k.shape[1])
            ratio[...] = power[np.arange(k.shape[0])[:, None], tested[k], cols] / thr[k, cols]
        if out is None:
            return k
        out[...] = k
        return out
    if out is None:
        out = np.empty((power.shape[0], power.shape[2]), dtype=np.int64)
    if ratio is None:
        _peak_bins_kernel(power, tested, expected, thr, out)
    else:
        _peak_bins_kernel(power, tested, expected, thr, out, ratio)
    return out


class FramePeaks:
    """Peak frequency (Hz) of every frame of a batch among a monitor's tested bins (:func:`peak_bins`).

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the frequencies (Hz), the tested bins and the frame threshold.
    expected : (bins, m) float array
        Expected healthy frame spectrum ``E``.
    """

    def __init__(self, monitor: ChatteringMonitor, expected: np.ndarray) -> None:
        thr = monitor.threshold
        tested = np.flatnonzero(thr.tested)  # the bins tested by the detector
        self._tested_idx = tested.astype(np.int64)
        self._tested_hz = monitor.freqs_hz[tested]
        self._tested_expected = np.ascontiguousarray(expected[tested])  # (k, m)
        self._tested_thr = np.ascontiguousarray(thr.values[tested])  # (k, m)

    def __call__(self, frames: list[Any]) -> tuple[np.ndarray, np.ndarray]:
        """(F, m) tested bin (Hz) with the largest excess power ``S - E`` among the bins over the threshold
        when a frame has any (as the batch report's ``peak_hz``: a frame's overall largest excess sits on
        noise once a fault fades), else among all tested bins (:func:`peak_bins`); and (F, m) its
        ``S / threshold``, for the frame blocks ``frames`` (each with ``power`` (n, bins, m)) in order."""
        m = self._tested_thr.shape[1]
        F = sum(f.n_frames for f in frames)
        k = np.empty((F, m), dtype=np.int64)
        ratio = np.empty((F, m))
        a = 0
        for f in frames:
            b = a + f.n_frames
            idx, ex, thr = self._tested_idx, self._tested_expected, self._tested_thr
            peak_bins(f.power, idx, ex, thr, out=k[a:b], ratio=ratio[a:b])
            a = b
        return self._tested_hz[k], ratio


# --------------------------------------------------------------------------- the spectrogram images


class SpectrogramImages:
    """The live and file spectrogram images of one monitor's channels.

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the frequencies, the frame threshold and the hop.
    keys : list of str
        Entity names of the channels (``/spectrogram/<key>``).
    width : float
        World width of the image (:func:`~chatterspec.viewer.blueprint.layout_geometry`).
    band_hz : (float, float), optional
        Band (Hz); default :func:`~chatterspec.viewer.spectrograms.default_band_hz`.
    scroll_frames, file_block_frames : int
        Columns of the live image; most columns of one file block (>= 1).
    """

    def __init__(
        self,
        monitor: ChatteringMonitor,
        keys: list[str],
        width: float,
        *,
        band_hz: tuple[float, float] | None = None,
        scroll_frames: int = 50,
        file_block_frames: int = 18_000,
    ) -> None:
        self.keys, self.width = keys, float(width)
        self.scroll_frames = int(scroll_frames)
        self.file_block_frames = int(file_block_frames)
        if self.scroll_frames < 1 or self.file_block_frames < 1:
            raise ParameterError("scroll_frames and file_block_frames must be >= 1")
        freqs, thr = monitor.freqs_hz, monitor.threshold
        lo, hi = default_band_hz(monitor) if band_hz is None else (float(band_hz[0]), float(band_hz[1]))
        inside = np.flatnonzero((freqs >= lo - 1e-9) & (freqs <= hi + 1e-9))
        if inside.size == 0:
            raise ParameterError(
                f"band_hz {band_hz} holds no STFT bin "
                f"({freqs[0]:g} .. {freqs[-1]:g} Hz, step {freqs[1]:g} Hz)"
            )
        self.band = slice(int(inside[0]), int(inside[-1]) + 1)
        self.band_hz = (float(freqs[self.band][0]), float(freqs[self.band][-1]))
        self._band_thr_db = (10.0 * np.log10(np.maximum(thr.values[self.band], 1e-300))).astype(np.float32)
        self.hop_s = monitor.n_hop * monitor.dt
        # live: ring of the last scroll_frames dB columns (slot j % S holds frame j)
        nb, m = self.band.stop - self.band.start, len(keys)
        self._ring = np.zeros((self.scroll_frames, nb, m), dtype=np.float16)
        self._ring_n = 0
        # file: the dB columns of the current block, frame times (s) of its first / last column
        self._file_cols: list[np.ndarray] = []
        self._pad = pad_columns(monitor)  # blank columns before the first and after the last frame
        self.n_blocks = 0  # blocks logged to the file
        self._file_n = 0
        self._file_block_start: int | None = None
        self._file_t: tuple[float, float] = (0.0, 0.0)  # (set when the file's first block opens)
        self._cols_span: tuple[float, float] | None = None  # centres (s) of the file's first / last column
        self._file_max_db = np.full(m, -np.inf)  # the file's brightest pixel per channel (dB)

    def covered_span(self) -> tuple[float, float] | None:
        """The time span (s) the file's spectrogram covers so far: from the left edge of its first column
        (padding included) to the right edge of its last; after :meth:`close`, the whole record, equal
        to :func:`record_span` of the record. None before the first frame."""
        if self._cols_span is None:
            return None
        half = self.hop_s / 2.0
        return (self._cols_span[0] - half, self._cols_span[1] + half)

    def close_file(self, file: RecordingStream) -> None:
        """Log the file's last block to ``file``, padded by :func:`pad_columns` blank columns after the
        record's last frame (the last block ends with the record)."""
        if self._pad and self._file_n:
            last = self._file_cols[-1]
            self._file_cols.append(
                np.full((last.shape[0], self._pad, last.shape[2]), DB_RANGE[0], last.dtype)
            )
            self._file_t = (self._file_t[0], self._file_t[1] + self._pad * self.hop_s)
            self._cols_span = (cast(tuple[float, float], self._cols_span)[0], self._file_t[1])
        self._flush(file)

    def db(self, power: np.ndarray) -> np.ndarray:
        """(F, bins, m) power -> (F, band, m) float16 ``10 log10(S / threshold)`` clipped to DB_RANGE."""
        with np.errstate(divide="ignore", invalid="ignore"):  # 0 -> -inf -> clipped
            db = np.log10(power[:, self.band, :].astype(np.float32))
        db *= 10.0
        db -= self._band_thr_db
        np.clip(db, DB_RANGE[0], DB_RANGE[1], out=db)
        return db.astype(np.float16)

    def live(self, live: RecordingStream, fr: FrameBlock) -> None:
        """Log the live viewer's scrolling spectrogram to ``live`` after every frame of ``fr``."""
        db = self.db(fr.power)
        S = self.scroll_frames
        for f in range(db.shape[0]):
            self._ring[self._ring_n % S] = db[f]
            self._ring_n += 1
            # always S columns, oldest first (blank before the S-th frame): a fixed scale in the view
            img = self._ring[(self._ring_n + np.arange(S)) % S]
            if self._ring_n < S:
                img = img.copy()
                img[: S - self._ring_n] = DB_RANGE[0]
            ns = int(to_ns(float(fr.times_s[f])))
            for i, c in enumerate(self.keys):
                log_image(live, f"/spectrogram/{c}", ns, img[:, :, i].T, self.width, DB_RANGE)

    def add_file(
        self,
        file: Any,
        times: np.ndarray,
        spectra: np.ndarray,
        origin_ns: int | None,  # file: a RecordingStream
    ) -> None:
        """Append a file batch's frames (``times`` (F,) s, channel-major ``spectra`` (m, F, bins)) to
        the file's spectrogram blocks as float16 dB columns (:meth:`db`'s values, per batch); a full
        block is logged to ``file`` once more frames come. ``origin_ns``: the record's start, where the
        first block is logged."""
        with np.errstate(divide="ignore", invalid="ignore"):  # 0 -> -inf -> clipped
            db = np.log10(spectra[:, :, self.band], dtype=np.float32)  # (m, F, band), one pass
        db *= 10.0
        db -= self._band_thr_db.T[:, None, :]
        np.clip(db, DB_RANGE[0], DB_RANGE[1], out=db)
        np.maximum(self._file_max_db, db.max(axis=(1, 2)), out=self._file_max_db)
        db = db.astype(np.float16)
        lo = 0
        while lo < db.shape[1]:
            if self._file_n >= self.file_block_frames:  # full: sent once more frames come (the last
                self._flush(file)  # block waits for close, which pads it)
            take = min(db.shape[1] - lo, self.file_block_frames - self._file_n)
            if self._file_n == 0:
                self._file_t = (float(times[lo]), float(times[lo]))
                if self._file_block_start is None:  # the first block starts with the record, padded
                    self._file_block_start = origin_ns
                    if self._pad:
                        self._file_cols.append(
                            np.full((db.shape[0], self._pad, db.shape[2]), DB_RANGE[0], db.dtype)
                        )
                        self._file_t = (self._file_t[0] - self._pad * self.hop_s, self._file_t[1])
                else:
                    self._file_block_start = int(to_ns(times[lo] - self.hop_s / 2))
            self._file_cols.append(db[:, lo : lo + take])
            self._file_n += take
            self._file_t = (self._file_t[0], float(times[lo + take - 1]))
            if self._cols_span is None:
                self._cols_span = self._file_t
            self._cols_span = (self._cols_span[0], self._file_t[1])
            lo += take

    def _flush(self, file: RecordingStream) -> None:
        if not self._file_n:
            return
        # (m, frames, band)
        block = np.concatenate(self._file_cols, axis=1) if len(self._file_cols) > 1 else self._file_cols[0]
        self._file_cols, self._file_n = [], 0
        ta = self._file_t[0]
        self.n_blocks += 1
        ns = self._file_block_start if self._file_block_start is not None else int(to_ns(ta))
        for i, c in enumerate(self.keys):  # (band, frames): freq rows, time columns
            log_image(file, f"/spectrogram/{c}", ns, block[i].T, self.width, DB_RANGE)

    def annotate_file(self, file: RecordingStream, collector: IntervalCollector) -> None:
        """Annotate a file's spectrogram (a record that fits one block) so that nothing is dark without a
        word: flagged frames whose peak frequency lies outside the band, or in its lowest or highest 4 %
        (a thin line at the image's edge), get a labelled mark at the top or bottom edge (one per run of
        such frames); a channel with no flagged frame and no bin of the band at its threshold gets a
        sentence saying so (its image is dark); and the image gets
        time labels along its bottom (s, the time views' times)."""
        import rerun as rr

        times, flags, hz = collector.frames()
        span = self.covered_span()
        if not times.size or self.n_blocks > 1 or span is None:
            return
        lo, hi = self.band_hz
        edge = 0.04 * (hi - lo)
        cols = times.size + 2 * self._pad
        ticks = [t for t in _nice_ticks(*span) if 0.1 < (t - span[0]) / (span[1] - span[0]) < 0.97]
        for i, c in enumerate(self.keys):
            x_t = [(t - span[0]) / (span[1] - span[0]) * self.width for t in ticks]
            file.log(
                f"/spectrogram/{c}/time_ticks",
                rr.Points2D(
                    [[x, 0.85] for x in x_t], labels=[f"{t:g} s" for t in ticks], radii=0.004,
                    colors=[[220, 220, 220]], show_labels=True,
                ),
                static=True,
            )  # fmt: skip
            if self._file_max_db[i] < 0.0 and not flags[:, i].any():  # nothing flagged: why it is dark
                file.log(
                    f"/spectrogram/{c}/note",
                    rr.Points2D(
                        [[0.5 * self.width, 0.45]],
                        labels=["no bin over its threshold in this record (dark: below it)"],
                        radii=0.001, colors=[[160, 160, 160]], show_labels=True,
                    ),
                    static=True,
                )  # fmt: skip
            out = flags[:, i] & ((hz[:, i] > hi - edge) | (hz[:, i] < lo + edge))
            if not out.any():
                continue
            pts, labels = [], []
            padded = np.concatenate(([False], out, [False]))
            edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
            last_x = {True: -np.inf, False: -np.inf}  # per edge, the last labelled mark
            for a, b in zip(edges[::2], edges[1::2], strict=True):
                f = float(np.median(hz[a:b, i]))
                x = (self._pad + (a + b) / 2.0) * self.width / cols
                top = f > 0.5 * (lo + hi)
                pts.append([x, 0.07 if top else 0.72])  # y grows downwards: 0 = the band's top
                where = "outside the band" if (f > hi or f < lo) else "band edge"
                # a label only where it does not run into the one before it on the same edge (~a third
                # of the image): the other runs get the mark alone
                far = x - last_x[top] > 0.35 * self.width
                labels.append(f"{'^' if top else 'v'} {f:.1f} Hz ({where})" if far else "")
                if far:
                    last_x[top] = x
            file.log(
                f"/spectrogram/{c}/outside",
                rr.Points2D(pts, labels=labels, colors=[list(FAULT)], radii=0.02, show_labels=True),
                static=True,
            )
