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

The work is split between two collaborators, both here: :class:`MonitorFilters` (both SVSFs,
measurements to chattering and estimate, the fused compiled push) and :class:`FrameAnalysis` (the
bounded buffer, STFT columns, verdicts, scores, alarm stream and events); the monitor checks the
input, keeps the clock and assembles each push's :class:`MonitorUpdate`. The outputs are frozen
dataclasses: :class:`DetectionEvent` (a fault start or end), :class:`FrameBlock` (the frames one push
completed) and :class:`MonitorUpdate` (everything one push produced); :class:`MonitorSettings` (what
the monitor tests and how it raises alarms) is defined in :mod:`chatterspec.detection.alarms.calibration`
(the batch alarm studies use it too) and exported here.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal, cast

import numpy as np

from .. import _jit
from .._validate import finite_array, positive_int
from ..detection.alarms.calibration import MonitorSettings
from ..detection.alarms.rules import FrameRule, alarm_label
from ..detection.alarms.streams import AlarmStream
from ..detection.spectral import FrameEngine
from ..detection.thresholds import Threshold, monitor_threshold
from ..detection.verdicts import FrameScore, FrameVerdicts
from ..errors import NonFiniteError, ParameterError, ShapeError
from ..filters.protocol import channel_rows, sample_rows
from ..filters.svsf import SVSF, NonlinearSgnSVSF, NonlinearSVSFState, SVSFState, auxiliary_svsf
from ..filters.svsf_recursion import rows_times as _rows_times
from ..jsonout import finite_or_none
from ..plants.models import LinearModel
from ..plants.nonlinear import NonlinearModel, require_linear
from ._push_kernels import (
    direct,
    filters_kernel,
    filters_one_kernel,
    frame_rfft,
    frames_in,
    hop_constants,
    hop_kernel,
    sample_times,
    sample_times_numpy,
)
from .fault_state import alarm_time

__all__ = [
    "ChatteringMonitor",
    "DetectionEvent",
    "EventKind",
    "FrameAnalysis",
    "FrameBlock",
    "MonitorFilters",
    "MonitorSettings",
    "MonitorUpdate",
]

EventKind = Literal["fault-start", "fault-end"]


