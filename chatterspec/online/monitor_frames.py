"""The monitor's frame analysis: chattering in, STFT columns, verdicts, alarm states and events out.

:class:`FrameAnalysis` holds the bounded chattering buffer (at most one STFT window of ``W``
samples plus the chunk being analysed), turns every complete frame into one column with
:class:`chatterspec.detection.spectral.FrameEngine` on the global frame grid (frame ``j``
covers chattering samples ``[j H, j H + W)``), gives each frame its verdicts
(:class:`chatterspec.detection.verdicts.FrameVerdicts`) and score ``-log p``
(:class:`chatterspec.detection.verdicts.FrameScore`), runs the alarm rule across pushes
(:class:`chatterspec.detection.alarms.streams.AlarmStream`) and turns the alarm's starts and ends into
:class:`~chatterspec.online.monitor_types.DetectionEvent` s. Any chunking of the chattering gives
the same columns, alarms and events as the whole record at once.

See Also
--------
chatterspec.online.monitor.ChatteringMonitor : the monitor that owns one of these.
chatterspec.online.monitor_filters.MonitorFilters : where the chattering comes from.
"""

from __future__ import annotations

import math

import numpy as np

from .. import _jit
from ..detection.alarms.rules import FrameRule
from ..detection.alarms.streams import AlarmStream
from ..detection.spectral import FrameEngine
from ..detection.thresholds import Threshold
from ..detection.verdicts import FrameScore, FrameVerdicts
from ._push_kernels import hop_kernel
from .fault_state import alarm_time
from .monitor_types import DetectionEvent, EventKind, FrameBlock, MonitorSettings

__all__ = ["FrameAnalysis"]


