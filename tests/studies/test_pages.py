"""The docs site's result blocks: each figure with its command, commit, date and machine; stale ones say so."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from studies import pages

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"


@pytest.mark.parametrize("path", sorted(RESULTS.glob("*.json")), ids=lambda p: p.stem)
def test_every_committed_result_records_how_it_was_made(path):
    p = json.loads(path.read_text())["provenance"]
    assert p["command"].startswith(("python -m studies ", "python -m bench "))
    assert p["commit"] and p["date"][:2] == "20"
    assert p["machine"]["cores"] >= 1 and p["machine"]["cpu_model"]


def test_a_result_block_shows_its_provenance_and_its_figures():
    block = pages.result_block("convergence_taylor_hood")
    prov = json.loads((RESULTS / "convergence_taylor_hood.json").read_text())["provenance"]
    assert f"`{prov['command']}`" in block and prov["commit"][:10] in block and prov["date"][:10] in block
    assert ("| 10 mm, 10 deg |" in block
            and "[convergence_taylor_hood.json](results/convergence_taylor_hood.json)" in block)


def test_a_result_older_than_the_code_it_describes_says_so():
    """HEAD's parent measured it and HEAD changed... nothing here: use the root commit, older than any code change."""
    root = subprocess.run(["git", "rev-list", "--max-parents=0", "HEAD"], cwd=ROOT, capture_output=True, text=True)
    if root.returncode != 0:
        pytest.skip("not a git checkout")
    first = root.stdout.split()[0]
    assert "Older than the code" in pages.stale_note(first, ("fem_offline",))
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    assert pages.stale_note(head, ("fem_offline",)) == ""
    assert pages.stale_note("not-a-commit", ("fem_offline",)) == ""


def test_a_page_placeholder_becomes_the_block_and_a_missing_result_says_so(tmp_path):
    text = pages.render_page('A\n\n{{ result "convergence_glued" }}\n\n{{ result nothing_here }}\n')
    assert "*Measured by*" in text and "No committed result `nothing_here`" in text and "{{" not in text


@pytest.mark.skipif(shutil.which("git") is None, reason="needs git for the staleness notes")
def test_the_site_builds_offline_and_strict(tmp_path):
    """`mkdocs build --strict` (what `make docs` runs) succeeds, and every page's placeholders are rendered."""
    pytest.importorskip("mkdocs")
    pytest.importorskip("material")
    site = tmp_path / "site"
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)], cwd=ROOT,
                         capture_output=True, text=True, env={"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin"})
    assert run.returncode == 0, run.stderr
    html = {p.parent.name: p.read_text() for p in site.glob("*/index.html")}
    assert {"physics", "convergence", "tradeoff", "service", "viewer", "patient", "changelog"} <= set(html)
    assert not any("{{" in h for h in html.values())
    assert "fonts.googleapis.com" not in (site / "index.html").read_text()
    assert (site / "results" / "convergence_taylor_hood.json").is_file()
