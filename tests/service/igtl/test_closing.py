"""/estimate and /plan over OpenIGTLink: a pyigtl client sends tracked POINTs and lesions over a real socket and gets
what POST /estimate and POST /plan answer, as TRANSFORM, POINT (uncertainty as the 2-sigma sphere) and STRING."""

import json
import math

import numpy as np
import pyigtl
import pytest

from contracts.materials import HALO_SIGMAS
from service.estimate.aim import ray_miss
from service.guide import Guide
from service.igtl import (ESTIMATE_REPORT_NAME, ESTIMATED_GUIDE_NAME, ESTIMATED_LESIONS_NAME, LESIONS_NAME,
                          PLAN_LESION_NAME, PLAN_REPORT_NAME, PLANNED_GUIDE_NAME, PLANNED_MISS_NAME, POINTS_NAME,
                          REFERENCES_NAME, STATUS_NAME, TRACKED_NAME, Peer, Responder)

from ..helpers import predict_json, prostate_point

TRUTH = {"displacement_mm": 4.2, "angle_deg": -3.5}
STD_MM = 0.2  # per coordinate; sent as the diameter 2 HALO_SIGMAS |std| = 4 sqrt(3) 0.2
DIAMETER = 2 * HALO_SIGMAS * math.sqrt(3) * STD_MM


def _send(peer, message, device: str):
    """Send one message and wait for the reply from `device`."""
    peer.send_message(message, wait=True)
    reply = peer.wait_for_message(device, timeout=20)
    assert reply is not None, f"no {device} reply to {message.device_name}"
    return reply


def _points(device: str, named: dict, diameter: float = 0.0) -> pyigtl.PointMessage:
    return pyigtl.PointMessage(positions=np.array(list(named.values()), dtype=np.float64).reshape(-1, 3),
                               names=list(named), diameters=[diameter] * len(named), device_name=device)


def _lesions(folder, guide: Guide) -> dict:
    """Two prostate points: one on the needle's tilt plane (a ray reaches it), one 1 mm off it."""
    p = np.array(prostate_point(folder))
    on_plane = p - ((p - guide.tip_mm) @ guide.tilt_normal) * guide.tilt_normal
    return {"L1": on_plane.tolist(), "L2": p.tolist()}


def _set(peer, device: str, named: dict) -> str:
    said = _send(peer, _points(device, named), STATUS_NAME).string
    assert "set" in said, said
    return said


def _tracked_markers(client, **guide) -> dict:
    at = predict_json(client, region="markers", **guide)["positions"]
    return {f"marker_{i + 1}": p for i, p in enumerate(at)}


def _float32(named: dict) -> list:
    """Positions as the POINT message carries them: float32."""
    return np.asarray(list(named.values()), dtype=np.float32).astype(np.float64).tolist()


def test_tracked_markers_give_post_estimates_state_and_lesions(served, peer, tiny_folder):  # noqa: F811
    """Noise-free markers from /predict at a known (d, beta): EstimatedGuide is that pose, EstimatedLesions and
    EstimateReport are POST /estimate's answer for the same observations, each lesion's diameter 4 |std|."""
    client, _, _ = served
    guide = Guide.of(tiny_folder.manifest)
    lesions = _lesions(tiny_folder, guide)
    assert _set(peer, LESIONS_NAME, lesions) == "lesions set: L1, L2"
    markers = _tracked_markers(client, **TRUTH)
    peer.send_message(_points(TRACKED_NAME, markers, DIAMETER), wait=True)
    report = json.loads(peer.wait_for_message(ESTIMATE_REPORT_NAME, timeout=20).string)
    pose = peer.wait_for_message(ESTIMATED_GUIDE_NAME, timeout=1)
    moved = peer.wait_for_message(ESTIMATED_LESIONS_NAME, timeout=1)
    np.testing.assert_allclose(guide.from_pose(pose.matrix), list(TRUTH.values()), atol=2e-3)
    std = float(np.float32(DIAMETER)) / (2 * HALO_SIGMAS * math.sqrt(3))  # the diameter as the message carries it
    body = {"markers": [{"index": i, "position_mm": p, "std_mm": float(std)} for i, p in enumerate(_float32(markers))],
            "targets": list(lesions.values())}
    http = client.post("/estimate", json=body).json()
    assert report["state"] == http["state"] and report["fit"] == http["fit"]  # the same numbers, to the bit
    assert moved.names == ["L1", "L2"] and not report["fit"]["contradiction"]
    np.testing.assert_allclose(moved.positions, [t["position_mm"] for t in http["targets"]], atol=1e-4)
    sigma = np.linalg.norm([t["std_mm"] for t in http["targets"]], axis=1)
    np.testing.assert_allclose(moved.diameters, 2 * HALO_SIGMAS * sigma, rtol=1e-5)
    assert ([report["lesions"][n]["total_mm"] for n in lesions]
            == pytest.approx([t["total_mm"] for t in http["targets"]]))
    # and the lesions are where the tissue carries them at the true state
    at_truth = predict_json(client, points=list(lesions.values()), **TRUTH)["positions"]
    np.testing.assert_allclose(moved.positions, at_truth, atol=2e-3)


