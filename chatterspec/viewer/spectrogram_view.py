"""The spectrogram as a 2-D image with a frequency scale and a dB colour key.

Rerun draws tensors without axis ticks (its tensor view names the dimensions only), so
a recording's spectrogram is a ``DepthImage`` of ``10 log10(S / threshold)`` (dB, colour
map ``magma`` over :data:`~chatterspec.viewer.record_geometry.DB_RANGE`) in a 2-D view, beside
labelled points that carry the scale:

- frequency labels ("50 Hz", ...) at the image's left edge, at their rows;
- a colour key (a small gradient image) left of the spectrogram with its dB values, :data:`KEY_PX`
  wide, so that the image starts where the time series' plot areas start (after their y tick labels).

Lining up with the time axes. The image spans the same time as the time views (a file's record span,
:func:`~chatterspec.viewer.record_geometry.record_span`: one column per frame, padded), and its right edge is
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
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

__all__ = ["KEY_FRACTION", "KEY_PX", "image_width", "key_width", "log_axes", "log_image", "spectrogram_view"]

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
