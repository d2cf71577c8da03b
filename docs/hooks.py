"""MkDocs hook: render `{{ result NAME }}`, `{{ accuracy }}`, `{{ speed }}`, `{{ material_check }}`,
`{{ service_targets }}` and `{{ changelog }}` in the pages.

Each result block comes from docs/results/NAME.json through studies.pages, with its provenance line and a
warning when the code it describes changed after the commit that measured it.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # a fresh clone's `mkdocs build` without the package installed
    sys.path.insert(0, str(ROOT))

from studies import pages  # noqa: E402


def on_page_markdown(markdown: str, page, config, files) -> str:
    text = pages.render_page(markdown)
    return text.replace("{{ changelog }}", (ROOT / "CHANGELOG.md").read_text().split("\n", 1)[1])
