"""The documentation's examples run as shown: the README's Python block as a script, and every console
transcript with output (``$ command`` followed by what it prints) in ``README.md`` and
``examples/README.md`` against the real output of its commands.

A transcript is read as a terminal shows it: standard output and standard error in the order they were
written, except where the command redirects them (``> FILE``, ``2> FILE``). Shown lines must equal the
printed ones in order, with two elisions: a line that is only ``...`` stands for any number of lines,
and ``...`` inside a line for any text. Timings are masked on both sides (``N s wall``, the stream's
latency, the JSON ``wall_time``). The commands of one block run in order in a fresh folder (where
``examples/`` is the repository's), up to the last one whose output is shown; a command with ``...``
in its arguments is a placeholder and is not run.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

import chatterspec
from chatterspec.cli import main

ROOT = Path(__file__).resolve().parents[1]
#: The checkout whose chatterspec this test process imported (the script imports the same one).
SOURCE = Path(chatterspec.__file__).resolve().parents[1]

#: Timings, masked in the shown and in the printed lines.
TIMINGS = (
    (re.compile(r"\b\d+(?:\.\d+)? s wall\b"), "<t> s wall"),
    (re.compile(r"latency median \S+ ms, max \S+ ms"), "latency median <t> ms, max <t> ms"),
    (re.compile(r'"wall_time": [0-9.e+]+'), '"wall_time": <t>'),
)
#: Transcripts too long for the default run (``-m slow``): (file, first command of the block) and why.
SLOW = {
    (
        "README.md",
        "chatterspec calibrate examples/eha_model.toml --rule cusum --false-alarms-per-hour 0.0417 "
        "--out cal.npz",
    ): "48 h of healthy EHA streams to calibrate",
    (
        "README.md",
        "chatterspec scenarios eha-healthy --model-toml eha.toml",
    ): "10 minutes of a 1 kHz actuator simulated (then commissioned, or its calibration refused)",
}


def _blocks(path: Path) -> list[list[tuple[str, list[str]]]]:
    """The console blocks of ``path`` that show output: per block, ``(command, shown lines)`` per ``$``."""
    blocks = []
    for body in re.findall(r"```console\n(.*?)```", path.read_text(encoding="utf-8"), re.S):
        steps: list[tuple[str, list[str]]] = []
        continued = False
        for line in body.splitlines():
            if continued:  # the rest of a command cut with a trailing backslash
                steps[-1] = (steps[-1][0][:-1].rstrip() + " " + line.strip(), [])
            elif line.startswith("$ "):
                steps.append((line[2:], []))
            elif steps:
                steps[-1][1].append(line)
            continued = bool(steps) and not steps[-1][1] and steps[-1][0].endswith("\\")
        if any(shown for _, shown in steps):
            blocks.append(steps)
    return blocks


def _cases() -> list[object]:
    cases = []
    for rel in ("README.md", "examples/README.md"):
        for steps in _blocks(ROOT / rel):
            first = shlex.split(steps[0][0], comments=True)
            key = (rel, " ".join(first))
            marks = [pytest.mark.slow] if key in SLOW else []
            cases.append(pytest.param(rel, steps, id=f"{rel}:{first[1]}", marks=marks))
    return cases


def _mask(line: str) -> str:
    for pattern, repl in TIMINGS:
        line = pattern.sub(repl, line)
    return line.rstrip()


def _matches(shown: list[str], printed: list[str]) -> bool:
    """Do the shown lines equal the printed ones, with the ``...`` elisions of the module docstring?"""
    pattern = "".join(
        r"(?:[^\n]*\n)*?" if line == "..." else ".*".join(map(re.escape, line.split("..."))) + r"\n"
        for line in map(_mask, shown)
    )
    return re.fullmatch(pattern, "".join(_mask(p) + "\n" for p in printed)) is not None


def _run(command: str, stdin: str | None, piped: bool) -> tuple[int, str, str]:
    """Run one chatterspec command in this process: (exit code, what the terminal shows, its standard
    output); ``stdin``: a file read as standard input; ``piped``: standard output goes to the next
    command, not to the terminal."""
    argv = shlex.split(command, comments=True)
    assert argv[0] == "chatterspec", command
    argv = argv[1:]
    out_file = err_file = None
    while len(argv) >= 2 and argv[-2] in (">", "2>"):
        if argv[-2] == ">":
            out_file = argv[-1]
        else:
            err_file = argv[-1]
        argv = argv[:-2]
    terminal, out, err = io.StringIO(), io.StringIO(), io.StringIO()

    class Tee(io.TextIOBase):
        def __init__(self, own: io.StringIO, shown: bool) -> None:
            self.own, self.shown = own, shown

        def write(self, text: str) -> int:
            self.own.write(text)
            if self.shown:
                terminal.write(text)
            return len(text)

    with contextlib.ExitStack() as stack:
        if stdin is not None:
            source = stack.enter_context(open(stdin, encoding="utf-8"))
            stack.enter_context(_replaced_stdin(source))
        stack.enter_context(contextlib.redirect_stdout(Tee(out, out_file is None and not piped)))
        stack.enter_context(contextlib.redirect_stderr(Tee(err, err_file is None)))
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = int(exc.code or 0)
    for name, buf in ((out_file, out), (err_file, err)):
        if name is not None:
            Path(name).write_text(buf.getvalue(), encoding="utf-8")
    return rc, terminal.getvalue(), out.getvalue()


@contextlib.contextmanager
def _replaced_stdin(source: object):  # type: ignore[no-untyped-def]
    saved = sys.stdin
    sys.stdin = source  # type: ignore[assignment]
    try:
        yield
    finally:
        sys.stdin = saved


@pytest.mark.parametrize(("rel", "steps"), _cases())
def test_console_transcripts_show_the_real_output(
    rel: str, steps: list[tuple[str, list[str]]], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    last = max(i for i, (_, shown) in enumerate(steps) if shown)
    for command, shown in steps[: last + 1]:
        if "..." in shlex.split(command, comments=True):
            assert not shown, f"{rel}: a placeholder command shows output: {command}"
            continue
        parts = command.split(" | ")
        stdin: str | None = None
        terminal = ""
        for i, part in enumerate(parts):
            rc, shown_now, stdout = _run(part, stdin, piped=i < len(parts) - 1)
            terminal += shown_now
            # a transcript that shows the command's one-line error shows a refusal: exit status 2
            refused = any(": error: " in line for line in shown)
            assert rc == (2 if refused else 0), f"{rel}: `{part}` exited {rc}:\n{terminal}"
            pipe = tmp_path / f".pipe{i}"
            pipe.write_text(stdout, encoding="utf-8")
            stdin = str(pipe)
        lines = terminal.splitlines()
        assert _matches(shown, lines), (
            f"{rel}: the transcript of `{command}` differs from the real output (timings masked).\n"
            "shown:\n" + "\n".join(shown) + "\nprinted:\n" + "\n".join(lines)
        )


def test_transcript_matching_rules() -> None:
    printed = ["a 1.5 s wall", "x", "y", "b 12 and more", "c"]
    assert _matches(["a 0.03 s wall", "...", "b 12 ...", "c"], printed)
    assert _matches(["a 9 s wall", "x", "y", "b 12 and more", "c"], printed)
    assert not _matches(["a 0.03 s wall", "x", "b 12 and more", "c"], printed)  # a line missing
    assert not _matches(["a 0.03 s wall", "...", "b 13 ...", "c"], printed)  # a number changed
    assert _matches(["a 0.03 s wall", "..."], [*printed, "d"])  # "..." may end a transcript


def _python_block() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("\n## Python\n") :]
    found = re.search(r"```python\n(.*?)```", section, re.S)
    assert found is not None
    return found.group(1)


def test_readme_python_block_runs_as_a_script(tmp_path: Path) -> None:
    """Saved as a file and run with ``python``: the worker processes of ``workers=2`` import the file
    (spawn), so it must run its work under ``if __name__ == "__main__":``. Fewer runs than shown (the
    same code): 65 runs in chunks of 64 still need two workers, 100 simulated runs become 2."""
    code = _python_block()
    assert 'if __name__ == "__main__":' in code
    small = code.replace("runs=100,", "runs=2,").replace("runs=1_000,", "runs=65, chunk_runs=64,")
    assert small.count("runs=65, chunk_runs=64,") == 2
    script = tmp_path / "readme_example.py"
    script.write_text(small, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": str(SOURCE)}
    out = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, cwd=tmp_path, env=env, timeout=600
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "DetectionReport(detected=True, scenario='eha-leak-medium'" in out.stdout


def _github_anchor(heading: str) -> str:
    """The fragment GitHub gives a heading: lower case, punctuation other than ``-`` and ``_`` dropped,
    spaces as ``-``."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_readme_contents_links_every_section() -> None:
    """The contents line names each second-level section once, in order, by a fragment that exists (a
    renamed or added section would otherwise leave a dead link or a gap)."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    prose = re.sub(r"```.*?```", "", text, flags=re.S)  # headings inside code blocks are not sections
    sections = [h for h in re.findall(r"^## (.+)$", prose, re.M) if h != "Quick start"]
    contents = next(line for line in text.splitlines() if line.startswith("**Contents:**"))
    linked = re.findall(r"\]\(#([^)]+)\)", contents)
    assert linked == [_github_anchor(h) for h in sections]
