"""Identification beside the online monitor, under its alarm budget: estimates every hop, fault names only
at alarms, the parameters' alarms when tolerances are declared, and when the data are blind.

:class:`IdentificationMonitor` takes the monitor's raw pushes (measurements and inputs) and, per STFT
hop, identifies the window ending there
(:class:`~chatterspec.detection.identification.OnlineIdentifier`) and decides on the identified
parameters (:class:`~chatterspec.detection.parameter_decision.ParameterDecision`). Each window gives a
:class:`WindowDecision`:

* the joint estimate of every declared parameter with its interval, detectable change and state
  (healthy, fault, not excited: :data:`~chatterspec.detection.parameter_decision.STATES`);
* a **fault label only under an alarm**. With tolerances the alarm is the parameters' own (their
  scores through the monitor's rule at the run's budget) and the label names the parameters in
  alarm ("leakage+friction"). Without tolerances the alarm is the spectral monitor's (reported with
  :meth:`IdentificationMonitor.note_alarm`) and the label is the hypothesis the identification
  selects in that window (every combination of parameters is a hypothesis, so two faults at once
  are named as both). Between alarms there is no label: the per-window hypothesis tests run at the
  per-frame alpha and would otherwise name a fault every few minutes of healthy data;
* per output channel a state: fault (an alarm on the channel; with tolerances, on a parameter the
  channel's chattering carries), else not excited (a parameter the channel carries is not
  excited), else healthy.

Window ``j`` of the identification is the monitor's frame ``j`` shifted by one sample, so the
spectral alarm state of a window is that of frame ``j`` (decided at the frame's last sample, the
``alarm_time_s`` of its events). Each window's states are decided at its last sample
(:attr:`WindowDecision.alarm_time_s`; with tolerances the ``alarm_time_s`` of the parameters' events).
The channels' one fault state (:mod:`chatterspec.online.fault_state`) follows from these: the
parameters' alarms and the excitation at the windows' alarm times with tolerances; without, the
spectral alarm at its frames' ends and the excitation (:attr:`IdentificationUpdate.not_excited`) at the
windows'.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np

from ..detection.identification import (
    IdentificationReport,
    IdentificationSetup,
    OnlineIdentification,
    OnlineIdentifier,
)
from ..detection.parameter_decision import (
    STATES,
    ParameterAlarmSettings,
    ParameterDecision,
    ParameterDecisions,
    ParameterEvent,
    band_position,
    joint_hypothesis,
)
from ..plants.parameters import NO_FAULT

__all__ = ["IdentificationMonitor", "IdentificationUpdate", "WindowDecision"]


@dataclass(frozen=True, eq=False)
class WindowDecision:
    """One identification window's decision.

    Attributes
    ----------
    index : int
        Position among the push's windows.
    time_s : float
        Window centre (s).
    window_s : (float, float)
        First and one-past-last chattering time of the window (s).
    alarm_time_s : float
        When the window's states are decided: its last sample (s).
    alarm : bool
        An alarm is active (the parameters' with tolerances, else the spectral monitor's).
    label : str or None
        The fault named: the parameters in alarm (tolerances) or the selected hypothesis (spectral
        alarm; possibly "no fault" or "unexplained"); None between alarms.
    states : tuple of str
        Per parameter (table order), one of :data:`~chatterspec.detection.parameter_decision.STATES`.
    channel_states : tuple of str
        Per output channel.
    """

    index: int
    time_s: float
    window_s: tuple[float, float]
    alarm_time_s: float
    alarm: bool
    label: str | None
    states: tuple[str, ...]
    channel_states: tuple[str, ...]


@dataclass(frozen=True, eq=False)
class IdentificationUpdate:
    """What one push gave: the identification windows, the parameter decisions and their windows' verdicts.

    Attributes
    ----------
    found : OnlineIdentification
    block : ParameterDecisions
    windows : tuple of WindowDecision
    not_excited : (W, m) bool array
        Per window and output channel: a parameter the channel's chattering carries is not excited (its
        detectable change exceeds its limit), whatever the alarms.
    events : tuple of ParameterEvent
        The parameters' alarm starts and ends (tolerances declared).
    """

    found: OnlineIdentification
    block: ParameterDecisions
    windows: tuple[WindowDecision, ...]
    not_excited: np.ndarray
    events: tuple[ParameterEvent, ...] = field(default=())

    def report(self, i: int) -> IdentificationReport:
        """The full identification report of window ``i`` (every hypothesis and test)."""
        return self.found.report(i)

    def channel_codes(self) -> tuple[np.ndarray, np.ndarray]:
        """The windows' alarm times ``(W,)`` (s) and channel state codes ``(W, m)`` (indices into
        :data:`~chatterspec.detection.parameter_decision.STATES`, the codes of
        :mod:`chatterspec.online.fault_state`)."""
        times = np.array([w.alarm_time_s for w in self.windows], dtype=float)
        codes = np.array([[STATES.index(s) for s in w.channel_states] for w in self.windows], dtype=np.int8)
        return times, codes.reshape(len(self.windows), -1)


class IdentificationMonitor:
    """Per-hop identification and parameter decisions beside a :class:`~chatterspec.online.monitor.
    ChatteringMonitor` (module docstring).

    Parameters
    ----------
    setup : IdentificationSetup
        Testing the joint hypothesis (the default setup of a model with a parameter map does).
    settings : ParameterAlarmSettings
        From :func:`~chatterspec.detection.parameter_decision.parameter_alarm_settings` (hop, window,
        budget; alarms when the model declares tolerances).
    t0 : float
        Time (s) of the first measurement pushed.
    alpha : float
        Level of the per-window hypothesis tests (the selection named under a spectral alarm).
    confidence : float
        Level of the intervals.
    frame_samples : int, optional
        The spectral monitor's STFT window (samples; ``ChatteringMonitor.n_window``): the spectral
        alarm times are the ends of its frames. Default: the identification window (``window_hops``
        hops), the same when the window is a whole number of hops.
    """

    def __init__(
        self,
        setup: IdentificationSetup,
        settings: ParameterAlarmSettings,
        *,
        t0: float = 0.0,
        alpha: float = 1e-3,
        confidence: float = 0.95,
        frame_samples: int | None = None,
    ) -> None:
        model = setup.model
        self.setup, self.settings = setup, settings
        self.dt = model.dt
        hop = max(1, round(settings.hop_s / model.dt))
        self.frame_samples = int(frame_samples) if frame_samples is not None else hop * settings.window_hops
        self.identifier = OnlineIdentifier(
            setup,
            hop_samples=hop,
            window_hops=settings.window_hops,
            t0=t0,
            alpha=alpha,
            confidence=confidence,
        )
        self.decision = ParameterDecision(setup, settings)
        self.parameters = setup.parameter_map.parameter_names
        self.channels = tuple(model.output_names)
        self._carried = _carried(setup)  # (m, P): channel i's chattering carries parameter k
        self._open: dict[str, float] = {}  # spectral alarms open: channel -> start (alarm time, s)
        self._closed: list[tuple[str, float, float]] = []  # recent (channel, start, end)

    @property
    def carried(self) -> np.ndarray:
        """``(m, P)`` bool: output channel ``i``'s chattering carries parameter ``k`` (table order): its
        state follows that parameter's excitation, and with tolerances its alarm."""
        return self._carried

    @property
    def tolerances(self) -> bool:
        """Whether the parameters raise the alarms (tolerances declared)."""
        return self.settings.alarms

    def reset(self, t0: float) -> None:
        """A gap or restart at ``t0`` (s): identification, parameter alarms and spectral state start over."""
        self.identifier.reset(t0)
        self.decision.reset()
        self._open.clear()
        self._closed.clear()

    def note_alarm(self, kind: str, channel: str, alarm_time_s: float) -> None:
        """A spectral alarm event (``fault-start`` / ``fault-end`` on ``channel`` decided at
        ``alarm_time_s``, the end of its frame: ``DetectionEvent.alarm_time_s``, a stream event's
        ``sample_time_s``), given before the identification of the same push."""
        if kind == "fault-start":
            self._open[channel] = float(alarm_time_s)
        elif kind == "fault-end" and channel in self._open:
            self._closed.append((channel, self._open.pop(channel), float(alarm_time_s)))

    def _spectral(self, t_alarm: np.ndarray) -> np.ndarray:
        """``(W, m)``: channels whose spectral alarm is active after each frame decided at ``t_alarm``
        ``(W,)`` (s; half a sample of slack for the rounding of times that are a hop apart)."""
        t = t_alarm + 0.5 * self.dt
        on = np.zeros((t.size, len(self.channels)), dtype=bool)
        for ch, start in self._open.items():
            on[:, self.channels.index(ch)] |= start <= t
        for ch, start, end in self._closed:
            on[:, self.channels.index(ch)] |= (start <= t) & (t < end)
        return on

    def frame_ends(self, found: OnlineIdentification) -> np.ndarray:
        """``(W,)``: the alarm time (last sample, s) of the spectral frame of each window's number (its
        first sample is the window's minus ``dt``)."""
        w = np.asarray(found.window_s, dtype=float).reshape(-1, 2)
        return w[:, 0] - self.dt + (self.frame_samples - 1) * self.dt

    def push(self, z: np.ndarray, u: np.ndarray) -> IdentificationUpdate:
        """Identify and decide on the windows one raw push ``z (K, m)``, ``u (K, p)`` completes."""
        return self.handle(self.identifier.push(z, u))

    def handle(self, found: OnlineIdentification) -> IdentificationUpdate:
        """Decide on the windows of ``found`` (the identifier's output for one push)."""
        block = self.decision.update(found)
        out = []
        # the selected hypothesis per window (none identified: "no fault")
        sel = np.full(found.n_windows, -1) if found.result is None else found.result.fit["selected"]
        names = [h.name for h in self.setup.hypotheses]
        decided = np.asarray(found.window_s, dtype=float).reshape(-1, 2)[:, 1] - self.dt  # last samples
        frame_end = self.frame_ends(found)
        nw = found.n_windows
        states = np.array(block.state[:nw], copy=True)  # (windows, P), codes of STATES
        if self.tolerances:
            fault = np.asarray(block.alarm[:nw], dtype=bool)  # (windows, P)
            chan_fault = (self._carried[None, :, :] & fault[:, None, :]).any(axis=2)  # (windows, m)
            alarms = cast(list[bool], fault.any(axis=1).tolist())
            labels: list[str | None] = [
                "+".join(p for p, a in zip(self.parameters, row, strict=True) if a) or None
                for row in fault.tolist()
            ]
        else:
            chan_fault = self._spectral(frame_end)
            alarms = cast(list[bool], chan_fault.any(axis=1).tolist())
            labels = [None] * nw
            for w in np.flatnonzero(alarms).tolist():
                s = int(sel[w])
                labels[w] = NO_FAULT if s == -1 else "unexplained" if s == -2 else names[s]
                if s >= 0:  # the parameters the selected hypothesis names are in fault
                    named = np.array([p in self.setup.hypotheses[s].parameters for p in self.parameters])
                    states[w] = np.where(named, 1, states[w])
        blind = (self._carried[None, :, :] & (states == 2)[:, None, :]).any(axis=2)  # (windows, m)
        chan = np.where(chan_fault, 1, np.where(blind, 2, 0))
        times, spans = found.times_s.tolist(), np.asarray(found.window_s, dtype=float).reshape(-1, 2).tolist()
        decided_s = decided.tolist()
        names_of, chan_of = _state_names(states), _state_names(chan)
        for j in range(nw):
            out.append(
                _window_decision(
                    j, times[j], (spans[j][0], spans[j][1]), decided_s[j], alarms[j], labels[j], names_of[j],
                    chan_of[j],
                )
            )  # fmt: skip
        if found.n_windows:
            last = float(frame_end[-1]) + 0.5 * self.dt
            self._closed = [c for c in self._closed if c[2] > last]
        blind = (self._carried[None, :, :] & ~np.asarray(block.excited, dtype=bool)[:, None, :]).any(axis=-1)
        return IdentificationUpdate(found, block, tuple(out), blind, block.events)

    def parameter_summary(self, block: ParameterDecisions, window: WindowDecision) -> list[dict[str, Any]]:
        """One window of ``block`` per parameter: estimate, interval, band, state, detectable change."""
        from ..jsonout import finite_or_none

        b = self.settings.bands
        j = window.index
        rows = []
        for i, p in enumerate(self.parameters):
            th = float(block.estimate[j, i])
            pos = band_position(float(block.ci_low[j, i]), float(block.ci_high[j, i]), b.low[i], b.high[i])
            rows.append(
                {
                    "parameter": p,
                    "estimate": finite_or_none(th),
                    "ci_low": finite_or_none(float(block.ci_low[j, i])),
                    "ci_high": finite_or_none(float(block.ci_high[j, i])),
                    "std_error": finite_or_none(float(block.std_error[j, i])),
                    "unit": b.units[i],
                    "nominal": float(b.nominal[i]),
                    "tolerance": b.tolerances[i] or None,
                    "position": pos if self.tolerances else None,
                    "score": finite_or_none(float(block.score[j, i])),
                    "state": window.states[i],
                    "detectable": finite_or_none(float(block.detectable[j, i])),
                }
            )
        return rows


