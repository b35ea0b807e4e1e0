"""Smoke tests of the matplotlib figures, the paper-figure registry and the figures/spectrum commands.

Fast: tiny run counts, one realization per spectrum figure.
"""

from __future__ import annotations

import argparse
import json
import re

import numpy as np
import pytest
from scipy import stats

matplotlib = pytest.importorskip("matplotlib")

from chatterspec.cli import figures as figures_cmd  # noqa: E402
from chatterspec.cli import spectrum as spectrum_cmd  # noqa: E402
from chatterspec.detection.spectral import periodogram_freqs  # noqa: E402
from chatterspec.detection.thresholds import exact_threshold, paper_threshold  # noqa: E402
from chatterspec.errors import ChatterspecError, ParameterError, ShapeError, UnknownScenarioError  # noqa: E402
from chatterspec.figures import paper_figures as pf  # noqa: E402
from chatterspec.figures import plotting as pl  # noqa: E402
from chatterspec.plants.models import second_order  # noqa: E402

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MAX_PNG_BYTES = 300_000


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    matplotlib.pyplot.close("all")


def _insets(fig):
    """Zoom axes drawn beside the main axes."""
    return pl.zoom_axes(fig)


def _legend_labels(fig):
    return [t.get_text() for t in fig.legends[0].get_texts()]


def _synthetic_panel(n_thresholds: int = 2, inset=None) -> pl.SpectrumPanel:
    f = np.linspace(0.0, 500.0, 201)
    rng = np.random.default_rng(0)
    p = rng.exponential(1e-6, f.size)
    th = tuple(
        pl.ThresholdCurve(np.full(f.size, 1e-5 * (i + 1)), f"thr {i}", "paper" if i % 2 else "exact", 1e-3)
        for i in range(n_thresholds)
    )
    return pl.SpectrumPanel(
        freqs_hz=f,
        curves=(pl.SpectrumCurve(p, "S"),),
        expected=np.full(f.size, 1e-6),
        thresholds=th,
        title="t",
        channel="velocity",
        unit="m/s",
        note="peak",
        inset_hz=inset,
    )


# --------------------------------------------------------------------------- labels
def test_format_alpha_and_power_unit():
    assert pl.format_alpha(1e-3) == "0.1 %"
    assert pl.format_alpha(0.01) == "1 %"
    assert pl.power_unit("m/s") == "(m/s)²"
    assert pl.power_unit("Pa") == "Pa²"
    assert pl.power_unit("") == "dimensionless"  # the paper's second-order benchmark has no unit


def test_threshold_label_says_which_threshold_and_alpha_meaning():
    paper = pl.threshold_label("paper", 1e-3, "per-bin")
    assert "paper" in paper and "eq 62" in paper and "per-bin" in paper and "0.1 %" in paper
    exact = pl.threshold_label("exact", 1e-3, "family-wise", correction="bonferroni", n_tested=1999)
    assert "exact" in exact and "family-wise" in exact and "Bonferroni" in exact and "1999" in exact
    assert "K=100" in pl.threshold_label("exact", 1e-3, "family-wise", averaged=100)


def test_threshold_curve_masks_untested_bins():
    model = second_order(10.0, 0.1, Q=np.diag([1e-8, 1e-6]), R=np.diag([1e-8, 1e-6]))
    f = periodogram_freqs(400, model.dt)
    th = exact_threshold(model, f, 400, 1e-3)
    c = pl.threshold_curve(th, 1)
    assert c.kind == "exact" and np.isnan(c.values[0]) and np.isnan(c.values[-1])
    assert np.all(np.isfinite(c.values[1:-1]))
    assert "family-wise" in c.label and "Bonferroni" in c.label
    cp = pl.threshold_curve(paper_threshold(model, f, 1e-2), 0)
    assert cp.kind == "paper" and "per-bin" in cp.label and "1 %" in cp.label


# --------------------------------------------------------------------------- figure functions
def test_spectrum_figure_axes_lines_and_labels():
    fig = pl.spectrum_figure([_synthetic_panel(2), _synthetic_panel(3)], ncols=2, suptitle="s")
    axes = fig.axes
    assert len(axes) == 2
    # 1 spectrum + expected + thresholds (no bin is near 10x the mean: no halo of bins over)
    assert [len(ax.get_lines()) for ax in axes] == [4, 5]
    for ax in axes:
        assert ax.get_yscale() == "log"
        assert "Hz" in ax.get_xlabel()
        assert "(m/s)²" in ax.get_ylabel() and "velocity" in ax.get_ylabel()
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "expected E[S] (eq 56)" in labels and "thr 2" in labels