class FrameAnalysis:
    """Frames, verdicts, alarms and events of a chattering stream, pushed chunk by chunk.

    Parameters
    ----------
    settings : MonitorSettings
        STFT (window ``W``, hop ``H``), alarm ``rule`` (None: the per-frame verdict at ``alpha``)
        and the false-alarm budget the events report.
    threshold : Threshold
        The per-frame threshold (already restricted to the tested band).
    dt : float
        Sample period (s).
    channels : tuple of str
        Output channel names (the events carry them).

    Attributes
    ----------
    rule : AlarmRule
        The alarm rule the events report (the per-frame rule at ``-log alpha`` without one).
    n_frames : int
        Frames emitted so far.
    n_buffered : int
        Chattering samples held between pushes (always < one window).
    n_events : int
        Events raised so far.
    t_first : float
        Time (s) of chattering sample 0 (the monitor sets it at its first push; frames are
        time-stamped at their centre from it).
    """

    def __init__(
        self, settings: MonitorSettings, threshold: Threshold, dt: float, channels: tuple[str, ...]
    ) -> None:
        s = settings
        self.settings = s
        self.dt = dt
        self.channels = channels
        self.n_window = s.stft.n_window(dt)
        self.n_hop = s.stft.n_hop(dt)
        self.n_bins = s.stft.freqs_hz(dt).shape[0]
        m = len(channels)
        # chattering samples from the next frame's start on (< W rows); room for one more hop so
        # that small pushes append in place instead of re-concatenating the window every time
        self._buf = np.empty((self.n_window + self.n_hop, m))
        self.n_buffered = 0
        self._verdicts = FrameVerdicts(threshold, compiled=_jit.enabled())
        # frame_columns with this monitor's scratch buffers (and compiled loops when enabled: same bits)
        self._columns = FrameEngine(s.stft, dt, compiled=_jit.enabled())
        self.no_frames = self.empty_frames()
        self.n_frames = 0
        # the frame score and the alarm rule (None: the per-frame rule at alpha, i.e. events where the
        # verdict flags change, fed to the layer as 0/1 against 0.5: the same events as before it)
        self._score = FrameScore(threshold, compiled=_jit.enabled())
        self._legacy = s.rule is None
        self.rule = FrameRule(-math.log(threshold.alpha)) if s.rule is None else s.rule
        self._alarm = AlarmStream(
            FrameRule(0.5) if self._legacy else self.rule, (m,), compiled=_jit.enabled()
        )
        self._fault_peak = [0.0] * m  # per channel, the active fault's largest peak ratio and its Hz
        self._fault_peak_hz = [0.0] * m
        self.n_events = 0
        self.t_first = 0.0
        # with numba: power, verdicts, score and alarm rule of a block of frames in one compiled call
        # (online._push_kernels.hop_kernel: the same steps as the four calls above, the same bits) when
        # the rule gives its channel step (RuleSteps.channel; a rule without one: the four calls)
        channel = self._alarm._steps.channel
        self._fused = bool(
            _jit.enabled() and self._verdicts.compiled and self._columns.compiled and self._alarm._compiled
            and channel is not None
        )  # fmt: skip
        self._hop = None if channel is None else hop_kernel(channel)

    @property
    def active(self) -> np.ndarray:
        """Per channel, whether an alarm (fault) is currently active (copy)."""
        return self._alarm.active

    def frame_time(self, index: np.ndarray | int, t_first: float) -> np.ndarray:
        """Centre time (s) of global frame(s) ``index`` when chattering sample 0 is at ``t_first`` (s)."""
        return t_first + (np.asarray(index) * self.n_hop + (self.n_window - 1) / 2.0) * self.dt

    def empty_frames(self) -> FrameBlock:
        """A block of no frames (the shapes of this stream's frames)."""
        m = len(self.channels)
        return FrameBlock(
            index=np.zeros(0, dtype=int),
            times_s=np.zeros(0),
            power=np.zeros((0, self.n_bins, m)),
            flags=np.zeros((0, m), dtype=bool),
            peak_hz=np.zeros((0, m)),
            peak_ratio=np.zeros((0, m)),
        )

    def push(self, e: np.ndarray) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """Analyse the next chattering samples ``e`` (K, m); the frames they complete and their events."""
        W = self.n_window
        K, nb = e.shape[0], self.n_buffered
        n = nb + K
        if n < W:  # the next frame (samples buf_start .. buf_start + W) is not complete yet
            self._buf[nb:n] = e
            self.n_buffered = n
            return self.no_frames, ()
        if nb == 0:
            data = e
        elif n <= self._buf.shape[0]:
            self._buf[nb:n] = e
            data = self._buf[:n]
        else:
            data = np.concatenate([self._buf[:nb], e])
        return self._analyse(data)

    def slot(self) -> tuple[np.ndarray, int]:
        """Where the next chattering sample goes: ``(buffer, row)`` (:meth:`commit_one` takes it)."""
        return self._buf, self.n_buffered

    def commit_one(self) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """:meth:`push` of the one sample written at :meth:`slot` (the same frames and events)."""
        n = self.n_buffered + 1
        if n < self.n_window:
            self.n_buffered = n
            return self.no_frames, ()
        return self._analyse(self._buf[:n])

    def _analyse(self, data: np.ndarray) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """The frames that ``data`` (the buffered samples, then the new ones; >= one window) completes."""
        if self._fused:
            return self._analyse_fused(data)
        H = self.n_hop
        buf_start = self.n_frames * H  # global index of data[0]
        idx, power = self._columns(data, buf_start)
        flags, peak_hz, peak_ratio = self._verdicts(power)
        score = self._score._unchecked(power)
        blk = self._alarm._advance(flags.astype(float) if self._legacy else score)
        stat = score if self._legacy else blk.statistic
        self._advance_buffer(data, int(idx[-1]) + 1)
        times = self.frame_time(idx, self.t_first)
        frames = FrameBlock(idx, times, power, flags, peak_hz, peak_ratio, score, blk.active, stat)
        return frames, self._events(frames, blk.starts, blk.ends)

    def _advance_buffer(self, data: np.ndarray, n_frames: int) -> None:
        """``n_frames`` frames done: keep the samples of ``data`` from the next frame's start on (< W)."""
        keep = data[n_frames * self.n_hop - self.n_frames * self.n_hop :]
        self.n_frames = n_frames
        self._buf[: keep.shape[0]] = keep  # numpy copes with the overlap when data is self._buf
        self.n_buffered = keep.shape[0]

    def _analyse_fused(self, data: np.ndarray) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """:meth:`_analyse` with one compiled call per block of frames (``_push_kernels.hop_kernel``)."""
        eng, ver, sc, al = self._columns, self._verdicts, self._score, self._alarm
        j_first, F, offset = eng.grid(data.shape[0], self.n_frames * self.n_hop)
        m = len(self.channels)
        power = np.empty((F, eng.n_bins, m))
        k_ratio = np.empty((F, m), dtype=np.int64)
        out = np.empty((4, F, m))  # peak_ratio, score, statistic, and the rule's input
        flags3 = np.empty((3, 1, F, m), dtype=np.bool_)  # active, starts, ends
        peak_ratio, score, stat, s3 = out[0], out[1], out[2][None], out[3][None]
        al._pos[0] = al._step
        lo = ver.sel.start  # type: ignore[union-attr]
        hop = self._hop
        assert hop is not None  # (fused: the rule gives its channel step)
        for a, b, Y in eng.transforms(data, offset, F):
            hop(
                Y, eng.scale, power[a:b], lo, ver.values, ver._positions, k_ratio[a:b], peak_ratio[a:b],
                *sc._kernel_args, score[a:b], self._legacy, al._h, al._p,
                al._active, al._g, al._count, al._ring, al._pos, s3[:, a:b], flags3[0, :, a:b], stat[:, a:b],
                flags3[1, :, a:b], flags3[2, :, a:b],
            )  # fmt: skip
            al._pos[0] += b - a
        al._step += F
        self._advance_buffer(data, j_first + F)
        idx = np.arange(j_first, j_first + F)
        stat2 = score if self._legacy else stat[0]
        times = self.frame_time(idx, self.t_first)
        frames = FrameBlock(
            idx, times, power, peak_ratio > 1.0, ver.freqs[k_ratio], peak_ratio, score, flags3[0, 0], stat2
        )
        return frames, self._events(frames, flags3[1, 0], flags3[2, 0])

    def _events(self, fr: FrameBlock, starts: np.ndarray, ends: np.ndarray) -> tuple[DetectionEvent, ...]:
        """Events from the alarm layer's starts / ends (F, m); tracks each fault's largest peak.

        A block is a few frames, read as Python lists (the same float values): numpy reductions and
        element indexing on (F, m) arrays cost ~5.8 us per push while a fault is active, the lists ~2.5 us.
        """
        alarm = fr.alarm
        assert alarm is not None  # (a block the alarm layer scored)
        on = alarm[0].tolist()  # active at the first frame and unchanged: active throughout
        changed = (starts | ends).any(axis=0).tolist()  # (m,)
        if not (any(changed) or any(on)):  # no change and nothing active: no event
            return ()
        ratios, hzs = fr.peak_ratio.T.tolist(), fr.peak_hz.T.tolist()  # per channel, per frame
        peak, peak_hz = self._fault_peak, self._fault_peak_hz
        events: list[DetectionEvent] = []
        for c, (ch, is_on) in enumerate(zip(changed, on, strict=True)):
            r_c = ratios[c]
            if not ch:
                if is_on:  # the fault goes on: only its largest peak may change
                    best = max(r_c)
                    if best > peak[c]:  # the first largest, as the loop's strict '>'
                        peak[c], peak_hz[c] = best, hzs[c][r_c.index(best)]
                continue
            s_c, e_c, a_c = starts[:, c].tolist(), ends[:, c].tolist(), alarm[:, c].tolist()
            for f, ratio in enumerate(r_c):
                if s_c[f]:
                    peak[c], peak_hz[c] = ratio, hzs[c][f]
                    events.append(self._event("fault-start", c, fr, f, hzs[c][f], ratio))
                elif e_c[f]:
                    events.append(self._event("fault-end", c, fr, f, peak_hz[c], peak[c]))
                elif a_c[f] and ratio > peak[c]:
                    peak[c], peak_hz[c] = ratio, hzs[c][f]
        events.sort(key=lambda ev: (ev.frame, ev.channel_index))
        self.n_events += len(events)
        return tuple(events)

    def _event(
        self, kind: EventKind, c: int, fr: FrameBlock, f: int, peak_hz: float, peak_ratio: float
    ) -> DetectionEvent:
        t = float(fr.times_s[f])
        j = int(fr.index[f])
        back = (self.n_window - 1) / 2.0 if j == 0 else self.n_hop / 2.0
        rule = self.rule
        score, statistic = fr.score, fr.alarm_statistic
        assert score is not None and statistic is not None  # (a block the alarm layer scored)
        return DetectionEvent(
            kind, self.channels[c], c, t, j, float(peak_hz), float(peak_ratio), t - back * self.dt,
            rule=rule.name, score=float(score[f, c]), statistic=float(statistic[f, c]),
            threshold=float(rule.threshold), false_alarms_per_hour=self.settings.false_alarms_per_hour,
            alarm_time_s=alarm_time(t, self.n_window, self.dt),
        )  # fmt: skip
