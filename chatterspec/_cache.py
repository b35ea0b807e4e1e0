"""The user cache folder: results that are slow to compute and fully determined by their inputs.

The monitor's in-call alarm calibration (:func:`chatterspec.studies.alarm_budget.calibrate_alarm`)
simulates hours of healthy data; its result depends only on the model, the detector and alarm
settings, the seed and the versions of the code, so it is kept here and read back by the next run.

Location
    ``$CHATTERSPEC_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/chatterspec``, else
    ``~/.cache/chatterspec``; one sub-folder per kind of entry. Deleting the folder clears the cache.
Opt-out
    ``CHATTERSPEC_NO_CACHE=1`` (any value but ``0`` or empty): nothing is read or written.
Entries
    One JSON file per entry, named by the SHA-256 of its key (the canonical JSON of every input that
    determines the value). The file repeats the key and a format tag: a truncated, corrupt or foreign
    file, or a hash collision, reads as a miss (the value is computed again), never as a wrong value.
    Files are written atomically (a temporary file in the same folder, then :func:`os.replace`), so a
    reader never sees half an entry and concurrent writers of one entry leave one whole file.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["CACHE_DIR_ENV", "FORMAT", "NO_CACHE_ENV", "cache_dir", "canonical", "load", "store"]

#: Environment variable naming the cache folder.
CACHE_DIR_ENV = "CHATTERSPEC_CACHE_DIR"
#: Environment variable that turns the cache off (any value but ``0`` or empty).
NO_CACHE_ENV = "CHATTERSPEC_NO_CACHE"
#: Format tag of an entry file (changed when the file layout changes: old files then read as misses).
FORMAT = "chatterspec-cache/1"
#: Largest entry file read (bytes): anything bigger is not an entry of ours.
MAX_ENTRY_BYTES = 1 << 22


def cache_dir() -> Path | None:
    """The cache folder (it may not exist yet), or None when the cache is turned off."""
    if os.environ.get(NO_CACHE_ENV, "") not in ("", "0"):
        return None
    explicit = os.environ.get(CACHE_DIR_ENV, "")
    if explicit:
        return Path(explicit).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "chatterspec"


def canonical(key: Mapping[str, Any]) -> str:
    """The canonical JSON text of ``key`` (sorted keys, no spaces; floats as ``repr``, exact).

    Raises
    ------
    TypeError
        ``key`` holds a value JSON cannot write (the caller builds keys from numbers, strings, lists).
    """
    return json.dumps(key, sort_keys=True, separators=(",", ":"), allow_nan=True)


def _path(kind: str, key: Mapping[str, Any]) -> Path | None:
    folder = cache_dir()
    if folder is None:
        return None
    return folder / kind / f"{hashlib.sha256(canonical(key).encode()).hexdigest()}.json"


def load(kind: str, key: Mapping[str, Any]) -> Any | None:
    """The value stored for ``key`` under ``kind``, or None (a miss, the cache off, or an unusable file).

    Parameters
    ----------
    kind : str
        The sub-folder (e.g. ``"alarm-calibrations"``).
    key : mapping
        Every input that determines the value (JSON-ready).
    """
    path = _path(kind, key)
    if path is None:
        return None
    try:
        if path.stat().st_size > MAX_ENTRY_BYTES:
            return None
        doc = json.loads(path.read_text(encoding="utf-8"))
        if doc.get("format") != FORMAT or doc.get("kind") != kind or canonical(doc["key"]) != canonical(key):
            return None
        return doc["value"]
    except (OSError, ValueError, TypeError, KeyError, AttributeError):  # missing, corrupt or foreign
        return None


def store(kind: str, key: Mapping[str, Any], value: Any) -> Path | str:
    """Write ``value`` for ``key`` under ``kind`` atomically.

    Returns
    -------
    Path or str
        The entry's file, or the reason it was not written (the cache is off, or the folder cannot be
        written); the caller goes on either way.
    """
    path = _path(kind, key)
    if path is None:
        return f"{NO_CACHE_ENV} is set"
    text = json.dumps(
        {"format": FORMAT, "kind": kind, "key": key, "value": value}, sort_keys=True, allow_nan=True
    )
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".tmp-", suffix=".json", dir=path.parent)
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except OSError as exc:
        if tmp is not None:
            try:
                os.unlink(tmp)
            except OSError:
                pass
        return f"cannot write {str(path.parent)!r} ({exc.strerror or exc})"
    return path