def test_spectrum_figure_inset_and_unused_cells():
    fig = pl.spectrum_figure([_synthetic_panel(1, inset=(0.0, 40.0))] * 3, ncols=2)
    assert len(pl.main_axes(fig)) == 3  # the 4th grid cell stays empty
    insets = _insets(fig)
    assert len(insets) == 3 and insets[0].get_xlim() == (0.0, 40.0)
    assert len(insets[0].get_lines()) == 3  # the panel's spectrum, expected and threshold
    # the zoom sits beside its main axes, not over it
    fig.canvas.draw()
    main, zoom = pl.main_axes(fig)[0].get_window_extent(), insets[0].get_window_extent()
    assert zoom.x0 > main.x1


def test_spectrum_figure_bad_input():
    with pytest.raises(ParameterError):
        pl.spectrum_figure([])
    bad = pl.SpectrumPanel(freqs_hz=np.arange(5.0), curves=(pl.SpectrumCurve(np.ones(4), "x"),))
    with pytest.raises(ShapeError, match="shape"):
        pl.spectrum_figure([bad])


def test_spectrogram_figure():
    t = np.arange(10) * 0.2 + 0.5
    f = np.arange(51.0)
    panel = pl.SpectrogramPanel(
        times_s=t,
        freqs_hz=f,
        power=np.ones((10, 51)),
        title="a",
        channel="velocity",
        fault_intervals=((0.0, 1.0),),
        detected_intervals=((0.2, 1.1),),
        flags=np.arange(10) < 3,
        fmax_hz=50.0,
    )
    fig = pl.spectrogram_figure([panel, panel])
    assert len(fig.axes) == 4  # two spectrograms and two colorbars
    ax = fig.axes[0]
    assert "Hz" in ax.get_ylabel() and "[s]" in ax.get_xlabel()
    with pytest.raises(ShapeError):
        pl.spectrogram_figure([pl.SpectrogramPanel(times_s=t, freqs_hz=f, power=np.ones((3, 3)))])


def test_boundary_layer_figure():
    t = np.linspace(0, 5, 101)
    k = 3
    panel = pl.BoundaryLayerPanel(
        t=t,
        psi=np.array([1e-4, 5e-4, 2e-3]),
        labels=("a", "b", "c"),
        error_measured=np.zeros((k, t.size)),
        error_unmeasured=np.zeros((k, t.size)),
        chattering=np.zeros((k, t.size)),
        fault_intervals=((1.0, 2.0),),
        fault_labels=("f0 = 3 Hz",),
    )
    fig = pl.boundary_layer_figure(panel)
    assert len(fig.axes) == 2 + k
    assert [len(ax.get_lines()) for ax in fig.axes] == [k, k, 1, 1, 1]
    assert fig.axes[-1].get_xlabel() == "time [s]"
    with pytest.raises(ShapeError):
        pl.boundary_layer_figure(pl.BoundaryLayerPanel(**{**panel.__dict__, "chattering": np.zeros((2, 5))}))


def test_save_figure_png(tmp_path):
    fig = pl.spectrum_figure([_synthetic_panel(2)])
    path = pl.save_figure(fig, tmp_path / "sub" / "x.png")
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and 1000 < len(data) < MAX_PNG_BYTES
    from PIL import Image

    with Image.open(path) as img:
        assert img.mode == "P" and img.text.get("Software") == "chatterspec"
    with pytest.raises(ParameterError, match=r"\.png"):
        pl.save_figure(pl.spectrum_figure([_synthetic_panel(1)]), tmp_path / "x.pdf")


# --------------------------------------------------------------------------- paper figures
def test_registry_names():
    assert pf.figure_names() == (
        "fig2",
        "fig4",
        "fig5",
        "fig6",
        "fig7",
        "fig8",
        "fig9",
        "fig10",
        "fig11",
        "fig12",
    )


def test_unknown_figure_lists_valid_names():
    with pytest.raises(ParameterError, match="valid figures: fig2, fig4"):
        pf.render("fig3")
    with pytest.raises(ParameterError, match="runs"):
        pf.render("fig5", runs=0)


