"""The channels' lanes: one fault state per channel (:mod:`chatterspec.online.fault_state`), drawn the same
in a file and in a live viewer, at the alarm times of the events.

A lane changes only where the alarm layer's state changes (or the channel's evidence), at the end of the
deciding frame: ``no-evidence`` (grey) from the record's first sample until the first frame is complete,
then ``healthy`` (green) or ``FAULT`` (red). The onset / offset estimate of each alarm (the event's
``estimate_s``) is an annotation of its segment, not a state of its own: a fault segment reads
``"FAULT at <alarm> s, onset est. <onset> s"``, the healthy segment after it
``"healthy at <alarm> s, offset est. <offset> s"`` (labels without the channel, which the viewer writes
above each lane: short segments keep more of their text). Labels belong to state values, so each
alarm episode has its own values (``fault#<k>``, ``healthy#<k>``; :func:`state_of` reads the state back),
in :data:`SLOTS` slots per channel reused in turn: a record with more alarms than that on one channel
shows the labels of the last :data:`SLOTS` (colours stay right).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..online.fault_state import FAULT, HEALTHY, NO_EVIDENCE, STATES, FaultStates, StateChanges
from ..online.monitor import DetectionEvent
from ..palette import FAULT as FAULT_RGB
from ..palette import HEALTHY as HEALTHY_RGB
from ..palette import NO_EVIDENCE as NO_EVIDENCE_RGB
from ..palette import rgba32

__all__ = ["SLOTS", "FaultLanes", "state_of"]

#: Alarm episodes per channel whose labels a lane keeps (see the module docstring).
SLOTS = 64
_COLOR = {HEALTHY: rgba32(HEALTHY_RGB), FAULT: rgba32(FAULT_RGB), NO_EVIDENCE: rgba32(NO_EVIDENCE_RGB)}


_NO_CHANGE: tuple[np.ndarray, np.ndarray, list[str]] = (np.zeros(0), np.zeros(0, dtype=np.intp), [])


def state_of(value: str) -> str:
    """The state (``healthy``, ``fault``, ``no-evidence``) of a lane's value (``fault#3`` -> ``fault``)."""
    return value.split("#", 1)[0]


class FaultLanes:
    """Follows the channels' fault states and turns them into lane changes with labelled episodes.

    Parameters
    ----------
    channels : tuple of str
        Channel names (shown in the labels).
    n_window : int
        STFT window (samples).
    dt : float
        Sampling interval (s).
    """

    def __init__(self, channels: tuple[str, ...], n_window: int, dt: float) -> None:
        self.channels = tuple(channels)
        self.states = FaultStates(len(self.channels), n_window, dt)
        m = len(self.channels)
        self.n_episodes = [0] * m
        # per channel and slot: the labels of the fault segment and of the healthy segment after it
        self._labels: list[list[tuple[str, str] | None]] = [[None] * SLOTS for _ in range(m)]
        self.version = [0] * m  # bumped when a channel's labels change (its configuration is re-sent)
        self.decided = False  # a first frame was decided (no lane is "no evidence" for want of a frame)

    def configuration(self, c: int) -> Any:
        """The lane's ``StateConfiguration`` of channel ``c``: its three states and the labelled episodes."""
        import rerun as rr

        values = [HEALTHY, FAULT, NO_EVIDENCE]
        labels = ["healthy", "FAULT", "no evidence"]
        colors = [_COLOR[v] for v in values]
        for k, pair in enumerate(self._labels[c]):
            if pair is not None:
                values += [f"{FAULT}#{k}", f"{HEALTHY}#{k}"]
                labels += list(pair)
                colors += [_COLOR[FAULT], _COLOR[HEALTHY]]
        return rr.StateConfiguration(values=values, labels=labels, colors=np.array(colors, dtype=np.uint32))

    def start(self, start_s: float) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """Every lane's first state (``no-evidence``) at ``start_s``: (times s, channels, values)."""
        ch = self.states.start(start_s)
        self.decided = False
        return ch.times_s, ch.channel, [STATES[k] for k in ch.code.tolist()]

    def update(
        self,
        times_s: np.ndarray,
        alarm: np.ndarray,
        events: list[DetectionEvent],
        excited: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, list[str]]:
        """The lane changes after a block of frames: (times s, channels, values) in time order.

        Parameters
        ----------
        times_s : (F,) array
            Frame centres (s).
        alarm : (F, m) bool array
            The alarm layer's state after each frame.
        events : list of DetectionEvent
            The block's events (their onset / offset estimates label the episodes).
        excited : (F, m) bool array, optional
            The channels' evidence per frame (:func:`chatterspec.online.fault_state.frame_states`).
        """
        if excited is None and not events and self.decided:
            # without an excitation measure the state changes only where the alarm does, and every alarm
            # change is an event: nothing to compute (the common case, every push of a long stream)
            return _NO_CHANGE
        ch: StateChanges = self.states.update(times_s, alarm, excited)
        self.decided = True
        # the event of a change: same channel, kind and alarm time (both from fault_state.alarm_time)
        by_key = {(ev.channel_index, ev.kind, ev.alarm_time_s): ev for ev in events}
        values = []
        for t, c, k in zip(ch.times_s.tolist(), ch.channel.tolist(), ch.code.tolist(), strict=True):
            state = STATES[k]
            if state == FAULT:
                ev = by_key.get((c, "fault-start", t))
                slot = self.n_episodes[c] % SLOTS
                self.n_episodes[c] += 1
                onset = "" if ev is None else f", onset est. {ev.estimate_s:.2f} s"
                self._labels[c][slot] = (f"FAULT at {t:.2f} s{onset}", "healthy")
                self.version[c] += 1
                values.append(f"{FAULT}#{slot}")
            elif state == HEALTHY and self.n_episodes[c]:
                ev = by_key.get((c, "fault-end", t))
                slot = (self.n_episodes[c] - 1) % SLOTS
                pair = self._labels[c][slot]
                if ev is None or pair is None or not np.isfinite(ev.estimate_s):
                    values.append(HEALTHY)
                    continue
                offset = f"healthy at {t:.2f} s, offset est. {ev.estimate_s:.2f} s"
                self._labels[c][slot] = (pair[0], offset)
                self.version[c] += 1
                values.append(f"{HEALTHY}#{slot}")
            else:
                values.append(state)
        return ch.times_s, ch.channel, values
