"""Rerun sinks: where a recording goes (file, live viewer, spawned viewer) and how to reach it."""

from __future__ import annotations

import errno
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import urlparse

if TYPE_CHECKING:
    from rerun.blueprint import Blueprint

    pass

__all__ = [
    "DEFAULT_RECORDINGS_DIR",
    "LiveViewerWarning",
    "Sinks",
    "default_recording_path",
    "find_viewer",
    "has_display",
    "open_sinks",
    "viewer_url",
]


#: Folder (relative to the current directory) where ``chatterspec demo`` writes recordings.
DEFAULT_RECORDINGS_DIR = Path("recordings")
#: Seconds to wait for a TCP connection to a live viewer before giving up on it.
CONNECT_TIMEOUT_S = 2.0
TIMELINE = "time"
#: Colour range (dB above the expected healthy frame spectrum) of the scrolling spectrogram.
DB_RANGE = (-10.0, 30.0)


class LiveViewerWarning(UserWarning):
    """The live viewer is unreachable or cannot be started; the file sink (if any) is kept."""


def has_display() -> bool:
    """True when a graphical session exists (``DISPLAY`` or ``WAYLAND_DISPLAY`` set, or macOS/Windows)."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def find_viewer() -> str | None:
    """Path of the ``rerun`` viewer executable: next to the Python interpreter, else on PATH."""
    here = Path(sys.executable).parent / ("rerun.exe" if sys.platform == "win32" else "rerun")
    if here.exists():
        return str(here)
    return shutil.which("rerun")


def default_recording_path(name: str, folder: str | Path = DEFAULT_RECORDINGS_DIR) -> Path:
    """``recordings/<name>-<YYYYmmdd-HHMMSS>.rrd`` (folder created on open)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in name) or "chatterspec"
    return Path(folder) / f"{safe}-{stamp}.rrd"


def viewer_url(live: str) -> str:
    """The gRPC URL of a live viewer given as a URL, ``host:port`` or a port number.

    Parameters
    ----------
    live : str
        ``rerun+http://host:port/proxy`` (or ``rerun+https://``), ``host:port``
        or a port number (then the host is 127.0.0.1).

    Returns
    -------
    str
        ``rerun+http(s)://host:port/proxy``.

    Raises
    ------
    ParameterError
        ``live`` is none of these (e.g. a bare word such as ``foo``, which is
        not taken as a host name), or its port is outside 1-65535.
    """
    from ..errors import ParameterError

    text = str(live).strip()
    hint = (
        "give 'spawn', a port (9876), HOST:PORT (127.0.0.1:9876) or a URL (rerun+http://127.0.0.1:9876/proxy)"
    )
    if text.isdigit():
        url = f"rerun+http://127.0.0.1:{text}/proxy"
    elif "://" not in text:
        host, sep, port = text.rpartition(":")
        if not sep or not host or not port.isdigit():
            raise ParameterError(f"--live {live!r} is not a viewer address; {hint}")
        url = f"rerun+http://{text}/proxy"
    else:
        url = text
    parsed = urlparse(url)
    if parsed.scheme not in ("rerun+http", "rerun+https", "rerun") or not parsed.hostname:
        raise ParameterError(f"--live {live!r} is not a Rerun viewer URL; {hint}")
    try:
        number = parsed.port
    except ValueError:
        number = -1
    if number is not None and not 0 < number < 65536:
        raise ParameterError(f"--live {live!r}: the port must lie in 1-65535; {hint}")
    return url


def _grpc_url(live: str) -> str:
    """Accept ``rerun+http://host:port/proxy``, ``host:port`` or a port number (see :func:`viewer_url`)."""
    return viewer_url(live)


def _reachable(url: str, timeout: float = CONNECT_TIMEOUT_S) -> tuple[bool, str]:
    parsed = urlparse(url.replace("rerun+", "", 1))
    host, port = parsed.hostname or "127.0.0.1", parsed.port or 9876
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return True, ""
    except OSError as exc:
        return False, f"{host}:{port}: {exc.strerror or exc}"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Sinks:
    """The open Rerun streams of one run: a file stream and/or a live-viewer stream (same recording id).

    Use as a context manager (or call :meth:`close`): the streams are always
    disconnected, which writes the ``.rrd`` footer, also on Ctrl-C. A dead live
    viewer is never flushed against, so closing takes at most a few seconds.

    Attributes
    ----------
    file_stream : rerun.RecordingStream or None
        Stream writing the ``.rrd`` file.
    live_stream : rerun.RecordingStream or None
        Stream to the live viewer (gRPC), sharing the file stream's recording id.
    path : Path or None
        The ``.rrd`` file being written.
    live_url : str or None
        gRPC URL of the viewer streamed to.
    notes : list of str
        Messages for the user (no display, unreachable viewer, fallback file).
    viewer_process : subprocess.Popen or None
        The viewer started by ``--live spawn`` (left running for the user).
    """

    file_stream: Any | None = None
    live_stream: Any | None = None
    path: Path | None = None
    live_url: str | None = None
    notes: list[str] = field(default_factory=list)
    viewer_process: subprocess.Popen | None = None
    _closed: bool = False

    @property
    def streams(self) -> list[Any]:
        """The open recording streams: the file's, then the live viewer's (each when present)."""
        return [s for s in (self.file_stream, self.live_stream) if s is not None]

    @property
    def live(self) -> bool:
        """Whether a live viewer is connected."""
        return self.live_stream is not None

    def __enter__(self) -> Sinks:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def send_blueprint(self, bp: Blueprint) -> None:
        """Send ``bp`` (a ``rerun.blueprint.Blueprint``) to every stream as the active and default one."""
        for s in self.streams:
            s.send_blueprint(bp, make_active=True, make_default=True)

    def _note(self, msg: str) -> None:
        self.notes.append(msg)
        _warn(msg)

    def close(self) -> None:
        """Disconnect every stream (writes the file footer); idempotent."""
        if self._closed:
            return
        self._closed = True
        failed: OSError | None = None
        if self.file_stream is not None:
            try:
                self.file_stream.flush(timeout_sec=30.0)
            except RuntimeError as exc:  # the disk filled during the run: an OSError for the caller
                failed = file_error(exc, self.path or "recording")
                if failed is None:
                    raise
            self.file_stream.disconnect()
        if self.live_stream is not None:
            # a stream the caller set up itself (notebook viewer, memory sink) has no URL to probe
            ok, why = (True, "") if self.live_url is None else _reachable(self.live_url, timeout=1.0)
            if ok:
                try:
                    self.live_stream.flush(timeout_sec=5.0)
                except RuntimeError as exc:  # viewer went away meanwhile
                    self._note(f"live viewer {self.live_url}: pending data dropped ({exc})")
            else:
                self._note(f"live viewer {self.live_url} went away ({why}); pending live data dropped")
            self.live_stream.disconnect()
        if failed is not None:
            raise failed