def test_fig5_shows_11hz_peak_and_both_thresholds():
    res = pf.render("fig5", seed=0)
    main = pl.main_axes(res.figure)
    assert len(main) == 2 and len(_insets(res.figure)) == 2
    for ax in main:
        labels = [ln.get_label() for ln in ax.get_lines()]
        assert sum("paper flat bound" in s for s in labels) == 2 and sum("exact" in s for s in labels) == 2
        assert (
            "velocity" in ax.get_ylabel() and "dimensionless" in ax.get_ylabel() and "Hz" in ax.get_xlabel()
        )
        # nominal (10 Hz) and true (11 Hz) natural frequency lines
        vlines = sorted(ln.get_xdata()[0] for ln in ax.get_lines() if "natural frequency" in ln.get_label())
        assert vlines == pytest.approx([10.0, 11.0])
    labels = _legend_labels(res.figure)
    assert any("paper" in s and "per-bin" in s for s in labels)
    assert any("exact" in s and "family-wise" in s for s in labels)
    assert all("11.00 Hz" in n for n in res.notes)


_RATIO = re.compile(r"max S/threshold ([0-9.e+-]+) at ([0-9.]+) Hz, (\d+) bins over")


@pytest.mark.parametrize("name", ["fig5", "fig10"])
def test_notes_report_each_thresholds_own_maximum(name):
    """A ratio above 1 always comes with bins over, and 'no bin over' with a ratio <= 1."""
    res = pf.render(name, seed=0)
    found = [m for n in res.notes for m in _RATIO.findall(n)]
    assert len(found) >= 4
    for ratio, _, n_over in found:
        assert (float(ratio) > 1.0) == (int(n_over) > 0), (ratio, n_over)


def test_note_is_outside_the_axes_and_no_headroom():
    fig = pl.spectrum_figure([_synthetic_panel(2)])
    fig.canvas.draw()
    ax = fig.axes[0]
    note = next(t for t in ax.texts if t.get_text() == "peak")
    assert note.get_window_extent().y1 <= ax.get_window_extent().y0
    # the top of the log axis sits just above the highest drawn value (thresholds 1e-5, 2e-5)
    assert 2e-5 <= ax.get_ylim()[1] <= 2e-5 * 1.61


def test_bins_over_a_threshold_are_marked():
    f = np.linspace(0.0, 500.0, 201)
    p = np.full(f.size, 1e-6)
    p[[20, 21, 80]] = [5e-5, 2e-5, 1.5e-5]
    panel = pl.SpectrumPanel(
        freqs_hz=f,
        curves=(pl.SpectrumCurve(p, "S"),),
        thresholds=(
            pl.ThresholdCurve(np.full(f.size, 1e-5), "low", "exact", 1e-2),
            pl.ThresholdCurve(np.full(f.size, 3e-5), "high", "exact", 1e-3),
        ),
    )
    fig = pl.spectrum_figure([panel])
    ax = fig.axes[0]
    marks = [ln for ln in ax.get_lines() if ln.get_linestyle() == "None"]
    xs = sorted(tuple(np.round(ln.get_xdata(), 6)) for ln in marks)
    assert xs == sorted([tuple(f[[20, 21, 80]]), (f[20],)])  # over "low": 3 bins; over "high": 1 bin
    assert any("bins above a threshold" in s for s in _legend_labels(fig))
    # a background curve is not marked
    bg = pl.SpectrumPanel(**{**panel.__dict__, "curves": (pl.SpectrumCurve(p, "S", mark=False),)})
    assert not [ln for ln in pl.spectrum_figure([bg]).axes[0].get_lines() if ln.get_linestyle() == "None"]


def test_fig6_averaged_thresholds_use_K():
    res = pf.render("fig6", runs=4, seed=1)
    labels = _legend_labels(res.figure)
    assert any("paper" in s and "K=4" in s for s in labels)
    assert any("exact" in s and "K=4" in s for s in labels)
    assert not any("single record" in s for s in labels)


def test_averaged_paper_threshold_formula_and_false_alarm_rate():
    model = second_order(10.0, 0.1, Q=np.diag([1e-8, 1e-6]), R=np.diag([1e-8, 1e-6]))
    f = periodogram_freqs(400, model.dt)
    alpha, K = 1e-2, 10
    single = paper_threshold(model, f, alpha)
    avg = pf.averaged_paper_threshold(single, K)
    scale = stats.chi2.isf(alpha, 2 * K) / (2 * K) / (stats.chi2.isf(alpha, 2) / 2)
    np.testing.assert_allclose(avg.values, single.values * scale, rtol=1e-12)
    assert avg.averaged == K and avg.kind == "paper" and avg.alpha_meaning == "per-bin"
    # Under eq 62 a bin is sigma chi2(2)/2; the mean of K such bins exceeds the bound with probability alpha.
    # 200000 draws: the count is Binomial(200000, alpha); accept within its central 1 - 1e-6 interval.
    sigma = float(single.values[1, 0]) / (stats.chi2.isf(alpha, 2) / 2)
    rng = np.random.default_rng(12)
    n = 200_000
    mean = sigma * rng.chisquare(2, size=(n, K)).mean(axis=1) / 2.0
    hits = int(np.count_nonzero(mean > avg.values[1, 0]))
    lo, hi = stats.binom.ppf([5e-7, 1 - 5e-7], n, alpha)
    assert lo <= hits <= hi
    with pytest.raises(ParameterError):
        pf.averaged_paper_threshold(avg, 2)
    with pytest.raises(ParameterError):
        pf.averaged_paper_threshold(single, 0)


