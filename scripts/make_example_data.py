"""Regenerate ``examples/eha_model.toml``, ``examples/eha_data.csv`` and ``examples/eha_rig.toml``.

An 8 s run of the linear EHA (Table 1, eq 65-67) at 1 kHz driven by a
10-100 Hz chirp: healthy for 4 s, then an internal leakage of 9e-11 m^3/(s Pa)
(the catalogue's ``eha-leak-major`` level). Values are written with 7
significant digits so the CSV stays below 500 kB. ``eha_rig.toml`` stands for a
real actuator in the commissioning walk-through: the Table 1 EHA with its bulk
modulus 10 % low and its friction 10 % high, the catalogue chirp in its
``[simulation]`` table.

Usage: ``python scripts/make_example_data.py [--seed 7]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from chatterspec.detection.spectral import chattering_autocovariance
from chatterspec.plants.models import eha_linear
from chatterspec.plants.scenarios import Scenario, Segment
from chatterspec.plants.signals import Chirp
from chatterspec.plants.simulate import simulate

ROOT = Path(__file__).resolve().parents[1] / "examples"
DURATION_S, FAULT_AT_S, LEAKAGE = 8.0, 4.0, 9e-11


def _fmt_matrix(M: np.ndarray) -> str:
    rows = ", ".join("[" + ", ".join(f"{v:.17g}" for v in row) + "]" for row in M)
    return f"[{rows}]"


def write_model(path: Path) -> None:
    model = eha_linear()
    gamma0, _ = chattering_autocovariance(model)
    psi = 3.0 * np.sqrt(gamma0)  # ~3 sigma of the healthy chattering: the sat SVSF rarely chatters
    text = f"""# Linear electro-hydraulic actuator (Table 1, eq 65-67), explicit Euler.
# Format: see examples/README.md. Regenerate with scripts/make_example_data.py.
name = "linear EHA (Table 1)"
dt = {model.dt!r}                       # sampling time, s

[channels]
outputs = ["position", "velocity", "pressure"]
units = ["m", "m/s", "Pa"]
inputs = ["pump_speed"]
states = ["position", "velocity", "pressure"]

[matrices]
form = "discrete"
A = {_fmt_matrix(model.A)}
B = {_fmt_matrix(model.B)}
C = {_fmt_matrix(model.C)}
Q_diag = [{", ".join(f"{v:.17g}" for v in np.diag(model.Q))}]
R_diag = [{", ".join(f"{v:.17g}" for v in np.diag(model.R))}]

[svsf]
psi = [{", ".join(f"{v:.6g}" for v in psi)}]   # 3 x healthy chattering std per output
gamma = 0.1

# Fault identification: the physical parameters, the other constants the formulas use (dt is
# the model's), the entries of the DISCRETE A and B they enter (1-based [row, column]), and the
# hypotheses (sets of parameters that may have changed together; default one per parameter).
# At the nominal values the formulas must give A and B above.
{model.parameter_map.to_toml()}
"leakage+friction" = ["leakage", "friction"]

[detector]
alpha = 0.001            # per-frame level: the drawn verdict, and the rule of `monitor --rule frame --alpha`
correction = "bonferroni"
window_s = 1.0
hop_s = 0.2
window = "hamming"
"""
    path.write_text(text)


def write_data(path: Path, seed: int) -> None:
    nominal = eha_linear()
    scenario = Scenario(
        name="eha-example",
        nominal=nominal,
        input=Chirp(10.0, 100.0, DURATION_S, 300.0),
        duration=DURATION_S,
        windows=(Segment(FAULT_AT_S, DURATION_S, eha_linear(leakage=LEAKAGE), f"leakage {LEAKAGE:g}"),),
        fault="leakage",
        fault_channel="pressure",
    )
    sim = simulate(scenario, runs=1, seed=seed)
    cols = np.column_stack([sim.t, sim.z[0], sim.u[:, 0]])
    header = "time,position,velocity,pressure,pump_speed"
    comment = (
        f"# linear EHA, chirp 10-100 Hz; healthy for t < {FAULT_AT_S:g} s, leakage {LEAKAGE:g} m^3/(s Pa) "
        f"from t = {FAULT_AT_S:g} s; seed {seed}\n"
    )
    with path.open("w") as fh:
        fh.write(comment)
        fh.write(header + "\n")
        np.savetxt(fh, cols, delimiter=",", fmt=["%.4f", "%.7g", "%.7g", "%.7g", "%.7g"])


def write_rig(path: Path) -> None:
    """The stand-in actuator: Table 1 with bulk modulus 10 % low and friction 10 % high."""
    import dataclasses

    from chatterspec.plants.modelfile import signal_table, write_model_toml

    nominal = eha_linear()
    pm = nominal.parameter_map
    rig = pm.apply(nominal, {"bulk_modulus": 0.9 * pm.parameter("bulk_modulus").value,
                             "friction": 1.1 * pm.parameter("friction").value})  # fmt: skip
    rig = dataclasses.replace(rig, name="EHA rig (bulk modulus 10 % low, friction 10 % high)")
    psi = 3.0 * np.sqrt(chattering_autocovariance(rig)[0])
    comment = (
        "A stand-in for a real actuator (commissioning walk-through in the README): the linear EHA of\n"
        "Table 1 with its bulk modulus 10 % low and its friction 10 % high, driven by the catalogue chirp.\n"
        "Regenerate with scripts/make_example_data.py."
    )
    sim = {"duration_s": 4.0, "input": signal_table(Chirp(10.0, 100.0, 4.0, 300.0))}
    write_model_toml(path, rig, psi, comment=comment, tables={"simulation": sim})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=7)
    args = ap.parse_args()
    ROOT.mkdir(exist_ok=True)
    write_model(ROOT / "eha_model.toml")
    write_data(ROOT / "eha_data.csv", args.seed)
    write_rig(ROOT / "eha_rig.toml")
    for name in ("eha_model.toml", "eha_data.csv", "eha_rig.toml"):
        print(f"wrote {ROOT / name} ({(ROOT / name).stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    main()
