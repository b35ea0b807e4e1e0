"""The events and lanes of a recording: the event log (``/events``), the fault intervals, the channels'
fault lanes and the true fault lane of a simulated record.

The event log: one row per alarm raised or cleared, at its alarm time (the end of the deciding frame or
window, when the detector knew: where the channel's lane changes too), each naming that time and the
onset / offset estimate. With tolerances the parameters' alarms are the faults
(:func:`parameter_event_text`) and the spectral detector's alarms are rows of *mismatch* (information,
not a fault). Rows are logged one per call (:func:`log_text_rows`): Rerun 0.41 shows wrong levels (an
``ERROR`` row as ``WARN`` or ``INFO``) for rows sent as one multi-row chunk after earlier single rows of
the same entity.

The fault intervals of a recorded file (:class:`IntervalCollector`): the window-extent onset/offset
estimates of its flagged frames, the numbers of ``detect --json``'s ``intervals`` and Fig 8, logged as
events at their onsets. The estimator is :func:`chatterspec.detection.verdicts.frame_intervals` applied to
the per-frame flags and statistic ``max S / threshold`` of each channel, with the healthy median
:func:`chatterspec.detection.verdicts.healthy_frame_level` of the frame threshold. They annotate the
channel's fault state; the state itself (the lanes) is the alarm layer's (:class:`FaultLanes`).

The channels' lanes (:class:`FaultLanes`): one fault state per channel
(:mod:`chatterspec.online.fault_state`), drawn the same in a file and in a live viewer, at the alarm
times of the events. A lane changes only where the run's decision or the channel's evidence changes, at
the time it was known: ``no-evidence`` (grey, "no evidence") from the record's first sample until the
first decision, then ``healthy`` (green), ``FAULT`` (red) or, where identification runs, ``no-evidence``
again while the channel is not excited (grey, "not excited"). What the lane follows
(:meth:`FaultLanes.follow_identification` sets the mode):

* **no identification**: the spectral alarm layer, frame by frame, changing at the frames' alarm times
  (:meth:`FaultLanes.update`);
* **identification without tolerances**: the spectral alarm at the frames' alarm times, and the
  channel's excitation (:attr:`~chatterspec.online.identification_monitor.IdentificationUpdate.
  not_excited`) at the identification windows' last samples (:meth:`FaultLanes.follow`; a frame is
  drawn once the window before it is known: until the first window a channel without alarm has no
  evidence);
* **identification with tolerances**: the windows' channel states (the parameters' alarms on the
  parameters the channel carries, and the excitation) at the windows' last samples; the spectral alarm
  is then a *mismatch*, a row of the event log, not a state.

The onset / offset estimate of each spectral alarm (the event's ``estimate_s``) is an annotation of its
segment, not a state of its own: a fault segment reads ``"FAULT at <alarm> s, onset est. <onset> s"``, the
healthy segment after it ``"healthy at <alarm> s, offset est. <offset> s"``; with tolerances the fault
segment names the parameters in alarm (``"FAULT at <alarm> s: leakage"``). Labels are without the channel,
which the viewer writes above each lane: short segments keep more of their text. Labels belong to state
values, so each alarm episode has its own values (``fault#<k>``, ``healthy#<k>``; :func:`state_of` reads
the state back), in :data:`SLOTS` slots per channel reused in turn: a record with more alarms than that
on one channel shows the labels of the last :data:`SLOTS` (colours stay right).

The true fault lane of a simulated recording (``/state/0_truth``, :func:`log_truth_lane`) and its
colours (:func:`truth_colors`): each true fault level gets its own amber (never red: red is a verdict),
healthy segments grey; the mode lanes of a diagnosis take the same colours by label, so that a mode lane
naming a true segment reads like the truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from ..detection.thresholds import db_over_threshold, two_bins_text
from ..detection.verdicts import frame_intervals, healthy_frame_level
from ..online.fault_state import FAULT, HEALTHY, NO_EVIDENCE, STATES, FaultStates, StateChanges
from ..online.monitor import DetectionEvent
from ..palette import FAULT as FAULT_RGB
from ..palette import HEALTHY as HEALTHY_RGB
from ..palette import NEUTRAL, fault_level_color, rgba32
from ..palette import NO_EVIDENCE as NO_EVIDENCE_RGB
from .blueprint import TRUTH_LANE
from .sinks import TIMELINE
from .spectrograms import to_ns

if TYPE_CHECKING:  # pragma: no cover
    from rerun import RecordingStream, StateConfiguration

    from ..detection.parameter_decision import ParameterEvent
    from ..online.identification_monitor import IdentificationUpdate

__all__ = [
    "EVENTS",
    "NOT_EXCITED",
    "SLOTS",
    "Changes",
    "FaultInterval",
    "FaultLanes",
    "IntervalCollector",
    "alarm_event_text",
    "interval_text",
    "log_text_rows",
    "log_truth_lane",
    "parameter_event_text",
    "send_alarm_events",
    "send_interval_events",
    "send_parameter_events",
    "state_of",
    "truth_colors",
]


#: Entity of the event log.
EVENTS = "/events"
#: Levels of the log rows: an alarm raised is a fault (red), everything else information.
ALARM_LEVEL, INFO_LEVEL = "ERROR", "INFO"


def alarm_event_text(ev: DetectionEvent, *, decides: bool = True) -> str:
    """Short, most important first (the log view cuts long bodies): when (the alarm time, end of the
    deciding frame), channel and what happened, the onset / offset estimate, then the bin and the rule.

    Parameters
    ----------
    ev : DetectionEvent
    decides : bool
        The spectral alarm is the run's fault decision; False (tolerances): a mismatch.

    Returns
    -------
    str
    """
    db = db_over_threshold(ev.peak_ratio)
    start = ev.kind == "fault-start"
    if decides:
        what = "ALARM" if start else "alarm cleared"
    else:
        what = "mismatch (tolerances decide)" if start else "mismatch over"
    est = "onset" if start else "offset"
    return (
        f"{ev.alarm_time_s:.2f} s {ev.channel} {what} ({est} est. {ev.estimate_s:.2f} s), "
        f"{ev.peak_hz:.1f} Hz {db:+.0f} dB, {ev.rule}"
    )


def parameter_event_text(ev: ParameterEvent) -> str:
    """A parameter's alarm raised or cleared (tolerances): its alarm time (the end of the deciding
    identification window), the parameter and its estimate against its band, then the rule.

    Parameters
    ----------
    ev : ParameterEvent

    Returns
    -------
    str
    """
    from ..detection.parameter_decision import band_position, status_text

    what = "ALARM" if ev.kind == "fault-start" else "alarm cleared"
    pos = band_position(ev.ci_low, ev.ci_high, *ev.band)
    st = status_text(ev.parameter, ev.estimate, ev.std_error, (ev.ci_low, ev.ci_high), ev.nominal, ev.unit,
                     ev.tolerance, pos)  # fmt: skip
    return f"{ev.alarm_time_s:.2f} s {ev.parameter} {what}: {st.removeprefix(ev.parameter + ' ')}, {ev.rule}"


def log_text_rows(
    stream: RecordingStream,
    entity: str,
    times_s: Sequence[float] | np.ndarray,
    texts: list[str],
    levels: list[str],
) -> None:
    """Log text rows one per call (see the module docstring) at ``times_s`` (:func:`to_ns`).

    Parameters
    ----------
    stream : rerun.RecordingStream
    entity : str
    times_s : sequence of float
        Row times (s).
    texts, levels : list of str
    """
    import rerun as rr

    for ns, text, level in zip(to_ns(np.asarray(times_s, dtype=float)).tolist(), texts, levels, strict=True):
        stream.set_time(TIMELINE, duration=np.timedelta64(int(ns), "ns"))
        stream.log(entity, rr.TextLog(text, level=level))


def send_alarm_events(stream: RecordingStream, events: list[DetectionEvent], *, decides: bool = True) -> None:
    """Log ``events`` to ``stream``'s event log at their alarm times.

    Parameters
    ----------
    stream : rerun.RecordingStream
    events : list of DetectionEvent
    decides : bool
        The spectral alarm is the run's fault decision (an alarm raised is an ``ERROR`` row); False
        (tolerances): every row is information (:func:`alarm_event_text`).
    """
    log_text_rows(
        stream,
        EVENTS,
        [ev.alarm_time_s for ev in events],
        [alarm_event_text(ev, decides=decides) for ev in events],
        [ALARM_LEVEL if decides and ev.kind == "fault-start" else INFO_LEVEL for ev in events],
    )


def send_parameter_events(stream: RecordingStream, events: Sequence[ParameterEvent]) -> None:
    """Log the parameters' alarm ``events`` (tolerances) to ``stream``'s event log at their alarm times.

    Parameters
    ----------
    stream : rerun.RecordingStream
    events : sequence of ParameterEvent
    """
    log_text_rows(
        stream,
        EVENTS,
        [ev.alarm_time_s for ev in events],
        [parameter_event_text(ev) for ev in events],
        [ALARM_LEVEL if ev.kind == "fault-start" else INFO_LEVEL for ev in events],
    )


# -------------------------------------------------------------------- the fault intervals of a file


def interval_text(onset_s: float, offset_s: float) -> str:
    """``"0.00-2.00 s"``, or ``"2.60 s"`` for an interval of zero length at two decimals.

    Parameters
    ----------
    onset_s, offset_s : float
        The interval (s).
    """
    on, off = f"{onset_s:.2f}", f"{offset_s:.2f}"
    return f"{on} s" if on == off else f"{on}-{off} s"


@dataclass(frozen=True)
class FaultInterval:
    """One estimated fault interval of one channel.

    Attributes
    ----------
    channel_index : int
    onset_s, offset_s : float
        Window-extent estimates (s), as ``detect --json``'s ``intervals``.
    peak_hz : float
        The most significant bin (largest ``S / threshold``, the detector's peak) of the interval's frame
        with the largest ``S / threshold`` (Hz).
    peak_db : float
        That largest ``10 log10(S / threshold)`` (dB).
    excess_hz : float
        In that frame, the bin of largest excess power ``S - E`` among the bins over the threshold (Hz;
        :mod:`chatterspec.detection.thresholds`).
    excess_db : float
        Its ``10 log10(S / threshold)`` (dB).
    """

    channel_index: int
    onset_s: float
    offset_s: float
    peak_hz: float
    peak_db: float
    excess_hz: float = float("nan")
    excess_db: float = float("nan")

    def describe(self, channel: str) -> str:
        """``"<onset>-<offset> s <channel> flagged frames (estimate), <two bins>"`` (``<onset> s`` for an
        estimate of zero length): times and channel first
        (the viewer's log view cuts long lines), both bins labelled (:func:`~chatterspec.detection.
        thresholds.two_bins_text`)."""
        bins = two_bins_text(self.peak_hz, self.peak_db, self.excess_hz, self.excess_db)
        return f"{interval_text(self.onset_s, self.offset_s)} {channel} flagged frames (estimate), {bins}"


@dataclass
class IntervalCollector:
    """Keeps the per-frame flags, statistic and the two peak bins of a record (``17 m`` bytes per frame) and
    estimates its fault intervals at the end.

    Parameters
    ----------
    monitor : ChatteringMonitor
        Gives the STFT settings, the sampling time and the frame threshold.
    """

    monitor: Any
    _flags: list[np.ndarray] = field(default_factory=list)
    _ratio: list[np.ndarray] = field(default_factory=list)
    _hz: list[np.ndarray] = field(default_factory=list)
    _times: list[np.ndarray] = field(default_factory=list)
    _excess: list[np.ndarray] = field(default_factory=list)

    def add(
        self,
        times: np.ndarray,
        flags: np.ndarray,
        ratio: np.ndarray,
        peak_hz: np.ndarray,
        excess_hz: np.ndarray | None = None,
        excess_ratio: np.ndarray | None = None,
    ) -> None:
        """Append frames: centre times (F,) s, flags (F, m), ``max S / threshold`` (F, m), the most
        significant bin (F, m) Hz (largest ``S / threshold``) and, optionally, the bin of largest excess
        ``S - E`` among the bins over the threshold (F, m) Hz with its ``S / threshold`` (F, m) (the
        logger's ``peak_hz``; NaN when not given)."""
        if len(times):
            self._flags.append(np.asarray(flags, dtype=bool))
            self._ratio.append(np.asarray(ratio, dtype=np.float32))
            self._hz.append(np.asarray(peak_hz, dtype=np.float32))
            self._times.append(np.asarray(times, dtype=float))
            nan = np.full(np.shape(flags), np.nan, dtype=np.float32)
            ex_hz = nan if excess_hz is None else np.asarray(excess_hz, dtype=np.float32)
            ex_r = nan if excess_ratio is None else np.asarray(excess_ratio, dtype=np.float32)
            self._excess.append(np.stack([ex_hz, ex_r], axis=-1))  # (F, m, 2)

    def frames(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """All frames so far: (times (F,) s, flags (F, m), peak_hz (F, m) Hz)."""
        if not self._flags:
            return np.zeros(0), np.zeros((0, 0), dtype=bool), np.zeros((0, 0))
        return np.concatenate(self._times), np.concatenate(self._flags), np.concatenate(self._hz)

    def intervals(self) -> list[FaultInterval]:
        """The record's fault intervals, channel by channel in time order (zero-length ones included).

        Returns
        -------
        list of FaultInterval
        """
        if not self._flags:
            return []
        mon = self.monitor
        flags, ratio = np.concatenate(self._flags), np.concatenate(self._ratio).astype(float)
        hz, times = np.concatenate(self._hz), np.concatenate(self._times)
        excess = np.concatenate(self._excess).astype(float)  # (F, m, 2): Hz, S / threshold
        level = healthy_frame_level(mon.threshold)
        out = []
        for c in range(flags.shape[1]):
            runs = _runs(flags[:, c])
            ivs = frame_intervals(flags[:, c], times, mon.settings.stft, mon.dt, ratio[:, c], level)
            for (a, b), (on, off) in zip(runs, ivs, strict=True):
                k = a + int(np.argmax(ratio[a:b, c]))
                db = db_over_threshold(ratio[k, c])
                ex_hz, ex_r = excess[k, c]
                ex_db = db_over_threshold(ex_r) if np.isfinite(ex_r) else float("nan")
                out.append(FaultInterval(c, on, off, float(hz[k, c]), float(db), float(ex_hz), ex_db))
        return out


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``[start, stop)`` frame ranges of the runs of flagged frames (as :func:`frame_intervals` merges)."""
    padded = np.concatenate(([False], flags, [False]))
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]


def send_interval_events(
    file: RecordingStream, intervals: list[FaultInterval], channels: tuple[str, ...]
) -> None:
    """Log one event per fault interval of a file at its onset estimate (:meth:`FaultInterval.describe`:
    both bins named), in time order: the window-extent estimates of ``detect --json``'s ``intervals``,
    which annotate the lanes' alarm episodes (the lanes show the alarm state,
    :mod:`~chatterspec.viewer.events`).

    Parameters
    ----------
    file : rerun.RecordingStream
    intervals : list of FaultInterval
        :meth:`IntervalCollector.intervals`.
    channels : tuple of str
    """
    order = sorted(intervals, key=lambda iv: iv.onset_s)
    text = [iv.describe(channels[iv.channel_index]) for iv in order]
    log_text_rows(file, EVENTS, [iv.onset_s for iv in order], text, [INFO_LEVEL] * len(text))


# ------------------------------------------------------------------------ the channels' fault lanes

#: Alarm episodes per channel whose labels a lane keeps (see the module docstring).
SLOTS = 64
#: The lane value of a channel that is not excited: the ``no-evidence`` state, labelled "not excited".
NOT_EXCITED = f"{NO_EVIDENCE}#not-excited"
_COLOR = {HEALTHY: rgba32(HEALTHY_RGB), FAULT: rgba32(FAULT_RGB), NO_EVIDENCE: rgba32(NO_EVIDENCE_RGB)}

#: Lane changes: (times s, channel indices, lane values), in time order.
Changes = tuple[np.ndarray, np.ndarray, list[str]]
_NO_CHANGE: Changes = (np.zeros(0), np.zeros(0, dtype=np.intp), [])


def state_of(value: str) -> str:
    """The state (``healthy``, ``fault``, ``no-evidence``) of a lane's value (``fault#3`` -> ``fault``)."""
    return value.split("#", 1)[0]


class FaultLanes:
    """Follows the channels' fault states and turns them into lane changes with labelled episodes.

    Parameters
    ----------
    channels : tuple of str
        Channel names.
    n_window, n_hop : int
        STFT window and hop (samples).
    dt : float
        Sampling interval (s).
    """

    def __init__(self, channels: tuple[str, ...], n_window: int, n_hop: int, dt: float) -> None:
        self.channels = tuple(channels)
        self.states = FaultStates(len(self.channels), n_window, dt)
        self.n_hop, self.dt = int(n_hop), float(dt)
        m = len(self.channels)
        self.n_episodes = [0] * m
        # per channel and slot: the labels of the fault segment and of the healthy segment after it
        self._labels: list[list[tuple[str, str] | None]] = [[None] * SLOTS for _ in range(m)]
        self.version = [0] * m  # bumped when a channel's labels change (its configuration is re-sent)
        self.decided = False  # a first decision was drawn (no lane is "no evidence" for want of one)
        self._start_ns: int | None = None  # the record's start: decisions before it are not drawn
        # spectral events until their frame is drawn (their estimates label the episodes)
        self._events: dict[tuple[int, str, int], DetectionEvent] = {}
        # identification (follow_identification): None, "excitation" (no tolerances), "parameters"
        self.mode: str | None = None
        self._parameters: tuple[str, ...] = ()
        self._carried = np.zeros((m, 0), dtype=bool)
        # "excitation": frames and windows waiting to be drawn in time order, and what is known
        self._frames: list[tuple[np.ndarray, np.ndarray]] = []  # (alarm times (F,), alarm (F, m))
        self._windows: list[tuple[np.ndarray, np.ndarray]] = []  # (last samples (W,), not excited (W, m))
        self._last_window_s = -np.inf  # the latest window seen
        self._alarm = np.zeros(m, dtype=bool)
        self._blind = np.ones(m, dtype=bool)  # no window yet: no evidence without an alarm

    def follow_identification(
        self, *, tolerances: bool, parameters: tuple[str, ...], carried: np.ndarray
    ) -> None:
        """Follow an identification monitor's windows (module docstring).

        Parameters
        ----------
        tolerances : bool
            The parameters decide (their alarms are the faults), else the spectral alarm.
        parameters : tuple of str
            The declared parameters (table order).
        carried : (m, P) bool array
            Channel ``i``'s chattering carries parameter ``k`` (the parameters a fault segment names).
        """
        self.mode = "parameters" if tolerances else "excitation"
        self._parameters, self._carried = tuple(parameters), np.asarray(carried, dtype=bool)

    def configuration(self, c: int) -> StateConfiguration:
        """The lane's ``StateConfiguration`` of channel ``c``: its three states and the labelled episodes."""
        import rerun as rr

        values = [HEALTHY, FAULT, NO_EVIDENCE, NOT_EXCITED]
        labels = ["healthy", "FAULT", "no evidence", "not excited"]
        colors = [_COLOR[state_of(v)] for v in values]
        for k, pair in enumerate(self._labels[c]):
            if pair is not None:
                values += [f"{FAULT}#{k}", f"{HEALTHY}#{k}"]
                labels += list(pair)
                colors += [_COLOR[FAULT], _COLOR[HEALTHY]]
        return rr.StateConfiguration(values=values, labels=labels, colors=np.array(colors, dtype=np.uint32))

    def start(self, start_s: float) -> Changes:
        """Every lane's first state (``no-evidence``) at ``start_s``: (times s, channels, values)."""
        ch = self.states.start(start_s)
        self.decided = False
        self._start_ns = int(to_ns(start_s))
        return ch.times_s, ch.channel, [STATES[k] for k in ch.code.tolist()]

    def update(
        self,
        times_s: np.ndarray,
        alarm: np.ndarray,
        events: list[DetectionEvent],
        excited: np.ndarray | None = None,
    ) -> Changes:
        """The lane changes after a block of STFT frames: (times s, channels, values) in time order (with
        identification, those that the windows known so far allow: :meth:`follow`).

        Parameters
        ----------
        times_s, alarm : arrays
            Frame centres (F,) and alarm states (F, m), as in
            :meth:`~chatterspec.online.fault_state.FaultStates.update`.
        events : list of DetectionEvent
            The block's events (their onset / offset estimates label the episodes).
        excited : (F, m) bool array, optional
            The channels' evidence per frame without identification
            (:func:`chatterspec.online.fault_state.frame_states`).
        """
        if self.mode == "parameters":  # the spectral alarm is a mismatch: not a state
            return _NO_CHANGE
        if self.mode == "excitation":
            self._note_events(events)
            self._frames.append((self.states.frame_ends(times_s), np.asarray(alarm, dtype=bool)))
            return self._drain(final=False)
        if excited is None and not events and self.decided:
            # without an excitation measure the state changes only where the alarm does, and every alarm
            # change is an event: nothing to compute (the common case, every push of a long stream)
            return _NO_CHANGE
        self._note_events(events)
        out = self._changes(self.states.update(times_s, alarm, excited), None)
        self.decided = True
        self._events.clear()  # a frame's events decide its own changes
        return out

    def follow(self, upd: IdentificationUpdate) -> Changes:
        """The lane changes after one push's identification windows (:meth:`follow_identification` first):
        (times s, channels, values) in time order; decisions before the record's start (a rotated file's)
        are not drawn.

        Parameters
        ----------
        upd : IdentificationUpdate
            The windows' states, excitation and alarm times (their last samples).
        """
        if not upd.windows or self.mode is None:
            return _NO_CHANGE
        if self.mode == "excitation":
            times = np.array([w.alarm_time_s for w in upd.windows], dtype=float)
            self._windows.append((times, np.asarray(upd.not_excited, dtype=bool)))
            self._last_window_s = float(times[-1])
            return self._drain(final=False)
        times, codes = upd.channel_codes()
        keep = self._after_start(times)
        if not keep.any():
            return _NO_CHANGE
        ch = self.states.follow(times[keep], codes[keep])
        self.decided = True
        return self._changes(ch, _Named(upd, self._parameters, self._carried))

    def finish(self) -> Changes:
        """The lane changes of the frames still waiting for a window (the record's end: no window comes)."""
        return self._drain(final=True) if self.mode == "excitation" else _NO_CHANGE

    def _after_start(self, times: np.ndarray) -> np.ndarray:
        if self._start_ns is None:
            return np.ones(times.size, dtype=bool)
        return to_ns(times) >= self._start_ns

    def _drain(self, *, final: bool) -> Changes:
        """Draw the waiting frames (alarm) and windows (excitation) in time order, a frame once the window
        one hop before it is known (that is what was known at its alarm time), unless ``final``."""
        if not self._frames and not self._windows:
            return _NO_CHANGE
        m = len(self.channels)
        queued = [
            (kind, at, rows) for kind, queue in ((0, self._frames), (1, self._windows)) for at, rows in queue
        ]
        t_all = np.concatenate([np.asarray(at, dtype=float) for _, at, _ in queued])
        kinds = np.concatenate([np.full(len(at), kind, dtype=np.int8) for kind, at, _ in queued])
        rows = np.concatenate([np.asarray(r, dtype=bool).reshape(-1, m) for _, _, r in queued])
        order = np.lexsort((kinds, t_all))  # time order, a frame before a window at the same time (stable)
        t_all, kinds, rows = t_all[order], kinds[order], rows[order]
        # the window one hop before a frame ends (n_hop - 1) samples before the frame's alarm time
        known = self._last_window_s + (self.n_hop - 0.5) * self.dt
        late = np.flatnonzero((kinds == 0) & (t_all > known)) if not final else np.empty(0, dtype=np.intp)
        done = int(late[0]) if late.size else t_all.size
        rest = np.arange(done, t_all.size)
        later = [rest[kinds[rest] == kind] for kind in (0, 1)]  # the items kept for the next drain
        self._frames, self._windows = ([(t_all[i], rows[i])] if rest.size else [] for i in later)
        if not done:
            return _NO_CHANGE
        # each drawn item's state: the last frame's alarm and the last window's blindness at or before it
        alarm, blind = (
            self._held(kinds[:done] == 0, rows, self._alarm),
            self._held(kinds[:done] == 1, rows, self._blind),
        )
        self._alarm, self._blind = alarm[-1], blind[-1]
        codes = np.where(alarm, 1, np.where(blind, 2, 0)).astype(np.int8)
        t_arr = t_all[:done]
        keep = self._after_start(t_arr)
        if not keep.any():
            return _NO_CHANGE
        ch = self.states.follow(t_arr[keep], codes[keep])
        self.decided = True
        out = self._changes(ch, None)
        last = int(to_ns(t_arr[-1]))
        self._events = {k: v for k, v in self._events.items() if k[2] > last}
        return out

    @staticmethod
    def _held(mine: np.ndarray, rows: np.ndarray, before: np.ndarray) -> np.ndarray:
        """Per item, the row of the last item at or before it for which ``mine`` holds (``before`` until
        the first): a forward fill over the (items, m) ``rows``."""
        last = np.maximum.accumulate(np.where(mine, np.arange(mine.size), -1))
        return np.where((last >= 0)[:, None], rows[np.maximum(last, 0)], before[None, :])

    def _note_events(self, events: list[DetectionEvent]) -> None:
        for ev in events:
            self._events[(ev.channel_index, ev.kind, int(to_ns(ev.alarm_time_s)))] = ev

    def _changes(self, ch: StateChanges, named: _Named | None) -> Changes:
        """Lane values of the changes ``ch``: the fault and healthy segments of an episode get labelled
        values (the spectral events' estimates; with tolerances, ``named``, the parameters in alarm that
        the channel carries), no evidence after the first decision reads "not excited"."""
        values = []
        for t, c, k in zip(ch.times_s.tolist(), ch.channel.tolist(), ch.code.tolist(), strict=True):
            state = STATES[k]
            ns = int(to_ns(t))
            if state == FAULT:
                slot = self.n_episodes[c] % SLOTS
                self.n_episodes[c] += 1
                if named is not None:
                    what = named.parameters_of(c, ns)
                    what = f": {what}" if what else ""
                else:
                    ev = self._events.get((c, "fault-start", ns))
                    what = "" if ev is None else f", onset est. {ev.estimate_s:.2f} s"
                self._labels[c][slot] = (f"FAULT at {t:.2f} s{what}", "healthy")
                self.version[c] += 1
                values.append(f"{FAULT}#{slot}")
            elif state == HEALTHY and self.n_episodes[c]:
                slot = (self.n_episodes[c] - 1) % SLOTS
                pair = self._labels[c][slot]
                ev = self._events.get((c, "fault-end", ns))
                estimated = ev is not None and bool(np.isfinite(ev.estimate_s))
                if pair is None or (named is None and not estimated):
                    values.append(HEALTHY)
                    continue
                offset = f", offset est. {ev.estimate_s:.2f} s" if ev is not None and estimated else ""
                self._labels[c][slot] = (pair[0], f"healthy at {t:.2f} s{offset}")
                self.version[c] += 1
                values.append(f"{HEALTHY}#{slot}")
            elif state == NO_EVIDENCE and self.decided:
                values.append(NOT_EXCITED)
            else:
                values.append(state)
        return ch.times_s, ch.channel, values


class _Named:
    """The parameters in alarm at each decision of an identification push (tolerances), for the labels of
    the fault segments: those a channel carries."""

    def __init__(self, upd: IdentificationUpdate, parameters: tuple[str, ...], carried: np.ndarray) -> None:
        self.parameters, self.carried = parameters, carried
        self.at = {int(to_ns(w.alarm_time_s)): [s == FAULT for s in w.states] for w in upd.windows if w.alarm}

    def parameters_of(self, c: int, ns: int) -> str:
        """``"leakage+friction"``: the parameters in alarm at ``ns`` that channel ``c`` carries."""
        flags = self.at.get(ns, [])
        mine = [p for p, a, k in zip(self.parameters, flags, self.carried[c], strict=False) if a and k]
        return "+".join(mine)


# ------------------------------------------------------------------------------ the true fault lane


def truth_colors(truth: list[tuple[float, str, bool]]) -> dict[str, int]:
    """Lane colours by label (``0xRRGGBBAA``): the k-th fault label in order of appearance
    ``fault_level_color(k)``, healthy labels :data:`~chatterspec.palette.NEUTRAL`.

    Parameters
    ----------
    truth : list of (start_s, label, is_fault)
        The true timeline (:func:`~chatterspec.viewer.recordings.scenario_truth`).

    Returns
    -------
    dict of str to int
    """
    out: dict[str, int] = {}
    k = 0
    for _, label, fault in truth:
        if label not in out:
            out[label] = rgba32(fault_level_color(k) if fault else NEUTRAL)
            k += bool(fault)
    return out


def log_truth_lane(streams: list[Any], truth: list[tuple[float, str, bool]]) -> None:
    """Log the true fault lane to ``streams``: its labels and colours (static), one state change per
    segment at its start (integer ns, :func:`~chatterspec.viewer.spectrograms.to_ns`).

    Parameters
    ----------
    streams : list of rerun.RecordingStream
    truth : list of (start_s, label, is_fault)
    """
    import rerun as rr

    colors = truth_colors(truth)
    labels = list(colors)
    ns = to_ns([start for start, _, _ in truth]).astype("timedelta64[ns]")
    for s in streams:
        s.log(
            TRUTH_LANE,
            rr.StateConfiguration(
                values=labels,
                labels=[f"true plant: {lab}" for lab in labels],
                colors=np.array([colors[lab] for lab in labels], dtype=np.uint32),
            ),
            static=True,
        )
        s.send_columns(
            TRUTH_LANE,
            indexes=[rr.TimeColumn(TIMELINE, duration=ns)],
            columns=rr.StateChange.columns(state=[lab for _, lab, _ in truth]),
        )
