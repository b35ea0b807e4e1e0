"""Screenshots of recordings in the real Rerun viewer, as a person sees each file when it opens.

Each ``.rrd`` is opened by the viewer binary of the installed rerun-sdk (``rerun``, 0.41) in a
1600x1000 window on a virtual X display (Xvfb, software rendering through Mesa's llvmpipe) with an
empty home directory, so no layout stored by an earlier session interferes; the viewer writes one
PNG and exits. The screen is much larger than the window so that the (virtual) pointer rests
outside it and no hover tooltip lands in the picture. Nothing is clicked: the picture is the file's
own blueprint as it first opens.

Without file arguments it first makes the standard set of recordings (into ``--work``):

* ``demo/<scenario>.rrd``: ``chatterspec demo`` (11 scenarios);
* ``detect-timeline.rrd``: ``chatterspec detect so-timeline-constant --record``;
* ``stream-leak.rrd``: ``chatterspec simulate eha-leak-minor --duration 30 --rate 0 | chatterspec monitor
  <eha-healthy model> --data - --record`` (a streamed file: its final blueprint);
* ``monitor-file.rrd``: ``chatterspec monitor --data <the same 30 s as a file> --record``;
* ``estimate.rrd``: ``chatterspec estimate detc-uncertain --runs 1 --record``;
* ``diagnose.rrd``: ``chatterspec diagnose eha4-leak-timeline --runs 2 --record``;
* ``closed-loop.rrd``: ``chatterspec detect eha-cl-bulk-25down --record``.

With ``--readme`` it also writes the README's pictures under ``docs/screenshots/`` (the demo's
``eha-leak-minor``, the streamed monitor, ``estimate`` and ``diagnose``), scaled to 1600x1000 (the
viewer writes twice that) and reduced to a 256-colour palette, so each stays far below 1 MB.

Setup (Debian, as root): ``apt-get install -y xvfb mesa-vulkan-drivers``. Usage::

    python scripts/screenshot_recordings.py --out shots                 # standard set, all of it
    python scripts/screenshot_recordings.py --out shots a.rrd b.rrd     # given files only
    python scripts/screenshot_recordings.py --out shots --readme        # and refresh docs/screenshots/
    python scripts/screenshot_recordings.py --out shots --work rec --reuse --readme  # resume: missing PNGs

One screenshot costs ~15 s of CPU (llvmpipe) and one to three minutes of wall time on a loaded machine;
they run one after the other.
"""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

WINDOW = "1600x1000"
SCREEN = "7000x4200x24"  # far larger than the window: the pointer stays off it
ROOT = Path(__file__).resolve().parents[1]
README_SHOTS = {  # picture under docs/screenshots/ <- recording of the standard set
    "demo-eha-leak-minor.png": "demo/eha-leak-minor.rrd",
    "monitor-stream.png": "stream-leak.rrd",
    "estimate.png": "estimate.rrd",
    "diagnose.png": "diagnose.rrd",
}


def _run(cmd: list[str], **kw) -> None:
    print("$", " ".join(cmd), file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True, **kw)


def make_recordings(work: Path) -> list[Path]:
    """Write the standard set of recordings into ``work``; return their paths."""
    cs = [sys.executable, "-m", "chatterspec"]
    work.mkdir(parents=True, exist_ok=True)
    out = subprocess.DEVNULL
    _run([*cs, "demo", "--no-figures", "--recordings-dir", str(work / "demo")], stdout=out)
    _run([*cs, "detect", "so-timeline-constant", "--record", str(work / "detect-timeline.rrd")], stdout=out)
    model = work / "eha-healthy.toml"
    _run([*cs, "scenarios", "eha-healthy", "--model-toml", str(model)], stdout=out)
    data = work / "eha-leak-minor-30s.csv"
    with data.open("w") as fh:
        _run([*cs, "simulate", "eha-leak-minor", "--duration", "30", "--rate", "0"], stdout=fh)
    with data.open() as fh:  # the same rows through standard input: a streamed file
        _run(
            [*cs, "monitor", str(model), "--data", "-", "--record", str(work / "stream-leak.rrd")],
            stdin=fh,
            stdout=out,
        )
    _run(
        [
            *cs,
            "monitor",
            str(model),
            "--data",
            str(data),
            "--record",
            str(work / "monitor-file.rrd"),
        ],
        stdout=out,
    )
    _run(
        [
            *cs,
            "estimate",
            "detc-uncertain",
            "--runs",
            "1",
            "--no-progress",
            "--record",
            str(work / "estimate.rrd"),
        ],
        stdout=out,
    )
    _run(
        [
            *cs,
            "diagnose",
            "eha4-leak-timeline",
            "--runs",
            "2",
            "--no-progress",
            "--record",
            str(work / "diagnose.rrd"),
        ],
        stdout=out,
    )
    _run([*cs, "detect", "eha-cl-bulk-25down", "--record", str(work / "closed-loop.rrd")], stdout=out)
    return sorted(work.rglob("*.rrd"))


