"""The single-channel ``spectrum`` figure's title: inside the figure, no orphans."""

from __future__ import annotations

import matplotlib.pyplot as plt
import pytest

from chatterspec.figures.paper_figures import scenario_spectrum
from chatterspec.figures.style import _wrap


@pytest.mark.parametrize("name", ["eha-leak-minor", "so-healthy-low"])
def test_single_channel_spectrum_title_fits_and_reads(name: str) -> None:
    fig = scenario_spectrum(name, channel=0).figure
    try:
        fig.canvas.draw()
        title = fig._suptitle
        box, page = title.get_window_extent(), fig.bbox
        assert page.x0 <= box.x0 and box.x1 <= page.x1 and box.y1 <= page.y1, (box, page)
        # no line is a short leftover of a wrapped one (was: "on E[S] (eq 56)," alone on a line)
        lines = title.get_text().split("\n")
        longest = max(len(line) for line in lines)
        assert min(len(line) for line in lines) >= 0.4 * longest, lines
    finally:
        plt.close(fig)


def test_wrap_balances_and_respects_the_width() -> None:
    text = "word " * 40  # 200 characters
    lines = _wrap(text.strip(), 8.0).split("\n")  # 100 characters per line at 8 in
    assert len(lines) == 2 and all(len(line) <= 100 for line in lines)
    assert abs(len(lines[0]) - len(lines[1])) <= 5
    assert _wrap("short\nlines", 8.0) == "short\nlines"
