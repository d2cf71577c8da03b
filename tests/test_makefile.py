"""`make help` lists every target of the Makefile, each with a one-line description."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _targets() -> set[str]:
    """Rule targets written by hand (no pattern, variable or dot targets)."""
    text = (ROOT / "Makefile").read_text()
    return set(re.findall(r"^([a-zA-Z][a-zA-Z0-9_-]*):(?!=)", text, flags=re.M))


def test_make_help_lists_every_target_with_a_description():
    out = subprocess.run(["make", "-s", "help"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    listed = dict(line.strip().split(None, 1) for line in out.splitlines() if line.strip())
    assert set(listed) == _targets()
    assert all(len(d) > 10 for d in listed.values())


def test_every_target_is_phony():
    """Every target names an action, not a file; a file of that name must not stop it running."""
    phony = set(re.search(r"^\.PHONY:(.*)$", (ROOT / "Makefile").read_text(), flags=re.M).group(1).split())
    assert _targets() <= phony


def test_make_with_no_target_prints_help():
    out = subprocess.run(["make", "-s"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert "  help " in out and "  docs " in out
