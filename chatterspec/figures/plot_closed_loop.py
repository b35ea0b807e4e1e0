"""Figures of the closed loop: power vs richness and dither, step responses, chattering spectra.

Imported on demand only (the numeric core never imports matplotlib).
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict, Unpack

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from ..palette import NEUTRAL, channel_color, mpl
from .style import power_unit

if TYPE_CHECKING:  # pragma: no cover
    from matplotlib.figure import Figure

    from ..plants.scenarios import Scenario
    from ..studies.closed_loop import ExcitationResult
    from ..studies.intervals import RateEstimate

__all__ = ["closed_loop_spectra_figure", "excitation_figure", "footprint_figure", "step_response_figure"]


def _color(index: int) -> tuple[float, float, float]:
    """Curve colour ``index`` from the shared palette (no red: red means a fault verdict)."""
    return mpl(channel_color(index))


class _Style(TypedDict):
    """The line style of one series of :func:`_errorbar`."""

    ls: str
    color: tuple[float, float, float]
    label: str
    marker: NotRequired[str]


def _errorbar(ax: plt.Axes, x: np.ndarray, ests: list[RateEstimate], **kw: Unpack[_Style]) -> None:
    rate = np.array([e.rate for e in ests])
    lo = np.array([e.ci_low for e in ests])
    hi = np.array([e.ci_high for e in ests])
    kw.setdefault("marker", "o")
    ax.errorbar(x, rate, yerr=[rate - lo, hi - rate], capsize=3, ms=4, **kw)


def excitation_figure(res: ExcitationResult, target: float = 0.95) -> Figure:
    """Detection power vs the reference's richness and vs dither, and the tracking cost of the dither.

    Left: detection rate (Clopper-Pearson bars) without dither against the RMS velocity of each
    reference's noise-free response. Middle: detection rate against the dither level for every
    reference run at several levels, with the ``target`` line and (faint) the healthy loop's
    false-alarm rate. Right: the healthy loop's tracking RMS (mm) against the dither level. One
    line style per position-sensor noise.

    Parameters
    ----------
    res : ExcitationResult
        From :func:`chatterspec.studies.closed_loop.excitation_study`.
    target : float
        Detection rate drawn as the target line.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.4))
    styles = ("-", "--", ":", "-.")
    markers = ("o", "s", "^", "D")  # one marker per sensor noise too: a short legend swatch hides a dash
    swept = [r for r in res.references if len(res.levels(r)) > 1]
    names: list[str] = []
    for i, noise in enumerate(res.position_noise):
        ls = styles[i % len(styles)]
        mk = markers[i % len(markers)]
        tag = f"sensor {noise * 1e3:g} mm"
        still = [p for p, (_, d) in enumerate(res.points) if d == 0.0]
        if still:
            speed = np.array([max(res.response_speed[res.points[p][0]] * 1e3, 0.1) for p in still])
            order = np.argsort(speed)
            ests = [res.detection(i, still[k]) for k in order]
            _errorbar(axes[0], speed[order], ests, ls=ls, marker=mk, color=_color(0), label=tag)
            if i == 0:
                # numbers beside the points, the names in a key: names of references with close speeds
                # ran into each other
                for n_lab, k in enumerate(order):
                    rate = ests[n_lab].rate
                    names.append(f"{n_lab + 1} {res.points[still[k]][0]}")
                    axes[0].annotate(
                        str(n_lab + 1), (speed[k], rate), fontsize=7, xytext=(0, -9 if rate > 0.5 else 5),
                        textcoords="offset points", ha="center", va="top" if rate > 0.5 else "bottom",
                    )  # fmt: skip
        for c, ref in enumerate(swept):
            ps = res.levels(ref)
            x = np.array([res.points[p][1] for p in ps])
            _errorbar(
                axes[1],
                x,
                [res.detection(i, p) for p in ps],
                ls=ls,
                marker=mk,
                color=_color(c + 1),
                label=f"{ref}, {tag}",
            )
            axes[1].plot(
                x, [res.false_alarm(i, p).rate for p in ps], ls="none", marker="x", ms=6,
                color="k" if i == 0 else mpl(NEUTRAL), zorder=5, label=f"false alarms, healthy, {tag}",
            )  # fmt: skip
            axes[2].errorbar(
                x,
                res.tracking_mm[i, ps, 0],
                yerr=res.tracking_se_mm[i, ps, 0],
                ls=ls,
                color=_color(c + 1),
                marker=mk,
                ms=4,
                capsize=3,
                label=f"{ref}, {tag}",
            )
    axes[0].set_xscale("log")
    axes[0].set_xlabel("RMS velocity of the response (mm/s; hold drawn at 0.1)")
    axes[0].set_ylabel(f"detection rate on {res.channel}")
    axes[0].set_title("(a) richness of the reference, no dither", fontsize=9)
    axes[1].axhline(target, color="k", lw=0.8, ls=":", label=f"{target:.0%}")
    axes[1].axhline(res.alpha, color="grey", lw=0.8, ls="--", label=f"alpha = {res.alpha:g}")
    unit = "mm" if "reference" in res.dither_description else "rad/s"
    unit += " per tone" if "multisine" in res.dither_description else ""
    axes[1].set_xlabel(f"dither amplitude ({unit})")
    axes[1].set_ylabel("detection rate (x: false-alarm rate)")
    # the study's description names the swept amplitude LEVEL: here it is A, the x axis
    dither = res.dither_description.replace(", LEVEL in", " in").replace("LEVEL", "A")
    axes[1].set_title(textwrap.fill(f"(b) dither: {dither}; A on the x axis", 60), fontsize=9)
    if names:
        axes[0].text(
            0.02, 0.62, "\n".join(names), transform=axes[0].transAxes, fontsize=7, va="top",
            bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
        )  # fmt: skip
    axes[2].set_xlabel(axes[1].get_xlabel())
    axes[2].set_ylabel("tracking RMS, healthy loop (mm)")
    axes[2].set_title("(c) the price in tracking", fontsize=9)
    for ax in axes:
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, handlelength=3.5)
    for ax in axes[:2]:
        ax.set_ylim(-0.03, 1.05)
    size = f"{res.size:g} {res.unit.replace('^3', '³')}"
    fig.suptitle(
        f"closed-loop EHA (PI position loop), {res.family} {size}: detection at family-wise "
        f"alpha = {res.alpha:g}, {res.runs} runs per point, {res.confidence:.0%} Clopper-Pearson",
        fontsize=11,
    )
    fig.tight_layout()
    return fig