@dataclass(frozen=True)
class DetectionEvent:
    """A change of a channel's verdict.

    Attributes
    ----------
    kind : {"fault-start", "fault-end"}
    channel : str
    channel_index : int
    time_s : float
        Centre time of the frame where the verdict changed (s).
    alarm_time_s : float
        When the alarm layer decided: the time of the deciding frame's last sample (s), ``time_s`` plus
        half a window (:func:`chatterspec.online.fault_state.alarm_time`). The channel's fault state
        changes here in the recording's lanes, events and live view.
    frame : int
        Global frame number.
    peak_hz : float
        ``fault-start``: frequency of the largest ``S / threshold`` in that frame;
        ``fault-end``: of the largest ratio seen during the fault.
    peak_ratio : float
        The corresponding ``S / threshold`` (> 1 means above threshold).
    estimate_s : float
        Onset / offset estimate of :func:`chatterspec.detection.verdicts.frame_intervals`:
        half a hop before ``time_s`` (the start of frame 0's window when the
        very first frame is flagged).
    rule : str
        The alarm rule that raised the event (``frame``, ``persistence``, ``cusum``).
    score : float
        The frame score ``-log p`` (nats) of the event's frame.
    statistic : float
        The rule's statistic at that frame (score, window count or CUSUM ``g``).
    threshold : float
        The rule's threshold ``h`` (same units as ``statistic``).
    false_alarms_per_hour : float or None
        The budget the threshold was set for (alarm starts per hour, all channels), None when
        the rule runs at a per-frame ``alpha``.
    """

    kind: EventKind
    channel: str
    channel_index: int
    time_s: float
    frame: int
    peak_hz: float
    peak_ratio: float
    estimate_s: float = float("nan")
    rule: str = "frame"
    score: float = float("nan")
    statistic: float = float("nan")
    threshold: float = float("nan")
    false_alarms_per_hour: float | None = None
    alarm_time_s: float = float("nan")

    def describe(self) -> str:
        """A short description for reports and recordings: the alarm time (end of the deciding frame) and
        the onset / offset estimate, each named."""
        what = "fault start" if self.kind == "fault-start" else "fault end"
        peak = "peak" if self.kind == "fault-start" else "largest peak during the fault"
        est = "onset" if self.kind == "fault-start" else "offset"
        return (
            f"{what} on {self.channel}: alarm {'raised' if self.kind == 'fault-start' else 'cleared'} at "
            f"t = {self.alarm_time_s:.2f} s (end of the deciding frame), {est} estimated "
            f"{self.estimate_s:.2f} s "
            f"({peak} {self.peak_ratio:.2f} x threshold at {self.peak_hz:.1f} Hz) "
            f"[{alarm_label(self.rule, self.false_alarms_per_hour)}]"
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready (non-finite numbers become None)."""
        return {
            "kind": self.kind,
            "channel": self.channel,
            "time_s": self.time_s,
            "alarm_time_s": finite_or_none(self.alarm_time_s),
            "estimate_s": finite_or_none(self.estimate_s),
            "frame": self.frame,
            "peak_hz": self.peak_hz,
            "peak_ratio": self.peak_ratio,
            "rule": self.rule,
            "score": finite_or_none(self.score),
            "statistic": finite_or_none(self.statistic),
            "threshold": finite_or_none(self.threshold),
            "false_alarms_per_hour": self.false_alarms_per_hour,
        }


@dataclass(frozen=True, eq=False)
class FrameBlock:
    """STFT frames completed by one push.

    Attributes
    ----------
    index : (F,) int array
        Global frame numbers.
    times_s : (F,) array
        Frame-centre times (s).
    power : (F, bins, m) array
        Frame spectra (columns of :func:`chatterspec.detection.spectral.spectrogram`).
    flags : (F, m) bool array
        Per-frame, per-channel verdict (any tested bin above the threshold).
    peak_hz, peak_ratio : (F, m) arrays
        Frequency and value of the largest ``S / threshold`` over the tested bins.
    score : (F, m) array or None
        The frame score ``-log p`` (nats, :mod:`chatterspec.detection.verdicts`).
    alarm : (F, m) bool array or None
        The alarm state after each frame (the rule's decision; events are its changes).
    alarm_statistic : (F, m) array or None
        The rule's statistic after each frame (score, window count or CUSUM ``g``).
    """

    index: np.ndarray
    times_s: np.ndarray
    power: np.ndarray
    flags: np.ndarray
    peak_hz: np.ndarray
    peak_ratio: np.ndarray
    score: np.ndarray | None = None
    alarm: np.ndarray | None = None
    alarm_statistic: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames."""
        return self.index.shape[0]


@dataclass(frozen=True, eq=False)
class MonitorUpdate:
    """What one :meth:`ChatteringMonitor.push` produced.

    Attributes
    ----------
    t : (K,) array
        Times of the new chattering samples (s).
    chattering : (K, m) array
        ``e(k|k-1)`` of the auxiliary filter.
    measured : (K, m) array or None
        The measurements at those times (raw pushes only).
    estimate : (K, m) array or None
        ``C x(k|k)`` of the ``sat`` SVSF (when ``psi`` is set and raw data pushed).
    frames : FrameBlock
    events : tuple of DetectionEvent
    """

    t: np.ndarray
    chattering: np.ndarray
    measured: np.ndarray | None
    estimate: np.ndarray | None
    frames: FrameBlock
    events: tuple[DetectionEvent, ...]


_NEW, _SET = object.__new__, object.__setattr__


def _frame_block(
    index: np.ndarray, times_s: np.ndarray, power: np.ndarray, flags: np.ndarray, peak_hz: np.ndarray,
    peak_ratio: np.ndarray, score: np.ndarray, alarm: np.ndarray, alarm_statistic: np.ndarray,
) -> FrameBlock:  # fmt: skip
    """``FrameBlock(...)`` with every field, its instance dict set in one call.

    A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__``: nine calls,
    ~1 us per push, twice this (tests/test_monitor.py checks that both give the same fields).
    """
    block = _NEW(FrameBlock)
    _SET(block, "__dict__", {
        "index": index, "times_s": times_s, "power": power, "flags": flags, "peak_hz": peak_hz,
        "peak_ratio": peak_ratio, "score": score, "alarm": alarm, "alarm_statistic": alarm_statistic,
    })  # fmt: skip
    return block


def _monitor_update(
    t: np.ndarray, chattering: np.ndarray, measured: np.ndarray | None, estimate: np.ndarray | None,
    frames: FrameBlock, events: tuple[DetectionEvent, ...],
) -> MonitorUpdate:  # fmt: skip
    """``MonitorUpdate(...)`` as :func:`_frame_block` builds a :class:`FrameBlock` (the same fields)."""
    update = _NEW(MonitorUpdate)
    _SET(update, "__dict__", {
        "t": t, "chattering": chattering, "measured": measured, "estimate": estimate, "frames": frames,
        "events": events,
    })  # fmt: skip
    return update


class MonitorFilters:
    """Both SVSFs of a :class:`~chatterspec.online.monitor.ChatteringMonitor`, advanced push by push.

    Parameters
    ----------
    model : LinearModel or NonlinearModel
        Nominal model (already checked by the monitor).
    settings : MonitorSettings
        ``gamma`` for both filters, ``psi`` (boundary layer of the ``sat`` SVSF, None: no estimate).

    Attributes
    ----------
    fused : bool
        Whether a push runs both filters in one compiled call (full measurement, at least one input,
        numba installed; the call is also skipped while compiled kernels are disabled).
    n_meas : int
        Measurements consumed so far (the first one only initializes the filters).
    """

    def __init__(self, model: LinearModel | NonlinearModel, settings: MonitorSettings) -> None:
        s = settings
        self.model = model
        nonlinear = isinstance(model, NonlinearModel)
        self._aux = NonlinearSgnSVSF(model, s.gamma) if nonlinear else auxiliary_svsf(model, s.gamma)
        self._sat = None if s.psi is None else SVSF(model, psi=np.asarray(s.psi), gamma=s.gamma)
        self._aux_state_obj: SVSFState | NonlinearSVSFState | None = None
        self._sat_state_obj: SVSFState | None = None
        # one compiled call per push for both filters (full measurement: the closed form of eq 23;
        # at least one input; numba installed, and enabled at push time)
        self.fused = (
            isinstance(self._aux, SVSF)
            and self._aux._L is None
            and model.n_inputs >= 1
            and _jit.HAVE_NUMBA
            and _jit.fits(model.n_states, model.n_outputs, vectors_only=True)
        )
        if self.fused:
            aux = cast(SVSF, self._aux)  # (fused: the linear auxiliary SVSF)
            self._GT = np.ascontiguousarray(aux._GT, dtype=float)
            self._aux_PhiT = np.ascontiguousarray(aux._PhiT, dtype=float)
            self._none3 = np.empty((0, 0, 0))
            e2 = np.empty((0, 0))
            self._no_sat = (e2, e2, e2, np.empty(0), 0.0, e2, e2, e2, self._none3, self._none3, self._none3)
            # the push loop, unrolled for small models (the EHA's 3 states): same steps, same bits
            self._kernel = filters_kernel(model.n_states, model.n_outputs)
            self._one = filters_one_kernel(model.n_states, model.n_outputs)
            self._one_cst = self._one_constants()
        # C = I (every state measured in its own units, the EHA): the estimate C x is x itself
        C = getattr(model, "C", None)
        self._C_identity = C is not None and C.shape[0] == C.shape[1] and np.array_equal(C, np.eye(len(C)))
        self._pending_obj: np.ndarray | None = None
        # the fused path's state between samples and pushes, in one array (the per-sample kernel's
        # layout): pending u(k), the aux y(k|k) = z(k), the sat filter's y and e(k|k), its estimate
        self._st: np.ndarray | None = None
        self.n_meas = 0

    def _one_constants(self) -> np.ndarray:
        """``cst`` of :func:`._push_kernels._filters_one` (zeros in the sat filter's place without one)."""
        model, sat = self.model, self._sat
        n, m, p = model.n_states, model.n_outputs, model.n_inputs
        if sat is None:
            head = [n, m, p, 0, 0.0, 0.0, 0.0, 0.0]
            sat_parts: list[np.ndarray] = [np.zeros(n * n), np.zeros(n), np.zeros(n * n)]
        else:
            PhiT, L_, P_, inv_psi_, gamma, S_inv = sat._kernel_consts
            # (the kernel's constants: empty arrays, never None)
            L, P, inv_psi = cast(np.ndarray, L_), cast(np.ndarray, P_), cast(np.ndarray, inv_psi_)
            psi_n = np.zeros(n)
            psi_n[: inv_psi.size] = inv_psi
            head = [n, m, p, L.shape[0], 1.0, gamma, 0.0, 0.0]
            sat_parts = [PhiT, L, P, psi_n, S_inv]
        parts = [np.asarray(head, dtype=float), self._GT, self._aux_PhiT, *sat_parts]
        return np.ascontiguousarray(np.concatenate([np.ravel(np.asarray(a, dtype=float)) for a in parts]))

    def _pack(self) -> None:
        """Move the states into the fused path's array (after the first push, whichever path made them)."""
        n, m, p = self.model.n_states, self.model.n_outputs, self.model.n_inputs
        st = np.zeros(p + m + n + m + n + m)
        st[:p] = cast(np.ndarray, self._pending_obj)  # (the first push set them all)
        st[p : p + m] = cast(SVSFState, self._aux_state_obj).y[0]
        if self._sat is not None:
            sat = cast(SVSFState, self._sat_state_obj)
            st[p + m : p + m + n] = sat.y[0]
            st[p + m + n : p + 2 * m + n] = sat.e_post[0]
            st[p + 2 * m + n : p + 2 * m + 2 * n] = (sat.y @ self._sat._S_inv.T)[0]
        self._st = st

    @property
    def _pending_u(self) -> np.ndarray | None:
        return self._pending_obj if self._st is None else self._st[: self.model.n_inputs]

    @_pending_u.setter
    def _pending_u(self, value: np.ndarray) -> None:
        if self._st is None:
            self._pending_obj = value
        else:
            self._st[: self.model.n_inputs] = value

    # the states as SVSFState objects (views of the fused path's array when it holds them)
    @property
    def _aux_state(self) -> SVSFState | NonlinearSVSFState | None:
        if self._st is None:
            return self._aux_state_obj
        p, m = self.model.n_inputs, self.model.n_outputs
        return SVSFState(y=self._st[None, p : p + m], e_post=np.zeros((1, m)), k=self.n_meas - 1)

    @_aux_state.setter
    def _aux_state(self, value: SVSFState | NonlinearSVSFState | None) -> None:
        self._aux_state_obj = value
        if self._st is not None and value is not None:
            p, m = self.model.n_inputs, self.model.n_outputs
            self._st[p : p + m] = value.y[0]

    @property
    def _sat_state(self) -> SVSFState | None:
        if self._st is None or self._sat is None:
            return self._sat_state_obj
        p, m, n = self.model.n_inputs, self.model.n_outputs, self.model.n_states
        o = p + m
        return SVSFState(
            y=self._st[None, o : o + n], e_post=self._st[None, o + n : o + n + m], k=self.n_meas - 1
        )

    @_sat_state.setter
    def _sat_state(self, value: SVSFState | None) -> None:
        self._sat_state_obj = value
        if self._st is not None and value is not None:
            p, m, n = self.model.n_inputs, self.model.n_outputs, self.model.n_states
            o = p + m
            self._st[o : o + n] = value.y[0]
            self._st[o + n : o + n + m] = value.e_post[0]

    @property
    def has_estimate(self) -> bool:
        """Whether pushes return the ``sat`` SVSF's output estimate (``psi`` was given)."""
        return self._sat is not None

    def advance(self, z: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Consume measurements ``z`` (K, m) and inputs ``u`` (K, p) (checked, K >= 1).

        ``u(k)`` drives x(k) -> x(k+1), so each push uses the previous push's last input first.
        The very first measurement only initializes the filters.

        Returns
        -------
        z_used : (K', m) array
            The measurements that produced chattering (``z`` without its first row on the first push).
        e : (K', m) array
            The chattering ``e(k+1|k)``, one row per row of ``z_used``.
        estimate : (K', m) array or None
            The ``sat`` SVSF's output estimate ``C x(k|k)`` (None without ``psi``).
        """
        if self._aux_state is None:
            self._aux_state = self._aux.initialize(z[:1])
            if self._sat is not None:
                self._sat_state = self._sat.initialize(z[:1])
            self._pending_u = u[0].copy()  # not a view of the caller's array
            self.n_meas = 1
            if self.fused:
                self._pack()
            z, u = z[1:], u[1:]
        K = z.shape[0]
        if K == 0:
            return z, z[:0], None
        u_used = np.empty((K, u.shape[1]))
        u_used[0] = self._pending_u
        u_used[1:] = u[:-1]
        self._pending_u = u[-1].copy()
        if self.fused and _jit.enabled():
            e, estimate = self._advance_fused(z, u_used)
        elif isinstance(self._aux, SVSF):
            # the checks of SVSF.update are done by the monitor; both filters share the model, hence G u(k)
            Gu = _rows_times(u_used, self._aux._GT, channel_major=True)
            self._aux_state, out = self._aux._advance(cast(SVSFState, self._aux_state), z[None], Gu)
            e, estimate = out.e_prior[0], None
            if self._sat is not None:
                sat_state = cast(SVSFState, self._sat_state)  # (initialized with the aux state)
                self._sat_state, sat_out = self._sat._advance(sat_state, z[None], Gu, store_states=True)
                estimate = self._output(cast(np.ndarray, sat_out.x_post)[0])  # (store_states)
        else:  # nonlinear auxiliary filter (no sat SVSF)
            aux_state = cast(NonlinearSVSFState, self._aux_state)
            self._aux_state, nl_out = self._aux.update(aux_state, z[None], u_used, check=False)
            e, estimate = nl_out.e_prior[0], None
        self.n_meas += K
        return z, e, estimate

    def _advance_fused(self, z: np.ndarray, u_used: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """Both filters over one push in one compiled call (:func:`._push_kernels.filters_kernel`).

        The same steps and sums as :meth:`SVSF.update` with compiled kernels on (closed form of
        eq 23 for the aux filter, whose a-posteriori error stays exactly 0; the recursion for
        the sat SVSF), without its per-call Python work; returns ``(e, estimate)``.
        """
        K, m = z.shape
        n, p = self.model.n_states, self.model.n_inputs
        z3 = np.ascontiguousarray(z)[None]  # one compiled specialization (no copy when contiguous)
        st = cast(np.ndarray, self._st)  # views of the state array: the kernel updates y, e(k|k) in place
        aux_y = st[None, p : p + m]
        e = np.empty((1, K, m))
        sat = self._sat
        none = self._none3
        if sat is None:
            self._kernel(z3, u_used, self._GT, self._aux_PhiT, aux_y, e, none, False, *self._no_sat)
            estimate = None
        else:
            PhiT, L, P, inv_psi, gamma, S_inv = sat._kernel_consts
            o = p + m
            y, ep = st[None, o : o + n], st[None, o + n : o + n + m]
            x_out = np.empty((1, K, n))
            self._kernel(
                z3, u_used, self._GT, self._aux_PhiT, aux_y, e, none, True,
                PhiT, L, P, inv_psi, gamma, S_inv, y, ep, none, x_out, none,
            )  # fmt: skip
            st[o + n + m : o + n + m + n] = x_out[0, -1]
            estimate = self._output(x_out[0])
        # the closed form's state: y(k|k) = z(k) exactly, e(k|k) = 0 (see SVSF.update, Notes)
        aux_y[0] = z[-1]
        st[-m:] = e[0, -1]
        return e[0], estimate

    def step(self, z: np.ndarray, u: np.ndarray, ebuf: np.ndarray, row: int) -> int:
        """One sample of both filters in one compiled call (:func:`._push_kernels.filters_one_kernel`).

        Only on the fused path after the first measurement. ``z`` (m,), ``u`` (p,) (float,
        contiguous); the chattering goes to ``ebuf[row]``. Returns 0, or 3 when ``z`` or ``u`` is
        not finite (nothing consumed). The sample's estimate is then :meth:`last_estimate`.
        """
        status = int(self._one(self._one_cst, self._st, z, u, ebuf, row))
        if status == 0:
            self.n_meas += 1
        return status

    def last_estimate(self) -> np.ndarray | None:
        """The sat SVSF's output estimate ``C x(k|k)`` (m,) of the last sample (None without ``psi``)."""
        if self._sat is None or self._st is None:
            return None
        n, m = self.model.n_states, self.model.n_outputs
        x = self._st[-n - m : -m]
        return x.copy() if self._C_identity else self.model.C @ x

    def last_chattering(self) -> np.ndarray | None:
        """The chattering ``e(k|k-1)`` (m,) of the last sample (fused path)."""
        return None if self._st is None else self._st[-self.model.n_outputs :].copy()

    def _output(self, x: np.ndarray) -> np.ndarray:
        """The sat-SVSF's output estimate ``C x(k|k)`` (K, m) of its states ``x`` (K, n): ``x`` itself
        when ``C`` is the identity (the same values as the product, which only adds exact zeros:
        the BLAS call cost 8 us of a push's ~150 us)."""
        return x if self._C_identity else x @ self.model.C.T


#: The native float64 dtype (an array of another float64 dtype object, e.g. byte-swapped, is converted).
_FLOAT = np.dtype(np.float64)

#: Rows the frame buffer keeps between pushes at most (a larger push gets a buffer of its own).
MAX_BUFFER_ROWS = 1 << 16


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
        # (channel-major: each channel's samples contiguous, so the compiled taper reads them in order)
        self._buf = np.empty((m, self.n_window + self.n_hop))
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
        # per channel, the active fault's largest peak ratio and its Hz (the fused push's kernel
        # keeps them over blocks without an alarm start or end; _events over the others)
        self._peak = np.zeros((2, m))
        self._no_peak = np.zeros((2, 0))
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
        # the fused path calls numba's dispatchers themselves (one Python call fewer per kernel call)
        self._frames_in = direct(frames_in) if self._fused else frames_in
        if self._fused and self._hop is not None:
            self._hop = direct(self._hop)
        # the fused push's constants, packed once (a numba call unboxes every array it is given), and
        # its taper buffer: frames in blocks of 2^15 values, as FrameEngine.transforms
        eng, ver, al = self._columns, self._verdicts, self._alarm
        self._block = max(1, (1 << 15) // max(1, m * self.n_window))
        self._tapered = np.empty(m * self._block * self.n_window)
        self._spectra = np.empty(m * self._block * self.n_bins, dtype=complex)
        self._views: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._cf, self._ci = hop_constants(
            eng.scale, ver.sel.start if isinstance(ver.sel, slice) else 0, ver.values, ver._positions,
            ver.freqs, self._score._kernel_args, al._h, al._p, self._legacy, self.n_window, self.n_hop,
        )  # fmt: skip
        self._no_rows = np.empty((0, m))

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

    def push(self, e: np.ndarray, check: bool = False) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """Analyse the next chattering samples ``e`` (K, m); the frames they complete and their events.

        ``check``: first look for NaN/inf in ``e`` (the compiled path does it while it copies ``e``).

        Raises
        ------
        NonFiniteError
            ``check`` and ``e`` has NaN/inf values (nothing is consumed then).
        """
        if self._fused:
            return self._push_fused(e, check)
        if check:
            finite_array("e", e)
        W = self.n_window
        K, nb = e.shape[0], self.n_buffered
        n = nb + K
        if n < W:  # the next frame (samples buf_start .. buf_start + W) is not complete yet
            self._buf[:, nb:n] = e.T
            self.n_buffered = n
            return self.no_frames, ()
        if nb == 0:
            data = e
        elif n <= self._buf.shape[1]:
            self._buf[:, nb:n] = e.T
            data = self._buf[:, :n].T
        else:
            data = np.concatenate([self._buf[:, :nb].T, e])
        return self._analyse(data)

    def slot(self) -> tuple[np.ndarray, int]:
        """Where the next chattering sample goes: ``buffer[:, column]`` (:meth:`commit_one` takes it)."""
        return self._buf, self.n_buffered

    def commit_one(self) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """:meth:`push` of the one sample written at :meth:`slot` (the same frames and events)."""
        n = self.n_buffered + 1
        if n < self.n_window:
            self.n_buffered = n
            return self.no_frames, ()
        if self._fused:
            self.n_buffered = n
            return self._push_fused(self._no_rows, False)
        return self._analyse(self._buf[:, :n].T)

    def _analyse(self, data: np.ndarray) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """The frames that ``data`` (the buffered samples, then the new ones; >= one window) completes."""
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
        self._buf[:, : keep.shape[0]] = keep.T  # numpy copes with the overlap when data is self._buf
        self.n_buffered = keep.shape[0]

    def _push_fused(self, e: np.ndarray, check: bool) -> tuple[FrameBlock, tuple[DetectionEvent, ...]]:
        """:meth:`push` in two compiled calls and one FFT per block of frames.

        :func:`~._push_kernels.frames_in` (append, check, taper, keep the rest) and
        :func:`~._push_kernels._hop_loop` (power, verdicts, score, alarm rule, frame times): the steps
        of :meth:`_analyse`, the same bits, with the constants packed once.
        """
        nb, K = self.n_buffered, e.shape[0]
        n = nb + K
        W, H = self.n_window, self.n_hop
        if n > self._buf.shape[1]:  # room for the push (a push of millions: only while it is analysed)
            buf = np.empty((e.shape[1], n))
            buf[:, :nb] = self._buf[:, :nb]
            if n <= MAX_BUFFER_ROWS:
                self._buf = buf
        else:
            buf = self._buf
        F = 0 if n < W else (n - W) // H + 1
        hi = min(F, self._block)
        win = self._columns.win
        views = self._views.get(hi) or self._frame_views(hi)
        kept = self._frames_in(buf, nb, e, check, win, H, 0, hi, F, views[0])
        if kept < 0:  # NaN/inf in e (nothing written)
            bad = int(e.size - np.count_nonzero(np.isfinite(e)))
            raise NonFiniteError(f"e contains {bad} NaN/inf value(s); all entries must be finite")
        if F == 0:
            self.n_buffered = kept
            return self.no_frames, ()
        m = len(self.channels)
        j_first = self.n_frames
        power = np.empty((F, self.n_bins, m))
        outf = np.empty((5, F, m))  # peak ratio, score, statistic, the rule's input, peak Hz
        outb = np.empty((4, F, m), dtype=np.bool_)  # active, starts, ends, flags
        times = np.empty(F)
        al = self._alarm
        pos = al._pos
        pos[0] = al._step
        hop = self._hop
        assert hop is not None  # (fused: the rule gives its channel step)
        any_alarm = 0
        lo = 0
        # one block: the kernel keeps the faults' peaks where no alarm starts or ends; several: _events
        # goes over all of the push's frames from the peaks before it
        tracked = hi == F
        peak = self._peak if tracked else self._no_peak
        while True:
            Y = frame_rfft(*views)
            any_alarm |= hop(
                Y, lo, j_first, self.t_first, self.dt, self._cf, self._ci,
                al._active, al._g, al._count, al._ring, pos, power, outf, outb, times, peak,
            )  # fmt: skip
            pos[0] += hi - lo
            if hi == F:
                break
            lo, hi = hi, min(hi + self._block, F)
            views = self._views.get(hi - lo) or self._frame_views(hi - lo)
            kept = self._frames_in(buf, n, self._no_rows, False, win, H, lo, hi, F, views[0])
        al._step += F
        if buf is not self._buf:
            self._buf[:, :kept] = buf[:, :kept]
        self.n_buffered = kept
        self.n_frames = j_first + F
        idx = np.arange(j_first, j_first + F)
        stat = outf[1] if self._legacy else outf[2]
        frames = _frame_block(idx, times, power, outb[3], outf[4], outf[0], outf[1], outb[0], stat)
        if not any_alarm & (2 if tracked else 3):  # no alarm start or end (peaks kept): no event
            return frames, ()
        return frames, self._events(frames, outb[1], outb[2])

    def _frame_views(self, frames: int) -> tuple[np.ndarray, np.ndarray]:
        """The fused push's buffers for a block of ``frames`` frames (the first values of each, C-ordered):
        the tapered frames (1, m, frames, W) and their transforms (1, m, frames, bins); made once per
        block size and kept."""
        m = len(self.channels)
        tapered = self._tapered[: m * frames * self.n_window].reshape(1, m, frames, self.n_window)
        spectra = self._spectra[: m * frames * self.n_bins].reshape(1, m, frames, self.n_bins)
        self._views[frames] = tapered, spectra
        return tapered, spectra

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
        peak, peak_hz = self._peak.tolist()
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
        self._peak[0], self._peak[1] = peak, peak_hz
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
    threshold : Threshold, optional
        The per-frame threshold of ``model`` and ``settings``
        (:func:`~chatterspec.detection.thresholds.monitor_threshold`) when the caller has it already
        (e.g. for the calibration of the alarm rule); computed here by default.

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
        self,
        model: LinearModel | NonlinearModel,
        settings: MonitorSettings | None = None,
        *,
        t0: float = 0.0,
        threshold: Threshold | None = None,
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
        self.threshold = monitor_threshold(model, s) if threshold is None else threshold
        # the two collaborators: the SVSFs (measurements -> chattering, estimate) and the frame
        # analysis (chattering -> STFT columns, verdicts, alarm states, events)
        self._filters = MonitorFilters(model, s)
        self._frames = FrameAnalysis(s, self.threshold, self.dt, model.output_names)
        self.rule = self._frames.rule
        self._mode: str | None = None  # "raw" or "chattering"
        self._n_chat = 0  # chattering samples produced / pushed
        self._t_chat0: float | None = None  # time of chattering sample 0
        self._last: MonitorUpdate | None = None  # the last push (None after a compiled step)
        # the pushed samples' times: one compiled call with numba (the bits of the numpy form)
        self._sample_times = direct(sample_times) if _jit.enabled() else sample_times_numpy
        self._m = model.n_outputs

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
        MonitorFilters.advance : the filters' step.
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
        t = self._sample_times(self.t0, self._filters.n_meas - K, K, self.dt)
        self._n_chat += K
        frames, events = self._frames.push(e)
        self._last = _monitor_update(t, e, z, estimate, frames, events)
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
        if self._mode != "chattering":
            self._set_mode("chattering")
        m = self._m
        if type(e) is np.ndarray and e.dtype is _FLOAT and e.ndim == 2 and e.shape[1] == m:
            if not e.flags.c_contiguous:
                e = np.ascontiguousarray(e)
        else:  # anything else: converted and checked here (the frame analysis checks NaN/inf)
            e = channel_rows("e", e, m, label="chattering")
        K = e.shape[0]
        if K == 0:
            return self._empty_update(raw=False)
        frames, events = self._frames.push(e, check=True)  # NaN/inf: NonFiniteError, nothing consumed
        t = self._sample_times(self._chatter_time0(), self._n_chat, K, self.dt)
        self._n_chat += K
        return _monitor_update(t, e, None, None, frames, events)

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
