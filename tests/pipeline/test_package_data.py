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
    """BuildOptions' default estimate is the package file, and fit's row lookup finds a row in it: its first row, as
    a label-map sweep manifest of that voxel size, mesher, sizes and element would ask (the scene as a sweep
    records it today, every mesh size stated, surface_near_tip_mm too, which the rows predate)."""
    from contracts.scene import parse_scene
    from pipeline.build import BuildOptions
    from training.fit import fe_label_map_estimate

    path = BuildOptions().fe_estimate
    assert Path(path) == Path(str(files("pipeline") / "data" / "labelmap_fe_error.json"))
    row = json.loads(Path(path).read_text())["rows"][0]
    label_map = {"path": "labels.nii.gz", "labels": {"prostate": 1, "rectal_wall": 2}, "mesher": row["mesher"]}
    if row["facet_distance_voxels"] is not None:
        label_map["facet_distance_voxels"] = row["facet_distance_voxels"]
    scene = parse_scene({"tissues": {t: {"youngs_kpa": 10.0} for t in ("prostate", "rectal_wall", "adipose")},
                         "label_map": label_map, "mesh": row["mesh_mm"],
                         "solver": {"volumetric": row.get("volumetric", "pointwise")}})
    assert "surface_near_tip_mm" not in row["mesh_mm"] and "surface_near_tip_mm" in scene.model_dump()["mesh"]
    manifest = SimpleNamespace(source=SimpleNamespace(spacing_mm=(row["spacing_mm"],) * 3), scene=scene)
    bands, text = fe_label_map_estimate(path, manifest)
    assert bands == {k: row["regions"][k]["bound_max_mm"] for k in ("markers", "prostate_surface")}
    assert "labelmap_fe_error.json" in text


def test_the_package_copy_equals_the_published_study():
    """A republished docs/results/labelmap_truth.json must update the package copy too (cp it there)."""
    copy = json.loads((ROOT / "pipeline" / "data" / "labelmap_fe_error.json").read_text())
    published = json.loads((ROOT / "docs" / "results" / "labelmap_truth.json").read_text())
    assert {k: copy[k] for k in ("case", "rows")} == {k: published[k] for k in ("case", "rows")}
