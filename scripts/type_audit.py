"""Count the loose annotations of the package: parameters typed ``object``/``Any`` and ``# type: ignore``.

Run from the repository root::

    python scripts/type_audit.py            # totals
    python scripts/type_audit.py --list     # every parameter and ignore, one a line

A parameter counts when its annotation is exactly ``object`` or ``Any`` (``typing.Any`` too), not when
one of them sits inside a larger type (``dict[str, Any]`` for a JSON document is a real type).
An ignore counts once per line that holds ``type: ignore``; ``--list`` marks those without a reason
(no text after the bracketed code).
"""

from __future__ import annotations

import argparse
import ast
import re
import sys
from pathlib import Path

LOOSE = {"object", "Any", "typing.Any"}
IGNORE = re.compile(r"#\s*type:\s*ignore(\[[^\]]*\])?(.*)$")


def loose_parameters(path: Path) -> list[str]:
    """``file:line function(parameter: type)`` for every parameter annotated ``object`` or ``Any``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        a = node.args
        params = [*a.posonlyargs, *a.args, *a.kwonlyargs]
        params += [p for p in (a.vararg, a.kwarg) if p is not None]
        for p in params:
            if p.annotation is not None and ast.unparse(p.annotation) in LOOSE:
                found.append(f"{path}:{p.lineno} {node.name}({p.arg}: {ast.unparse(p.annotation)})")
    return found


def ignores(path: Path) -> list[str]:
    """``file:line [reason?] text`` for every line holding ``# type: ignore``."""
    out = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        m = IGNORE.search(line)
        if m:
            reason = m.group(2).strip().lstrip("#").strip()
            tag = "reason" if reason else "NO REASON"
            out.append(f"{path}:{i} [{tag}] {line.strip()}")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("root", nargs="?", default="chatterspec")
    ap.add_argument("--list", action="store_true", help="print every item, not only the totals")
    args = ap.parse_args(argv)
    files = sorted(Path(args.root).rglob("*.py"))
    params = [x for f in files for x in loose_parameters(f)]
    ign = [x for f in files for x in ignores(f)]
    if args.list:
        print("\n".join(params + ign))
    no_reason = sum("[NO REASON]" in x for x in ign)
    print(f"object/Any parameters: {len(params)}")
    print(f"type: ignore lines: {len(ign)} ({no_reason} without a reason)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