def _state_names(codes: np.ndarray) -> list[tuple[str, ...]]:
    """Rows of state codes ``(W, k)`` as tuples of :data:`STATES` names, one tuple per distinct row (a
    push's windows repeat a handful of rows)."""
    if codes.shape[0] == 0:
        return []
    rows, inverse = np.unique(codes, axis=0, return_inverse=True)
    names = [tuple(STATES[k] for k in row) for row in rows.tolist()]
    return [names[i] for i in inverse.reshape(-1).tolist()]


_NEW, _SET = object.__new__, object.__setattr__


def _window_decision(
    index: int, time_s: float, window_s: tuple[float, float], alarm_time_s: float, alarm: bool,
    label: str | None, states: tuple[str, ...], channel_states: tuple[str, ...],
) -> WindowDecision:  # fmt: skip
    """``WindowDecision(...)`` with every field, its instance dict set in one call (a frozen dataclass's
    ``__init__`` sets each field through ``object.__setattr__``: ~1.5 us per window, a replay decides one
    per hop; tests/test_monitor.py checks that both give the same fields)."""
    decision = _NEW(WindowDecision)
    _SET(decision, "__dict__", {
        "index": index, "time_s": time_s, "window_s": window_s, "alarm_time_s": alarm_time_s, "alarm": alarm,
        "label": label, "states": states, "channel_states": channel_states,
    })  # fmt: skip
    return decision


def _carried(setup: IdentificationSetup) -> np.ndarray:
    """``(m, P)`` bool: output channel ``i``'s chattering carries parameter ``k`` (an estimated entry of
    row ``i`` that the parameter moves)."""
    h, idx = joint_hypothesis(setup)
    moves = np.asarray(setup.slopes[h])[:, idx] != 0  # (D, P), table order
    out = np.zeros((setup.model.n_outputs, moves.shape[1]), dtype=bool)
    for a, ch in enumerate(setup.channels):
        out[int(ch)] |= moves[a]
    return out
