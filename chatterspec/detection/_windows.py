"""Old home of the STFT tapers: :mod:`chatterspec._windows` (shared with :mod:`chatterspec._stft`)."""

from __future__ import annotations

from .._windows import NATIVE_WINDOWS, get_window

__all__ = ["NATIVE_WINDOWS", "get_window"]
