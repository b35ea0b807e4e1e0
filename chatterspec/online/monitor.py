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
(:class:`chatterspec.detection.frame_score.FrameScore`, the per-frame threshold's law), and an
alarm rule of :mod:`chatterspec.detection.alarms` (``MonitorSettings.rule``: frame, k-of-n
persistence or CUSUM, its threshold set for a budget in false alarms per hour by
:mod:`chatterspec.studies.alarm_budget`) turns the scores into an alarm state per channel, in
an :class:`~chatterspec.detection.alarms.AlarmStream` that continues across pushes (any chunking
gives the same alarms). A ``fault-start`` is raised at the centre time of the frame where a
channel's alarm starts, a ``fault-end`` at the centre of the frame where it ends; both carry the
rule, the frame's score, the rule's statistic and threshold and the budget. Without a rule
(``MonitorSettings.rule = None``, the API default) the events are those of the per-frame verdict
at ``alpha``, as before the alarm layer: a start at the first flagged frame after an unflagged
one, an end at the first unflagged frame, every frame a test at level ``alpha`` (at 0.001 and
3 channels about 42 false alarms per hour of healthy data).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator

import numpy as np

from .. import _jit
from .._validate import finite_array, positive_int
from ..detection.alarms import AlarmStream, FrameRule
from ..detection.frame_engine import FrameEngine
from ..detection.frame_score import FrameScore
from ..detection.frames import FrameVerdicts, frame_verdicts
from ..detection.thresholds import frame_threshold
from ..errors import ParameterError, ShapeError
from ..filters.nonlinear_svsf import NonlinearSgnSVSF
from ..filters.svsf import SVSF, SVSFState, auxiliary_svsf
from ..filters.svsf_steps import rows_times as _rows_times
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel, require_linear
from ._push_kernels import filters_kernel
from .monitor_types import DetectionEvent, EventKind, FrameBlock, MonitorSettings, MonitorUpdate

__all__ = [
    "ChatteringMonitor",
    "DetectionEvent",
    "FrameBlock",
    "MonitorSettings",
    "MonitorUpdate",
    "frame_verdicts",
]


_Verdicts = FrameVerdicts  # the old private name (tests and old code)


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
        self, model: LinearModel, settings: MonitorSettings | None = None, *, t0: float = 0.0
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
                model, self.freqs_hz, s.stft, self.dt, s.alpha, s.correction, band=s.band
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
        self._aux = NonlinearSgnSVSF(model, s.gamma) if nonlinear else auxiliary_svsf(model, s.gamma)
        self._sat = None if s.psi is None else SVSF(model, psi=np.asarray(s.psi), gamma=s.gamma)
        self._aux_state: SVSFState | None = None
        # one compiled call per push for both filters (full measurement: the closed form of eq 23;
        # at least one input; numba installed, and enabled at push time)
        self._fused = (
            isinstance(self._aux, SVSF)
            and self._aux._L is None
            and model.n_inputs >= 1
            and _jit.HAVE_NUMBA
            and _jit.fits(model.n_states, model.n_outputs, vectors_only=True)
        )
        if self._fused:
            self._GT = np.ascontiguousarray(self._aux._GT, dtype=float)
            self._aux_PhiT = np.ascontiguousarray(self._aux._PhiT, dtype=float)
            self._none3 = np.empty((0, 0, 0))
            e2 = np.empty((0, 0))
            self._no_sat = (e2, e2, e2, np.empty(0), 0.0, e2, e2, e2, self._none3, self._none3, self._none3)
            # the push loop, unrolled for small models (the EHA's 3 states): same steps, same bits
            self._kernel = filters_kernel(model.n_states, model.n_outputs)
        self._sat_state: SVSFState | None = None
        # C = I (every state measured in its own units, the EHA): the estimate C x is x itself
        C = getattr(model, "C", None)
        self._C_identity = C is not None and C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(len(C)))
        self._pending_u: np.ndarray | None = None
        self._mode: str | None = None  # "raw" or "chattering"
        self._n_meas = 0  # measurements pushed (raw mode)
        self._n_chat = 0  # chattering samples produced / pushed
        self._t_chat0: float | None = None  # time of chattering sample 0
        m = model.n_outputs
        # chattering samples from the next frame's start on (< W rows); room for one more hop so
        # that small pushes append in place instead of re-concatenating the window every time
        self._buf = np.empty((self.n_window + self.n_hop, m))
        self._n_buf = 0
        self._verdicts = FrameVerdicts(self.threshold, compiled=_jit.enabled())
        # frame_columns with this monitor's scratch buffers (and compiled loops when enabled: same bits)
        self._columns = FrameEngine(s.stft, self.dt, compiled=_jit.enabled())
        self._no_frames = self._empty_frames()
        self._n_frames = 0
        # the frame score and the alarm rule (None: the per-frame rule at alpha, i.e. events where the
        # verdict flags change, fed to the layer as 0/1 against 0.5: the same events as before it)
        self._score = FrameScore(self.threshold, compiled=_jit.enabled())
        self._legacy = s.rule is None
        self.rule = FrameRule(-math.log(self.threshold.alpha)) if s.rule is None else s.rule
        self._alarm = AlarmStream(
            FrameRule(0.5) if self._legacy else self.rule, (m,), compiled=_jit.enabled()
        )
        self._fault_peak = np.zeros(m)
        self._fault_peak_hz = np.zeros(m)
        self.n_events = 0

    # ------------------------------------------------------------- properties
    @property
    def channels(self) -> tuple[str, ...]:
        """Output channel names of the monitored model."""
        return self.model.output_names

    @property
    def n_frames(self) -> int:
        """Frames emitted so far."""
        return self._n_frames

    @property
    def n_samples(self) -> int:
        """Chattering samples processed so far."""
        return self._n_chat

    @property
    def active(self) -> np.ndarray:
        """Per channel, whether an alarm (fault) is currently active (copy)."""
        return self._alarm.active

    @property
    def buffered_samples(self) -> int:
        """Chattering samples held between pushes (always < one window)."""
        return self._n_buf

    def frame_time(self, index: np.ndarray | int) -> np.ndarray:
        """Centre time (s) of global frame(s) ``index``."""
        t_first = self._chatter_time0()
        return t_first + (np.asarray(index) * self.n_hop + (self.n_window - 1) / 2.0) * self.dt

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
        """
        self._set_mode("raw")
        m, p = self.model.n_outputs, self.model.n_inputs
        z = finite_array("z", z, ndim=(1, 2))
        if z.ndim == 1:
            z = z[None, :]
        if z.shape[1] != m:
            raise ShapeError(f"z must have {m} channel(s) {list(self.channels)}; got shape {z.shape}")
        K = z.shape[0]
        u = finite_array("u", u, ndim=(1, 2))
        if u.ndim == 1:
            u = u[None, :] if (p > 1 or K == 1) and u.shape[0] == p else u[:, None]
        if u.shape != (K, p):
            raise ShapeError(f"u must have shape ({K}, {p}) to match z; got {u.shape}")
        if K == 0:
            return self._empty_update(raw=True)
        if self._aux_state is None:
            self._aux_state = self._aux.initialize(z[:1])
            if self._sat is not None:
                self._sat_state = self._sat.initialize(z[:1])
            self._pending_u = u[0].copy()  # not a view of the caller's array
            self._n_meas = 1
            z, u = z[1:], u[1:]
            K -= 1
            if K == 0:
                return self._empty_update(raw=True)
        u_used = np.empty((K, p))
        u_used[0] = self._pending_u
        u_used[1:] = u[:-1]
        self._pending_u = u[-1].copy()
        if self._fused and _jit.enabled():
            e, estimate = self._advance_fused(z, u_used)
        elif isinstance(self._aux, SVSF):
            # the checks of SVSF.update are done above; both filters share the model, hence G u(k)
            Gu = _rows_times(u_used, self._aux._GT, channel_major=True)
            self._aux_state, out = self._aux._advance(self._aux_state, z[None], Gu)
            e, estimate = out.e_prior[0], None
            if self._sat is not None:
                self._sat_state, sat_out = self._sat._advance(self._sat_state, z[None], Gu, store_states=True)
                estimate = self._output(sat_out.x_post[0])
        else:  # nonlinear auxiliary filter (no sat SVSF)
            self._aux_state, out = self._aux.update(self._aux_state, z[None], u_used, check=False)
            e, estimate = out.e_prior[0], None
        # float arange of integers (exact below 2^53): the bits of t0 + (n + arange(K)) * dt, one pass fewer
        t = self.t0 + np.arange(self._n_meas, self._n_meas + K, dtype=float) * self.dt
        self._n_meas += K
        return self._analyse(e, t, measured=z, estimate=estimate)

    def _advance_fused(self, z: np.ndarray, u_used: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Both filters over one push in one compiled call (:func:`._push_kernels.filters_kernel`).

        The same steps and sums as :meth:`SVSF.update` with compiled kernels on (closed form of
        eq 23 for the aux filter, whose a-posteriori error stays exactly 0; the recursion for
        the sat SVSF), without its per-call Python work; returns ``(e, estimate)``.
        """
        K, m = z.shape
        z3 = np.ascontiguousarray(z)[None]  # one compiled specialization (no copy when contiguous)
        aux = self._aux_state
        e = np.empty((1, K, m))
        sat = self._sat
        none = self._none3
        if sat is None:
            self._kernel(z3, u_used, self._GT, self._aux_PhiT, aux.y, e, none, False, *self._no_sat)
            estimate = None
        else:
            PhiT, L, P, inv_psi, gamma, S_inv = sat._kernel_consts
            st = self._sat_state
            y, ep = st.y.copy(), st.e_post.copy()
            x_out = np.empty((1, K, self.model.n_states))
            self._kernel(
                z3, u_used, self._GT, self._aux_PhiT, aux.y, e, none, True,
                PhiT, L, P, inv_psi, gamma, S_inv, y, ep, none, x_out, none,
            )  # fmt: skip
            self._sat_state = SVSFState(y=y, e_post=ep, k=st.k + K)
            estimate = self._output(x_out[0])
        # the closed form's state: y(k|k) = z(k) exactly, e(k|k) = 0 (see SVSF.update, Notes)
        self._aux_state = SVSFState(y=z[-1:].copy(), e_post=aux.e_post, k=aux.k + K)
        return e[0], estimate

    def _output(self, x: np.ndarray) -> np.ndarray:
        """The sat-SVSF's output estimate ``C x(k|k)`` (K, m) of its states ``x`` (K, n): ``x`` itself
        when ``C`` is the identity (the same values as the product, which only adds exact zeros:
        the BLAS call cost 8 us of a push's ~150 us)."""
        return x if self._C_identity else x @ self.model.C.T

    def push_chattering(self, e: np.ndarray) -> MonitorUpdate:
        """Feed precomputed chattering samples ``e`` (K, m) (e.g. a :class:`ChatteringRecord`'s values).

        The first sample is at ``t0``; do not mix with :meth:`push` on one monitor.
        """
        self._set_mode("chattering")
        m = self.model.n_outputs
        e = finite_array("e", e, ndim=(1, 2))
        if e.ndim == 1:
            e = e[None, :]
        if e.shape[1] != m:
            raise ShapeError(f"chattering must have {m} channel(s); got shape {e.shape}")
        if e.shape[0] == 0:
            return self._empty_update(raw=False)
        t = self._chatter_time0() + np.arange(self._n_chat, self._n_chat + e.shape[0], dtype=float) * self.dt
        return self._analyse(e, t, measured=None, estimate=None)

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
        elif self._mode != mode:
            raise ParameterError(
                "this monitor was fed with "
                + ("raw measurements (push)" if self._mode == "raw" else "chattering (push_chattering)")
                + "; use one kind of input per monitor"
            )

    def _empty_frames(self) -> FrameBlock:
        m, bins = self.model.n_outputs, self.freqs_hz.shape[0]
        return FrameBlock(
            index=np.zeros(0, dtype=int),
            times_s=np.zeros(0),
            power=np.zeros((0, bins, m)),
            flags=np.zeros((0, m), dtype=bool),
            peak_hz=np.zeros((0, m)),
            peak_ratio=np.zeros((0, m)),
        )

    def _empty_update(self, raw: bool) -> MonitorUpdate:
        m = self.model.n_outputs
        return MonitorUpdate(
            t=np.zeros(0),
            chattering=np.zeros((0, m)),
            measured=np.zeros((0, m)) if raw else None,
            estimate=np.zeros((0, m)) if (raw and self._sat is not None) else None,
            frames=self._empty_frames(),
            events=(),
        )

    def _analyse(
        self, e: np.ndarray, t: np.ndarray, *, measured: np.ndarray | None, estimate: np.ndarray | None
    ) -> MonitorUpdate:
        W, H = self.n_window, self.n_hop
        K, nb = e.shape[0], self._n_buf
        self._n_chat += K
        buf_start = self._n_frames * H  # global index of self._buf[0]
        n = nb + K
        if n < W:  # the next frame (samples buf_start .. buf_start + W) is not complete yet
            self._buf[nb:n] = e
            self._n_buf = n
            return MonitorUpdate(t, e, measured, estimate, self._no_frames, ())
        if nb == 0:
            data = e
        elif n <= self._buf.shape[0]:
            self._buf[nb:n] = e
            data = self._buf[:n]
        else:
            data = np.concatenate([self._buf[:nb], e])
        idx, power = self._columns(data, buf_start)
        self._n_frames = int(idx[-1]) + 1
        keep = data[self._n_frames * H - buf_start :]  # < W samples: the next frame's start on
        self._buf[: keep.shape[0]] = keep  # numpy copes with the overlap when data is self._buf
        self._n_buf = keep.shape[0]
        flags, peak_hz, peak_ratio = self._verdicts(power)
        score = self._score._unchecked(power)
        blk = self._alarm._advance(flags.astype(float) if self._legacy else score)
        stat = score if self._legacy else blk.statistic
        times = self.frame_time(idx)
        frames = FrameBlock(idx, times, power, flags, peak_hz, peak_ratio, score, blk.active, stat)
        events = self._events(frames, blk.starts, blk.ends)
        return MonitorUpdate(t, e, measured, estimate, frames, events)

    def _events(self, fr: FrameBlock, starts: np.ndarray, ends: np.ndarray) -> tuple[DetectionEvent, ...]:
        """Events from the alarm layer's starts / ends (F, m); tracks each fault's largest peak."""
        active = fr.alarm
        on = active[0]  # active at the first frame and unchanged: active throughout
        if not (starts.any() or ends.any() or on.any()):  # no change and nothing active: no event
            return ()
        changed = (starts | ends).any(axis=0)  # (m,)
        events: list[DetectionEvent] = []
        for c in np.flatnonzero(changed | on).tolist():
            s_c, e_c = starts[:, c], ends[:, c]
            if not changed[c]:  # the fault goes on: only its largest peak may change
                f = int(np.argmax(fr.peak_ratio[:, c]))  # the first largest, as the loop's strict '>'
                if fr.peak_ratio[f, c] > self._fault_peak[c]:
                    self._fault_peak[c], self._fault_peak_hz[c] = fr.peak_ratio[f, c], fr.peak_hz[f, c]
                continue
            for f in range(s_c.shape[0]):
                ratio = float(fr.peak_ratio[f, c])
                if s_c[f]:
                    self._fault_peak[c], self._fault_peak_hz[c] = ratio, float(fr.peak_hz[f, c])
                    events.append(self._event("fault-start", c, fr, f, fr.peak_hz[f, c], ratio))
                elif e_c[f]:
                    events.append(
                        self._event("fault-end", c, fr, f, self._fault_peak_hz[c], self._fault_peak[c])
                    )
                elif active[f, c] and ratio > self._fault_peak[c]:
                    self._fault_peak[c], self._fault_peak_hz[c] = ratio, float(fr.peak_hz[f, c])
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
        return DetectionEvent(
            kind, self.channels[c], c, t, j, float(peak_hz), float(peak_ratio), t - back * self.dt,
            rule=rule.name, score=float(fr.score[f, c]), statistic=float(fr.alarm_statistic[f, c]),
            threshold=float(rule.threshold), false_alarms_per_hour=self.settings.false_alarms_per_hour,
        )  # fmt: skip
