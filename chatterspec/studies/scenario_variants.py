"""Scenario variants for diagnosis: a fault present from ``t = 0`` moved to a later onset.

A catalogue scenario such as ``eha-leak-minor`` is faulty over its whole record: it has no healthy
time on which a detector could raise a false alarm, and its "onset" is the detector's own start.
:func:`with_onset` keeps the record (nominal model, input, duration, noise) and runs the nominal plant
until ``onset``, the scenario's faulty plant afterwards, so that a diagnosis measures false alarms on
``[0, onset)`` and a detection delay from a fault that starts while the detector is in its healthy
steady state. (:func:`~chatterspec.studies.chattering_diagnosis.healthy_version` is the companion that
removes the fault altogether.)
"""

from __future__ import annotations

import dataclasses

from .._validate import positive
from ..errors import ParameterError
from ..plants.scenarios import Scenario, Segment

__all__ = ["faulty_at_start", "with_onset"]


def faulty_at_start(sc: Scenario) -> bool:
    """True when scenario ``sc``'s true plant differs from its nominal model at ``t = 0``."""
    return bool(sc.segments) and sc.deviates(sc.segments[0])


def with_onset(sc: Scenario, onset: float) -> Scenario:
    """The scenario with its fault starting at ``onset`` seconds instead of ``t = 0``.

    Parameters
    ----------
    sc : Scenario
        A scenario whose true plant is faulty at ``t = 0`` (:func:`faulty_at_start`), e.g.
        ``eha-leak-minor`` (faulty base plant) or ``eha4-leak-minor`` (a fault window from 0 s).
    onset : float
        Fault onset in seconds, ``0 < onset < duration``.

    Returns
    -------
    Scenario
        Named ``<name>-onset<onset>s``: the nominal plant (its ``Q`` and ``R``) on ``[0, onset)``;
        from ``onset`` on, the plant that was active there (every later window unchanged).

    Raises
    ------
    ParameterError
        ``onset`` outside ``(0, duration)``, or a scenario that is healthy at ``t = 0`` (it has an
        onset of its own).
    """
    t0 = positive("onset", onset, unit="s")
    if not t0 < sc.duration:
        raise ParameterError(f"onset must be < the record length {sc.duration:g} s; got {t0:g} s")
    if not faulty_at_start(sc):
        first = next((s.start for s in sc.segments if sc.deviates(s)), None)
        where = "no fault at all" if first is None else f"its first fault starts at {first:g} s"
        raise ParameterError(
            f"scenario {sc.name!r} is healthy at t = 0 ({where}): an onset applies only to a scenario "
            "faulty from the start"
        )
    windows = []
    for s in sc.segments:
        if s.stop <= t0 or not sc.deviates(s):
            continue
        windows.append(Segment(max(s.start, t0), s.stop, s.model, s.label or sc.fault))
    label = f"{sc.level or sc.fault} from {t0:g} s"
    return dataclasses.replace(
        sc,
        name=f"{sc.name}-onset{t0:g}s",
        plant=None,
        windows=tuple(windows),
        level=label,
        description=f"{sc.description}; nominal plant before {t0:g} s",
    )
