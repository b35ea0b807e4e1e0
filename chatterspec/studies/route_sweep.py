"""Alarm rules swept over thresholds on one chunk of route scores: false alarms and delays per threshold.

The comparison of the diagnosis routes (``chatterspec diagnose``) needs, for every route and every
threshold ``h`` of a grid, on the *same* realizations:

* the alarm **starts** on healthy time (the false alarms; their rate per hour is what a budget sets);
* per fault onset and run, the first step at or after the onset where the route is in alarm (the
  detection; the delay is that step's time minus the onset), whether the run was already in alarm
  on the last step before the onset, and the label the route isolates at the detection.

:func:`route_geometry` places the onsets and the healthy steps on a route's step times, and
:func:`sweep_chunk` runs the rule (:func:`chatterspec.detection.alarms.streams.run_rule`) for each threshold
and keeps only per-run integers, so that the chunks of a study fold into the same numbers whatever
the chunking (:func:`merge_sweeps`).

Conventions
    * The detector starts at the warm-up time: steps known before it are not fed to the rule (the
      start-up transient of a filter started from ``x0 = 0``, uniform mode probabilities, is not a
      false alarm a person monitoring for hours would see).
    * Healthy time is the time before the first fault onset (after the warm-up); a step is healthy
      when its score is known by the onset (a frame whose last sample is at or before it: the data
      of time ``t`` come from the plant active before ``t``).
    * Onset ``a`` (next change ``b``) is detected at the first step in alarm known in ``(a, b]``.
    * A route is in alarm when any of its score channels is; its alarm starts are counted per
      channel (all channels together, as the monitor's budget counts them).
    * An onset's detection window ends at the next change of the true plant (or the record's end).
    * A run already in alarm on the last step before an onset (a false alarm still active, or an
      earlier fault's alarm) has no new detection there: its delay is not defined (the conditional
      delay of sequential detection, given no alarm at the change) and it is counted apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ..errors import ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from ..detection.alarms.rules import AlarmRule
    from ..plants.scenarios import Scenario
    from .routes import RouteScores

__all__ = ["DEFAULT_WARMUP_S", "RouteGeometry", "merge_sweeps", "onsets_of", "route_geometry", "sweep_chunk"]

#: Seconds of start-up not fed to the rules (the filters start from ``x0 = 0`` and uniform modes).
DEFAULT_WARMUP_S = 0.1


def onsets_of(sc: Scenario) -> tuple[tuple[float, float, int], ...]:
    """Fault onsets of scenario ``sc``: ``(onset_s, end_s, segment)`` per change into a faulty segment.

    ``end_s`` is the next change of the true plant (or the record's end); a scenario faulty from
    ``t = 0`` has an onset at 0.
    """
    segs = sc.segments
    out = []
    for i, s in enumerate(segs):
        if not sc.deviates(s):
            continue
        if i > 0 and segs[i - 1].model is s.model:
            continue
        out.append((float(s.start), float(s.stop), i))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class RouteGeometry:
    """Where the healthy steps and the onsets fall on a route's step times.

    Attributes
    ----------
    first : int
        First step fed to the rule (the first whose time is >= the warm-up).
    times : (steps,) array
        Step times (s) from ``first`` on.
    healthy : (steps,) bool array
        Steps known by the first onset.
    onsets : tuple of float
        Onset times (s).
    lo, hi : tuple of int
        Per onset, the detection window: steps ``lo .. hi - 1`` (from ``first``), known in ``(a, b]``.
    true_labels : tuple of str or None
        Per onset, the label a correct isolation names (the new mode), when the route isolates modes.
    step_s : float
        Seconds of data per step (``dt`` or the STFT hop).
    """

    first: int
    times: np.ndarray
    healthy: np.ndarray
    onsets: tuple[float, ...]
    lo: tuple[int, ...]
    hi: tuple[int, ...]
    true_labels: tuple[str | None, ...]
    step_s: float

    @property
    def healthy_steps(self) -> int:
        """Number of healthy steps."""
        return int(np.count_nonzero(self.healthy))


def route_geometry(
    sc: Scenario, times: np.ndarray, step_s: float, warmup: float, modes: tuple[str, ...] | None = None
) -> RouteGeometry:
    """Healthy steps and onset windows of a route whose step ``j`` is known at ``times[j]`` (s).

    Parameters
    ----------
    sc : Scenario
        The diagnosed scenario.
    times : (steps,) array
        When each step's score is known (s).
    step_s : float
        Seconds of data per step.
    warmup : float
        Steps known before this time (s) are not fed to the rule.
    modes : tuple of str, optional
        The route's mode names (mode routes): the onsets' true new modes are looked up among them.

    Returns
    -------
    RouteGeometry
    """
    times = np.asarray(times, dtype=float)
    first = int(np.searchsorted(times, warmup - 1e-9 * step_s, side="left"))
    t = times[first:]
    if not t.size:
        raise ParameterError(f"the warm-up ({warmup:g} s) leaves no step of the record to diagnose")
    ons = onsets_of(sc)
    t_first = ons[0][0] if ons else float("inf")
    # the score known at t depends on the data up to t, which the plant active before t produced:
    # a step is healthy when t <= the first onset, and onset a's window (next change b) is (a, b]
    eps = 1e-9 * step_s
    healthy = t <= t_first + eps
    lo = tuple(int(np.searchsorted(t, a + eps, side="right")) for a, _, _ in ons)
    hi = tuple(int(np.searchsorted(t, b + eps, side="right")) for _, b, _ in ons)
    labels: list[str | None] = []
    for _, _, i in ons:
        name = None
        if modes is not None and sc.filter_settings is not None:
            from ..plants.nonlinear import same_dynamics

            seg = sc.segments[i]
            hit = [j for j, m in enumerate(sc.filter_settings.mode_models) if same_dynamics(m, seg.model)]
            name = modes[hit[0]] if hit else None
        labels.append(name)
    return RouteGeometry(first, t, healthy, tuple(a for a, _, _ in ons), lo, hi, tuple(labels), float(step_s))


def sweep_chunk(
    route_scores: RouteScores,
    geometry: RouteGeometry,
    rule: AlarmRule,
    thresholds: np.ndarray,
    labels: tuple[str, ...],
) -> dict[str, Any]:
    """Run ``rule`` at every threshold on one chunk's scores; keep per-run integers.

    Parameters
    ----------
    route_scores : RouteScores
        The chunk's scores ``(runs, steps, C)`` (all steps; :attr:`RouteGeometry.first` on are fed).
    geometry : RouteGeometry
    rule : alarm rule
        Its threshold is replaced by each entry of ``thresholds``.
    thresholds : (G,) array
    labels : tuple of str
        The route's labels (``route_scores.label`` indexes them; with no label array, the score
        channel in alarm is the label).

    Returns
    -------
    dict
        ``healthy_starts`` (G,) int; per onset ``first`` (G, runs) int step in the window (-1: none),
        ``label`` (G, runs) int label at detection (-1), ``iso_first`` (G, runs) first step in alarm
        with the correct label (-1; mode routes), ``before`` (G, runs) bool: in alarm on the last step
        before the onset.
    """
    from ..detection.alarms.streams import run_rule

    g0 = geometry
    s = np.ascontiguousarray(route_scores.score[:, g0.first :])
    lab = None if route_scores.label is None else route_scores.label[:, g0.first :]
    runs = s.shape[0]
    if s.shape[1] != g0.times.size:
        raise ParameterError(
            f"every chunk must have the scenario's record length: {s.shape[1]} steps, not {g0.times.size}"
        )
    G = len(thresholds)
    n_on = len(g0.onsets)
    out: dict[str, Any] = {
        "runs": runs,
        "healthy_starts": np.zeros(G, dtype=np.int64),
        "first": [np.full((G, runs), -1, dtype=np.int32) for _ in range(n_on)],
        "label": [np.full((G, runs), -1, dtype=np.int16) for _ in range(n_on)],
        "iso_first": [np.full((G, runs), -1, dtype=np.int32) for _ in range(n_on)],
        "before": [np.zeros((G, runs), dtype=bool) for _ in range(n_on)],
    }
    true_idx = [labels.index(x) if x is not None and x in labels else -1 for x in g0.true_labels]
    rows = np.arange(runs)
    for g, h in enumerate(thresholds):
        blk = run_rule(rule.with_threshold(float(h)), s)
        act_c = blk.active  # (runs, steps, C)
        active = cast(np.ndarray, act_c.any(axis=-1))  # (runs, steps)
        if g0.healthy.any():
            out["healthy_starts"][g] = int(np.count_nonzero(blk.starts[:, g0.healthy]))
        for i in range(n_on):
            lo, hi = g0.lo[i], g0.hi[i]
            win = active[:, lo:hi]
            hit = win.any(axis=1)
            first = np.where(hit, np.argmax(win, axis=1), -1)
            out["first"][i][g] = first
            if lo > 0:
                out["before"][i][g] = active[:, lo - 1]
            k = lo + np.maximum(first, 0)
            if lab is not None:
                at = lab[rows, k]
            else:
                at = np.argmax(act_c[rows, k], axis=-1)
            out["label"][i][g] = np.where(hit, at, -1)
            if lab is not None and true_idx[i] >= 0:
                ok = win & (lab[:, lo:hi] == true_idx[i])
                out["iso_first"][i][g] = np.where(ok.any(axis=1), np.argmax(ok, axis=1), -1)
    return out


def merge_sweeps(acc: dict[str, Any] | None, part: dict[str, Any]) -> dict[str, Any]:
    """Fold ``part``, one chunk's :func:`sweep_chunk`, into ``acc`` (None at first; runs in chunk order)."""
    if acc is None:
        return part
    out = {
        "runs": acc["runs"] + part["runs"],
        "healthy_starts": acc["healthy_starts"] + part["healthy_starts"],
    }
    for key in ("first", "label", "iso_first", "before"):
        out[key] = [np.concatenate([a, b], axis=1) for a, b in zip(acc[key], part[key], strict=True)]
    return out
