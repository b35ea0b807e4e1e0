"""The public API: ``import chatterspec as cs`` reaches every documented name, lazily, documented.

The names are listed once, in ``chatterspec._GROUPS`` (by topic); ``__all__`` must be that table plus
the exception classes, and every function and class in it must have a numpydoc docstring whose
``Parameters`` section (``Attributes`` for dataclasses) names each of its parameters.
"""

from __future__ import annotations

import inspect
import re
import subprocess
import sys

import pytest
from test_api_docs import _parameters, _section

import chatterspec as cs
from chatterspec import errors


def test_all_is_the_table_plus_the_errors() -> None:
    assert set(cs.__all__) == set(cs._LAZY) | set(errors.__all__) | {"__version__"}
    assert len(cs.__all__) == len(set(cs.__all__))


def test_the_estimation_api_is_reachable_from_the_top() -> None:
    # the names a new user looked for and had to import from deep modules before
    wanted = {
        "KalmanFilter",
        "ExtendedKalmanFilter",
        "SVSFCov",
        "SecondOrderSVSF",
        "SMMSVSF",
        "IMM",
        "NonlinearModel",
        "load_model",
        "detect_record",
        "DetectionReport",
        "calibrate",
        "estimation_study",
        "diagnose_modes",
        "identify",
    }
    assert wanted <= set(cs.__all__)


def test_importing_the_package_loads_none_of_the_api() -> None:
    code = (
        "import sys, chatterspec; "
        "print(sorted(m for m in sys.modules if m.startswith('chatterspec.') "
        "and m not in ('chatterspec.errors', 'chatterspec._lazy')))"  # (_lazy: the loader of the names)
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def _documented() -> list:
    skip = set(errors.__all__) | {"__version__"}
    return [pytest.param(n, id=n) for n in sorted(cs._LAZY) if n not in skip]


@pytest.mark.parametrize("name", _documented())
def test_each_public_name_has_a_numpydoc_docstring(name: str) -> None:
    obj = getattr(cs, name)
    doc = inspect.getdoc(obj)
    assert doc and doc.strip(), f"chatterspec.{name} has no docstring"
    titles = ("Parameters", "Attributes") if inspect.isclass(obj) else ("Parameters",)
    params = _parameters(obj)
    section = _section(doc, titles)
    if params:
        assert section is not None, f"chatterspec.{name}: no numpydoc {' / '.join(titles)} section"
        missing = [p for p in params if not re.search(rf"(?<![\w]){re.escape(p)}(?![\w])", section)]
        assert not missing, f"chatterspec.{name}: its {titles[0]} section does not mention {missing}"


def test_docs_api_lists_every_public_name() -> None:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "docs" / "api.md").read_text()
    missing = [n for n in cs.__all__ if n != "__version__" and f"`{n}`" not in text]
    assert not missing, f"docs/api.md does not list {missing}"
