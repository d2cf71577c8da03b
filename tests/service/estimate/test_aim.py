"""POST /plan: the needle path of the planned pose passes the displaced lesion (as /predict moves it) at the miss it
states, no pose does better, an unreachable lesion says so with its closest approach, naive aiming, the 422s."""

import numpy as np
import pytest

from service.estimate.aim import REACH_MM, ray_miss
from service.guide import Guide

from ..helpers import predict_json, prostate_point


def _plan(client, **body) -> dict:
    reply = client.post("/plan", json=body)
    assert reply.status_code == 200, reply.text
    return reply.json()


def _miss_at(client, guide: Guide, lesion, displacement_mm: float, angle_deg: float) -> float:
    """The needle ray's distance from the lesion where /predict moves it at (d, beta)."""
    moved = predict_json(client, points=[lesion], displacement_mm=displacement_mm, angle_deg=angle_deg)["positions"][0]
    return float(ray_miss(guide, np.array([displacement_mm]), np.array([angle_deg]), np.array([moved]))[0][0])


def _lesion_on_the_needle_plane(folder, guide: Guide) -> list[float]:
    """A prostate point moved into the guide's tilt plane (where some ray passes through it) and inside the mesh."""
    p = np.array(prostate_point(folder))
    return (p - ((p - guide.tip_mm) @ guide.tilt_normal) * guide.tilt_normal).tolist()


def test_the_planned_needle_path_passes_the_displaced_lesion_at_the_stated_miss(tiny_client, tiny_folder):
    guide = Guide.of(tiny_folder.manifest)
    lesion = _lesion_on_the_needle_plane(tiny_folder, guide)
    reply = _plan(tiny_client, lesion_mm=lesion, displacement_mm=4.0)
    pose = reply["plan"]
    assert reply["reachable"] and pose["displacement_mm"] == 4.0
    assert pose["miss_mm"] == pytest.approx(_miss_at(tiny_client, guide, lesion, 4.0, pose["angle_deg"]), abs=1e-4)
    assert pose["miss_mm"] < 0.05
    np.testing.assert_allclose(reply["needle_tip_mm"], guide.tip_mm + 4.0 * guide.direction(pose["angle_deg"]),
                               atol=1e-9)
    assert reply["naive"]["miss_mm"] >= pose["miss_mm"]


def test_an_unreachable_lesion_is_said_to_be_so_with_the_closest_approach(tiny_client, tiny_folder):
    """A lesion 6 mm off the tilt plane: no pose's ray comes within 2.5 mm, the reply says so, and its closest
    approach is no worse than the best of a 6 x 11 grid of poses checked through /predict."""
    guide = Guide.of(tiny_folder.manifest)
    lesion = (np.array(_lesion_on_the_needle_plane(tiny_folder, guide)) + 6.0 * guide.tilt_normal).tolist()
    reply = _plan(tiny_client, lesion_mm=lesion)
    assert not reply["reachable"] and reply["message"].startswith("unreachable")
    assert reply["plan"]["miss_mm"] > REACH_MM
    (d_lo, d_hi), (a_lo, a_hi) = tiny_folder.manifest.envelope.displacement_mm, tiny_folder.manifest.envelope.angle_deg
    grid = [_miss_at(tiny_client, guide, lesion, d, a) for d in np.linspace(d_lo, d_hi, 6)
            for a in np.linspace(a_lo, a_hi, 11)]
    assert reply["plan"]["miss_mm"] <= min(grid) + 1e-6


def test_naive_aiming_points_at_the_undisplaced_lesion(tiny_client, tiny_folder):
    guide = Guide.of(tiny_folder.manifest)
    lesion = _lesion_on_the_needle_plane(tiny_folder, guide)
    naive = _plan(tiny_client, lesion_mm=lesion, displacement_mm=5.0)["naive"]
    # its ray passes through the lesion's reference position (up to the 0.01 deg search step)...
    rest = ray_miss(guide, np.array([0.0]), np.array([naive["angle_deg"]]), np.array([lesion]))[0][0]
    assert rest < 0.01
    # ...and its miss is that ray's distance from where /predict moves the lesion
    assert naive["miss_mm"] == pytest.approx(_miss_at(tiny_client, guide, lesion, 5.0, naive["angle_deg"]), abs=1e-4)


@pytest.mark.parametrize("body, field, kind", [
    ({}, "lesion_mm", "missing"),
    ({"lesion_mm": [0.0, -21.0, 35.0]}, "lesion_mm", "outside_mesh"),
    ({"lesion_mm": [0.0, 0.0, 35.0], "displacement_mm": 50.0}, "displacement_mm", "less_than_equal"),
    ({"lesion_mm": [0.0, 0.0]}, "lesion_mm.2", "missing"),
    ({"lesion_mm": [0.0, 0.0, 35.0], "materials": {}}, "materials", "extra_forbidden"),
])
def test_a_bad_plan_request_is_a_422_naming_the_field(tiny_client, body, field, kind):
    reply = tiny_client.post("/plan", json=body)
    assert reply.status_code == 422, reply.text
    detail = reply.json()["detail"]
    assert [(d["field"], d["type"]) for d in detail] == [(field, kind)]
    assert detail[0]["message"].startswith(field)


def test_a_material_model_states_the_misss_std_from_the_stiffnesses(tiny_material_model):
    from ..helpers import served

    with served(tiny_material_model) as client:
        from service.model import read_model_folder

        folder = read_model_folder(tiny_material_model)
        guide = Guide.of(folder.manifest)
        lesion = (np.array(_lesion_on_the_needle_plane(folder, guide)) + 1.0 * guide.tilt_normal).tolist()
        sure = _plan(client, lesion_mm=lesion, displacement_mm=4.0,
                     materials={t: {"std_percent": 0.0} for t in ("prostate", "rectal_wall", "adipose", "bladder")})
        unsure = _plan(client, lesion_mm=lesion, displacement_mm=4.0)
    assert sure["miss_std_mm"] == pytest.approx(0.0, abs=1e-5) and unsure["miss_std_mm"] > 1e-4
