"""``chatterspec scenarios [--json]``: list the scenario catalogue (DESIGN.md section 4)."""

from __future__ import annotations

import argparse
import json


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "scenarios",
        help="list the scenario catalogue",
        description="List every catalogue scenario with its plant kind (linear / nonlinear) and, per "
        "segment, the true plant's natural frequency (Hz) and damping ratio (for a nonlinear plant: "
        "of its linearization at rest, marked ~).",
    )
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.set_defaults(func=run)


def _fmt(x: float | None, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def run(args: argparse.Namespace) -> int:
    from ..plants.scenarios import catalogue

    entries = [sc.describe() for sc in catalogue().values()]
    if args.json:
        print(json.dumps({"scenarios": entries}, indent=2))
        return 0
    print(
        f"{'name':<22} {'kind':<9} {'fault':<18} {'level':<26} "
        "segments (true plant: f0 Hz / zeta on [start, stop) s)"
    )
    for e in entries:
        segs = "; ".join(
            f"[{s['start_s']:g},{s['stop_s']:g}) {'~' if s.get('linearized') else ''}"
            f"{_fmt(s['natural_frequency_hz'], '.2f')} Hz/"
            f"{_fmt(s['damping_ratio'], '.4f')}" + ("" if s["matches_nominal"] else " *")
            for s in e["segments"]
        )
        print(f"{e['name']:<22} {e['plant_kind']:<9} {e['fault']:<18} {e['level']:<26} {segs}")
    print("\n* = true plant differs from the filter's nominal model")
    print("~ = nonlinear plant: natural frequency and damping of its linearization at rest")
    return 0
