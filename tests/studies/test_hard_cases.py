"""studies/hard_cases.py without solving: the box's points from the patient scene, and the table of the rows."""

import numpy as np
import pytest

from fem_offline.scene import load_scene
from studies.hard_cases import SCENE, box_of, box_points, fat_between_wall_and_gland, fat_markdown, markdown


def test_the_box_is_the_patient_scenes_ranges_as_factors():
    scene = load_scene(SCENE)
    box = box_of(scene)
    assert list(box) == ["prostate", "adipose", "rectal_wall", "bladder"]
    for t, (lo, hi) in box.items():
        np.testing.assert_allclose([lo, hi], np.array(scene.materials[t].youngs_kpa_range) / scene.tissues[t].youngs)


def test_corners_then_face_centres_each_once():
    box = {"a": (0.5, 2.0), "b": (0.1, 1.0), "c": (1.0, 4.0)}
    points = box_points(box)
    names = [n for n, _ in points]
    assert len(points) == 2**3 + 2 * 3 and len(set(names)) == len(names)
    corners = [f for n, f in points if n.startswith("corner")]
    assert {tuple(f.values()) for f in corners} == {(a, b, c) for a in (0.5, 2.0) for b in (0.1, 1.0)
                                                    for c in (1.0, 4.0)}
    face = dict(points)["face b+"]
    assert face == {"a": 1.0, "b": 1.0, "c": 2.0}  # b at its upper end, the others at their geometric centres


def test_the_table_shows_each_element_side_by_side_and_what_is_not_run():
    where = {"tissue": "adipose", "centroid_mm": [0, 0, 0]}
    row = {"point": "corner --", "angle_deg": 0.0, "reached_mm": 10.0, "solved": True, "load_steps": 40, "halvings": 0,
           "newton_iterations": 200, "min_det_f": 0.6, "min_det_f_at": where, "min_volume_ratio": 0.95,
           "penetration_mm": 0.004, "seconds": 80.0}
    rows = [{**row, "element": "mean_dilatation"},
            {**row, "element": "taylor_hood", "reached_mm": 8.75, "solved": False, "min_det_f": 0.002}]
    text = markdown(rows, {"a": (0.5, 2.0), "b": (0.1, 1.0)}, [0.0, 10.0])
    assert "mean_dilatation**: 1 of the 16 solves run; 1 of 1 reach the full push" in text
    assert ("taylor_hood**: 1 of the 16 solves run; 0 of 1 reach" in text and "8.75 (failed)" in text
            and "0.002 (adipose)" in text)
    assert "| corner -- | 10 | not run" in text


def test_the_fat_layer_in_front_of_the_tip_is_measured_across_and_through():
    """A slab of rectal wall, 2 mm of fat and prostate across the guide's axis, on a grid of 0.5 mm cubes cut into
    6 tets: every line through it crosses 2 mm of fat and at least the 4 cube layers' tets."""
    from types import SimpleNamespace

    h = 0.5
    xs, ys, zs = np.arange(-12, 12.01, 1.0), np.arange(-16, -2.01, h), np.arange(-12, 12.01, 1.0)
    nodes = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)
    index = np.arange(len(nodes)).reshape(len(xs), len(ys), len(zs))
    cube = [(0, 1, 3, 7), (0, 1, 5, 7), (0, 2, 3, 7), (0, 2, 6, 7), (0, 4, 5, 7), (0, 4, 6, 7)]  # Kuhn split
    tets = []
    for i, j, k in np.ndindex(len(xs) - 1, len(ys) - 1, len(zs) - 1):
        corner = [index[i + a, j + b, k + c] for a in (0, 1) for b in (0, 1) for c in (0, 1)]
        corner = [corner[(v >> 2) * 4 + ((v >> 1) & 1) * 2 + (v & 1)] for v in range(8)]
        tets += [[corner[v] for v in t] for t in cube]
    tets = np.array(tets)
    y = nodes[tets].mean(axis=1)[:, 1]
    tissue = np.where(y < -10, 0, np.where(y < -8, 1, 2))  # wall, fat (y -10 to -8), prostate
    mesh = SimpleNamespace(nodes=nodes, tets=tets, tissue=tissue, tissue_names=("rectal_wall", "adipose", "prostate"))
    guide = SimpleNamespace(tip_mm=(0.0, -14.0, 0.0), axis=(0.0, 1.0, 0.0), tilt_normal=(0.0, 0.0, 1.0))
    fat = fat_between_wall_and_gland(mesh, guide, reach_mm=8.0, spacing_mm=2.0)
    bands = [b for b in fat["bands"] if b["lines"]]
    assert sum(b["lines"] for b in bands) == sum(1 for x in range(-8, 9, 2) for z in range(-8, 9, 2)
                                                 if np.hypot(x, z) <= 8)
    for b in bands:
        assert b["thickness_min_mm"] == pytest.approx(2.0, abs=0.02)
        assert b["thickness_max_mm"] == pytest.approx(2.0, abs=0.02)
        assert b["tets_min"] >= 4
    assert "2.00 / 2.00 / 2.00 mm" in fat_markdown(fat)
