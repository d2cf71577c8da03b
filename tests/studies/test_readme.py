"""README.md's generated tables match models/default's manifest and the committed benchmark; the README stays short."""

import re
from pathlib import Path

from studies import pages, readme

ROOT = Path(__file__).resolve().parents[2]


def test_the_readme_tables_are_the_ones_the_manifest_and_results_give():
    """`python -m studies readme --check` would pass: every generated block equals what it renders now."""
    text = (ROOT / "README.md").read_text()
    assert re.findall(r"<!-- generated:(\w+) -->", text) == ["accuracy", "speed"]
    assert pages.fill(text) == text, "README.md is stale: run `python -m studies readme`"


def test_check_exits_1_with_a_diff_on_a_stale_readme(tmp_path, capsys):
    stale = tmp_path / "README.md"
    stale.write_text((ROOT / "README.md").read_text().replace("| markers |", "| markers (typed by hand) |", 1))
    assert readme.main(["--check", "--readme", str(stale)]) == 1
    assert "+| markers |" in capsys.readouterr().out
    assert readme.main(["--readme", str(stale)]) == 0 and readme.main(["--check", "--readme", str(stale)]) == 0


def test_the_accuracy_table_states_each_regions_end_to_end_error_from_the_manifest(tmp_path):
    """Each row is surrogate | FE | end to end of the manifest's region, and the block names its sources."""
    import json

    manifest = json.loads((ROOT / "models" / "default" / "manifest.json").read_text())
    table = pages.accuracy_table()
    for key, label in pages.REGIONS:
        if key in manifest["accuracy"]["regions"]:
            r = manifest["accuracy"]["regions"][key]
            row = next(line for line in table.splitlines() if line.startswith(f"| {label} |"))
            nominal = (f"| {label} | {pages._mm(r['surrogate_mm'])} | {pages._mm(r['fe_discretisation_mm'])} | "
                       f"**{pages._mm(r['end_to_end_mm'])}** |")
            materials = ((manifest.get("materials") or {}).get("accuracy") or {}).get("regions", {})
            if key in materials:  # then the model over the stiffness ranges, and that plus the FE, end to end
                over = max(materials[key]["model_mm"], r["surrogate_mm"])
                nominal += f" {pages._mm(over)} | **{pages._mm(over + r['fe_discretisation_mm'])}** |"
            assert row == nominal
    assert f"PCA rank {manifest['pca']['rank']}" in table and f"1x{manifest['network']['width']}" in table
    assert "models/default/manifest.json" in table and "python -m studies model-vs-converged" in table


def test_the_speed_table_is_the_benchmarks_rows_or_says_there_is_none(tmp_path):
    import json

    assert "no committed result" in pages.speed_table(tmp_path)
    rows = [{"what": "markers, JSON", "p50_ms": 0.41, "p99_ms": 0.9, "req_s": 2100.0}]
    prov = {"command": "python -m bench service --publish", "commit": "abc", "date": "2026-12-05T00:00:00Z",
            "machine": {"cores": 2, "cpu_model": "X"}}
    (tmp_path / "bench_service.json").write_text(json.dumps({"provenance": prov, "readme_rows": rows}))
    table = pages.speed_table(tmp_path)
    assert "| markers, JSON | 0.41 | 0.90 | 2,100 |" in table and "`python -m bench service --publish`" in table


def test_the_readme_is_a_front_door():
    """At most 250 lines; no run folders a clone lacks (outside the generated provenance, which names a study's
    inputs), no notes on rounds or machine load."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    prose = re.sub(r"<!-- generated:(\w+) -->.*?<!-- /generated:\1 -->", "", text, flags=re.S)
    assert not re.search(r"\bruns/(?!results/)\w", prose)  # runs/results/: where a study writes, not reads
    assert not re.search(r"this round|while other jobs|shared the cores|busy", text, flags=re.I)


def test_the_readmes_defaults_are_the_codes():
    """Worker count, port and the default model's rank and width as the README states them."""
    import json

    from service.settings import Settings

    text = (ROOT / "README.md").read_text()
    s = Settings()
    for name in ("workers", "threads"):  # derived from the usable cores, and the README says so
        assert "from the usable cores" in Settings.model_fields[name].description
    assert "`--workers` and `--threads` (onnxruntime threads; both default from the cores" in text
    assert f"127.0.0.1:{s.port}" in text and f"(default {s.max_points:,})" in text
    manifest = json.loads((ROOT / "models" / "default" / "manifest.json").read_text())
    assert f"{manifest['mesh']['n_tets']:,} tets" in text