def test_tracked_reference_points_work_like_markers(served, peer, tiny_folder):  # noqa: F811
    client, _, _ = served
    refs = {f"fid_{i}": p for i, p in enumerate(tiny_folder.nodes[tiny_folder.regions["markers"][:4]].tolist())}
    refs["fid_lesion"] = prostate_point(tiny_folder)
    assert _set(peer, REFERENCES_NAME, refs).startswith("tracked references set: fid_0")
    at = predict_json(client, points=list(refs.values()), **TRUTH)["positions"]
    peer.send_message(_points(TRACKED_NAME, dict(zip(refs, at)), DIAMETER), wait=True)
    pose = peer.wait_for_message(ESTIMATED_GUIDE_NAME, timeout=20)
    np.testing.assert_allclose(Guide.of(tiny_folder.manifest).from_pose(pose.matrix), list(TRUTH.values()), atol=2e-3)


def test_a_moved_marker_is_named_as_the_outlier(served, peer):  # noqa: F811
    client, _, _ = served
    markers = _tracked_markers(client, **TRUTH)
    markers["marker_3"] = (np.asarray(markers["marker_3"]) + [0.0, 0.0, 5.0]).tolist()
    peer.send_message(_points(TRACKED_NAME, markers, DIAMETER), wait=True)
    fit = json.loads(peer.wait_for_message(ESTIMATE_REPORT_NAME, timeout=20).string)["fit"]
    assert fit["contradiction"] and fit["outliers"] == ["marker_3"]


@pytest.mark.parametrize("device, named, diameter, said", [
    (TRACKED_NAME, {"marker_1": [0, 0, 35]}, 0.0, "refused TrackedPoints: 'marker_1' has diameter 0"),
    (TRACKED_NAME, {"marker_9": [0, 0, 35]}, 1.0, "'marker_9' is no tracked point"),
    (TRACKED_NAME, {"marker_1": [0, 0, 35]}, 1e-4, "refused TrackedPoints: 'marker_1' std_mm: Input should be greater"),
    (LESIONS_NAME, {"L1": [0, 0, 500]}, 0.0, "refused Lesions: lesion 'L1' [0.0, 0.0, 500.0] is outside the mesh"),
    (LESIONS_NAME, {"marker_2": [0, 0, 35]}, 0.0, "refused Lesions: 'marker_2' is a marker's name"),
    (REFERENCES_NAME, {"marker_2": [0, 0, 35]}, 0.0, "refused TrackedReferences: 'marker_2' is a marker's name"),
    (PLAN_LESION_NAME, {"a": [0, 0, 35], "b": [0, 0, 36]}, 0.0, "refused PlanLesion: 2 points"),
    (PLAN_LESION_NAME, {"far": [0, 0, 500]}, 0.0, "refused PlanLesion: lesion_mm.2: Input should be less than"),
])
def test_an_unusable_message_gets_a_status_naming_the_point_and_the_connection_reads_on(served, peer, tiny_folder,
                                                                                       device, named, diameter, said):
    assert said in _send(peer, _points(device, named, diameter), STATUS_NAME).string
    pose = pyigtl.TransformMessage(Guide.of(tiny_folder.manifest).pose(1.0, 1.0), device_name="NeedleGuide")
    assert _send(peer, pose, POINTS_NAME).names[:8] == [f"marker_{i}" for i in range(1, 9)]


