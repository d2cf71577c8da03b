"""The pipeline's package data: the label-map FE error table travels with the package, not with docs/."""

import io
import json
import tokenize
from importlib.resources import files
from pathlib import Path
from types import SimpleNamespace

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = ("contracts", "fem_offline", "training", "service", "pipeline")


def _path_literals_under_docs(path: Path) -> list[str]:
    """String literals of a module that name docs/ as a path ("docs", "docs/x.json"), comments and prose aside."""
    hits = []
    for tok in tokenize.generate_tokens(io.StringIO(path.read_text()).readline):
        if tok.type != tokenize.STRING:
            continue
        body = tok.string.lstrip("rbfuRBFU").strip("'\"")
        if body == "docs" or body.startswith("docs/"):
            hits.append(f"{path.relative_to(ROOT)}:{tok.start[0]}: {tok.string}")
    return hits


def test_no_installed_package_reads_a_file_under_docs():
    """docs/ is the site and its results; an installed package must run without it."""
    hits = [h for pkg in PACKAGES for f in sorted((ROOT / pkg).rglob("*.py")) for h in _path_literals_under_docs(f)]
    assert hits == []


def test_the_build_reads_the_package_copy_of_the_label_map_fe_table():
    """BuildOptions' default estimate is the package file, and fit's row lookup finds a row in it: the default
    phantom's 1 mm CGAL row, as a label-map sweep manifest of that voxel size, mesher and sizes would ask."""
    from pipeline.build import BuildOptions
    from training.fit import fe_label_map_estimate

    path = BuildOptions().fe_estimate
    assert Path(path) == Path(str(files("pipeline") / "data" / "labelmap_fe_error.json"))
    row = json.loads(Path(path).read_text())["rows"][0]
    label_map = {"mesher": row["mesher"]}
    if row["facet_distance_voxels"] is not None:
        label_map["facet_distance_voxels"] = row["facet_distance_voxels"]
    manifest = SimpleNamespace(source=SimpleNamespace(spacing_mm=(row["spacing_mm"],) * 3),
                               scene={"label_map": label_map, "mesh": row.get("mesh_mm"),
                                      "solver": {"volumetric": row.get("volumetric", "pointwise")}})
    bands, text = fe_label_map_estimate(path, manifest)
    assert bands == {k: row["regions"][k]["bound_max_mm"] for k in ("markers", "prostate_surface")}
    assert "labelmap_fe_error.json" in text


def test_the_package_copy_equals_the_published_study():
    """A republished docs/results/labelmap_truth.json must update the package copy too (cp it there)."""
    copy = json.loads((ROOT / "pipeline" / "data" / "labelmap_fe_error.json").read_text())
    published = json.loads((ROOT / "docs" / "results" / "labelmap_truth.json").read_text())
    assert {k: copy[k] for k in ("case", "rows")} == {k: published[k] for k in ("case", "rows")}
