"""Argument helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from ..errors import ParameterError


def alpha_arg(text: str) -> float:
    """argparse type: a probability in the open interval (0, 1)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"alpha must be a number in (0, 1); got {text!r}") from None
    if not 0.0 < value < 1.0:
        raise argparse.ArgumentTypeError(f"alpha must lie in the open interval (0, 1); got {value}")
    return value


def positive_int_arg(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1; got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1; got {value}")
    return value


def nonnegative_int_arg(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0; got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0; got {value}")
    return value


def band_edge_arg(text: str) -> float:
    """argparse type: one edge of ``--band LO HI``, a finite frequency >= 0 in Hz."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--band edges are frequencies in Hz; got {text!r}") from None
    if not (value >= 0.0 and value < float("inf")):
        raise argparse.ArgumentTypeError(f"--band edges must be finite and >= 0 Hz; got {text!r}")
    return value


def band_from_args(args: argparse.Namespace) -> tuple[float, float] | None:
    """The validated ``--band LO HI`` of ``args`` (None when not given).

    Raises
    ------
    ParameterError
        If ``LO >= HI``.
    """
    band = getattr(args, "band", None)
    if band is None:
        return None
    from ..detection.thresholds import check_band

    return check_band(band)


def add_detector_args(p: argparse.ArgumentParser) -> None:
    """--alpha, --threshold, --correction, --band, --runs, --seed."""
    p.add_argument(
        "--alpha",
        type=alpha_arg,
        default=1e-3,
        help="false-alarm probability: family-wise for 'exact' (default 0.001), per bin for 'paper'",
    )
    p.add_argument(
        "--threshold",
        choices=("exact", "paper"),
        default="exact",
        help="'exact': per-bin chi-squared thresholds from the expected spectrum with family-wise "
        "control (default); 'paper': the paper's flat bound (eq 58-62) at per-bin alpha",
    )
    p.add_argument(
        "--correction",
        choices=("bonferroni", "sidak", "none"),
        default="bonferroni",
        help="family-wise correction over the tested bins for 'exact' and for the averaged verdict "
        "of every threshold with --runs > 1 (default bonferroni)",
    )
    p.add_argument(
        "--band",
        nargs=2,
        type=band_edge_arg,
        metavar=("LO", "HI"),
        help="test only the bins with LO <= f <= HI (Hz), for every threshold (single, averaged, STFT "
        "frames); the correction counts only these bins; DC and Nyquist stay excluded",
    )
    p.add_argument("--runs", type=positive_int_arg, default=1, help="Monte Carlo realizations (default 1)")
    p.add_argument("--seed", type=nonnegative_int_arg, default=0, help="random seed (default 0)")


def add_live_args(p: argparse.ArgumentParser) -> None:
    """--record FILE.rrd and --live URL|spawn."""
    p.add_argument("--record", metavar="FILE.rrd", help="write a Rerun recording of the run to FILE.rrd")
    p.add_argument(
        "--live",
        metavar="URL|spawn",
        help="stream to a running Rerun viewer (gRPC URL such as rerun+http://127.0.0.1:9876/proxy) "
        "or 'spawn' one (needs a display)",
    )


def print_json(doc: Any) -> None:
    json.dump(doc, sys.stdout, indent=2, allow_nan=False, default=_json_default)
    sys.stdout.write("\n")


def _json_default(obj: Any) -> Any:
    import numpy as np

    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"not JSON serializable: {type(obj).__name__}")


def check_record_path(path: str | None) -> None:
    if path is not None and not path.endswith(".rrd"):
        raise ParameterError(f"--record expects a path ending in .rrd; got {path!r}")