def test_lesions_replace_the_targets_that_poses_are_answered_with(served, peer, tiny_folder):  # noqa: F811
    client, _, _ = served
    lesions = _lesions(tiny_folder, Guide.of(tiny_folder.manifest))
    _set(peer, LESIONS_NAME, lesions)
    pose = pyigtl.TransformMessage(Guide.of(tiny_folder.manifest).pose(5.0, 3.0), device_name="NeedleGuide")
    points = _send(peer, pose, POINTS_NAME)
    assert points.names[8:] == ["L1", "L2"]
    np.testing.assert_allclose(points.positions[8:], predict_json(client, points=_float32(lesions), displacement_mm=5.0,
                                                                  angle_deg=3.0)["positions"], atol=1e-4)


def test_a_plan_over_the_socket_is_post_plans_and_its_needle_passes_the_lesion(served, peer, tiny_folder):  # noqa: F811
    """PlannedGuide is /plan's pose; PlannedMiss holds the lesion where /predict moves it at that pose and the needle
    ray's closest point, their distance the miss (under 0.05 mm for a lesion on the needle's plane)."""
    client, _, _ = served
    guide = Guide.of(tiny_folder.manifest)
    lesion = _float32({"L1": _lesions(tiny_folder, guide)["L1"]})[0]
    peer.send_message(_points(PLAN_LESION_NAME, {"L1": lesion}), wait=True)
    report = json.loads(peer.wait_for_message(PLAN_REPORT_NAME, timeout=20).string)
    planned = peer.wait_for_message(PLANNED_GUIDE_NAME, timeout=1)
    miss = peer.wait_for_message(PLANNED_MISS_NAME, timeout=1)
    http = client.post("/plan", json={"lesion_mm": lesion}).json()
    assert report["reachable"] and report["lesion"] == "L1" and report["message"] == http["message"]
    assert report["miss_mm"] == http["plan"]["miss_mm"] and report["naive"]["miss_mm"] == http["naive"]["miss_mm"]
    np.testing.assert_allclose(planned.matrix, http["plan"]["transform"], atol=1e-6)
    d, beta = guide.from_pose(planned.matrix)
    at = predict_json(client, points=[lesion], displacement_mm=d, angle_deg=beta)["positions"][0]
    np.testing.assert_allclose(miss.positions[0], at, atol=1e-3)
    assert (miss.names == ["L1", "L1_needle"]
            and miss.diameters[0] == pytest.approx(2 * HALO_SIGMAS * http["miss_std_mm"]))
    gap = float(np.linalg.norm(np.subtract(miss.positions[0], miss.positions[1])))
    assert gap == pytest.approx(report["miss_mm"], abs=1e-4) and gap < 0.05
    assert ray_miss(guide, np.array([d]), np.array([beta]), np.array([at]))[0][0] < 0.05


def test_an_unreachable_lesion_gets_no_planned_guide_only_the_closest_approach(served, peer, tiny_folder):  # noqa: F811
    guide = Guide.of(tiny_folder.manifest)
    far = (np.array(_lesions(tiny_folder, guide)["L1"]) + 6.0 * guide.tilt_normal).tolist()
    peer.send_message(_points(PLAN_LESION_NAME, {"far": far}), wait=True)
    report = json.loads(peer.wait_for_message(PLAN_REPORT_NAME, timeout=20).string)
    assert not report["reachable"] and report["message"].startswith("unreachable")
    miss = peer.wait_for_message(PLANNED_MISS_NAME, timeout=1)  # sent before the report, in one write
    gap = float(np.linalg.norm(np.subtract(miss.positions[0], miss.positions[1])))
    assert gap == pytest.approx(report["miss_mm"], abs=1e-4) and gap > 2.5
    assert peer.wait_for_message(PLANNED_GUIDE_NAME, timeout=0) is None


def test_each_peer_starts_its_next_fit_from_its_own_last_estimate(tiny_folder, tiny_predictor, tiny_client):  # noqa: F811
    responder, peer = Responder(tiny_folder), Peer()
    markers = _tracked_markers(tiny_client, **TRUTH)
    answer = responder.answer(tiny_predictor, _points(TRACKED_NAME, markers, DIAMETER), peer)
    assert [m.device_name for m in answer] == [ESTIMATED_GUIDE_NAME, ESTIMATE_REPORT_NAME]  # no lesions: no POINT
    np.testing.assert_allclose(peer.state[:2], list(TRUTH.values()), atol=2e-3)
    assert Peer().state is None
