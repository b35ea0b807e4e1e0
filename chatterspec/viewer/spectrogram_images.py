"""The spectrogram images of a recording: ``10 log10(S / threshold)`` in dB over the band, as float16.

A live viewer gets a scrolling image of the last ``scroll_frames`` columns after every frame; a file
gets ONE image per channel for the whole record (blocks of ``file_block_frames`` columns on longer
streams), padded by :func:`~chatterspec.viewer.record_geometry.pad_columns` blank columns on each side
so that it covers the record's span (:meth:`SpectrogramImages.covered_span`). Drawn by
:mod:`chatterspec.viewer.spectrogram_view`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ..errors import ParameterError
from ..online.monitor import ChatteringMonitor
from ..palette import FAULT
from .record_geometry import DB_RANGE, default_band_hz, pad_columns, to_ns
from .spectrogram_view import _nice_ticks, log_image

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream

    from ..online.monitor import FrameBlock
    from .interval_events import IntervalCollector

__all__ = ["SpectrogramImages"]


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
        Band (Hz); default :func:`~chatterspec.viewer.record_geometry.default_band_hz`.
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
