"""Suite-wide setup: the user cache (``chatterspec._cache``) lives in a temporary folder, and the
slowest test files run first.

The cache folder is set in ``pytest_configure``, before the test modules are imported, so that modules
which copy ``os.environ`` for their subprocesses at import time pass it on too: no test reads or writes
the user's own ``~/.cache/chatterspec``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest

_CACHE_DIR: str | None = None


def pytest_configure(config) -> None:
    global _CACHE_DIR
    _CACHE_DIR = tempfile.mkdtemp(prefix="chatterspec-test-cache-")
    os.environ["CHATTERSPEC_CACHE_DIR"] = _CACHE_DIR
    os.environ.pop("CHATTERSPEC_NO_CACHE", None)
    # xdist (3.8 on) hands out the files in collection order, SLOW_FIRST's, instead of most tests first
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def pytest_unconfigure(config) -> None:
    if _CACHE_DIR is not None:
        shutil.rmtree(_CACHE_DIR, ignore_errors=True)


#: The slowest test files from a clean checkout (most of their time compiles numba kernels), slowest
#: first. With ``--dist loadfile`` (pyproject.toml) and xdist's reordering off (``pytest_configure``),
#: the workers take whole files in collection order, so these start first and each worker ends on
#: short files. (xdist's default order, most tests first, started test_imm_kernel.py, about a seventh
#: of the suite's work, near the end.) The order is a schedule only: every file still runs whole.
SLOW_FIRST = (
    "test_multiple_model.py",
    "test_imm_kernel.py",
    "test_one_sample.py",
    "test_svsf_cov.py",
    "test_notebooks.py",
    "test_svsf2.py",
    "test_estimation.py",
    "test_kalman.py",
)


def pytest_collection_modifyitems(session, config, items) -> None:
    here = Path(__file__).parent
    gone = [name for name in SLOW_FIRST if not (here / name).is_file()]
    if gone:  # a renamed or removed file: the schedule would silently lose it
        raise pytest.UsageError(f"tests/conftest.py: SLOW_FIRST names no such test file: {', '.join(gone)}")
    rank = {name: i for i, name in enumerate(SLOW_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(SLOW_FIRST)))  # stable: files stay whole
