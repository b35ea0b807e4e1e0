"""Detection delay of the alarm rules at fault onsets from a healthy steady state.

A fault of the catalogue is turned into *onset scenarios* (:func:`onset_scenarios`): the true
plant is healthy for ``healthy_s`` seconds, then faulty; the input runs relative to the onset.
For the EHA faults (whole-record faults driven by the 4 s chirp, repeated) one scenario per
input phase at the onset (``phases``), since the fault's footprint depends on where the chirp is
(from 218 nats per frame at its 10 Hz start to 7 at its 100 Hz end for the minor leakage); for the
second-order timelines one scenario per fault window, with the window's input (the step of
``so-timeline-step`` lands at the onset).

:func:`alarm_delays` runs every rule on the same realizations through the monitor's frames and
score (batch STFT, :class:`~chatterspec.detection.verdicts.FrameScore` and
:func:`~chatterspec.detection.alarms.streams.run_rule`: the same numbers as the online monitor, whose
frames, score and alarm layer are these functions on the same grid). The **delay** of a run is the
time of the last sample of the frame at which the first alarm starts, on any channel, among the
frames that end at or after the onset and begin before the fault ends, minus the onset time (s):
when the alarm could have been raised. A run without such a start is a miss. Starts before the
onset are false alarms of the healthy stretch (counted).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from ..detection.alarms.calibration import MonitorSettings
from ..detection.alarms.rules import AlarmRule
from ..detection.alarms.streams import run_rule
from ..detection.pipeline import iter_chattering
from ..detection.spectral import STFTConfig, frame_columns
from ..errors import ParameterError
from ..jsonout import finite_or_none
from ..plants.nonlinear import Model
from ..plants.scenarios import Scenario, Segment, scenario
from .alarm_budget import monitor_score

__all__ = ["DelayResult", "Shifted", "alarm_delays", "onset_scenarios", "score_delays"]


@dataclass(frozen=True)
class Shifted:
    """``signal`` in the time frame of an onset: ``u(t) = signal((t - shift) mod period)``.

    ``period`` None: no wrap (a ``Step`` before ``shift`` keeps its initial value).
    """

    signal: Any
    shift: float
    period: float | None = None

    def sample(self, t: np.ndarray) -> np.ndarray:
        """The values at the given times (s), one row per time."""
        x = np.asarray(t, dtype=float) - self.shift
        if self.period:
            x = np.mod(x, self.period)
        return self.signal.sample(x)

    def describe(self) -> str:
        """A short description for reports and recordings."""
        wrap = f", repeated every {self.period:g} s" if self.period else ""
        return f"{self.signal.describe()} from t = {self.shift:g} s{wrap}"


def onset_scenarios(
    name: str | Scenario,
    *,
    healthy_s: float = 6.0,
    fault_s: float = 8.0,
    phases: Sequence[float] = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5),
) -> list[Scenario]:
    """Onset versions of catalogue fault ``name`` (see the module docstring).

    Parameters
    ----------
    name : str or Scenario
        A faulty catalogue scenario (or a Scenario built like one): a whole-record fault
        (``eha-leak-minor``, ...) or a timeline (``so-timeline-constant``, ...).
    healthy_s : float
        Healthy stretch before the onset (s); it must exceed one STFT window.
    fault_s : float
        Fault duration of a whole-record fault (s); a timeline window keeps its own.
    phases : sequence of float
        Whole-record faults: times into the scenario's input (s) at which the onset falls
        (the input repeats with the scenario's duration).
    """
    base = name if isinstance(name, Scenario) else scenario(name)
    name = base.name
    if base.is_healthy:
        raise ParameterError(f"{name!r} is healthy: no onset")
    out = []
    if base.windows:
        for w in base.windows:
            d = w.stop - w.start
            out.append(
                Scenario(
                    name=f"{name}@{w.start:g}s",
                    nominal=base.nominal,
                    input=Shifted(base.input, healthy_s - w.start),
                    duration=healthy_s + d + 1.0,
                    windows=(Segment(healthy_s, healthy_s + d, w.model, w.label),),
                    fault=base.fault,
                    level=w.label,
                    fault_channel=base.fault_channel,
                )
            )
        return out
    for ph in phases:
        out.append(
            Scenario(
                name=f"{name}@phase{ph:g}s",
                nominal=base.nominal,
                input=Shifted(base.input, healthy_s - float(ph), base.duration),
                duration=healthy_s + fault_s,
                windows=(
                    Segment(healthy_s, healthy_s + fault_s, cast(Model, base.plant), base.level),
                ),  # (set)
                fault=base.fault,
                level=base.level,
                fault_channel=base.fault_channel,
            )
        )
    return out


@dataclass(frozen=True)
class DelayResult:
    """Delays of one rule over onset scenarios.

    Attributes
    ----------
    delays_s : (runs,) array
        Per run (all scenarios together), the delay (s); ``inf`` for a miss.
    on_fault_channel : (runs,) bool array
        The first alarm after the onset is on the scenario's fault channel.
    false_starts : int
        Alarm starts before the onset (healthy stretch).
    healthy_hours : float
        Healthy time observed before the onsets, all runs (h).
    """

    delays_s: np.ndarray
    on_fault_channel: np.ndarray
    false_starts: int
    healthy_hours: float

    @property
    def detected(self) -> float:
        """Fraction of runs whose fault was detected (finite delay)."""
        return float(np.mean(np.isfinite(self.delays_s)))

    def quantile(self, q: float) -> float:
        """Delay quantile (s) over all runs, misses counted as ``inf``."""
        d = np.sort(self.delays_s)
        k = min(d.size - 1, max(0, math.ceil(q * d.size) - 1))
        return float(d[k])

    def to_dict(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (what the JSON outputs print)."""
        med, p90, mx = (finite_or_none(self.quantile(q)) for q in (0.5, 0.9, 1.0))
        return {
            "runs": int(self.delays_s.size),
            "detected": self.detected,
            "median_s": med,
            "p90_s": p90,
            "max_s": mx,
            "on_fault_channel": float(np.mean(self.on_fault_channel)),
            "false_starts_before_onset": self.false_starts,
            "healthy_hours": self.healthy_hours,
        }


def score_delays(
    S: np.ndarray,
    t: np.ndarray,
    interval: tuple[float, float],
    rules: Mapping[str, AlarmRule],
    cfg: STFTConfig,
    dt: float,
    fault_channel: int = -1,
) -> dict[str, tuple[np.ndarray, np.ndarray, int, float]]:
    """Delays of each rule on the frame scores of onset records (module docstring's definitions).

    Parameters
    ----------
    S : (runs, F, m) array
        Frame scores of records whose chattering samples are at times ``t``.
    t : (N,) array
        Times (s) of the chattering samples.
    interval : (float, float)
        Fault onset and end (s).
    rules : mapping label -> rule
        Rules with their thresholds set.
    cfg : STFTConfig
        The frames' window and hop.
    dt : float
        Sampling time (s).
    fault_channel : int
        Index of the fault's channel (-1: none).

    Returns
    -------
    dict label -> (delays (runs,), on fault channel (runs,), false starts before the onset, healthy hours)
    """
    on, off = interval
    W, H = cfg.n_window(dt), cfg.n_hop(dt)
    F = S.shape[1]
    t_end = t[np.arange(F) * H + W - 1]
    t_start = t[np.arange(F) * H]
    valid = (t_end >= on - 1e-9) & (t_start < off)
    pre = t_end < on - 1e-9
    healthy_h = S.shape[0] * float(np.count_nonzero(pre)) * H * dt / 3600.0
    out = {}
    for label, rule in rules.items():
        st = run_rule(rule, S).starts  # (runs, F, m)
        any_st = st.any(axis=-1)
        hit = any_st & valid
        first = np.where(hit.any(axis=1), np.argmax(hit, axis=1), -1)
        d = np.where(first >= 0, t_end[np.maximum(first, 0)] - on, np.inf)
        ch = np.array(
            [fault_channel >= 0 and f >= 0 and bool(st[r, f, fault_channel]) for r, f in enumerate(first)],
            dtype=bool,
        )
        out[label] = (d, ch, int(np.count_nonzero(st[:, pre])), healthy_h)
    return out


def alarm_delays(
    scenarios: Sequence[Scenario],
    rules: Mapping[str, AlarmRule],
    runs: int,
    seed: int = 0,
    *,
    settings: MonitorSettings | None = None,
) -> dict[str, DelayResult]:
    """Delays of each rule of ``rules`` on ``runs`` realizations of every onset scenario.

    Parameters
    ----------
    scenarios : sequence of Scenario
        Onset scenarios (:func:`onset_scenarios`), one fault window each, same nominal model.
    rules : mapping label -> rule
        Rules with their thresholds set (e.g. for a budget, by
        :func:`chatterspec.studies.alarm_budget.calibrate_alarm`).
    runs : int
        Realizations per scenario.
    seed : int
        Root seed; scenario ``i`` uses ``SeedSequence([seed, i])``.
    settings : MonitorSettings, optional
        The monitor's STFT, band and threshold (the score's law); default ``MonitorSettings()``.
    """
    from ..detection.alarms.calibration import MonitorSettings

    settings = settings or MonitorSettings()
    cfg: STFTConfig = settings.stft
    acc: dict[str, dict[str, list[Any]]] = {k: {"d": [], "ch": [], "pre": [0]} for k in rules}
    healthy_h = 0.0
    for i, sc in enumerate(scenarios):
        if len(sc.fault_intervals) != 1:
            raise ParameterError(f"{sc.name}: an onset scenario has exactly one fault window")
        ((on, off),) = sc.fault_intervals
        model = sc.nominal
        score, _ = monitor_score(model, settings)
        fault_c = list(model.output_names).index(sc.fault_channel) if sc.fault_channel else -1
        for rec in iter_chattering(sc, runs, np.random.SeedSequence([int(seed), i])):
            _, P = frame_columns(rec.values, model.dt, cfg)
            part = score_delays(score(P), rec.t, (on, off), rules, cfg, model.dt, fault_c)
            for label, (d, ch, pre, _) in part.items():
                acc[label]["d"].append(d)
                acc[label]["ch"].append(ch)
                acc[label]["pre"][0] += pre
            healthy_h += next(iter(part.values()))[3] if part else 0.0
    return {
        k: DelayResult(np.concatenate(v["d"]), np.concatenate(v["ch"]), v["pre"][0], healthy_h)
        for k, v in acc.items()
    }