def step_response_figure(scenarios: Sequence[Scenario], runs: int = 1, seed: int = 0) -> Figure:
    """Position, pump speed and pressure of closed-loop scenarios (realization 0 and the noise-free response).

    Parameters
    ----------
    scenarios : sequence of Scenario
        Closed-loop scenarios on the same reference (e.g. healthy and faulty).
    runs : int
        Realizations simulated (the first is drawn).
    seed : int
        Root seed.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..plants.simulate import loop_response, simulate

    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for s, sc in enumerate(scenarios):
        t, r, x, u = loop_response(sc)
        sim = simulate(sc, runs, seed)
        color = _color(s)
        if s == 0:
            axes[0].plot(t, r * 1e3, color="k", lw=1, ls="--", label="reference")
        # the noise-free response a wide light band, the realization a thin line inside it (they nearly
        # coincide: two lines of one width hid each other)
        wide: dict[str, Any] = {"color": color, "lw": 4.0, "alpha": 0.3, "solid_capstyle": "butt"}
        axes[0].plot(t, x[:, 0] * 1e3, label=sc.name, **wide)
        axes[0].plot(t, sim.x[0, :, 0] * 1e3, color=color, lw=0.7)
        axes[1].plot(t, u, **wide)
        axes[1].plot(t, sim.u[0, :, 0], color=color, lw=0.7)
        axes[2].plot(t, x[:, 2] * 1e-3, **wide)
    loop = scenarios[0].closed_loop
    assert loop is not None  # (closed-loop scenarios)
    sat = loop.controller.saturation
    for v in (-sat, sat):
        axes[1].axhline(v, color=mpl(NEUTRAL), lw=0.8, ls=":", label="saturation" if v > 0 else None)
    axes[0].set_ylabel("position (mm)")
    axes[1].set_ylabel("pump speed u (rad/s)")
    axes[2].set_ylabel("pressure (kPa), noise-free")
    axes[2].set_xlabel("time (s)")
    axes[0].set_title(
        f"closed-loop EHA (PI position loop), {len(scenarios)} plants on one reference: noise-free "
        f"response (wide, light), realization 0 of seed {seed} (thin)",
        fontsize=10,
    )
    for ax in axes:
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    handles += [
        plt.Line2D([], [], color="k", lw=4.0, alpha=0.3),
        plt.Line2D([], [], color="k", lw=0.7),
    ]
    labels += ["noise-free response", f"realization 0 (seed {seed})"]
    # one legend: the colours are the same in every row
    axes[0].legend(handles, labels, fontsize=7, loc="upper right", handlelength=3)
    axes[1].legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig


def closed_loop_spectra_figure(
    scenarios: Sequence[Scenario],
    runs: int = 50,
    seed: int = 0,
    alpha: float = 1e-3,
) -> Figure:
    """Mean chattering periodogram per channel of several scenarios against their expected healthy spectra.

    Typically an open-loop fault beside the same fault in closed loop, moving and held still
    (``eha-leak-medium``, ``eha-cl-leak-medium``, ``eha-cl-hold-leak-medium``). The expected healthy
    spectrum (eq 56, exact finite-N form) and the single-record threshold are drawn once per
    distinct nominal model (the closed-loop scenarios' position sensor is quieter than eq 66's).

    Parameters
    ----------
    scenarios : sequence of Scenario
        Linear scenarios with the same output channels.
    runs : int
        Realizations averaged.
    seed : int
        Root seed.
    alpha : float
        Family-wise level of the single-record threshold drawn.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..detection.pipeline import iter_chattering
    from ..detection.spectral import expected_spectrum, periodogram, spectrum_model
    from ..detection.thresholds import exact_threshold

    m = scenarios[0].nominal.n_outputs
    fig, axes = plt.subplots(m, 1, figsize=(9, 2.6 * m), sharex=True, squeeze=False)
    drawn: dict[str, str] = {}
    models: list[np.ndarray] = []  # each distinct nominal model's threshold (bins, m)
    for k, sc in enumerate(scenarios):
        total, P = None, None
        for rec in iter_chattering(sc, runs, seed):
            P = periodogram(rec.values, rec.dt)
            part = P.power.sum(axis=0)
            total = part if total is None else total + part
        assert total is not None and P is not None  # (runs >= 1 records)
        mean = total / runs
        f = P.freqs_hz
        nom, N = spectrum_model(sc.nominal), sc.n_samples - 1
        key = nom.fingerprint()
        if key not in drawn:
            drawn[key] = sc.name
            E = expected_spectrum(nom, f, N)
            thr = exact_threshold(nom, f, N, alpha)
            models.append(np.asarray(thr.values))
        for c in range(m):
            ax = axes[c, 0]
            # earlier scenarios wider underneath, later ones thinner on top: coinciding curves stay visible
            width = 0.7 + 0.6 * (len(scenarios) - 1 - k)
            kw = {"lw": width, "color": _color(k), "alpha": 0.85, "zorder": 2 + k}
            ax.semilogy(f[1:], mean[1:, c], label=sc.name, **kw)
            if drawn[key] == sc.name:
                ax.semilogy(
                    f[1:],
                    E[1:, c],
                    color="k",
                    lw=1,
                    ls="-" if k == 0 else "-.",
                    label=f"E[S] healthy ({sc.name}'s model)",
                    zorder=10,
                )
                ax.semilogy(
                    f[1:],
                    thr.values[1:, c],
                    color="k",
                    lw=0.8,
                    ls="--" if k == 0 else ":",
                    label=f"threshold, alpha {alpha:g} ({sc.name}'s model)",
                    zorder=10,
                )
    nominal = scenarios[0].nominal
    for c in range(m):
        if len(models) > 1 and all(np.allclose(th[1:, c], models[0][1:, c], rtol=0.01) for th in models[1:]):
            axes[c, 0].text(
                0.01, 0.95, "the models' E[S] and thresholds coincide on this channel (one curve each)",
                transform=axes[c, 0].transAxes, fontsize=7, va="top",
            )  # fmt: skip
        axes[c, 0].set_ylabel(f"{nominal.output_names[c]}\n[{power_unit(nominal.output_units[c])}]")
        axes[c, 0].set_xscale("log")
        axes[c, 0].grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=7, frameon=False)
    axes[-1, 0].set_xlabel("frequency (Hz)")
    fig.suptitle(
        f"EHA chattering, open vs closed loop: mean periodogram over {runs} runs per scenario (seed {seed})\n"
        f"black: healthy E[S] (eq 56) and threshold (family-wise alpha {alpha:g}) of each nominal model",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.02 + 0.018 * ((len(labels) + 1) // 2), 1, 1))
    return fig


def footprint_figure(scenario: Scenario, seed: int = 0) -> Figure:
    """Fault minus healthy, realization 0, same noise: the loop hides the fault in the position, not in u.

    Three rows against time: the position change (closed loop, and the healthy loop's command
    replayed open loop, :func:`chatterspec.studies.closed_loop.replayed_open_loop`), the pump speed
    change (closed loop), and the pressure chattering of the faulty closed loop (with its 100 ms
    moving average, where the leak's slow term shows) against the healthy chattering's +-3 standard
    deviations.

    Parameters
    ----------
    scenario : Scenario
        A faulty closed-loop scenario (linear), e.g. ``eha-cl-leak-medium``.
    seed : int
        Root seed.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..detection.pipeline import chattering_record
    from ..detection.spectral import chattering_autocovariance, spectrum_model
    from ..plants.simulate import simulate
    from ..studies.closed_loop import replayed_open_loop
    from ..studies.diagnosis import healthy_version

    replay = replayed_open_loop(scenario)
    sims = {
        k: simulate(s, 1, seed)
        for k, s in (
            ("closed", scenario),
            ("closed-healthy", healthy_version(scenario)),
            ("replay", replay),
            ("replay-healthy", healthy_version(replay)),
        )
    }
    t = sims["closed"].t
    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for key, color, label in (
        ("replay", _color(1), "command replayed open loop"),
        ("closed", _color(0), "closed loop"),
    ):
        d = (sims[key].z[0, :, 0] - sims[f"{key}-healthy"].z[0, :, 0]) * 1e3
        axes[0].plot(t, d, color=color, lw=1, label=f"{label}: RMS {np.sqrt(np.mean(d**2)):.3f} mm")
    du = sims["closed"].u[0, :, 0] - sims["closed-healthy"].u[0, :, 0]
    axes[1].plot(
        t, du, color=_color(0), lw=0.8, label=f"closed loop: RMS {np.sqrt(np.mean(du**2)):.2f} rad/s"
    )
    model = spectrum_model(scenario.nominal)
    p = model.output_names.index("pressure") if "pressure" in model.output_names else model.n_outputs - 1
    e = chattering_record(model, sims["closed"].z, sims["closed"].u).values[0, :, p]
    sd = np.sqrt(chattering_autocovariance(model)[0][p])
    axes[2].plot(
        t[1:], e, color=_color(0), lw=0.4, label=f"{model.output_names[p]} chattering, faulty closed loop"
    )
    smooth = np.convolve(e, np.full(100, 0.01), mode="same")
    axes[2].plot(
        t[1:], smooth, color=_color(2), lw=1.2, label="its 100 ms moving average (the leak's slow term)"
    )
    for v in (-3 * sd, 3 * sd):
        axes[2].axhline(v, color="k", lw=0.8, ls="--")
    axes[0].set_ylabel("position change (mm)")
    axes[1].set_ylabel("pump speed change (rad/s)")
    axes[2].set_ylabel(f"chattering ({model.output_units[p]})")
    axes[2].set_xlabel("time (s)")
    axes[0].set_title(
        f"{scenario.name}: fault minus healthy on the same noise (realization 0); dashed: ±3 sd healthy",
        fontsize=10,
    )
    for ax in axes:
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    return fig