@pytest.mark.parametrize(("name", "levels"), [("fig10", 3), ("fig12", 4)])
def test_fault_levels_overlaid_on_one_axes(name, levels):
    res = pf.render(name, seed=0)
    (ax,) = pl.main_axes(res.figure)
    assert ax.get_xlim() == (0.0, pf.OVERLAY_FMAX_HZ)
    curves = [ln for ln in ax.get_lines() if ln.get_label().startswith("eha-")]
    assert len(curves) == levels + 1  # healthy + each level
    f_n = [ln for ln in ax.get_lines() if "natural frequency" in ln.get_label()]
    assert len(f_n) == levels + 1  # nominal + one true line per level
    band = [p for p in ax.patches if "chirp" in p.get_label()]
    assert len(band) == 1
    assert (band[0].get_x(), band[0].get_width()) == pytest.approx((10.0, 90.0))  # 10-100 Hz


def test_fig8_spectrograms_and_intervals():
    res = pf.render("fig8", seed=0)
    assert len(res.figure.axes) == 4
    assert len(res.notes) == 2 and all("true [0, 2) s, [4, 6) s" in n for n in res.notes)
    ax = res.figure.axes[0]
    labels = _legend_labels(res.figure)
    assert any("nominal natural frequency 5.0 Hz" in s for s in labels)
    assert any("true natural frequency 8.0 Hz on [0, 2) s" in s for s in labels)
    (seg,) = [c for c in ax.collections if "8.0 Hz" in c.get_label()]
    (xy,) = seg.get_segments()
    assert xy[:, 0].tolist() == [0.0, 2.0] and xy[:, 1] == pytest.approx([8.0, 8.0])  # only in its window


def test_fig2_small_run_count():
    res = pf.render("fig2", runs=2, seed=0)
    k = len(pf.FIG2_PSIS)
    axes = res.figure.axes
    assert len(axes) == 2 + k  # (a), (b), and one chattering row per psi
    assert [len(ax.get_lines()) for ax in axes] == [k, k] + [1] * k
    assert len(res.notes) == k
    assert "unit" not in "".join(ax.get_ylabel() + ax.get_title() for ax in axes)
    # the two mismatch windows are shaded differently
    shades = {tuple(p.get_facecolor()) for p in axes[0].patches}
    assert len(shades) == 2


def test_scenario_spectrum_errors():
    with pytest.raises(UnknownScenarioError, match="valid names"):
        pf.scenario_spectrum("no-such-scenario")
    with pytest.raises(ParameterError, match="unknown channel"):
        pf.scenario_spectrum("so-f11-low", channel="pressure")
    with pytest.raises(ParameterError, match="threshold"):
        pf.scenario_spectrum("so-f11-low", threshold="flat")


def test_scenario_spectrum_average_uses_averaged_paper_bound():
    res = pf.scenario_spectrum("so-f11-high", runs=2, threshold="paper")
    labels = _legend_labels(res.figure)
    assert any("paper" in s and "K=2" in s for s in labels)
    assert not any("single record" in s for s in labels)


def test_scenario_spectrum_all_channels_averaged():
    res = pf.scenario_spectrum("eha-healthy", channel="all", runs=2, threshold="exact")
    main = res.figure.axes
    assert len(main) == 3 and not _insets(res.figure)
    for ax in main:
        labels = [ln.get_label() for ln in ax.get_lines() if not ln.get_label().startswith("_")]
        assert len(labels) == 4  # one realization (grey), mean, expected, exact threshold
        assert [p.get_label() for p in ax.patches] == ["chirp input band 10-100 Hz"]


# --------------------------------------------------------------------------- commands
def _run(module, argv):
    parser = argparse.ArgumentParser(prog="chatterspec")
    module.register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


