"""Argument helpers shared by the subcommands."""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, Protocol, TypeVar, overload

from ..errors import ParameterError

if TYPE_CHECKING:  # pragma: no cover
    from ..plants.scenarios import Scenario

T = TypeVar("T")
R = TypeVar("R")
P = ParamSpec("P")


class StudyResult(Protocol):
    """A Monte Carlo study's result as :func:`report_study` takes it: its JSON document."""

    def to_dict(self) -> dict[str, Any]:
        """The result as a JSON-ready dict."""
        ...


def parsed_arg(
    text: str, convert: Callable[[str], T], ok: Callable[[T], bool], not_a_number: str, out_of_range: str
) -> T:
    """``convert(text)`` if it works and ``ok`` accepts it, else ``argparse.ArgumentTypeError``.

    The messages are templates: ``{text}`` is the text given, ``{value}`` the converted value.
    """
    try:
        value = convert(text)
    except ValueError:
        raise argparse.ArgumentTypeError(not_a_number.format(text=text, value=None)) from None
    if not ok(value):
        raise argparse.ArgumentTypeError(out_of_range.format(text=text, value=value))
    return value


def _open_unit_arg(what: str, name: str) -> Any:
    """argparse type ``name``: a number in the open interval (0, 1), named ``what`` in messages."""

    def parse(text: str) -> float:
        return parsed_arg(
            text,
            float,
            lambda v: 0.0 < v < 1.0,
            f"{what} must be a number in (0, 1); got {{text!r}}",
            f"{what} must lie in the open interval (0, 1); got {{value}}",
        )

    parse.__name__ = parse.__qualname__ = name
    parse.__doc__ = f"argparse type: {what}, a number in the open interval (0, 1)."
    return parse


alpha_arg = _open_unit_arg("alpha", "alpha_arg")
confidence_arg = _open_unit_arg("confidence", "confidence_arg")


def rate_arg(text: str) -> float:
    """argparse type of ``--rate``: data seconds per wall second, finite and >= 0 (0: as fast as possible)."""
    return parsed_arg(
        text,
        float,
        lambda v: 0.0 <= v < float("inf"),
        "--rate must be a number (1.0 = real time, 0 = as fast as possible); got {text!r}",
        "--rate must be finite and >= 0 (1.0 = real time, 0 = as fast as possible); got {value}",
    )


