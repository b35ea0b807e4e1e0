"""Regenerate the closed-loop figures in figures/ and print the numbers the docs quote.

    python scripts/make_closed_loop_figures.py            # 2000-run hold study, 500-run figure
    python scripts/make_closed_loop_figures.py --quick    # small run counts (a smoke test)
    python scripts/make_closed_loop_figures.py --figures-only  # the four figures at full size only

Writes ``figures/closed_loop_step_response.png`` (healthy vs leaky vs high-friction actuator on the
saturating step reference), ``figures/closed_loop_spectra.png`` (mean chattering periodograms:
open loop, closed loop moving, held still, held with dither), ``figures/closed_loop_footprint.png``
(fault minus healthy: position, pump speed, pressure chattering) and
``figures/closed_loop_power_dither.png`` (power vs richness and dither, tracking cost), and prints
the catalogue loop's move metrics, the footprint table and the excitation study's answer.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from chatterspec.figures.plot_closed_loop import (
    closed_loop_spectra_figure,
    excitation_figure,
    footprint_figure,
    step_response_figure,
)
from chatterspec.figures.plot_studies import save
from chatterspec.plants.closed_loop import ClosedLoop, loop_mode
from chatterspec.plants.models import eha_linear
from chatterspec.plants.scenarios import (
    EHA4_CL_CONTROLLER,
    EHA_CL_CONTROLLER,
    eha_closed_loop_scenario,
    scenario,
)
from chatterspec.plants.simulate import move_metrics
from chatterspec.studies.closed_loop import (
    EXCITATION_REFERENCES,
    dither_signal,
    excitation_points,
    excitation_scenario,
    excitation_study,
    footprint_table,
)

OUT = Path(__file__).resolve().parents[1] / "figures"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small run counts")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument(
        "--figures-only",
        action="store_true",
        help="skip what only prints (footprint table, 2000-run hold study): the figures in minutes",
    )
    args = ap.parse_args()
    q = args.quick
    out = args.out
    t0 = time.perf_counter()

    print("catalogue controller:", EHA_CL_CONTROLLER.describe())
    print("  dominant closed-loop mode:", loop_mode(eha_linear(), EHA_CL_CONTROLLER).to_dict())
    for name in ("eha-cl-healthy", "eha-cl-leak-major"):
        for m in move_metrics(scenario(name)):
            print(f"  {name}: {m.to_dict()}")
    steps = eha_closed_loop_scenario(
        "4-steps", ClosedLoop(EHA_CL_CONTROLLER, EXCITATION_REFERENCES["4-steps"])
    )
    for m in move_metrics(steps):
        print(f"  4 steps: {m.to_dict()}")
    print("eha4 controller:", EHA4_CL_CONTROLLER.describe())
    for m in move_metrics(scenario("eha4-cl-leak-timeline")):
        print(f"  eha4-cl-leak-timeline: {m.to_dict()}")

    step_scenarios = [
        excitation_scenario("leakage", None, "4-steps"),
        excitation_scenario("leakage", 9e-11, "4-steps"),
        excitation_scenario("friction", 7000.0, "4-steps"),
    ]
    labels = ("healthy", "leak L = 9e-11 m³/(s·Pa)", "friction a = 7000 N·s/m")
    for sc, label in zip(step_scenarios, labels, strict=True):
        object.__setattr__(sc, "name", f"4 steps, {label}")
    print("wrote", save(step_response_figure(step_scenarios), out / "closed_loop_step_response.png"))

    held_dither = excitation_scenario("leakage", 6e-11, "hold", dither_signal("multisine", 6.0))
    object.__setattr__(held_dither, "name", "eha-cl-hold-leak-medium + 6 rad/s dither")
    spectra = [scenario(n) for n in ("eha-leak-medium", "eha-cl-leak-medium", "eha-cl-hold-leak-medium")]
    fig = closed_loop_spectra_figure([*spectra, held_dither], runs=10 if q else 200, seed=0)
    print("wrote", save(fig, out / "closed_loop_spectra.png"))

    print("wrote", save(footprint_figure(scenario("eha-cl-leak-medium")), out / "closed_loop_footprint.png"))
    if not args.figures_only:
        _, table = footprint_table(runs=10 if q else 200, seed=0)
        print(table)
        hold = excitation_study(
            points=excitation_points(["hold"], [0, 3, 4, 5, 5.5, 6, 6.5, 7, 8, 10]),
            runs=64 if q else 2000,
            seed=20,
            progress=not q,
        )
        print(json.dumps(hold.answers(0.95), indent=1))
    res = excitation_study(position_noise=(1e-5, 1e-3), runs=32 if q else 500, seed=0, progress=not q)
    print("wrote", save(excitation_figure(res), out / "closed_loop_power_dither.png"))
    for row in res.rows():
        print(
            f"  sensor {row['position_noise_mm']:g} mm {row['reference']:<12} dither {row['dither']:>4g}: "
            f"FA {row['false_alarm']['rate']:.4f} detect {row['detection']['rate']:.4f} "
            f"[{row['detection']['ci_low']:.4f}, {row['detection']['ci_high']:.4f}] "
            f"track {row['tracking_rms_mm']:.4f} mm, u RMS {row['u_rms']:.1f}"
        )
    print(f"done in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
