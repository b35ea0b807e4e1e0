"""The ``chatterspec`` command.

Each subcommand lives in ``chatterspec/cli/<name>.py`` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` (a callable
taking the parsed ``argparse.Namespace`` and returning an exit code). With
``--json`` a subcommand prints exactly one JSON document on stdout and nothing
else there (progress and warnings go to stderr).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Sequence
from typing import TextIO

from ..errors import ChatterspecError
from ._report import quiet_stdout

#: Subcommand modules, in help order.
COMMANDS: tuple[str, ...] = (
    "demo",
    "scenarios",
    "detect",
    "spectrum",
    "figures",
    "monitor",
    "simulate",
    "replay",
    "calibrate",
    "commission",
    "far",
    "power",
    "estimate",
    "diagnose",
)


def build_parser() -> argparse.ArgumentParser:
    """The ``chatterspec`` argument parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="chatterspec",
        description="Fault detection from the spectral content of SVSF chattering.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"chatterspec {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f".{name}", __package__).register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default ``sys.argv[1:]``); returns the exit status (2: bad input)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit:  # --help / usage errors: `chatterspec --help | head` must not end in a traceback
        _flush_stdout()
        raise
    from ..montecarlo import fix_mmap_threshold  # numpy: after parsing, so that --help stays light

    fix_mmap_threshold()  # peak memory independent of --runs (see chatterspec.montecarlo)
    try:
        with warnings.catch_warnings():
            _one_line_warnings(args.command)
            code = int(args.func(args) or 0)
        sys.stdout.flush()  # a reader that went away shows here, not as a traceback at exit
        return code
    except BrokenPipeError:  # stdout's reader closed it (`chatterspec scenarios | head -1`): not an error
        quiet_stdout()
        return 0
    except ChatterspecError as exc:
        print(f"chatterspec {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"chatterspec {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # a file that cannot be read or written: one line, never a traceback
        where = f" {exc.filename!r}" if getattr(exc, "filename", None) else ""
        print(f"chatterspec {args.command}: error:{where} {exc.strerror or exc}", file=sys.stderr)
        return 2


def _flush_stdout() -> None:
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        quiet_stdout()


def _one_line_warnings(command: str) -> None:
    """Show warnings as one ``chatterspec CMD: warning: ...`` line (no source path, no code line).

    :class:`~chatterspec.viewer.sinks.LiveViewerWarning` is not shown: its text is
    also in the sinks' notes, which every command prints.
    """
    from ..viewer.sinks import LiveViewerWarning

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: TextIO | None = None,
        line: str | None = None,
    ) -> None:
        print(f"chatterspec {command}: warning: {message}", file=sys.stderr)

    warnings.showwarning = show
    warnings.simplefilter("ignore", LiveViewerWarning)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
