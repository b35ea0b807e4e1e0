"""The true fault lane of a simulated recording (``/state/0_truth``) and its colours.

Each true fault level gets its own amber (never red: red is a verdict), healthy segments grey; the
mode lanes of a diagnosis take the same colours by label, so that a mode lane naming a true segment
reads like the truth.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..palette import NEUTRAL, fault_level_color, rgba32
from .blueprint import TRUTH_LANE
from .record_geometry import to_ns
from .sinks import TIMELINE

__all__ = ["log_truth_lane", "truth_colors"]


def truth_colors(truth: list[tuple[float, str, bool]]) -> dict[str, int]:
    """Lane colours by label (``0xRRGGBBAA``): the k-th fault label in order of appearance
    ``fault_level_color(k)``, healthy labels :data:`~chatterspec.palette.NEUTRAL`.

    Parameters
    ----------
    truth : list of (start_s, label, is_fault)
        The true timeline (:func:`~chatterspec.viewer.drivers.scenario_truth`).

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
    segment at its start (integer ns, :func:`~chatterspec.viewer.record_geometry.to_ns`).

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
