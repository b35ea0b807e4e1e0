"""``chatterspec simulate NAME|MODEL.toml [--rate 1.0] [--seed S] [--duration S]``: a live CSV stream.

Writes the header ``time,<outputs>,<inputs>`` and then one row per sample to
standard output, paced so that data time advances ``--rate`` times as fast as
wall time (``--rate 0``: as fast as the reader takes it). The columns are those
``chatterspec monitor`` expects, so

    chatterspec scenarios eha-leak-major --model-toml eha.toml
    chatterspec simulate eha-leak-major | chatterspec monitor eha.toml --data -

monitors the scenario live. A model file (linear or nonlinear) streams its healthy plant under its
``[simulation]`` table (input, initial state, duration). The scenario is simulated block by block in time
(:func:`chatterspec.online.simulated_stream.simulate_blocks`: constant memory, the
scenario repeats beyond its own duration; the same ``--seed`` gives the same rows at any
``--rate``). A reader that goes away (a closed pipe) ends the program quietly with status 0.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from ..errors import ParameterError
from ._options import add, add_name, command, load_scenario

#: Most seconds of wall time between two writes when paced (rows are written when due).
PACE_S = 0.005


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec simulate`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "simulate",
        run,
        help="write a scenario's measurements and inputs as a live CSV stream on stdout",
        description="Simulate a catalogue scenario and write time, measurements and inputs as CSV rows "
        "to standard output, paced in real time (the input of `chatterspec monitor --data -`).",
    )
    add_name(
        p,
        "catalogue scenario (see `chatterspec scenarios`) or model file MODEL.toml (its [simulation] "
        "table: input, initial state, duration)",
    )
    add(p, "--rate", default=1.0)
    add(p, "--seed")
    p.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="seconds of data (default: the scenario's duration; longer runs repeat the scenario)",
    )


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec simulate`` with the parsed ``args``; returns the exit status."""
    from ..online.simulated_stream import csv_header, csv_lines, simulate_blocks

    if args.duration is not None and not (args.duration > 0 and args.duration < float("inf")):
        raise ParameterError(f"--duration must be > 0 s; got {args.duration}")
    sc = load_scenario(args.name)
    dt = sc.dt
    out = sys.stdout
    # blocks of ~PACE_S of wall time when paced (rows go out when due), 1 s of data otherwise
    block_s = max(dt, PACE_S * args.rate) if args.rate > 0 else 1.0
    try:
        out.write(csv_header(sc.nominal) + "\n")
        out.flush()
        start = time.perf_counter()
        for t, z, u in simulate_blocks(sc, args.seed, args.duration, block_s=block_s):
            if args.rate > 0:
                delay = start + float(t[-1]) / args.rate - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
            out.write(csv_lines(t, z, u))
            out.flush()
    except BrokenPipeError:
        # the reader went away: no traceback, no "Exception ignored" at interpreter exit
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 0
    return 0
