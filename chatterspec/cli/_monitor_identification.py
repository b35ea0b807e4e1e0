"""``chatterspec monitor``'s identification output: the parameters' alarm events (tolerances), the
``identification`` events, the human lines and the summary, from
:class:`~chatterspec.online.identification_monitor.IdentificationMonitor`.

JSON lines (``--events jsonl``):

* with tolerances, the parameters' alarms are the monitor's fault events: ``{"event": "fault-start",
  "sample_time_s": <alarm time: the deciding window's last sample>, "time_s": <its centre>,
  "channel": <parameter>, "parameter": ..., "estimate", "ci_low", "ci_high", "band", "tolerance",
  "score", "statistic", "threshold", "rule", "false_alarms_per_hour", "detectable", ...}``; the
  spectral detector's events are not emitted (they see the in-tolerance mismatch) and are counted in
  the summary's ``spectral_mismatch``;
* ``--identification-events changes``: an ``identification`` event whenever the fault named (only
  under an alarm) or a parameter's or channel's state changes; ``every-hop``: every window. Fields:
  ``sample_time_s``, ``window_s``, ``alarm``, ``fault`` (the name, null between alarms), ``fits`` (false:
  the window is not described by constant parameters, e.g. it straddles a change; no evidence),
  ``parameters`` (joint estimate, interval, band, ``inside``, ``score``, ``state``, ``detectable``),
  ``channels`` (state per output channel), and under a spectral alarm the full report of the window
  (``selected``, ``hypotheses``, ``alpha``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from ..online.identification_monitor import IdentificationUpdate

__all__ = ["MonitorIdentification"]


class MonitorIdentification:
    """The monitor's identification output (module docstring).

    Parameters
    ----------
    monitor : IdentificationMonitor
    emit : callable or None
        Writes one JSON line (``--events jsonl``); None: no JSON lines.
    say : callable
        Writes one human line.
    every_hop : bool or None
        ``identification`` events at every window (True), at changes (False), none (None).
    """

    def __init__(self, monitor: Any, emit: Any, say: Any, every_hop: bool | None = None) -> None:
        import numpy as np  # lazily: building the parser does not import numpy

        self.monitor = monitor
        self.emit, self.say, self.every_hop = emit, say, every_hop
        self.windows = 0
        self.changes: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []
        self._last: tuple[Any, Any] | None = None  # (update, window) of the last window
        self._last_doc: dict[str, Any] | None = None
        self.spectral_mismatch = 0
        self._key: tuple[Any, ...] | None = None
        self._label: str | None = None
        self._states: tuple[str, ...] | None = None
        self._since_reset = 0  # windows since the start or a reset: the detectability's horizon fills
        P = len(monitor.parameters)
        self._not_excited = np.zeros(P)
        self._hop_s = monitor.settings.hop_s
        #: Called with each push's update before it is reported (e.g. the recordings of a stream).
        self.on_update: Callable[[IdentificationUpdate], None] | None = None

    @property
    def last(self) -> dict[str, Any] | None:
        """The report of the last window (the ``identification`` event's fields), None before one."""
        if self._last_doc is None and self._last is not None:
            self._last_doc = self._doc(*self._last)
        return self._last_doc

    def _current(self) -> dict[str, Any]:
        """:attr:`last` while its window is being reported."""
        doc = self.last
        assert doc is not None  # (set before the window's report is asked for)
        return doc

    def _doc(self, upd: Any, w: Any) -> dict[str, Any]:
        """The fields of window ``w``'s ``identification`` event (``upd`` the push's update)."""
        mon, blk = self.monitor, upd.block
        doc = {
            "sample_time_s": round(w.time_s, 9),
            "window_s": [round(w.window_s[0], 9), round(w.window_s[1], 9)],
            "alarm": w.alarm,
            "fault": w.label,
            "fits": bool(blk.fits[w.index]),
            "parameters": mon.parameter_summary(blk, w),
            "channels": dict(zip(mon.channels, w.channel_states, strict=True)),
        }
        if w.alarm and not self.tolerances:
            rep = upd.report(w.index).to_dict()
            doc.update({k: rep[k] for k in ("selected", "hypotheses", "alpha", "confidence")})
        return doc

    @property
    def identifier(self) -> Any:
        """The online identifier (its setup and confidence name the recording's views)."""
        return self.monitor.identifier

    @property
    def tolerances(self) -> bool:
        """Whether the parameters raise the alarms."""
        return bool(self.monitor.tolerances)

    def reset(self, t0: float) -> None:
        """A gap or restart at ``t0``: start over (the label and states too)."""
        self.monitor.reset(t0)
        self._key = self._label = self._states = None
        self._since_reset = 0

    def note(self, kind: str, channel: str | None, alarm_time_s: float | None) -> None:
        """A spectral event of the monitor decided at ``alarm_time_s`` (the end of its frame): the alarm
        state of the label (no tolerances), or a mismatch counted (tolerances)."""
        if kind not in ("fault-start", "fault-end") or channel is None or alarm_time_s is None:
            return
        if self.tolerances:
            self.spectral_mismatch += kind == "fault-start"
        else:
            self.monitor.note_alarm(kind, channel, alarm_time_s)

    def push(self, z: Any, u: Any) -> None:
        """Identify on one raw push and report it."""
        upd = self.monitor.push(z, u)
        if self.on_update is not None:
            self.on_update(upd)
        self.handle(upd)

    def handle(self, upd: Any) -> None:
        """Report one push's :class:`~chatterspec.online.identification_monitor.IdentificationUpdate`."""
        import numpy as np  # lazily: building the parser does not import numpy

        from ..jsonout import dumps

        mon, blk = self.monitor, upd.block
        events: dict[int, list[Any]] = {int(ev.frame): [] for ev in upd.events}
        for ev in upd.events:
            events[int(ev.frame)].append(ev)
        for w in upd.windows:
            self.windows += 1
            self._since_reset += 1
            for ev in events.get(int(blk.frames[w.index]), ()):
                doc = ev.to_dict()
                kind, t = doc.pop("kind"), doc.pop("alarm_time_s")
                line = {"event": kind, "sample_time_s": round(t, 9), "wall_time": time.time(), **doc}
                self.events.append(line)
                if self.emit is not None:
                    self.emit(dumps(line))
                self.say(ev.describe())
            self._not_excited += np.array([s == "not-excited" for s in w.states]) * self._hop_s
            # the window's report is built only where it is written (most windows of a replay are not)
            self._last, self._last_doc = (upd, w), None
            key = (w.label, w.states, w.channel_states)
            changed = key != self._key
            if self.emit is not None and self.every_hop is not None and (self.every_hop or changed):
                self.emit(dumps({"event": "identification", **self._current()}))
            if w.label != self._label:
                self._say_label(w, self._current())
            warm = self._since_reset > mon.settings.horizon_hops  # the horizon holds data only after it
            if warm and self._states is not None and w.states != self._states:
                self._say_states(w, self._current())
            if changed:
                self.changes.append(
                    {
                        "time_s": round(w.time_s, 9),
                        "fault": w.label,
                        "states": dict(zip(mon.parameters, w.states, strict=True)),
                    }
                )
            self._key, self._label, self._states = key, w.label, w.states

    def _say_label(self, w: Any, doc: dict[str, Any]) -> None:
        """A human line when the fault named changes (an alarm starts or ends, or names another fault)."""
        at = f"t = {w.time_s:.2f} s (window {w.window_s[0]:.2f}-{w.window_s[1]:.2f} s)"
        if w.label is None:
            if self._label is not None:
                self.say(f"alarm over at {at}: {self._status(doc)}")
            return
        if self.tolerances:
            return  # the parameters' fault events said it
        rows = [r for r in doc.get("hypotheses", []) if r["hypothesis"] == w.label and r["parameter"]]
        from ._identify import summary_line

        what = summary_line({"selected": w.label, "hypotheses": rows}) if rows else w.label
        self.say(f"identified at {at}: {what}")

    def _say_states(self, w: Any, doc: dict[str, Any]) -> None:
        """A human line when a parameter becomes not excited, or excited again."""
        rows = {r["parameter"]: r for r in doc["parameters"]}
        for p, old, new in zip(self.monitor.parameters, self._states or (), w.states, strict=True):
            if (old == "not-excited") == (new == "not-excited"):
                continue
            r = rows[p]
            det = "none" if r["detectable"] is None else f"{r['detectable']:.2g}"
            unit = f" {r['unit']}" if r["unit"] else ""
            horizon = self.monitor.settings.horizon_hops * self._hop_s
            what = "not excited" if new == "not-excited" else "excited"
            self.say(
                f"{p} {what} at t = {w.time_s:.2f} s: changes >= {det}{unit} detectable over the last "
                f"{horizon:g} s (not excited above {self._limit(p)})"
            )

    def _limit(self, p: str) -> str:
        b = self.monitor.settings.bands
        i = b.names.index(p)
        unit = f" {b.units[i]}" if b.units[i] else ""
        return f"{b.limit[i]:.2g}{unit}" + (f", its tolerance {b.tolerances[i]}" if b.tolerances[i] else "")

    def _status(self, doc: dict[str, Any]) -> str:
        return "; ".join(self.status_lines(doc))

    def status_lines(self, doc: dict[str, Any] | None = None) -> list[str]:
        """``"bulk_modulus 1.86e8 Pa, 10 % below nominal, inside its +-15 %"`` per parameter (last window)."""
        import numpy as np  # lazily: building the parser does not import numpy

        from ..detection.parameter_decision import status_text

        doc = self.last if doc is None else doc
        if doc is None:
            return []
        out = []
        for r in doc["parameters"]:
            est, se, lo, hi = (
                np.nan if r[k] is None else r[k] for k in ("estimate", "std_error", "ci_low", "ci_high")
            )
            text = status_text(
                r["parameter"],
                est,
                se,
                (lo, hi),
                r["nominal"],
                r["unit"],
                r["tolerance"] or "",
                r["position"] or "",
            )
            out.append(text + ("" if r["state"] == "healthy" else f" ({r['state']})"))
        return out

    @property
    def starts(self) -> int:
        """The parameters' alarm starts so far (tolerances)."""
        return sum(e["event"] == "fault-start" for e in self.events)

    def rule_short(self) -> str:
        """``"cusum rule, 1 false alarm per 24 h, on the parameters"``."""
        from ..detection.alarms.rules import alarm_label

        cal = self.monitor.settings.calibration
        if cal is None:
            return "no parameter alarm"
        return f"{alarm_label(cal.rule.name, cal.false_alarms_per_hour)}, on the parameters"

    def into_summary(self, doc: dict[str, Any]) -> None:
        """Put the identification into a ``monitor --json`` summary ``doc``; with tolerances the
        parameters' alarms become its ``events`` (and ``counts``), the spectral ones ``spectral_events``."""
        doc["identification"] = self.to_dict()
        if not self.tolerances:
            return
        cal = self.monitor.settings.calibration
        doc["decision"] = "parameters (tolerances)"
        doc["alarm"] = None if cal is None else cal.to_dict()
        doc["spectral_events"] = doc.get("events", [])
        doc["events"] = list(self.events)
        if "counts" in doc:
            counts = dict(doc["counts"])
            doc["spectral_counts"] = {k: counts.get(k, 0) for k in ("fault-start", "fault-end")}
            for k in ("fault-start", "fault-end"):
                counts[k] = sum(e["event"] == k for e in self.events)
            doc["counts"] = counts

    def to_dict(self) -> dict[str, Any]:
        """The summary's ``identification``: windows, the decision's settings, the fault-name and state
        ``changes``, the parameters' alarm events (tolerances), time not excited per parameter, the last
        window."""
        ident = self.monitor.identifier
        return {
            "window_s": ident.window_s,
            "windows": self.windows,
            "decision": self.monitor.settings.to_dict(),
            "changes": self.changes,
            "events": self.events,
            "not_excited_s": {
                p: round(float(s), 9) for p, s in zip(self.monitor.parameters, self._not_excited, strict=True)
            },
            "spectral_mismatch": self.spectral_mismatch if self.tolerances else None,
            "last": self.last,
        }
