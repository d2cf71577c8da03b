"""Measured results as JSON with their provenance: the command, the commit, the date and the machine.

A study or benchmark writes `runs/results/NAME.json` by default; with `--publish` it writes
`docs/results/NAME.json`, the one current result of that study that the docs site renders. The
provenance sits under the key "provenance" beside the study's own keys.
"""

from __future__ import annotations

import datetime as dt
import json
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

from service.cores import usable_cores  # its one owner; the service must not import studies

ROOT = Path(__file__).resolve().parents[1]
RUNS_RESULTS = ROOT / "runs" / "results"
DOCS_RESULTS = ROOT / "docs" / "results"


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (platform.processor() where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine() -> dict:
    """Cores usable and present, CPU model, 1-min load average, Python and OS."""
    return {"cores": usable_cores(), "cpu_count": os.cpu_count(), "cpu_model": cpu_model(),
            "load_1min": round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else None,
            "python": platform.python_version(), "platform": platform.platform()}


def commit() -> str:
    """HEAD's hash, with "-dirty" when tracked files differ from it; "unknown" outside a git checkout."""
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True,
                              check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("-dirty" if dirty else "")


def command() -> str:
    """The command line that is running, as a user would type it again."""
    prog = sys.argv[0]
    if prog.startswith("python -m "):  # set by studies._cli.dispatch
        return f"{prog} {shlex.join(sys.argv[1:])}".strip()
    return f"python {shlex.join(sys.argv)}"


def provenance() -> dict:
    return {"command": command(), "commit": commit(),
            "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"), "machine": machine()}


def write(name: str, data: dict, *, publish: bool = False, folder: Path | None = None) -> Path:
    """Write `data` plus its provenance as NAME.json: docs/results/ when `publish`, else runs/results/ (or `folder`)."""
    out = (DOCS_RESULTS if publish else RUNS_RESULTS) if folder is None else Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{name}.json"
    body = {k: v for k, v in data.items() if k != "provenance"}
    path.write_text(json.dumps({"provenance": provenance(), **body}, indent=1) + "\n")
    return path


def read(name: str, folder: Path = DOCS_RESULTS) -> dict:
    """A result as written by `write` (docs/results/ by default)."""
    return json.loads((Path(folder) / f"{name}.json").read_text())


def add_publish_flag(ap) -> None:
    """The shared `--publish` flag: write docs/results/NAME.json instead of runs/results/."""
    ap.add_argument("--publish", action="store_true",
                    help="write the result to docs/results/ (the docs site's current result) instead of runs/results/")