def screenshot(rrd: Path, png: Path, timeout_s: float = 600.0, *, retry: bool = True) -> None:
    """Open ``rrd`` in the Rerun viewer under Xvfb and save what it shows as ``png`` (1600x1000)."""
    viewer = shutil.which(
        "rerun", path=os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]])
    )
    xvfb = shutil.which("xvfb-run")
    if viewer is None or xvfb is None:
        raise SystemExit(
            "needs the `rerun` viewer of rerun-sdk and `xvfb-run` (apt-get install xvfb mesa-vulkan-drivers)"
        )
    png.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="rerun-home-") as home:
        env = {
            "PATH": os.environ["PATH"],
            "HOME": home,  # no stored layout or settings from an earlier session
            "XDG_CONFIG_HOME": str(Path(home) / ".config"),
            "XDG_DATA_HOME": str(Path(home) / ".local" / "share"),
            "XDG_CACHE_HOME": str(Path(home) / ".cache"),
            "RERUN_ANALYTICS": "0",
        }
        cmd = [
            xvfb,
            "-a",
            "-s",
            f"-screen 0 {SCREEN}",
            viewer,
            "--new",  # a viewer of its own: a viewer already on the default port would take the file
            "--window-size",
            WINDOW,
            "--screenshot-to",
            str(png.resolve()),
            str(rrd.resolve()),
        ]
        print("$", " ".join(cmd[-4:]), file=sys.stderr, flush=True)
        # its own process group: on a timeout the viewer and Xvfb are ended with xvfb-run
        proc = subprocess.Popen(
            cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
        )
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait()
            print(f"  timed out after {timeout_s:g} s", file=sys.stderr)
    if not png.exists():  # e.g. two xvfb-run -a took the same display number: once more
        if retry:
            screenshot(rrd, png, timeout_s, retry=False)
            return
        raise SystemExit(f"the viewer wrote no screenshot for {rrd}")


def palette_png(src: Path, dst: Path) -> None:
    """Copy ``src`` to ``dst`` at 1600x1000 (the viewer renders at twice the window's logical size)
    reduced to 256 colours (the views are flat colours and text)."""
    from PIL import Image

    dst.parent.mkdir(parents=True, exist_ok=True)
    with Image.open(src) as im:
        size = tuple(int(v) for v in WINDOW.split("x"))
        im.convert("RGB").resize(size, Image.Resampling.LANCZOS).quantize(
            colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE
        ).save(dst, optimize=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("files", nargs="*", type=Path, help="recordings to shoot (default: make the standard set)")
    p.add_argument("--out", type=Path, default=Path("screenshots"), help="where to write <name>.png")
    p.add_argument(
        "--work", type=Path, default=None, help="where to write the standard set (default: a temp dir)"
    )
    p.add_argument(
        "--readme", action="store_true", help="also refresh docs/screenshots/ from the standard set"
    )
    p.add_argument(
        "--reuse", action="store_true", help="with --work: take its recordings, shoot only the missing PNGs"
    )
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="chatterspec-shots-") as tmp:
        work = args.work or Path(tmp)
        if args.files:
            files, base = args.files, None
        elif args.reuse and args.work is not None and any(work.rglob("*.rrd")):
            first = set(README_SHOTS.values())  # the README's pictures first
            files = sorted(work.rglob("*.rrd"), key=lambda f: (str(f.relative_to(work)) not in first, str(f)))
            base = work
        else:
            files, base = make_recordings(work), work
        for rrd in files:
            name = str(rrd.relative_to(base)) if base else rrd.name
            png = args.out / (name.replace("/", "-").removesuffix(".rrd") + ".png")
            if not (args.reuse and png.exists()):
                screenshot(rrd, png)
        if args.readme:
            if base is None:
                raise SystemExit("--readme shoots the standard set: give no files")
            for dst, rel in README_SHOTS.items():
                palette_png(
                    args.out / (rel.replace("/", "-").removesuffix(".rrd") + ".png"),
                    ROOT / "docs" / "screenshots" / dst,
                )
                size_kb = (ROOT / "docs" / "screenshots" / dst).stat().st_size // 1024
                print(f"docs/screenshots/{dst}: {size_kb} kB", file=sys.stderr)


if __name__ == "__main__":
    main()