def test_figures_command_writes_png(tmp_path, capsys):
    out = tmp_path / "figs"
    assert _run(figures_cmd, ["figures", "--figures-dir", str(out), "--only", "fig5,11", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [e["name"] for e in doc["figures"]] == ["fig5", "fig11"]
    for name in ("fig5", "fig11"):
        data = (out / f"{name}.png").read_bytes()
        assert data[:8] == PNG_SIGNATURE and 10_000 < len(data) < MAX_PNG_BYTES


def test_figures_command_unknown_name(tmp_path):
    with pytest.raises(ChatterspecError, match="valid figures: fig2, fig4, fig5"):
        _run(figures_cmd, ["figures", "--figures-dir", str(tmp_path), "--only", "fig5,fig99"])


def test_figures_command_list(capsys):
    assert _run(figures_cmd, ["figures", "--list"]) == 0
    assert "fig12" in capsys.readouterr().out


def test_spectrum_command_writes_png(tmp_path, capsys):
    out = tmp_path / "s.png"
    argv = ["spectrum", "so-f11-high", "--plot", str(out), "--channel", "velocity", "--threshold", "paper"]
    assert _run(spectrum_cmd, argv) == 0
    assert "wrote" in capsys.readouterr().out
    data = out.read_bytes()
    assert data[:8] == PNG_SIGNATURE and 10_000 < len(data) < MAX_PNG_BYTES


def test_spectrum_command_errors(tmp_path):
    with pytest.raises(UnknownScenarioError, match="valid names"):
        _run(spectrum_cmd, ["spectrum", "nope", "--plot", str(tmp_path / "x.png")])
    with pytest.raises(ParameterError, match=r"\.png"):
        _run(spectrum_cmd, ["spectrum", "so-f11-low", "--plot", str(tmp_path / "x.jpg")])
    with pytest.raises(SystemExit):
        _run(spectrum_cmd, ["spectrum", "so-f11-low", "--alpha", "5"])


def test_plotting_not_imported_by_numeric_core():
    import subprocess
    import sys

    code = (
        "import sys, chatterspec, chatterspec.detection.spectral, chatterspec.detection.thresholds, "
        "chatterspec.detection.detect, "
        "chatterspec.detection.pipeline; print('matplotlib' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


# --------------------------------------------------------------------------- demo summary
def _demo_docs():
    def doc(name, ratios, healthy, fault_channel):
        chans = [
            {"channel": c, "peak_ratio": r}
            for c, r in zip(("position", "velocity", "pressure"), ratios, strict=False)
        ]
        return {
            "scenario": name,
            "channels": chans,
            "healthy": healthy,
            "fault_channel": fault_channel,
            "runs": 1,
            "threshold": {"kind": "exact", "alpha": 1e-3, "alpha_meaning": "family-wise"},
        }

    return [
        doc("eha-healthy", (0.5, 0.6, 0.55), True, None),
        doc("eha-leak-major", (0.5, 0.6, 19.5), False, "pressure"),
        doc("so-timeline-constant", (0.6, 3e5), False, "velocity"),
    ]


def test_demo_summary_figure(tmp_path):
    from chatterspec.figures import plot_studies

    docs = _demo_docs()
    rows = plot_studies.rows_from_reports(docs)
    assert [r.ratios for r in rows][1] == (0.5, 0.6, 19.5) and rows[0].healthy
    fig = plot_studies.summary_figure(rows, title="t", threshold_label="thr")
    (ax,) = fig.axes
    assert ax.get_xscale() == "log"
    lo, hi = ax.get_xlim()
    assert lo < 0.5 and hi > 3e5  # every ratio is inside the axis
    assert [t.get_text() for t in ax.get_yticklabels()] == [d["scenario"] for d in reversed(docs)]
    one = [ln for ln in ax.get_lines() if np.allclose(ln.get_xdata(), 1.0) and len(ln.get_xdata()) == 2]
    assert len(one) == 1  # the threshold line at ratio 1
    filled = [
        ln
        for ln in ax.get_lines()
        if ln.get_marker() != "None" and matplotlib.colors.to_rgba(ln.get_markerfacecolor()) != (1, 1, 1, 1)
    ]
    assert sorted(float(ln.get_xdata()[0]) for ln in filled) == [19.5, 3e5]  # fault channels only
    path = plot_studies.demo_summary(docs, tmp_path / "summary.png")
    assert path.read_bytes()[:8] == PNG_SIGNATURE
    with pytest.raises(ParameterError, match="peak_ratio"):
        plot_studies.rows_from_reports([{"scenario": "x", "channels": [{"channel": "a"}], "healthy": True}])
    with pytest.raises(ShapeError):
        plot_studies.summary_figure([plot_studies.RatioRow("x", ("a", "b"), (1.0,))])
    with pytest.raises(ParameterError):
        plot_studies.summary_figure([])
