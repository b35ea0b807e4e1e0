"""Default Rerun blueprint of a chatterspec recording."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from .viewer import TIMELINE

if TYPE_CHECKING:
    pass

__all__ = [
    "blueprint",
]


# --------------------------------------------------------------------------- blueprint
def _entity(name: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in name)


def blueprint(channels: tuple[str, ...], *, has_truth: bool = False, history_s: float = 10.0) -> Any:
    """The default layout: per channel (columns) chattering, scrolling spectrogram, detection statistic;
    below, the state lanes (verdict per channel and true fault) and the event log.

    Parameters
    ----------
    channels : tuple of str
        Measured channel names, one column of views each.
    has_truth : bool
        Add the true fault timeline lane (simulated data).
    history_s : float
        Seconds of history shown by the time-series views (cursor-relative).

    Returns
    -------
    rerun.blueprint.Blueprint
    """
    import rerun as rr
    import rerun.blueprint as rrb

    recent = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-history_s),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    columns = []
    for name in channels:
        c = _entity(name)
        columns.append(
            rrb.Vertical(
                rrb.TimeSeriesView(
                    origin=f"/chattering/{c}",
                    name=f"{name}: chattering e(k|k-1) and boundary ±psi",
                    time_ranges=recent,
                ),
                rrb.TensorView(
                    origin=f"/spectrogram/{c}",
                    name=f"{name}: spectrogram, dB above healthy (freq up, time right)",
                    slice_selection=rrb.TensorSliceSelection(
                        width=rr.components.TensorWidthDimension(dimension=1),
                        height=rr.components.TensorHeightDimension(dimension=0, invert=True),
                    ),
                    scalar_mapping=rrb.TensorScalarMapping(colormap="viridis"),
                    # 501 frequency rows x 50 time columns: stretch to the panel
                    view_fit="Fill",
                ),
                rrb.TimeSeriesView(
                    origin=f"/detection/{c}",
                    name=f"{name}: peak S/threshold (fault when > 1)",
                    time_ranges=recent,
                ),
                row_shares=[1, 1.4, 1],
            )
        )
    lanes = ["/state/**", "/truth/**"] if has_truth else ["/state/**"]
    return rrb.Blueprint(
        rrb.Vertical(
            rrb.Horizontal(*columns),
            rrb.Horizontal(
                rrb.StateTimelineView(
                    origin="/",
                    contents=lanes,
                    name="verdict per channel" + (" vs true fault" if has_truth else ""),
                ),
                rrb.TextLogView(origin="/events", name="detection events"),
                column_shares=[2, 1],
            ),
            row_shares=[4, 1],
        ),
        rrb.TimePanel(state="expanded", timeline=TIMELINE),
        collapse_panels=True,
    )