def _integer_arg(minimum: int, name: str) -> Callable[[str], int]:
    """argparse type ``name``: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        expected = f"expected an integer >= {minimum}; got "
        return parsed_arg(text, int, lambda v: v >= minimum, expected + "{text!r}", expected + "{value}")

    parse.__name__ = parse.__qualname__ = name
    parse.__doc__ = f"argparse type: an integer >= {minimum}."
    return parse


positive_int_arg = _integer_arg(1, "positive_int_arg")
nonnegative_int_arg = _integer_arg(0, "nonnegative_int_arg")


def band_edge_arg(text: str) -> float:
    """argparse type: one edge of ``--band LO HI``, a finite frequency >= 0 in Hz."""
    return parsed_arg(
        text,
        float,
        lambda v: v >= 0.0 and v < float("inf"),
        "--band edges are frequencies in Hz; got {text!r}",
        "--band edges must be finite and >= 0 Hz; got {text!r}",
    )


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


def stderr_note(command: str) -> Any:
    """A function that prints one ``chatterspec COMMAND: note: TEXT`` line on stderr (library notes)."""

    def note(text: str) -> None:
        print(f"chatterspec {command}: note: {text}", file=sys.stderr, flush=True)

    return note


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


def load_scenario(name: str) -> Scenario:
    """A catalogue scenario, or the healthy scenario of a model file (``NAME.toml``, linear or nonlinear).

    A model file's scenario is its ``[simulation]`` table (input, initial state, duration; zero input
    and 4 s by default) with the file's model as nominal model and true plant.
    """
    from ..plants.simulate import as_scenario

    return as_scenario(name)


def print_json(doc: Any, *, allow_nan: bool = False) -> None:
    """Print ``doc`` as indented JSON on standard output (NaN refused unless ``allow_nan``: the JSON stays
    standard; the Monte Carlo studies write NaN where a rate has no trials)."""
    from ..jsonout import dumps

    sys.stdout.write(dumps(doc, indent=2, allow_nan=allow_nan) + "\n")


def check_record_path(path: str | os.PathLike | None) -> None:
    """``--record FILE.rrd``: a ``.rrd`` name whose file can be created (see :func:`check_output_path`)."""
    if path is not None and not str(path).endswith(".rrd"):
        raise ParameterError(f"--record expects a path ending in .rrd; got {str(path)!r}")
    check_output_path(path, "--record")


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


@overload
def check_output_path(
    path: str | os.PathLike, option: str, *, folder: bool = False, suffixes: tuple[str, ...] | None = None
) -> Path: ...
@overload
def check_output_path(
    path: None, option: str, *, folder: bool = False, suffixes: tuple[str, ...] | None = None
) -> None: ...
@overload
def check_output_path(
    path: str | os.PathLike | None,
    option: str,
    *,
    folder: bool = False,
    suffixes: tuple[str, ...] | None = None,
) -> Path | None: ...
def check_output_path(
    path: str | os.PathLike | None,
    option: str,
    *,
    folder: bool = False,
    suffixes: tuple[str, ...] | None = None,
) -> Path | None:
    """Check, before any computation, that ``path`` can be written as a file (or used as a folder).

    Parameters
    ----------
    path : str or path-like or None
        The file the command will write, or with ``folder`` the folder it will write into (None:
        nothing to check).
    option : str
        The option that named it (e.g. ``"--plot"``), for the message.
    folder : bool
        ``path`` is a folder, existing or created at write time with any missing parents (default:
        a file, whose folder must exist: a mistyped folder is refused rather than created).
    suffixes : tuple of str, optional
        Accepted lower-case suffixes of a file (e.g. ``(".png",)``); None accepts any.

    Returns
    -------
    Path or None
        ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputPathError
        A file ``path`` is an existing folder, an existing read-only file, has a refused suffix or a
        folder that does not exist; a folder ``path`` is an existing file; or the folder written
        into (``path`` itself or its nearest existing parent for a folder, the file's folder for a
        file) is not writable.
    """
    if path is None:
        return None
    p = Path(path)
    if folder:
        if p.exists() and not p.is_dir():
            raise OutputPathError(f"{option} {str(p)!r} is an existing file; give a folder")
        base = _nearest_existing(p)
    else:
        if suffixes is not None and p.suffix.lower() not in suffixes:
            raise OutputPathError(f"{option} {str(p)!r}: the file name must end in {' or '.join(suffixes)}")
        if p.is_dir():
            raise OutputPathError(f"{option} {str(p)!r} is an existing folder; give a file name")
        if p.exists() and not os.access(p, os.W_OK):
            raise OutputPathError(f"{option} {str(p)!r}: the file exists and is not writable")
        base = p.parent if str(p.parent) else Path(".")
        if not base.exists():
            raise OutputPathError(
                f"{option} {str(p)!r} cannot be written: the folder {str(base)!r} does not exist (create it "
                "first)"
            )
    why = _probe_writable(base)
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

    def write(
        self,
        option: str,
        target: str | os.PathLike[str],
        fn: Callable[P, R],
        /,
        *args: P.args,
        **kwargs: P.kwargs,
    ) -> R | None:
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


# --- the end of a command: figure, document or table, failed writes ------------------------------------
def check_figure_path(path: str | os.PathLike | None, option: str = "--plot") -> None:
    """Check, before any computation, that the figure file ``path`` can be written (a matplotlib suffix)."""
    if path:
        check_output_path(path, option, suffixes=figure_suffixes())


def write_plot(
    outputs: Outputs, args: argparse.Namespace, doc: dict[str, Any], figure: str, *figure_args: object
) -> None:  # (figure_args: whatever the named drawing function takes)
    """With ``--plot FILE``: save the figure there, noted as ``doc["figure"]`` (None: not saved).

    ``figure`` names the drawing function in :mod:`chatterspec.figures` as ``"module.function"``
    (e.g. ``"plot_studies.far_figure"``), called with ``figure_args``; it is imported only here, so
    a command without ``--plot`` never loads matplotlib.
    """
    if not args.plot:
        return
    import importlib

    from ..figures.plot_studies import save

    module, name = figure.rsplit(".", 1)
    draw = getattr(importlib.import_module(f"..figures.{module}", __package__), name)
    saved = outputs.write("--plot", args.plot, save, draw(*figure_args), args.plot)
    doc["figure"] = None if saved is None else str(saved)


def report(
    args: argparse.Namespace,
    doc: dict[str, Any],
    outputs: Outputs,
    print_text: Callable[[], None],
    *,
    allow_nan: bool = False,
) -> int:
    """Print the result and end the command: ``doc`` as JSON with ``--json`` (NaN written only with
    ``allow_nan``), else ``print_text()``; then :meth:`Outputs.finish`. Returns 0."""
    if args.json:
        print_json(doc, allow_nan=allow_nan)
    else:
        print_text()
    outputs.finish()
    return 0


def report_study(
    args: argparse.Namespace, res: StudyResult, figure: str, print_text: Callable[[dict[str, Any]], None]
) -> int:
    """The end of a Monte Carlo study command (``far``, ``power``, ``power --closed-loop``): the result
    ``res``'s document, its ``--plot`` figure (:func:`write_plot`, ``figure`` called with ``res``),
    then :func:`report` with ``print_text(doc)`` and the figure's path as the text (NaN kept in the JSON:
    a rate without trials)."""
    outputs = Outputs()
    doc = res.to_dict()
    write_plot(outputs, args, doc, figure, res)

    def text() -> None:
        print_text(doc)
        if doc.get("figure"):
            print(f"figure: {doc['figure']}")

    return report(args, doc, outputs, text, allow_nan=True)
