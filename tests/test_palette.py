"""One palette for figures and recordings (chatterspec.palette), and red only for faults."""

from __future__ import annotations

from pathlib import Path

import matplotlib.colors as mcolors
import numpy as np
import pytest

from chatterspec import filter_registry, palette


def _reddish(rgb) -> bool:
    """Red enough to read as 'fault' on a dark or white background."""
    r, g, b = (round(255 * c) if isinstance(c, float) else int(c) for c in rgb[:3])
    return r > 170 and g < 110 and b < 110


def test_no_red_outside_faults() -> None:
    assert _reddish(palette.FAULT)
    for group in (palette.CHANNEL_COLORS, palette.MODE_COLORS, palette.FAULT_LEVEL_COLORS):
        assert not any(_reddish(c) for c in group), group
    assert not any(_reddish(c) for c in palette.FILTER_COLORS.values())
    # distinct fault levels and channels
    assert len(set(palette.FAULT_LEVEL_COLORS)) == len(palette.FAULT_LEVEL_COLORS)
    assert len(set(palette.CHANNEL_COLORS)) == len(palette.CHANNEL_COLORS)
    assert palette.rgba32((1, 2, 3)) == 0x010203FF


def test_figures_use_the_palette() -> None:
    from chatterspec.figures import estimators, plot_diagnosis
    from chatterspec.figures.plot_diagnosis import mode_weights_figure

    for name in filter_registry.FILTERS:
        assert estimators._line(name, 0)["color"] == palette.mpl(palette.filter_color(name))
    for name, color in plot_diagnosis.METHOD_COLORS.items():
        assert color == palette.mpl(palette.filter_color(name))
    t = np.linspace(0.0, 1.0, 5)
    mu = np.full((1, 5, 3), 1.0 / 3.0)
    fig = mode_weights_figure(t, mu, ("normal", "a", "b"), title="x")
    lines = fig.axes[0].get_lines()
    got = [mcolors.to_rgb(line.get_color()) for line in lines]
    assert got == [palette.mpl(palette.mode_color(j)) for j in range(3)]


def test_recordings_use_the_palette(tmp_path: Path) -> None:
    rr = pytest.importorskip("rerun")
    from rerun.chunk import RrdReader

    from chatterspec.studies.estimation import estimate_records
    from chatterspec.viewer import blueprint
    from chatterspec.viewer.recordings import record_estimates

    styles = dict(blueprint.series_styles(("a", "b", "c", "d"), ("", "", "", "")))
    assert styles[blueprint.STATISTIC] is not None
    # the channel colours of the views are the palette's (the 4th is no longer red)
    want = [list(palette.channel_color(i)) for i in range(4)]
    assert blueprint._COLORS[:4] == want
    assert blueprint._RED == list(palette.FAULT)

    records = estimate_records("detc-normal", "kf,svsf2", runs=1, seed=0)
    path = record_estimates(records, tmp_path / "e.rrd")
    reader = RrdReader(str(path))
    colors = {}
    for chunk in reader.stream().to_chunks():
        if chunk.is_static and chunk.entity_path.startswith("/states/position/"):
            rb = chunk.to_record_batch()
            if "SeriesLines:colors" in rb.schema.names:
                colors[chunk.entity_path] = rb.column("SeriesLines:colors").to_pylist()[0][0]
    assert colors["/states/position/kf"] == palette.rgba32(palette.filter_color("kf"))
    assert colors["/states/position/svsf2"] == palette.rgba32(palette.filter_color("svsf2"))
    assert colors["/states/position/truth"] == palette.rgba32(palette.TRUTH)
    del rr
