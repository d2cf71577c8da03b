"""Deformed meshes as VTU, PLY and GLB: read back with meshio and trimesh, they hold what /predict's JSON says."""

import io
import subprocess
import sys

import numpy as np
import pytest
from ..helpers import predict_json

CASE = {"displacement_mm": 4.5, "angle_deg": -4.0}  # inside the tiny model's envelope (0..5 mm, tests/conftest.py)


@pytest.fixture(scope="module")
def json_positions(tiny_client):  # noqa: F811
    reply = predict_json(tiny_client, **CASE)
    return np.asarray(reply["positions"], dtype=np.float32)  # (n_nodes, 3), the reply's float32 values


def _export(client, fmt: str, **extra):
    return client.post("/predict", params={"format": fmt}, json={**CASE, **extra})


def test_vtu_holds_the_volume_with_tissues_and_displacement(tiny_client, tiny_folder, json_positions, tmp_path):  # noqa: F811
    import meshio

    reply = _export(tiny_client, "vtu")
    assert reply.status_code == 200 and reply.headers["content-type"].startswith("application/xml")
    assert reply.headers["x-tissues"].split(",") == tiny_folder.manifest.mesh.tissues
    assert 'filename="' in reply.headers["content-disposition"]
    (tmp_path / "case.vtu").write_bytes(reply.content)
    mesh = meshio.read(tmp_path / "case.vtu")
    assert len(mesh.points) == len(json_positions) == tiny_folder.manifest.mesh.n_nodes
    np.testing.assert_allclose(mesh.points, json_positions, atol=1e-5)
    np.testing.assert_allclose(mesh.point_data["displacement"], json_positions - tiny_folder.nodes, atol=1e-4)
    assert [block.type for block in mesh.cells] == ["tetra10"]
    np.testing.assert_array_equal(mesh.cells[0].data, tiny_folder.tets)
    np.testing.assert_array_equal(mesh.cell_data["tissue"][0], tiny_folder.mesh.tissue)


def test_vtu_names_each_tissue_by_a_cell_array(tiny_client, tiny_folder, tmp_path):  # noqa: F811
    """`tissue_<name>` is 1 on exactly that tissue's cells: the names are in the file, not only in X-Tissues."""
    import meshio

    (tmp_path / "case.vtu").write_bytes(_export(tiny_client, "vtu").content)
    cell_data = meshio.read(tmp_path / "case.vtu").cell_data
    names = tiny_folder.manifest.mesh.tissues
    assert set(cell_data) == {"tissue", *(f"tissue_{name}" for name in names)}
    for i, name in enumerate(names):
        np.testing.assert_array_equal(cell_data[f"tissue_{name}"][0], tiny_folder.mesh.tissue == i, err_msg=name)


def _triangle_set(triangles: np.ndarray) -> set:
    return set(map(tuple, np.sort(triangles, axis=1).tolist()))


def test_ply_holds_every_tissue_surface_tagged(tiny_client, tiny_folder, json_positions):  # noqa: F811
    import trimesh

    reply = _export(tiny_client, "ply")
    assert reply.status_code == 200
    surface = trimesh.load(io.BytesIO(reply.content), file_type="ply", process=False)
    raw = surface.metadata["_ply_raw"]
    node_id = raw["vertex"]["data"]["node_id"]
    tissue = raw["face"]["data"]["tissue"]
    np.testing.assert_allclose(surface.vertices, json_positions[node_id], atol=1e-5)
    for t, name in enumerate(tiny_folder.manifest.mesh.tissues):
        # the faces tagged with a tissue are exactly that tissue's surface triangles
        assert _triangle_set(node_id[surface.faces[tissue == t]]) == _triangle_set(tiny_folder.surfaces[name]), name


def test_glb_holds_one_named_surface_per_tissue(tiny_client, tiny_folder, json_positions):  # noqa: F811
    import trimesh

    reply = _export(tiny_client, "glb")
    assert reply.status_code == 200 and reply.headers["content-type"] == "model/gltf-binary"
    scene = trimesh.load(io.BytesIO(reply.content), file_type="glb", process=False)
    assert sorted(scene.geometry) == sorted(tiny_folder.surfaces)
    for name, part in scene.geometry.items():
        ids = np.unique(tiny_folder.surfaces[name])
        assert len(part.vertices) == len(ids), name
        np.testing.assert_array_equal(scene.graph[name][0], np.eye(4))
        np.testing.assert_allclose(part.vertices, json_positions[ids], atol=1e-5)
        assert _triangle_set(ids[part.faces]) == _triangle_set(tiny_folder.surfaces[name]), name


def test_format_refuses_a_region_or_points_and_unknown_names(tiny_client):  # noqa: F811
    reply = _export(tiny_client, "vtu", region="markers")
    assert reply.status_code == 422 and reply.json()["detail"][0]["type"] == "format_conflict"
    reply = _export(tiny_client, "stl")
    assert reply.status_code == 422 and "format" in reply.json()["detail"][0]["field"]


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "service", "export", *map(str, args)], capture_output=True,
                          text=True, timeout=120)


def test_cli_writes_the_same_mesh_as_the_service(tiny_model, tmp_path, json_positions):  # noqa: F811
    import meshio

    out = tmp_path / "case.vtu"
    run = _cli("--model", tiny_model, "--displacement-mm", CASE["displacement_mm"], "--angle-deg",
               CASE["angle_deg"], "--out", out)
    assert run.returncode == 0, run.stderr
    np.testing.assert_allclose(meshio.read(out).points, json_positions, atol=1e-5)


@pytest.mark.parametrize("args, message", [
    (["--displacement-mm", "11", "--angle-deg", "0", "--out", "x.vtu"], "--displacement-mm: 11.0 is outside"),
    (["--displacement-mm", "5", "--angle-deg", "0", "--out", "x.stl"], "--out: use .vtu, .ply or .glb"),
    (["--displacement-mm", "five", "--angle-deg", "0", "--out", "x.vtu"], "--displacement-mm: invalid float"),
    (["--displacement-mm", "5", "--out", "x.vtu"], "required: --angle-deg"),
])
def test_cli_bad_flags_get_one_line_and_exit_2(tiny_model, tmp_path, args, message):  # noqa: F811
    run = _cli("--model", tiny_model, *[str(tmp_path / a) if a.startswith("x.") else a for a in args])
    assert run.returncode == 2 and message in run.stderr, run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and not list(tmp_path.iterdir())
