"""pipeline build: a label map and a short scene file in, a model folder the service serves out; for the
tiny phantom and for each anatomical variant (fem_offline/scenes/anatomy/)."""

import importlib.util
import json

import numpy as np
import pytest

from contracts.files import sha256
from fem_offline.labelmap.io import write_label_map
from fem_offline.scene import load_scene
from studies.phantom_labelmap import LABELS, labelmap_scene, voxelise

SCENES = __import__("pathlib").Path(__file__).resolve().parents[2] / "fem_offline" / "scenes"


# The tiny phantom, and the three anatomical variants of issue #14 at the tiny scene's sizes.
BUILDS = ("tiny", "anatomy/small", "anatomy/medium", "anatomy/large")
# CGAL sizes its tets by the scene's mesh sizes, TetGen by the voxels (fem_offline/labelmap/meshers.py): the 1 mm map
# gives TetGen 86,509 tets and the build 8.5 min on a loaded 2-core machine; at 2 mm it gives 18,577 tets,
# about CGAL's 19,642 at 1 mm. The first mesher installed builds.
VOXEL_MM = {"cgal": 1.0, "tetgen": 2.0}


# The linear glued guide inverts the voxel meshes' tets by 5 mm (det F bounded everywhere: -0.06 to -0.13 at
# 5 mm on anatomy/small's TetGen mesh, +0.74 at 2.5 mm), and the build trains only below that: a 3 x 4 sweep
# up to 4 mm in 1 mm steps keeps every snapshot in the valid part.
SWEEP = {"displacement_step_mm": 1.0, "displacement_max_mm": 4.0}


def _tiny_sized(name: str):
    """Scene `name` at tiny.toml's mesh sizes, solver and angles, 1..4 mm (SWEEP), linear with the glued guide
    (each solve: superposition), without the material inputs the anatomy variants inherit from default.toml (the
    build is tested here; tests/training/test_materials.py tests the materials)."""
    tiny = load_scene(SCENES / "tiny.toml")
    return load_scene(SCENES / f"{name}.toml", mesh=tiny.mesh.model_dump(), sweep={**tiny.sweep.model_dump(), **SWEEP},
                      solver=tiny.solver.model_dump(),
                      effects={"geometric_nonlinearity": False, "guide_contact": False}, materials=None)


@pytest.fixture(scope="module", params=BUILDS)
def built(request, tmp_path_factory):
    """The scene voxelised (1 mm, or 2 mm for TetGen), a linear 3 x 4 sweep, 2 off-grid cases: the whole build."""
    mesher = next((m for m, package in (("cgal", "pygalmesh"), ("tetgen", "tetgen"))
                   if importlib.util.find_spec(package)), None)
    if mesher is None:
        pytest.skip("label-map meshing needs pygalmesh (`make labelmesh`) or tetgen (offline extra)")
    import tomli_w

    from pipeline.build import BuildOptions, build

    folder = tmp_path_factory.mktemp("build")
    scene, voxel = _tiny_sized(request.param), VOXEL_MM[mesher]
    write_label_map(folder / "labels.nrrd", voxelise(scene.phantom, voxel))
    name = "patient_" + request.param.split("/")[-1]
    data = labelmap_scene(scene, "labels.nrrd", name=name)
    data["label_map"]["mesher"] = mesher
    (folder / "scene.toml").write_text(tomli_w.dumps(data))
    lines = []
    model = build(folder / "scene.toml", folder / "models" / name, work=folder / "work",
                  options=BuildOptions(offgrid_cases=2, workers=1), say=lines.append)
    return folder, model, lines, scene, voxel


def test_build_writes_a_model_that_records_its_label_map(built):
    folder, model, lines, _, voxel = built
    assert model.source is not None
    assert model.source.sha256 == sha256(folder / "labels.nrrd")
    assert model.source.labels == LABELS and model.source.spacing_mm == (voxel, voxel, voxel)
    assert model.source.shape == tuple(int(n / voxel) for n in (100, 80, 90))
    assert model.metrics.offgrid_summary.n_cases == 2
    assert model.fit.width == 30  # the build's default network (README, "The patient sweep")
    assert lines[0].startswith("[1/3]") and "whole build" in lines[-1]


def test_surrogate_matches_its_own_linear_fe(built):
    """A linear sweep spans 2 modes in f = u / d (to round-off); PCA keeps those above 1e-9 of the first
    instead of the 32 asked. The network learns cos/sin beta from three angles: held-out e_NN
    measured 0.005-0.031 mm over runs (CGAL's mesh differs slightly from run to run), off the grid 0.014 mm."""
    _, model, _, _, _ = built
    assert model.pca.rank < 8 and model.pca.energy > 1 - 1e-12
    assert model.metrics.offgrid_summary.e_nn_mm < 0.1
    assert model.metrics.table3_summary.e_nn_mm < 0.1


def test_service_serves_it_and_reports_the_source(built):
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    folder, model, _, _, voxel = built
    with TestClient(create_app(Settings(model=folder / "models" / model.name))) as client:
        info = client.get("/model").json()
        assert info["source"]["sha256"] == model.source.sha256 == sha256(folder / "labels.nrrd")
        assert info["source"]["labels"] == LABELS and info["source"]["spacing_mm"] == [voxel] * 3
        assert (info["source"]["shape"] == [int(n / voxel) for n in (100, 80, 90)]
                and info["source"]["file"] == "labels.nrrd")
        r = client.post("/predict", json={"displacement_mm": 3.0, "angle_deg": 0.0, "region": "markers"})
        assert r.status_code == 200, r.text
        assert np.linalg.norm(np.asarray(r.json()["displacements"]), axis=1).max() > 0.05


