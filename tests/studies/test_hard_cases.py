"""studies/hard_cases.py without solving: the box's points from the patient scene, and the table of the rows."""

import numpy as np

from fem_offline.scene import load_scene
from studies.hard_cases import SCENE, box_of, box_points, markdown


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
