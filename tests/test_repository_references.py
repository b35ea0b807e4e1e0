"""Every reference in the repository points into the repository.

Code, tests, docs, notebooks and benchmarks may cite the papers (title, tag such as [SMM], equation and
table numbers) and files of this repository (``docs/design.md``, ``docs/paper-notes.md``, modules), but
nothing a maintainer of this repository cannot open: design notes kept elsewhere, tracker issue numbers,
development branch or round names, local file names of paper extractions, or paths of a build machine.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = (".py", ".md", ".ipynb", ".toml")

#: (what, pattern). Each pattern is a kind of reference that leads out of the repository.
FORBIDDEN: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("design notes kept outside the repository", re.compile(r"(?<![\w/.-])DESIGN\.md")),
    ("notes kept outside the repository", re.compile(r"\b(?:estimators|alarms|rerun-0\.41)\.md\b")),
    ("notes kept outside the repository", re.compile(r"\.\./shared|\bshared/|(?<![\w-])notes/")),
    (
        "a section of an outside note",
        re.compile(r"\bnote (?:§|sections? \d)|\bthe note's\b|\bclosing note\b|\s\(note\)", re.IGNORECASE),
    ),
    (
        "a tracker issue",
        re.compile(r"\bissues?[- ]#?\d+|\bthe issue(?:'s)?\b|\bissue targets?\b", re.IGNORECASE),
    ),
    ("an item of a tracker issue", re.compile(r"\bitems? \d+(?:-\d+)?\b(?! (?:above|below))", re.IGNORECASE)),
    (
        "a development round or branch",
        re.compile(
            r"\b(?:first|second|third|fourth) round\b|\bround \d\b|\bbranch `"
            r"|\b(?:trust-b|pushfast|loglayout|est-mm)\b",
            re.IGNORECASE,
        ),
    ),
    (
        "a local file name of a paper extraction (cite the paper and its tag instead)",
        re.compile(
            r"(?:chattering-spectral-analysis-svsf-2023|smm-svsf-eha-(?:journal|conference)"
            r"|(?:imm-)?dynamic-2nd-order-svsf-eha)\.txt"
        ),
    ),
    ("a path of a build machine", re.compile(r"(?:^|[\s`'\"(])/(?:work|home|Users|root|mnt)/|\b[A-Z]:\\\\")),
)


def _tracked_files() -> list[Path]:
    """The repository's text files of the checked kinds (``git ls-files``; a directory walk without git)."""
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True, timeout=60
        ).stdout.decode()
        names = [n for n in out.split("\0") if n]
    except (OSError, subprocess.SubprocessError):
        skip = {".git", ".venv", "build", "dist", "__pycache__", ".ipynb_checkpoints"}
        names = [
            str(p.relative_to(ROOT))
            for p in ROOT.rglob("*")
            if p.is_file() and not skip.intersection(p.relative_to(ROOT).parts)
        ]
    this = Path(__file__).resolve()
    return [ROOT / n for n in names if n.endswith(SUFFIXES) and (ROOT / n).resolve() != this]


def find_outside_references(text: str) -> list[tuple[int, str, str]]:
    """``(line number, what, matched text)`` of every reference in ``text`` that leads outside."""
    hits = []
    for lineno, line in enumerate(text.splitlines(), start=1):
        for what, pattern in FORBIDDEN:
            for m in pattern.finditer(line):
                hits.append((lineno, what, m.group(0)))
    return hits


@pytest.mark.parametrize(
    "text",
    [
        "see DESIGN.md section 5",
        "``estimators.md`` §1.6",
        "(note §1.2)",
        "Note section 3.3: with +-60 rad/s",
        "choices (note): pump speed",
        "the note's choices (section 2.3)",
        "resolutions from shared/notes/estimators.md",
        "(issue 9 item 5)",
        "Issue 11: a single record",
        "The issue-10 baselines",
        "checks the issue's criterion",
        "# issue target: argmax",
        "# --- item 7 ---",
        "after the third round",
        "branch pushfast",
        "paper (``smm-svsf-eha-journal.txt``)",
        "Notation of /work/x/y.md",
    ],
)
def test_each_kind_of_outside_reference_is_recognized(text: str) -> None:
    assert find_outside_references(text), text


@pytest.mark.parametrize(
    "text",
    [
        "docs/design.md §7.6 and docs/paper-notes.md",
        "[SMM] Table 1 step 3, [IMM] eq 18",
        "the numpy branch's memory layout; round(duration / dt) + 1",
        "(item 9 above)",
        "/proc/self/task/*/schedstat",
        "shared by all realizations",
    ],
)
def test_references_into_the_repository_are_allowed(text: str) -> None:
    assert not find_outside_references(text), text


def test_no_reference_leads_outside_the_repository() -> None:
    files = _tracked_files()
    if not any(f.suffix == ".py" and f.parent.name == "chatterspec" for f in files):
        pytest.skip("not run from a source checkout")
    found = []
    for path in files:
        text = path.read_text(encoding="utf-8", errors="replace")
        for lineno, what, match in find_outside_references(text):
            found.append(f"{path.relative_to(ROOT)}:{lineno}: {what}: {match!r}")
    assert not found, "references that lead outside the repository:\n" + "\n".join(found)
