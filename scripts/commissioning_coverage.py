"""Coverage of commissioning's parameter intervals over plants drawn with random parameter errors.

Each plant is the nominal model file's plant (default: the catalogue EHA, ``chatterspec scenarios
eha-healthy --model-toml``) with every declared parameter multiplied by an independent
``U(1 - spread, 1 + spread)`` factor (default +-30 %), driven by the catalogue chirp (10-100 Hz over
4 s, 300 rad/s, repeating) for ``--duration`` seconds (default 600 s, 10 minutes) with its own noise
seed; :func:`chatterspec.studies.commissioning.commission` fits the nominal model to the first two
thirds (the fit span of the default held-out split; the check is not run here) and the script counts,
per parameter and pooled, how often the plant's true value lies in the 95 % interval, with a 99 %
Clopper-Pearson interval of that fraction. It also reports the coverage of the R intervals.

    python scripts/commissioning_coverage.py --plants 200             # ~15 min on 2 shared cores
    python scripts/commissioning_coverage.py --plants 50 --duration 60
"""

from __future__ import annotations

import argparse
import time

import numpy as np

import chatterspec as cs
from chatterspec.online.simulated_stream import simulate_blocks
from chatterspec.studies.commissioning import commission
from chatterspec.studies.intervals import clopper_pearson


def _record(plant: cs.LinearModel, seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """``(z, u)`` of ``plant`` under the catalogue chirp (repeating every 4 s) for ``seconds``."""
    sc = cs.Scenario(name="plant", nominal=plant, input=cs.Chirp(10.0, 100.0, 4.0, 300.0), duration=4.0)
    parts = list(simulate_blocks(sc, seed, seconds, block_s=60.0))
    return np.concatenate([p[1] for p in parts]), np.concatenate([p[2] for p in parts])


def main(argv: list[str] | None = None) -> None:
    """Run the study and print the coverage table."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default=None, help="nominal model file (default: the catalogue EHA's)")
    ap.add_argument("--plants", type=int, default=200)
    ap.add_argument("--duration", type=float, default=600.0, help="seconds of data per plant")
    ap.add_argument("--spread", type=float, default=0.30, help="relative parameter error, uniform +-")
    ap.add_argument("--seed", type=int, default=2029)
    args = ap.parse_args(argv)
    if args.model is None:
        import tempfile
        from pathlib import Path

        from chatterspec.cli.scenarios import export_model_toml

        args.model = str(export_model_toml("eha-healthy", Path(tempfile.mkdtemp()) / "eha.toml"))
    spec = cs.load_model(args.model)
    nominal = spec.model
    names = nominal.parameter_map.parameter_names
    values = np.array([nominal.parameter_map.parameter(p).value for p in names])
    rng = np.random.default_rng(args.seed)
    factors = rng.uniform(1 - args.spread, 1 + args.spread, size=(args.plants, len(names)))
    hit = np.zeros((args.plants, len(names)), dtype=bool)
    r_hit = np.zeros((args.plants, nominal.n_outputs), dtype=bool)
    t0 = time.process_time()
    for i in range(args.plants):  # each plant is another model: one simulation and fit per plant
        truth = values * factors[i]
        plant = nominal.parameter_map.apply(nominal, dict(zip(names, truth.tolist(), strict=True)))
        z, u = _record(plant, args.duration, seed=args.seed + 1 + i)
        n_fit = z.shape[0] - round(z.shape[0] / 3)
        res = commission(spec, z[:n_fit], u[:n_fit], check=False, confidence=0.95)
        for j, p in enumerate(res.parameters.parameters):
            hit[i, j] = p.ci_low <= truth[j] <= p.ci_high
        nf = res.noise
        r_true = np.diag(nominal.R)
        r_hit[i] = (nf.r_ci_low <= r_true) & (r_true <= nf.r_ci_high)
    cpu = time.process_time() - t0
    print(
        f"{args.plants} plants, parameters x U(1 - {args.spread:g}, 1 + {args.spread:g}), "
        f"{args.duration:g} s each (fit on the first two thirds), seed {args.seed}; {cpu:.0f} s CPU"
    )
    print(f"{'quantity':<16} {'in 95% interval':>16} {'fraction':>9}  99% Clopper-Pearson   contains 0.95")
    rows = [(n, hit[:, j]) for j, n in enumerate(names)] + [("all parameters", hit.ravel())]
    rows += [(f"R {n}", r_hit[:, c]) for c, n in enumerate(nominal.output_names)]
    for label, h in rows:
        k, n = int(h.sum()), int(h.size)
        lo, hi = clopper_pearson(k, n, 0.99)
        print(f"{label:<16} {k:>8} of {n:<5} {k / n:>9.3f}  [{lo:.3f}, {hi:.3f}]      {lo <= 0.95 <= hi}")
    print("(the pooled row counts each plant's parameters as separate trials; they come from one fit)")


if __name__ == "__main__":
    main()
