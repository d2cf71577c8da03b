"""Rewrite README.md's generated tables (accuracy, speed) from models/default and docs/results/; --check: exit 1 when stale."""  # noqa: E501 -- the first line is the command's summary in --list and its --help description

from __future__ import annotations

import argparse
import difflib
import sys
from pathlib import Path

from studies.pages import fill
from studies.results import ROOT

README = ROOT / "README.md"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m studies readme", description=__doc__)
    ap.add_argument("--check", action="store_true",
                    help="change nothing; print a diff and exit 1 when the README is stale")
    ap.add_argument("--readme", type=Path, default=README)
    args = ap.parse_args(argv)
    old = args.readme.read_text()
    new = fill(old)
    if new == old:
        print(f"{args.readme.name}: generated tables are current")
        return 0
    if args.check:
        sys.stdout.writelines(difflib.unified_diff(old.splitlines(True), new.splitlines(True), "README.md",
                                                   "generated"))
        print(f"\n{args.readme.name} is stale: run `python -m studies readme`", file=sys.stderr)
        return 1
    args.readme.write_text(new)
    print(f"rewrote the generated tables of {args.readme.name}")
    return 0
