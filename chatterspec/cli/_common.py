"""Argument helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
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
    """argparse type: ``text`` as an int >= 0 (a usage error otherwise)."""
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


def add_execution_args(p: argparse.ArgumentParser) -> None:
    """--workers N and --scheduler ADDRESS (the Monte Carlo commands; the numbers do not depend on them)."""
    p.add_argument(
        "--workers",
        type=positive_int_arg,
        default=1,
        help="local worker processes (default 1; the results do not depend on it)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on Dask: 'local-dask' or a scheduler address (needs chatterspec[distributed])",
    )


def add_live_args(p: argparse.ArgumentParser) -> None:
    """--record FILE.rrd and --live URL|spawn."""
    p.add_argument("--record", metavar="FILE.rrd", help="write a Rerun recording of the run to FILE.rrd")
    p.add_argument(
        "--live",
        type=live_arg,
        metavar="URL|spawn",
        help="stream to a running Rerun viewer (gRPC URL such as rerun+http://127.0.0.1:9876/proxy) "
        "or 'spawn' one (needs a display)",
    )


def live_arg(text: str) -> str:
    """argparse type of ``--live``: ``spawn``, a port, ``host:port`` or a viewer URL (not a bare word)."""
    if text == "spawn":
        return text
    from ..viewer.sinks import viewer_url

    try:
        viewer_url(text)
    except ParameterError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix(f"--live {text!r} ")) from None
    return text


def load_scenario(name: str) -> Any:
    """A catalogue scenario, or the healthy scenario of a model file (``NAME.toml``, linear or nonlinear).

    A model file's scenario is its ``[simulation]`` table (input, initial state, duration; zero input
    and 4 s by default) with the file's model as nominal model and true plant.
    """
    from ..plants.simulate import as_scenario

    return as_scenario(name)


def print_json(doc: Any) -> None:
    """Print ``doc`` as indented JSON on standard output (NaN refused: the JSON stays standard)."""
    from ..jsonout import dumps

    sys.stdout.write(dumps(doc, indent=2) + "\n")


def check_record_path(path: str | os.PathLike | None) -> None:
    """``--record FILE.rrd``: a ``.rrd`` name whose file can be created (see :func:`check_output_file`)."""
    if path is not None and not str(path).endswith(".rrd"):
        raise ParameterError(f"--record expects a path ending in .rrd; got {str(path)!r}")
    check_output_file(path, "--record")


# --- output paths --------------------------------------------------------------------------------------
class OutputPathError(ParameterError):
    """An output path cannot be written (checked before the computation, or failed at the end)."""


def _nearest_existing(path: Path) -> Path:
    p = path
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def _probe_writable(folder: Path) -> str | None:
    """Create and remove one empty file in ``folder``; None when that works, else the reason."""
    import tempfile

    if not folder.is_dir():
        return f"{str(folder)!r} is not a folder"
    try:
        fd, name = tempfile.mkstemp(prefix=".chatterspec-probe-", dir=folder)
    except OSError as exc:
        return f"cannot create files in {str(folder)!r} ({exc.strerror or exc})"
    os.close(fd)
    try:
        os.unlink(name)
    except OSError:  # pragma: no cover - the probe file is empty; leaving it is harmless
        pass
    return None


def check_output_file(
    path: str | os.PathLike | None, option: str, *, suffixes: tuple[str, ...] | None = None
) -> Path | None:
    """Check, before any computation, that ``path`` can be written as a file.

    Parameters
    ----------
    path : str or path-like or None
        The file the command will write (None: nothing to check).
    option : str
        The option that named it (e.g. ``"--plot"``), for the message.
    suffixes : tuple of str, optional
        Accepted lower-case suffixes (e.g. ``(".png",)``); None accepts any.

    Returns
    -------
    Path or None
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputPathError
        ``path`` is an existing folder, an existing read-only file, has a refused
        suffix, or its nearest existing parent is not a writable folder (missing
        parent folders are created at write time).
    """
    if path is None:
        return None
    p = Path(path)
    if suffixes is not None and p.suffix.lower() not in suffixes:
        raise OutputPathError(f"{option} {str(p)!r}: the file name must end in {' or '.join(suffixes)}")
    if p.is_dir():
        raise OutputPathError(f"{option} {str(p)!r} is an existing folder; give a file name")
    if p.exists() and not os.access(p, os.W_OK):
        raise OutputPathError(f"{option} {str(p)!r}: the file exists and is not writable")
    base = _nearest_existing(p.parent if str(p.parent) else Path("."))
    why = _probe_writable(base)
    if why is not None:
        raise OutputPathError(f"{option} {str(p)!r} cannot be written: {why}")
    return p


def check_output_dir(path: str | os.PathLike | None, option: str) -> Path | None:
    """Check, before any computation, that ``path`` is (or can be created as) a writable folder.

    Parameters
    ----------
    path : str or path-like or None
        The folder the command will write into (None: nothing to check).
    option : str
        The option that named it (e.g. ``"--out"``), for the message.

    Returns
    -------
    Path or None
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputPathError
        ``path`` is an existing file, or neither it nor its nearest existing
        parent is a writable folder.
    """
    if path is None:
        return None
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"{option} {str(p)!r} is an existing file; give a folder")
    why = _probe_writable(_nearest_existing(p))
    if why is not None:
        raise OutputPathError(f"{option} {str(p)!r} cannot be written: {why}")
    return p


def figure_suffixes() -> tuple[str, ...]:
    """File suffixes matplotlib can write (``.png``, ``.pdf``, ``.svg``, ...)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return tuple(sorted(f".{k}" for k in FigureCanvasBase.get_supported_filetypes()))


class Outputs:
    """Write the outputs of a finished computation; failures are kept, not raised, until :meth:`finish`.

    A command computes, writes through :meth:`write`, prints its result (table
    or JSON) and then calls :meth:`finish`, so a study whose output cannot be
    written (disk full, folder removed meanwhile) is still shown before the
    one-line error (exit 2).
    """

    def __init__(self) -> None:
        self.failures: list[str] = []

    def write(self, option: str, target: str | os.PathLike, fn: Any, /, *args: Any, **kwargs: Any) -> Any:
        """Call ``fn(*args, **kwargs)``; on ``OSError`` (or Rerun's file-sink ``RuntimeError``) note it.

        Returns ``fn``'s result, or None when the write failed.
        """
        try:
            result = fn(*args, **kwargs)
        except (OSError, RuntimeError) as exc:
            from ..viewer.sinks import file_error  # Rerun reports a full disk as a RuntimeError

            err = file_error(exc, target) if isinstance(exc, RuntimeError) else exc
            if err is None:
                raise
            reason = getattr(err, "strerror", None) or str(err).splitlines()[0]
            self.failures.append(f"{option} {str(target)!r} could not be written ({reason})")
            return None
        late = getattr(result, "write_error", None)  # a recording that failed after the run finished
        if late:
            self.failures.append(f"{option} {str(target)!r} could not be completed ({late})")
        return result

    def finish(self) -> None:
        """Raise :class:`OutputPathError` naming every failed write (after the result was printed)."""
        if self.failures:
            done = " -- the result above was computed but not saved"
            raise OutputPathError("; ".join(self.failures) + done)
