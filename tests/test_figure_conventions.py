"""The figures' shared conventions: red only for faults, units on the axes, one builder for the overlays.

Fast: one realization per scenario, no Monte Carlo.
"""

from __future__ import annotations

import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")

from matplotlib.colors import to_rgb  # noqa: E402

from chatterspec.figures import paper_figures as pf  # noqa: E402
from chatterspec.figures.paper_figures import OVERLAYS, overlay_builder  # noqa: E402
from chatterspec.figures.plot_closed_loop import closed_loop_spectra_figure  # noqa: E402
from chatterspec.palette import FAULT, mpl  # noqa: E402
from chatterspec.plants.eha4 import eha4  # noqa: E402
from chatterspec.plants.models import state_units  # noqa: E402
from chatterspec.plants.scenarios import scenario  # noqa: E402

#: Reds a reader takes for "fault": the palette's fault colour and matplotlib's red.
REDS = [np.array(mpl(FAULT)), np.array(to_rgb("tab:red")), np.array(to_rgb("C3"))]


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    matplotlib.pyplot.close("all")


def _is_red(color) -> bool:
    rgb = np.array(to_rgb(color))
    return any(np.abs(rgb - r).max() < 0.05 for r in REDS)


def test_closed_loop_spectra_have_power_units_and_no_red_curve():
    scs = [scenario(n) for n in ("eha-leak-medium", "eha-cl-leak-medium", "eha-cl-hold-leak-medium")]
    # a fourth scenario: the old colour cycle gave it matplotlib's red (C3)
    fig = closed_loop_spectra_figure([*scs, scenario("eha-cl-leak-minor")], runs=1, seed=0)
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels == ["position\n[m²]", "velocity\n[(m/s)²]", "pressure\n[Pa²]"]
    colors = [ln.get_color() for ax in fig.axes for ln in ax.get_lines()]
    assert colors and not any(_is_red(c) for c in colors)


def test_overlay_builders_come_from_the_table():
    assert [n for n in pf.FIGURES if n in OVERLAYS] == ["fig7", "fig10", "fig11", "fig12"]
    for name, spec in OVERLAYS.items():
        builder = pf.FIGURES[name].builder
        assert builder.__name__ == name
        assert builder.__doc__.startswith(spec.title.replace(" — ", ": "))
        assert "Parameters" in builder.__doc__
    # a new entry needs no new code: a two-level friction overlay on the same seed
    spec = OVERLAYS["fig11"]
    res = overlay_builder(spec)(None, 1)
    assert res.name == "fig11" and len(res.notes) == 1 + len(spec.levels)


def test_single_realization_builders_document_their_parameters():
    for name in ("fig4", "fig5", "fig8", "fig9"):
        doc = pf.FIGURES[name].builder.__doc__
        assert "runs : int, optional" in doc and "seed :" in doc and "Returns" in doc, name
    assert "flagged frames" in pf.fig8.__doc__


def test_state_units_of_linear_and_nonlinear_models():
    detc = scenario("detc-normal").nominal
    # the DETC paper gives R = 0.1 cm^2: position in cm; the linear model declares output units only, and
    # velocity / acceleration follow from the measured position's
    assert state_units(detc) == ("cm", "cm/s", "cm/s^2")
    assert state_units(eha4("normal")) == ("m", "m/s", "m/s^2", "Pa")
