"""The package's layers, read from the source with :mod:`ast` (docs/design.md §3).

Every ``import`` in ``chatterspec/`` counts, at module level or inside a function, so a circle
closed by a deferred import is still a circle. Three rules:

1. **Layer order.** A folder imports only from folders below it::

       base (top-level modules) < plants < filters < detection < studies < online < viewer < figures < cli

   The package's ``__init__`` and ``__main__`` are the facade on top and may import anything.
2. **No import circles** between modules (the module graph is acyclic; imports under
   ``if TYPE_CHECKING:`` are never run and do not count here, but they do count for rules 1 and 3).
3. **No private names across folders**: an import from another folder names neither a private
   module (a path component starting with ``_``) nor a private name. The private top-level
   modules (``_validate``, ``_jit``, ``_stft``, ...) are the package's shared base and may be
   imported by module, but not their private names.

``ALLOWED`` lists the edges that still break a rule, each with its reason; it must only shrink.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path
from typing import NamedTuple

PACKAGE = Path(__file__).resolve().parent.parent / "chatterspec"

LAYERS = ("base", "plants", "filters", "detection", "studies", "online", "viewer", "figures", "cli")
FACADE = {"chatterspec", "chatterspec.__main__"}

# (importer, imported module), both without the leading ``chatterspec.`` -> why the edge is still
# there. Each entry breaks one rule (named first); fix the code and delete the entry.
ALLOWED: dict[tuple[str, str], str] = {}


class Import(NamedTuple):
    importer: str
    target: str  # a module of the package
    name: str | None  # the name taken from it (None: the module itself)
    line: int
    typing_only: bool = False  # under ``if TYPE_CHECKING:``: a layer edge, but never run


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def _imports(module: str, path: Path) -> list[Import]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module.split(".") if path.name == "__init__.py" else module.split(".")[:-1]
    typing_only = {
        id(inner)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
        for stmt in node.body
        for inner in ast.walk(stmt)
    }
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            pairs = [(a.name, None) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                source = ".".join(base + ([node.module] if node.module else []))
            else:
                source = node.module or ""
            pairs = [
                (f"{source}.{a.name}", None) if f"{source}.{a.name}" in MODULES else (source, a.name)
                for a in node.names
            ]
        else:
            continue
        for target, name in pairs:
            if target != "chatterspec" and not target.startswith("chatterspec."):
                continue
            while target not in MODULES:  # ``import chatterspec.a.b`` of a name: its module
                target = target.rsplit(".", 1)[0]
            found.append(Import(module, target, name, node.lineno, id(node) in typing_only))
    return found


IMPORTS = [imp for module, path in MODULES.items() for imp in _imports(module, path)]


def _folder(module: str) -> str:
    parts = module.split(".")
    if len(parts) > 2 or (len(parts) == 2 and (PACKAGE / parts[1]).is_dir()):
        return parts[1]
    return "base"


def _private(imp: Import) -> bool:
    names = imp.target.split(".")[1:] if _folder(imp.target) != "base" else []
    if imp.name is not None:
        names.append(imp.name)
    return any(n.startswith("_") and not (n.startswith("__") and n.endswith("__")) for n in names)


def _breaks_layers(imp: Import) -> bool:
    if imp.importer in FACADE:
        return False
    return LAYERS.index(_folder(imp.target)) > LAYERS.index(_folder(imp.importer))


def _breaks_privacy(imp: Import) -> bool:
    return _folder(imp.target) != _folder(imp.importer) and _private(imp)


def _allowed(importer: str, target: str) -> bool:
    return (importer.removeprefix("chatterspec."), target.removeprefix("chatterspec.")) in ALLOWED


def _show(imps: list[Import]) -> str:
    return "\n".join(
        f"  {i.importer}:{i.line} imports {i.target}" + (f".{i.name}" if i.name else "") for i in imps
    )


def test_every_folder_has_a_layer() -> None:
    folders = {_folder(m) for m in MODULES}
    assert folders <= set(LAYERS), folders - set(LAYERS)


def test_no_upward_imports() -> None:
    bad = [i for i in IMPORTS if _breaks_layers(i) and not _allowed(i.importer, i.target)]
    assert not bad, "imports from a higher layer:\n" + _show(bad)


def test_no_private_names_across_folders() -> None:
    bad = [i for i in IMPORTS if _breaks_privacy(i) and not _allowed(i.importer, i.target)]
    assert not bad, "private names imported from another folder:\n" + _show(bad)


def _cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found = []
    for root in sorted(MODULES):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    component.append(m)
                    if m == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def _edges(skip_allowed: bool) -> dict[str, set[str]]:
    """The run-time import graph (imports only a type checker reads cannot close a circle)."""
    edges: dict[str, set[str]] = defaultdict(set)
    for i in IMPORTS:
        if i.typing_only:
            continue
        if i.target != i.importer and not (skip_allowed and _allowed(i.importer, i.target)):
            edges[i.importer].add(i.target)
    return edges


def test_no_import_circles() -> None:
    circles = _cycles(_edges(skip_allowed=True))
    assert not circles, "import circles (imports inside functions count):\n" + "\n".join(
        "  " + " <-> ".join(c) for c in circles
    )


def test_allow_list_is_still_needed() -> None:
    """Each allowed edge exists and breaks a rule (so the list shrinks when one is fixed)."""
    edges = _edges(skip_allowed=False)
    in_circle = {(a, b) for c in _cycles(edges) for a in c for b in c if b in edges[a]}
    stale = []
    for importer, target in (("chatterspec." + a, "chatterspec." + b) for a, b in ALLOWED):
        imps = [i for i in IMPORTS if (i.importer, i.target) == (importer, target)]
        breaks = any(_breaks_layers(i) or _breaks_privacy(i) for i in imps)
        if not breaks and (importer, target) not in in_circle:
            stale.append(f"{importer} -> {target}")
    assert not stale, "allow-list entries that no longer break a rule (remove them):\n  " + "\n  ".join(stale)


def test_the_reader_sees_deferred_and_relative_imports() -> None:
    """The ast reader resolves relative imports and finds imports inside functions."""
    found = {(i.target, i.name) for i in IMPORTS if i.importer == "chatterspec.__main__"}
    assert ("chatterspec.cli", "main") in found
    deferred = [i for i in IMPORTS if i.line > 1 and i.importer == "chatterspec.cli.monitor"]
    assert any(i.target == "chatterspec.plants.modelfile" for i in deferred)
    typing = [i for i in IMPORTS if i.importer == "chatterspec.plants.parameters" and i.name == "LinearModel"]
    assert typing and all(i.typing_only for i in typing)
