"""One fault state per channel: what the recording's lanes, the events, the JSON and the live view show.

The state of a channel is the **run's fault decision**, with three values:

``fault``
    the decision's alarm is raised (from the ``fault-start`` event to the ``fault-end`` event);
``healthy``
    no alarm, and the data could show one;
``no-evidence``
    no alarm, but the data cannot tell: before the first window of a record is decided (the detector
    has seen no window yet), and wherever the channel is **not excited**.

Which decision, and which excitation, depends on what runs beside the spectral monitor:

* **Identification runs** (a linear model with declared parameters: the
  :class:`~chatterspec.online.identification_monitor.IdentificationMonitor`): a channel is not excited
  when a parameter its chattering carries is not excited, i.e. the change the data of the last few
  seconds would detect exceeds the parameter's tolerance (without one, its nominal value:
  :mod:`chatterspec.detection.parameter_decision`). The fault is the spectral alarm layer's (the run's
  rule and false-alarm budget, :mod:`chatterspec.detection.alarms.streams`) without tolerances, and the
  parameters' alarm on a parameter the channel carries with tolerances (the spectral detector then
  only reports mismatch). Per window:
  :attr:`~chatterspec.online.identification_monitor.WindowDecision.channel_states`, followed with
  :meth:`FaultStates.follow`.
* **No identification** (a nonlinear model, a model without declared parameters, precomputed
  chattering, ``--no-identify``): the spectral alarm layer's state per frame, and no excitation
  measure: every frame counts as excited, so only the first window reads ``no-evidence``
  (:meth:`FaultStates.update`; :func:`frame_states` takes an ``excited`` mask where a caller has one).

Every change happens at an **alarm time**, when the deciding layer knew: the last sample of the deciding
STFT frame (:func:`alarm_time`; a ``DetectionEvent``'s ``alarm_time_s``), or with tolerances the last
sample of the deciding identification window (a ``ParameterEvent``'s ``alarm_time_s``). The
window-extent onset / offset estimates (``estimate_s`` of an event, ``detect --json``'s ``intervals``)
are annotations of the same episode, never a second state.

:class:`FaultStates` follows the state window by window (a live stream or a whole record alike) and
returns only its changes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "FAULT",
    "HEALTHY",
    "NO_EVIDENCE",
    "STATES",
    "FaultStates",
    "StateChanges",
    "alarm_time",
    "frame_states",
]

HEALTHY = "healthy"
FAULT = "fault"
NO_EVIDENCE = "no-evidence"
#: The state values, indexed by the codes of :func:`frame_states` (0 healthy, 1 fault, 2 no evidence); the
#: same codes as the identification's parameter and channel states
#: (:data:`chatterspec.detection.parameter_decision.STATES`, whose code 2 is "not excited").
STATES = (HEALTHY, FAULT, NO_EVIDENCE)


def alarm_time(frame_centre_s: float, n_window: int, dt: float) -> float:
    """When the alarm layer decides on a frame: its last sample (s).

    Parameters
    ----------
    frame_centre_s : float
        Centre time of the frame (s).
    n_window : int
        Window length in samples.
    dt : float
        Sampling interval (s).

    Returns
    -------
    float
        ``frame_centre_s + (n_window - 1) dt / 2``.
    """
    return float(frame_centre_s) + (n_window - 1) / 2.0 * dt


def frame_states(alarm: np.ndarray, excited: np.ndarray | None = None) -> np.ndarray:
    """The state code of each frame and channel: 1 where the alarm is raised, else 2 where the channel is
    not excited, else 0.

    Parameters
    ----------
    alarm : (F, m) bool array
        The alarm layer's state after each frame (``FrameBlock.alarm``).
    excited : (F, m) bool array, optional
        Whether each frame could show the fault (the detectability of the run); None: every frame.

    Returns
    -------
    (F, m) int8 array
        Codes into :data:`STATES`.
    """
    codes = np.asarray(alarm, dtype=np.int8).copy()
    if excited is not None:
        codes[(codes == 0) & ~np.asarray(excited, dtype=bool)] = 2
    return codes


@dataclass(frozen=True)
class StateChanges:
    """The state changes of one block of frames, in time order.

    Attributes
    ----------
    times_s : (n,) array
        Alarm times of the changes (s; :func:`alarm_time` of the deciding frame).
    channel : (n,) int array
        Channel index of each change.
    code : (n,) int8 array
        New state (index into :data:`STATES`).
    """

    times_s: np.ndarray
    channel: np.ndarray
    code: np.ndarray

    def of(self, c: int) -> tuple[np.ndarray, list[str]]:
        """(times s, state values) of channel ``c``."""
        mine = self.channel == c
        return self.times_s[mine], [STATES[k] for k in self.code[mine].tolist()]


class FaultStates:
    """The fault state of every channel, followed decision by decision (STFT frames or identification
    windows).

    Parameters
    ----------
    n_channels : int
    n_window : int
        STFT window (samples).
    dt : float
        Sampling interval (s).

    Notes
    -----
    Before the first decision the state is ``no-evidence`` from the first window's first sample (the
    record's start, :meth:`start`).
    """

    def __init__(self, n_channels: int, n_window: int, dt: float) -> None:
        self.n_window, self.dt = int(n_window), float(dt)
        self.code = np.full(int(n_channels), 2, dtype=np.int8)

    def start(self, start_s: float) -> StateChanges:
        """Every channel ``no-evidence`` from ``start_s`` (the first window's start) to its first decision."""
        m = self.code.size
        self.code = np.full(m, 2, dtype=np.int8)
        return StateChanges(np.full(m, float(start_s)), np.arange(m), self.code.copy())

    def update(
        self, times_s: np.ndarray, alarm: np.ndarray, excited: np.ndarray | None = None
    ) -> StateChanges:
        """The changes after the STFT frames centred at ``times_s`` (F,) with alarm states (F, m).

        Parameters
        ----------
        times_s : (F,) array
            Frame centres (s).
        alarm : (F, m) bool array
            The alarm layer's state after each frame.
        excited : (F, m) bool array, optional
            See :func:`frame_states`.

        Returns
        -------
        StateChanges
            One entry per channel and frame whose state differs from the one before, at that frame's
            alarm time.
        """
        return self.follow(self.frame_ends(times_s), frame_states(alarm, excited))

    def frame_ends(self, times_s: np.ndarray) -> np.ndarray:
        """The alarm times (last samples, s) of the frames centred at ``times_s`` (:func:`alarm_time`)."""
        return np.asarray(times_s, dtype=float) + (self.n_window - 1) / 2.0 * self.dt

    def follow(self, decided_s: np.ndarray, codes: np.ndarray) -> StateChanges:
        """The changes after decisions taken at ``decided_s`` (W,) with state codes (W, m).

        Parameters
        ----------
        decided_s : (W,) array
            When each decision was taken (s): its alarm time.
        codes : (W, m) int array
            Codes into :data:`STATES`.

        Returns
        -------
        StateChanges
            One entry per channel and decision whose state differs from the one before.
        """
        codes = np.asarray(codes, dtype=np.int8)
        if codes.shape[0] == 0:
            return StateChanges(np.zeros(0), np.zeros(0, dtype=np.intp), np.zeros(0, dtype=np.int8))
        prev = np.vstack([self.code[None, :], codes[:-1]])
        f, c = np.nonzero(codes != prev)  # row-major: decision order, then channel
        self.code = codes[-1].copy()
        return StateChanges(np.asarray(decided_s, dtype=float)[f], c, codes[f, c])
