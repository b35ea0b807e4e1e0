"""Online chattering monitor: chunks in, STFT columns, per-frame verdicts and detection events out.

Pure numpy/scipy (no Rerun; :mod:`chatterspec.online` does the logging).

The monitor advances the auxiliary ``sgn`` SVSF (whose a-priori output error is
the chattering, eq 17) and, when a boundary layer ``psi`` is given, the
smoothing ``sat`` SVSF (state estimate) with the kernels of
:meth:`chatterspec.filters.svsf.SVSF.update`, which the batch path
(:func:`chatterspec.detection.pipeline.chattering_record`) runs too (with numba, both
filters of a push in one compiled call, :mod:`chatterspec.online._push_kernels`: the
same kernels and sums, the same bits). Measurements may arrive
in chunks of any size (one sample to millions); the chattering goes into a
bounded buffer holding at most one STFT window (``W`` samples) plus the chunk
being analysed, and every complete frame is turned into one column by
:func:`chatterspec.detection.spectral.frame_columns` on the global frame grid, so the
columns and verdicts equal those of :func:`chatterspec.detection.spectral.spectrogram` on
the whole record whatever the chunking.

Sample alignment matches :class:`chatterspec.detection.pipeline.ChatteringRecord`: the
first measurement ``z(0)`` initializes the filters; chattering sample ``j`` is
``e(j+1|j)`` at time ``t0 + (j + 1) dt``; frame ``j`` covers chattering samples
``[j H, j H + W)`` and is time-stamped at its centre.

Alarms: every frame gets a score per channel, ``-log p`` of its Bonferroni p-value
(:class:`chatterspec.detection.verdicts.FrameScore`, the per-frame threshold's law), and an
alarm rule of :mod:`chatterspec.detection.alarms.streams` (``MonitorSettings.rule``: frame, k-of-n
persistence or CUSUM, its threshold set for a budget in false alarms per hour by
:mod:`chatterspec.studies.alarm_budget`) turns the scores into an alarm state per channel, in
an :class:`~chatterspec.detection.alarms.streams.AlarmStream` that continues across pushes (any chunking
gives the same alarms). A ``fault-start`` is raised at the centre time of the frame where a
channel's alarm starts, a ``fault-end`` at the centre of the frame where it ends; both carry the
rule, the frame's score, the rule's statistic and threshold and the budget. Without a rule
(``MonitorSettings.rule = None``, the API default) the events are those of the per-frame verdict
at ``alpha``, as before the alarm layer: a start at the first flagged frame after an unflagged
one, an end at the first unflagged frame, every frame a test at level ``alpha`` (at 0.001 and
3 channels about 42 false alarms per hour of healthy data).

The work is split between two collaborators: :class:`~chatterspec.online.monitor_filters.MonitorFilters`
(both SVSFs, measurements to chattering and estimate, the fused compiled push) and
:class:`~chatterspec.online.monitor_frames.FrameAnalysis` (the bounded buffer, STFT columns,
verdicts, scores, alarm stream and events); the monitor checks the input, keeps the clock and
assembles each push's :class:`~chatterspec.online.monitor_types.MonitorUpdate`.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator

import numpy as np

from .. import _jit
from .._validate import finite_array, positive_int
from ..detection.spectral import spectrum_model
from ..detection.thresholds import frame_threshold
from ..errors import NonFiniteError, ParameterError, ShapeError
from ..filters.protocol import channel_rows, sample_rows
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel, require_linear
from .monitor_filters import MonitorFilters
from .monitor_frames import FrameAnalysis
from .monitor_types import DetectionEvent, FrameBlock, MonitorSettings, MonitorUpdate

__all__ = [
    "ChatteringMonitor",
    "DetectionEvent",
    "FrameBlock",
    "MonitorSettings",
    "MonitorUpdate",
]


class ChatteringMonitor:
    """Streaming SVSF chattering detector with bounded memory.

    Parameters
    ----------
    model : LinearModel
        Nominal model (full measurement: the frame threshold needs it).
    settings : MonitorSettings, optional
    t0 : float
        Time (s) of the first measurement pushed with :meth:`push`, or of the
        first chattering sample pushed with :meth:`push_chattering`.

    Examples
    --------
    >>> import chatterspec as cs
    >>> from chatterspec.online.monitor import ChatteringMonitor
    >>> sim = cs.simulate(cs.scenario("eha-leak-major"), runs=1, seed=1)
    >>> mon = ChatteringMonitor(sim.scenario.nominal)
    >>> for k in range(0, sim.z.shape[1], 250):
    ...     upd = mon.push(sim.z[0, k : k + 250], sim.u[k : k + 250])
    >>> mon.n_frames
    16
    """

    def __init__(
        self, model: LinearModel | NonlinearModel, settings: MonitorSettings | None = None, *, t0: float = 0.0
    ) -> None:
        nonlinear = isinstance(model, NonlinearModel)
        if nonlinear and (settings is None or settings.threshold is None or settings.psi is not None):
            # a nonlinear model works with a calibrated per-frame threshold (docs/design.md §6), no sat-SVSF
            require_linear(
                model,
                "the chattering monitor without a calibrated threshold (pass MonitorSettings(threshold="
                "calibrate(...).threshold('frame-family-wise'), psi=None))",
            )
        if not (nonlinear or isinstance(model, LinearModel)):
            raise TypeError(f"model must be a LinearModel; got {type(model).__name__}")
        self.model = model
        self.settings = settings or MonitorSettings()
        s = self.settings
        self.dt = model.dt
        self.t0 = float(t0)
        self.n_window = s.stft.n_window(self.dt)
        self.n_hop = s.stft.n_hop(self.dt)
        self.freqs_hz = s.stft.freqs_hz(self.dt)
        if s.threshold is None:
            self.threshold = frame_threshold(
                spectrum_model(model), self.freqs_hz, s.stft, self.dt, s.alpha, s.correction, band=s.band
            )
        else:
            th = s.threshold
            if th.values.shape != (self.freqs_hz.size, model.n_outputs) or not np.allclose(
                th.freqs_hz, self.freqs_hz
            ):
                raise ShapeError(
                    f"the given per-frame threshold has shape {th.values.shape} at other frequencies than "
                    f"this monitor's frames ({self.freqs_hz.size} bins x {model.n_outputs} channels): it "
                    "was made for another STFT window or model"
                )
            self.threshold = th.restricted(s.band)
        # the two collaborators: the SVSFs (measurements -> chattering, estimate) and the frame
        # analysis (chattering -> STFT columns, verdicts, alarm states, events)
        self._filters = MonitorFilters(model, s)
        self._frames = FrameAnalysis(s, self.threshold, self.dt, model.output_names)
        self.rule = self._frames.rule
        self._mode: str | None = None  # "raw" or "chattering"
        self._n_chat = 0  # chattering samples produced / pushed
        self._t_chat0: float | None = None  # time of chattering sample 0
        self._last: MonitorUpdate | None = None  # the last push (None after a compiled step)

    # ------------------------------------------------------------- properties
    @property
    def channels(self) -> tuple[str, ...]:
        """Output channel names of the monitored model."""
        return self.model.output_names

    @property
    def n_frames(self) -> int:
        """Frames emitted so far."""
        return self._frames.n_frames

    @property
    def n_samples(self) -> int:
        """Chattering samples processed so far."""
        return self._n_chat

    @property
    def n_events(self) -> int:
        """Detection events raised so far."""
        return self._frames.n_events

    @property
    def active(self) -> np.ndarray:
        """Per channel, whether an alarm (fault) is currently active (copy)."""
        return self._frames.active

    @property
    def buffered_samples(self) -> int:
        """Chattering samples held between pushes (always < one window)."""
        return self._frames.n_buffered

    def frame_time(self, index: np.ndarray | int) -> np.ndarray:
        """Centre time (s) of global frame(s) ``index``."""
        return self._frames.frame_time(index, self._chatter_time0())

    def _chatter_time0(self) -> float:
        if self._t_chat0 is not None:
            return self._t_chat0
        return self.t0 + (self.dt if self._mode != "chattering" else 0.0)

    # ------------------------------------------------------------------ input
    def push(self, z: np.ndarray, u: np.ndarray) -> MonitorUpdate:
        """Feed measurements ``z`` (K, m) and inputs ``u`` (K, p) sampled at the same times.

        ``u(k)`` is the input applied after ``z(k)`` was measured (it drives
        x(k) -> x(k+1)). A 1-D ``z`` is one sample; a 1-D ``u`` is one sample
        when ``p > 1`` or ``K == 1``, otherwise one input channel.

        Raises
        ------
        ShapeError, NonFiniteError
            On wrong shapes or NaN/inf samples (nothing is consumed then).

        See Also
        --------
        chatterspec.online.monitor_filters.MonitorFilters.advance : the filters' step.
        """
        self._set_mode("raw")
        m, p = self.model.n_outputs, self.model.n_inputs
        z = channel_rows("z", z, m, channels=self.channels)
        K = z.shape[0]
        u = finite_array("u", u, ndim=(1, 2))
        if u.ndim == 1:
            u = u[None, :] if (p > 1 or K == 1) and u.shape[0] == p else u[:, None]
        if u.shape != (K, p):
            raise ShapeError(f"u must have shape ({K}, {p}) to match z; got {u.shape}")
        if K == 0:
            return self._empty_update(raw=True)
        z, e, estimate = self._filters.advance(z, u)
        self._last = None
        K = z.shape[0]
        if K == 0:  # the first push's first measurement only initializes the filters
            return self._empty_update(raw=True)
        # float arange of integers (exact below 2^53): the bits of t0 + (n + arange(K)) * dt, one pass fewer
        n = self._filters.n_meas - K
        t = self.t0 + np.arange(n, n + K, dtype=float) * self.dt
        self._n_chat += K
        frames, events = self._frames.push(e)
        self._last = MonitorUpdate(t, e, z, estimate, frames, events)
        return self._last

    def step(self, z: object, u: object) -> tuple[DetectionEvent, ...]:
        """Feed one sample: ``z`` (m,) and the input ``u`` (p,) sampled with it; the events it raises.

        The numbers of :meth:`push` (steps and pushes may be mixed on one monitor): with numba, after
        the first sample, both filters and the chattering's place in the frame buffer are one compiled
        call (:func:`chatterspec.online._push_kernels.filters_one_kernel`), and a completed frame is
        analysed as a push's; otherwise a one-sample :meth:`push`. The sample's chattering and
        estimate are then :attr:`last_chattering` and :attr:`last_estimate`.

        Raises
        ------
        ShapeError, NonFiniteError
            On a wrong shape or a NaN/inf entry (nothing is consumed then).
        """
        filters = self._filters
        if self._mode != "raw" or filters._st is None or not (filters.fused and _jit.enabled()):
            upd = self.push(z, u)  # type: ignore[arg-type]
            self._last = upd
            return upd.events
        z = sample_rows("z", z, self.model.n_outputs)
        u = sample_rows("u", u, self.model.n_inputs)
        buf, row = self._frames.slot()
        if filters.step(z, u, buf, row):
            bad = "z" if not np.isfinite(z).all() else "u"
            raise NonFiniteError(f"{bad} contains NaN/inf value(s); all entries must be finite")
        self._last = None
        self._n_chat += 1
        return self._frames.commit_one()[1]

    @property
    def last_chattering(self) -> np.ndarray | None:
        """The chattering ``e(k|k-1)`` (m,) of the last sample fed by :meth:`step` or :meth:`push`."""
        if self._last is not None:
            return self._last.chattering[-1].copy() if len(self._last.chattering) else None
        return self._filters.last_chattering()

    @property
    def last_estimate(self) -> np.ndarray | None:
        """The sat SVSF's output estimate (m,) of the last sample (None without ``psi``)."""
        if self._last is not None:
            est = self._last.estimate
            return None if est is None or not len(est) else est[-1].copy()
        return self._filters.last_estimate()

    def push_chattering(self, e: np.ndarray) -> MonitorUpdate:
        """Feed precomputed chattering samples ``e`` (K, m) (e.g. a :class:`ChatteringRecord`'s values).

        The first sample is at ``t0``; do not mix with :meth:`push` on one monitor.
        """
        self._set_mode("chattering")
        m = self.model.n_outputs
        e = channel_rows("e", e, m, label="chattering")
        if e.shape[0] == 0:
            return self._empty_update(raw=False)
        t = self._chatter_time0() + np.arange(self._n_chat, self._n_chat + e.shape[0], dtype=float) * self.dt
        self._n_chat += e.shape[0]
        frames, events = self._frames.push(e)
        return MonitorUpdate(t, e, None, None, frames, events)

    def stream(
        self, z: np.ndarray, u: np.ndarray, chunk_samples: int | np.ndarray = 1000
    ) -> Iterator[MonitorUpdate]:
        """Push ``z`` (T, m) / ``u`` (T, p) in chunks; ``chunk_samples`` is a size or a sequence of sizes."""
        z = np.asarray(z, dtype=float)
        u = np.asarray(u, dtype=float)
        if u.ndim == 1:
            u = u[:, None]
        T = z.shape[0]
        if np.ndim(chunk_samples) == 0:
            size = positive_int("chunk_samples", int(chunk_samples))
            bounds = [*list(range(0, T, size)), T]
        else:
            bounds = [0, *np.cumsum(np.asarray(chunk_samples, dtype=int)).tolist()]
            bounds = [b for b in bounds if b < T] + [T]
        for lo, hi in itertools.pairwise(bounds):
            yield self.push(z[lo:hi], u[lo:hi])

    # --------------------------------------------------------------- internals
    def _set_mode(self, mode: str) -> None:
        if self._mode is None:
            self._mode = mode
            if mode == "chattering":
                self._t_chat0 = self.t0
            else:
                self._t_chat0 = self.t0 + self.dt
            self._frames.t_first = self._t_chat0  # frames are time-stamped from chattering sample 0
        elif self._mode != mode:
            raise ParameterError(
                "this monitor was fed with "
                + ("raw measurements (push)" if self._mode == "raw" else "chattering (push_chattering)")
                + "; use one kind of input per monitor"
            )

    def _empty_frames(self) -> FrameBlock:
        return self._frames.empty_frames()

    def _empty_update(self, raw: bool) -> MonitorUpdate:
        m = self.model.n_outputs
        return MonitorUpdate(
            t=np.zeros(0),
            chattering=np.zeros((0, m)),
            measured=np.zeros((0, m)) if raw else None,
            estimate=np.zeros((0, m)) if (raw and self._filters.has_estimate) else None,
            frames=self._empty_frames(),
            events=(),
        )