def test_viewer_draws_the_label_maps_tissues(built):
    from fastapi.testclient import TestClient

    from service.app import create_app
    from service.settings import Settings

    folder, model, _, _, _ = built
    with TestClient(create_app(Settings(model=folder / "models" / model.name))) as client:
        scene = client.get("/viewer/scene.json")
        assert scene.status_code == 200, scene.text
        assert {"prostate", "rectal_wall", "bladder"} <= {t["name"] for t in scene.json()["tissues"]}
        assert client.get("/viewer").status_code == 200


def test_served_mesh_is_the_scenes_anatomy(built):
    """The model's prostate is the scene's: as long as its ellipsoid and centred where the scene puts it
    (within a voxel and the facet distance); prostate and rectal wall of the label map's volume
    (measured with CGAL at 1 mm: prostate -2.4 to -3.1 %, the faceting's inscribed loss; wall -0.3 to -0.8 %)."""
    from contracts.model import read_model_folder
    from fem_offline.labelmap.io import read_label_map
    from fem_offline.labelmap.quality import tissue_volumes

    folder, model, _, scene, voxel = built
    mesh = read_model_folder(folder / "models" / model.name).mesh
    ph = scene.phantom
    prostate = mesh.nodes[np.unique(mesh.tets[mesh.tissue == mesh.tissue_names.index("prostate")])]
    assert np.ptp(prostate[:, 0]) == pytest.approx(2 * ph.prostate_semi_axes_mm[0], abs=1.5 * voxel)
    np.testing.assert_allclose(0.5 * (prostate.min(axis=0) + prostate.max(axis=0)), ph.prostate_center_mm, atol=voxel)
    labels = read_label_map(folder / "labels.nrrd").labels
    volumes = tissue_volumes(mesh.nodes, mesh.tets, mesh.tissue, mesh.tissue_names)
    for tissue in ("prostate", "rectal_wall"):
        assert volumes[tissue] == pytest.approx((labels == LABELS[tissue]).sum() * voxel**3, rel=0.05), tissue


@pytest.mark.parametrize("built", ["tiny"], indirect=True)
def test_rerun_resumes_without_solving_again(built):
    from pipeline.build import BuildOptions, build

    folder, model, _, _, _ = built
    lines = []
    again = build(folder / "scene.toml", folder / "models" / model.name, work=folder / "work",
                  options=BuildOptions(offgrid_cases=2, workers=1), say=lines.append)
    sweep = json.loads((folder / "work" / "sweep" / "manifest.json").read_text())
    assert sweep["wall_seconds_this_run"] < 1.0  # nothing left to solve
    assert again.mesh == model.mesh


def test_fe_estimate_for_the_voxels_and_mesher_goes_into_the_manifest(built, tmp_path):
    """With a row of `python -m studies labelmap-truth`'s JSON for the model's voxel size and mesher, the manifest
    and report.md state it as the FE error, said to be an estimate, and end to end = surrogate + it;
    with no matching row they say the FE error was not measured."""
    from training.fit import fit

    folder, model, _, _, voxel = built
    scene = model.scene.spec
    mesher = scene.label_map.mesher
    row = {"spacing_mm": voxel, "mesher": mesher, "facet_distance_voxels": 0.5 if mesher == "cgal" else None,
           "volumetric": scene.solver.volumetric, "tets": 1000, "finest_level_tets": 32252,
           "mesh_mm": scene.mesh.model_dump(mode="json"),
           "regions": {"markers": {"bound_max_mm": 0.3}, "prostate_surface": {"bound_max_mm": 0.7}}}
    truth = tmp_path / "truth.json"
    truth.write_text(json.dumps({"case": "10 mm, 0 deg", "rows": [row]}))
    work = folder / "work"
    est = fit(work / "sweep", tmp_path / "m", model.fit, offgrid=work / "offgrid", fe_estimate=truth, progress=False)
    regions = est.accuracy.regions
    assert regions["markers"].fe_discretisation_mm == 0.3
    assert regions["markers"].end_to_end_mm == pytest.approx(regions["markers"].surrogate_mm + 0.3)
    assert regions["prostate_surface"].end_to_end_mm == pytest.approx(regions["prostate_surface"].surrogate_mm + 0.7)
    assert regions["all_nodes"].fe_discretisation_mm is None and regions["all_nodes"].end_to_end_mm is None
    assert "estimated, not measured on this anatomy" in est.accuracy.reference
    assert "estimated, not measured on this anatomy" in (tmp_path / "m" / "report.md").read_text()
    other_sizes = {**row, "mesh_mm": {**row["mesh_mm"], "max_mm": 2 * row["mesh_mm"]["max_mm"]}}
    other_element = {**row, "volumetric": "mean_dilatation"}  # measured with another element: not this model's
    truth.write_text(json.dumps({"case": "10 mm, 0 deg",
                                 "rows": [{**row, "spacing_mm": 2 * voxel}, other_sizes, other_element]}))
    other = fit(work / "sweep", tmp_path / "m2", model.fit, offgrid=work / "offgrid", fe_estimate=truth, progress=False)
    assert other.accuracy.regions["markers"].end_to_end_mm is None and "not measured" in other.accuracy.reference
