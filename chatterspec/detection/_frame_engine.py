"""Old home of :mod:`chatterspec.detection.frame_engine` (private names kept for old imports)."""

from __future__ import annotations

from .frame_engine import FrameEngine as _FrameEngine
from .frame_engine import _power_kernel, _taper_kernel

__all__: list[str] = []
_OLD_NAMES = (_FrameEngine, _power_kernel, _taper_kernel)
