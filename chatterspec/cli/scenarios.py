"""``chatterspec scenarios [--json]``: list the scenario catalogue (``docs/design.md`` §5)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, cast

from ..errors import ParameterError
from ..jsonout import dumps
from ._options import add_report_args, command

if TYPE_CHECKING:  # pragma: no cover
    from ..plants.nonlinear import NonlinearModel
    from ..plants.scenarios import Scenario


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec scenarios`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "scenarios",
        run,
        help="list the scenario catalogue",
        description="List every catalogue scenario with its plant kind (linear / nonlinear) and, per "
        "segment, the true plant's natural frequency (Hz) and damping ratio (for a nonlinear plant: "
        "of its linearization at rest, marked ~).",
    )
    add_report_args(p, progress=False)
    p.add_argument(
        "name", nargs="?", default=None, metavar="NAME", help="one scenario (needed by --model-toml)"
    )
    p.add_argument(
        "--model-toml",
        type=Path,
        default=None,
        metavar="FILE",
        help="write NAME's nominal model as a TOML model file for `chatterspec monitor FILE`",
    )


def export_model_toml(name: str, path: Path) -> Path:
    """Write the nominal model of catalogue scenario ``name`` as a monitor model file.

    ``psi`` is the scenario's boundary layer when it has one, otherwise three
    standard deviations of the healthy chattering per output (eq 58; the value
    ``examples/eha_model.toml`` uses): the smoothing SVSF then rarely chatters
    on healthy data. The ``[detector]`` table is left to the loader's defaults.
    """
    import numpy as np

    from ..detection.spectral import chattering_autocovariance, spectrum_model
    from ..plants.modelfile import write_model_toml
    from ..plants.scenarios import scenario

    sc = scenario(name)
    if not sc.is_linear:
        return _export_nonlinear(sc, name, path)
    model = spectrum_model(sc.nominal)  # (linear: the nonlinear export returned above)
    if sc.psi is not None:
        psi, why = np.asarray(sc.psi, dtype=float), "the scenario's boundary layer"
    else:
        psi, why = 3.0 * np.sqrt(chattering_autocovariance(model)[0]), "3 x healthy chattering std"
    comment = (
        _comment_head(sc, name) + f"Written by `chatterspec scenarios {name} --model-toml`; psi = {why}.\n"
        f"Stream it: chatterspec simulate {name} | chatterspec monitor {path.name} --data -"
    )
    return write_model_toml(path, model, psi, gamma=0.1, comment=comment)


def _comment_head(sc: Scenario, name: str) -> str:
    """The first lines of an exported model file's comment: whose nominal model it is, and its fault."""
    head = f"Nominal (healthy) model of the chatterspec catalogue scenario {name!r}: {_nominal_text(sc)}.\n"
    if not sc.is_healthy:
        head += f"The scenario's true plant differs from it (the fault to find): {sc.description}.\n"
    return head


def _export_nonlinear(sc: Scenario, name: str, path: Path) -> Path:
    """A nonlinear nominal model as a model file naming its functions, with the scenario's input."""
    from ..plants.modelfile import signal_table, write_nonlinear_model_toml

    simulation: dict = {"duration_s": sc.duration}
    if sc.x0 is not None and sc.x0.any():
        simulation["x0"] = sc.x0
    table = signal_table(sc.input)
    if table is not None:
        simulation["input"] = table
    comment = (
        _comment_head(sc, name)
        + f"Written by `chatterspec scenarios {name} --model-toml`. A nonlinear model: calibrate it\n"
        f"first (chatterspec calibrate {path.name} --out cal.npz), then\n"
        f"chatterspec monitor {path.name} --calibration cal.npz"
    )
    model = cast("NonlinearModel", sc.nominal)  # (the caller's branch for a nonlinear scenario)
    return write_nonlinear_model_toml(path, model, simulation=simulation, comment=comment)


def _nominal_text(sc: Scenario) -> str:
    """One line on the nominal model itself (name, natural frequency, damping), not the scenario's plant."""
    nominal = sc.nominal
    f0, zeta = nominal.natural_frequency_hz, nominal.damping_ratio
    mode = "" if f0 is None else f", natural frequency {f0:.4g} Hz, damping {zeta:.4g}"
    return f"{nominal.name}{mode}, dt = {nominal.dt:g} s"


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec scenarios`` with the parsed ``args``; returns the exit status."""
    if args.model_toml is not None:
        if args.name is None:
            raise ParameterError("--model-toml needs a scenario NAME (see `chatterspec scenarios`)")
        from ._report import check_output_path

        check_output_path(args.model_toml, "--model-toml", suffixes=(".toml",))
        path = export_model_toml(args.name, args.model_toml)
        if args.json:
            print(dumps({"scenario": args.name, "model_toml": str(path)}, indent=2))
        else:
            print(f"wrote {path} (nominal model of {args.name}; use it with `chatterspec monitor {path}`)")
        return 0
    from ..plants.scenarios import catalogue, scenario

    entries = [sc.describe() for sc in catalogue().values()]
    if args.name is not None:
        entries = [scenario(args.name).describe()]
    if args.json:
        print(dumps({"scenarios": entries}, indent=2, allow_nan=True))
        return 0
    print(
        f"{'name':<24} {'kind':<9} {'fault':<18} {'level':<26} "
        "segments (true plant: f0 Hz / zeta on [start, stop) s)"
    )
    for e in entries:
        segs = "; ".join(
            f"[{s['start_s']:g},{s['stop_s']:g}) {'~' if s.get('linearized') else ''}"
            f"{_fmt(s['natural_frequency_hz'], '.2f')} Hz/"
            f"{_fmt(s['damping_ratio'], '.4f')}" + ("" if s["matches_nominal"] else " *")
            for s in e["segments"]
        )
        print(f"{e['name']:<24} {e['plant_kind']:<9} {e['fault']:<18} {e['level']:<26} {segs}")
    print("\n* = true plant differs from the filter's nominal model")
    print("~ = nonlinear plant: natural frequency and damping of its linearization at rest")
    return 0
