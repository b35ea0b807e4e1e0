"""``chatterspec commission NOMINAL.toml --data HEALTHY.csv|.npz|- --out FITTED.toml``.

Fits the nominal model file to a healthy recording of the user's plant (every declared physical
parameter at once, the noise covariances Q and R, the boundary layer psi), checks the fitted model on
the held-out end of the recording and writes it, with a ``[commissioning]`` table of provenance, only
when the check passes (``--force`` writes it anyway). The method is
:mod:`chatterspec.studies.commissioning` (``docs/commissioning.md``). Errors (a model or recording
that cannot identify the parameters, a fitted covariance the data make negative, a check that fails)
are one line on stderr, exit 2, with nothing written.
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from ._options import add, add_report_args, alpha_arg, command, parsed_arg, positive_int_arg
from ._report import Outputs, check_output_path, print_json


def _fraction_arg(text: str) -> float:
    """argparse type of ``--holdout``: a fraction in (0, 1)."""
    return parsed_arg(
        text,
        float,
        lambda v: 0.0 < v < 1.0,
        "--holdout must be a fraction in (0, 1); got {text!r}",
        "--holdout must lie in the open interval (0, 1); got {value}",
    )


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec commission`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "commission",
        run,
        help="fit a model file to your plant's healthy recording, check it on held-out data, write it",
        description="Fit every physical parameter the model file declares (jointly), the noise covariances "
        "Q and R and the boundary layer psi to a healthy recording of your plant; check the fitted model on "
        "the held-out end of the recording (whiteness of the chattering, its spectrum, the monitor's alarm "
        "count at one false alarm per day) and write it with its provenance when it is adequate.",
    )
    p.add_argument("model", metavar="MODEL", type=Path, help="nominal model file (.toml, linear)")
    add(
        p,
        "--data",
        required=True,
        help="healthy recording: .csv or .npz with columns named after the model's outputs and inputs (and "
        "optionally time), or '-' for CSV rows on standard input, read to their end",
    )
    add(
        p,
        "--out",
        help="write the fitted model file (.toml) here, atomically and only if the held-out check passes "
        "(unless --force); without --out nothing is written",
    )
    p.add_argument(
        "--holdout",
        type=_fraction_arg,
        default=1.0 / 3.0,
        metavar="FRACTION",
        help="fraction at the end of the recording kept for the check (default 1/3)",
    )
    add(
        p,
        "--confidence",
        help="confidence level of the intervals of the fitted parameters, Q and R (default 0.95)",
    )
    p.add_argument(
        "--check-alpha",
        type=alpha_arg,
        default=0.01,
        metavar="A",
        help="probability at most that a recording of a plant the fitted model describes fails the "
        "check (default 0.01, shared by its three tests)",
    )
    p.add_argument(
        "--lags", type=positive_int_arg, default=20, help="Ljung-Box lags of the whiteness test (default 20)"
    )
    p.add_argument(
        "--force", action="store_true", help="write --out even when the held-out check fails (it says so)"
    )
    add_report_args(p, progress=False, json_help="print one JSON document on stdout (the report)")


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec commission`` with the parsed ``args``; returns the exit status."""
    from ..errors import CommissioningError

    check_output_path(args.out, "--out", suffixes=(".toml",))
    from ..plants.modelfile import load_model
    from ..studies.commissioning import commission, nominal_spec, read_recording

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        spec = nominal_spec(load_model(args.model))  # a model that cannot be commissioned fails first
    for w in caught:
        print(f"chatterspec commission: warning: {w.message}", file=sys.stderr)
    data, source = read_recording(args.data, spec.model)
    res = commission(
        spec,
        data.z,
        data.u,
        holdout=args.holdout,
        confidence=args.confidence,
        alpha=args.check_alpha,
        lags=args.lags,
        t0=float(data.t[0]),
        source=source,
    )
    outputs = Outputs()  # a file that cannot be written (disk full): the report first, then exit 2
    refused = None
    written = None
    if args.out is not None:
        try:
            written = outputs.write("--out", args.out, res.write, args.out, force=args.force)
        except CommissioningError as exc:
            refused = exc
    elif res.adequate is False:
        assert res.check is not None  # a verdict comes from the check
        refused = CommissioningError(
            "the fitted model is not adequate on the held-out data (" + "; ".join(res.check.failures()) + ")"
        )
    if args.json:
        print_json({**res.to_dict(), "out": None if written is None else str(written)})
    else:
        print(res.table())
        if written is not None:
            forced = " although the held-out check failed (--force)" if res.adequate is False else ""
            print(f"wrote {written}{forced}; its [commissioning] table records what was fitted from what")
        elif args.out is None and not refused:
            print("(no --out: nothing written)")
    outputs.finish()
    if refused is not None:
        raise refused
    return 0
