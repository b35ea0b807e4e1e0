"""Suite-wide setup: the user cache (``chatterspec._cache``) lives in a temporary folder.

Set in ``pytest_configure``, before the test modules are imported, so that modules which copy
``os.environ`` for their subprocesses at import time pass it on too: no test reads or writes the
user's own ``~/.cache/chatterspec``.
"""

from __future__ import annotations

import os
import shutil
import tempfile

_CACHE_DIR: str | None = None


def pytest_configure(config) -> None:
    global _CACHE_DIR
    _CACHE_DIR = tempfile.mkdtemp(prefix="chatterspec-test-cache-")
    os.environ["CHATTERSPEC_CACHE_DIR"] = _CACHE_DIR
    os.environ.pop("CHATTERSPEC_NO_CACHE", None)


def pytest_unconfigure(config) -> None:
    if _CACHE_DIR is not None:
        shutil.rmtree(_CACHE_DIR, ignore_errors=True)
