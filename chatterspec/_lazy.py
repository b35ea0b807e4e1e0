"""Names of a package that load from their module on first use (PEP 562 ``__getattr__``, ``__dir__``)."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable
from typing import Any


def lazy_names(package: str, table: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``(__getattr__, __dir__)`` for ``package``, whose names ``table`` maps to their relative modules.

    A name is imported on first use and then kept in the package's namespace.
    """
    namespace = vars(sys.modules[package])

    def load(name: str) -> Any:
        module = table.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = namespace[name] = getattr(importlib.import_module(module, package), name)
        return value

    def names() -> list[str]:
        return sorted(set(namespace) | set(table))

    return load, names