def _warn(msg: str) -> None:
    warnings.warn(msg, LiveViewerWarning, stacklevel=4)


def open_sinks(
    *,
    record: str | Path | None = None,
    live: str | None = None,
    application_id: str = "chatterspec",
    recording_id: str | None = None,
    recording_name: str | None = None,
    default_record: str | Path | None = None,
) -> Sinks:
    """Open the sinks of ``--record FILE.rrd`` and ``--live URL|spawn``.

    Parameters
    ----------
    record : path, optional
        ``.rrd`` file to write (parent folders are created).
    live : str, optional
        ``"spawn"`` starts the ``rerun`` viewer (only when a display exists);
        otherwise a gRPC URL ``rerun+http://host:port/proxy``, ``host:port`` or a
        port. An unreachable viewer is reported once (:class:`LiveViewerWarning`)
        after at most :data:`CONNECT_TIMEOUT_S` seconds and skipped.
    application_id, recording_id, recording_name : str
        Rerun identifiers (``recording_id`` defaults to a fresh UUID; both
        streams share it so the viewer merges them).
    default_record : path, optional
        File written when the live viewer cannot be used and ``record`` is None
        (so the data is never lost).

    Returns
    -------
    Sinks
        Possibly with no stream at all (nothing requested, or viewer unusable
        and no fallback file); ``notes`` holds what the user should be told.
    """
    if record is None and live is None:
        return Sinks()  # nothing to open: Rerun is not even imported
    import rerun as rr

    rid = recording_id or str(uuid.uuid4())
    sinks = Sinks()

    def new_stream() -> Any:
        s = rr.RecordingStream(application_id, recording_id=rid)
        if recording_name:
            s.send_recording_name(recording_name)
        return s

    if live is not None:
        url: str | None = None
        if live == "spawn":
            exe = find_viewer()
            if not has_display():
                sinks.notes.append(
                    "no display (DISPLAY / WAYLAND_DISPLAY unset): the viewer was not started; "
                    "open the recording later with `chatterspec replay FILE.rrd` on a machine with a display"
                )
            elif exe is None:
                sinks.notes.append("the `rerun` viewer executable was not found; install rerun-sdk")
            else:
                port = _free_port()
                proc = subprocess.Popen(
                    [exe, "--port", str(port)],
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,
                )
                url = f"rerun+http://127.0.0.1:{port}/proxy"
                deadline = time.monotonic() + 10.0
                while time.monotonic() < deadline and not _reachable(url, 0.2)[0]:
                    if proc.poll() is not None:
                        break
                    time.sleep(0.1)
                sinks.viewer_process = proc
        else:
            url = _grpc_url(live)
        if url is not None:
            ok, why = _reachable(url)
            if ok:
                s = new_stream()
                s.set_sinks(rr.GrpcSink(url))
                sinks.live_stream, sinks.live_url = s, url
            else:
                sinks._note(f"live viewer {url} is unreachable ({why}); continuing without it")
        if sinks.live_stream is None and record is None and default_record is not None:
            record = default_record
    if record is not None:
        path = Path(record)
        path.parent.mkdir(parents=True, exist_ok=True)
        s = new_stream()
        try:
            s.set_sinks(rr.FileSink(str(path)))
        except RuntimeError as exc:  # e.g. disk full: Rerun's error as the OSError it is
            err = file_error(exc, path)
            if err is None:
                raise
            sinks.close()
            raise err from None
        sinks.file_stream, sinks.path = s, path
    return sinks


def file_error(exc: BaseException, path: str | os.PathLike[str]) -> OSError | None:
    """The :class:`OSError` behind a Rerun file-sink ``RuntimeError`` (None if it is not about a file).

    Rerun reports I/O failures as ``RuntimeError("Failed to encode LogMsg: Failed to write: No space
    left on device (os error 28)")``; the command line turns an ``OSError`` into one error line.

    Parameters
    ----------
    exc : BaseException
        What Rerun raised.
    path : str or Path
        The ``.rrd`` file being written.
    """
    if isinstance(exc, OSError):
        return exc
    text = str(exc)
    code = re.search(r"os error (\d+)", text)
    if code is not None:
        n = int(code.group(1))
        return OSError(n, os.strerror(n), str(path))
    if any(w in text.lower() for w in ("file", "write", "disk")):
        return OSError(errno.EIO, text.splitlines()[0] if text else "write failed", str(path))
    return None
