"""``chatterspec replay FILE.rrd``: open a recording in the Rerun viewer."""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

from ..errors import DataFileError, ViewerUnavailableError
from ._options import command


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``chatterspec replay`` and its options to the subcommand parsers ``sub``."""
    p = command(
        sub,
        "replay",
        run,
        help="open a .rrd recording in the Rerun viewer",
        description="Open a recording written by `chatterspec detect/demo/monitor --record` in the Rerun "
        "viewer. Without a display, prints how to open it elsewhere.",
    )
    p.add_argument("file", type=Path, help="the .rrd recording")
    p.add_argument("--wait", action="store_true", help="block until the viewer window is closed")


#: First bytes of every Rerun (>= 0.x, RRF2 encoding) recording file.
RRD_MAGIC = b"RRF2"


def _is_rrd(path: Path) -> bool:
    """True unless the file has bytes and they do not start with :data:`RRD_MAGIC` (an empty file is let
    through: the viewer shows it as an empty recording)."""
    with path.open("rb") as fh:
        head = fh.read(len(RRD_MAGIC))
    return head in (b"", RRD_MAGIC)


def run(args: argparse.Namespace) -> int:
    """Run ``chatterspec replay`` with the parsed ``args``; returns the exit status."""
    from ..viewer.sinks import find_viewer, has_display

    path: Path = args.file
    if not path.is_file():
        raise DataFileError(f"recording {str(path)!r}: no such file")
    if path.suffix.lower() != ".rrd" or not _is_rrd(path):
        raise DataFileError(
            f"{str(path)!r} is not a Rerun recording (.rrd file starting with the RRF2 header); give a file "
            "written by `chatterspec detect/demo/monitor --record FILE.rrd`"
        )
    exe = find_viewer()
    if exe is None:
        raise ViewerUnavailableError("the `rerun` viewer was not found; install rerun-sdk>=0.41,<0.42")
    if not has_display():
        raise ViewerUnavailableError(
            f"no display (DISPLAY / WAYLAND_DISPLAY unset). Copy {path} to a machine with a display and "
            f"run `chatterspec replay {path.name}` or `rerun {path.name}` there; or serve it to a browser "
            f"with `{exe} --serve-web {path}` and open the printed URL."
        )
    proc = subprocess.Popen([exe, str(path)], start_new_session=not args.wait)
    if args.wait:
        status = proc.wait()
        if status != 0:  # one exit status per outcome: the viewer's own is reported, not passed on
            raise ViewerUnavailableError(f"the viewer ended with status {status}")
        return 0
    print(f"opened {path} in the Rerun viewer (pid {proc.pid})", file=sys.stderr)
    return 0
