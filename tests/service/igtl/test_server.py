"""OpenIGTLink: a pyigtl client as a real peer sends NeedleGuide poses and gets the deformed points of /predict;
framing errors get a status and never stop the server."""

import socket
import struct
import subprocess
import sys

import numpy as np
import pyigtl
import pytest
from fastapi.testclient import TestClient
from pyigtl.messages import CRC64

from service.guide import Guide, OffAxisPose
from service.igtl import POINTS_NAME, STATUS_NAME, Responder, read_message

from ..helpers import predict_json

# the tiny model answers up to 5 mm, where its linear sweep stops being valid (tests/conftest.py)
POSES = [(0.0, 0.0), (5.0, 3.0), (5.0, -10.0), (2.25, 7.5), (5.0, 10.0)]


def _ask(peer, matrix, device=POINTS_NAME):
    peer.send_message(pyigtl.TransformMessage(matrix, device_name="NeedleGuide"), wait=True)
    reply = peer.wait_for_message(device, timeout=10)
    assert reply is not None, f"no {device} reply"
    return reply


def test_guide_of_the_manifest_is_the_scenes_and_turns_as_fem_offlines(tiny_folder):
    from fem_offline.scene import Guide as SceneGuide
    from fem_offline.scene import parse_scene

    manifest = tiny_folder.manifest
    scene_guide, ours = parse_scene(manifest.scene.spec).guide, Guide.of(manifest)
    np.testing.assert_array_equal(ours.tip_mm, scene_guide.tip_mm)
    assert ours.patch_radius_mm == scene_guide.patch_radius_mm
    tilted = SceneGuide(axis=(0.0, 0.6, 0.8), tilt_normal=(1.0, 0.0, 0.0))
    ours = Guide(np.zeros(3), np.array([0.0, 0.6, 0.8]), np.array([1.0, 0.0, 0.0]), 6.0)
    for beta in (-10.0, 0.0, 7.0):
        np.testing.assert_allclose(ours.direction(beta), tilted.direction(beta), atol=1e-15)
        np.testing.assert_allclose(ours.rotation(beta) @ ours.axis, tilted.direction(beta), atol=1e-15)


def test_pose_round_trip_and_off_axis_tolerances(tiny_folder):  # noqa: F811
    guide = Guide.of(tiny_folder.manifest)
    for d, beta in POSES:
        np.testing.assert_allclose(guide.from_pose(guide.pose(d, beta).astype(np.float32)), (d, beta), atol=1e-5)
    across = np.cross(guide.tilt_normal, guide.direction(4.0))
    for offset_mm, ok in ((0.05, True), (0.2, False)):
        pose = guide.pose(5.0, 4.0)
        pose[:3, 3] += offset_mm * across
        if ok:
            assert guide.from_pose(pose)[0] == pytest.approx(5.0, abs=1e-9)
        else:
            with pytest.raises(OffAxisPose, match="off the guide axis"):
                guide.from_pose(pose)
    for angle_deg, ok in ((0.05, True), (0.2, False)):
        pose = guide.pose(5.0, 4.0)
        b = np.deg2rad(angle_deg)  # a turn about the guide axis itself: a pose the model does not know
        pose[:3, :3] = pose[:3, :3] @ np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
        if ok:
            assert guide.from_pose(pose)[1] == pytest.approx(4.0, abs=1e-9)
        else:
            with pytest.raises(OffAxisPose, match="about an axis other than the tilt normal"):
                guide.from_pose(pose)
    with pytest.raises(OffAxisPose, match="not a rotation"):
        guide.from_pose(np.diag([1.01, 1.0, 1.0, 1.0]))


def test_peer_gets_the_deformed_markers_and_target_of_predict(served, peer, tiny_folder):  # noqa: F811
    client, _, target = served
    guide = Guide.of(tiny_folder.manifest)
    for d, beta in POSES:
        reply = _ask(peer, guide.pose(d, beta))
        assert reply.names == [f"marker_{i}" for i in range(1, 9)] + ["lesion"]
        got = np.asarray(reply.positions)  # (9, 3)
        markers = predict_json(client, displacement_mm=d, angle_deg=beta, region="markers")["positions"]
        lesion = predict_json(client, displacement_mm=d, angle_deg=beta, points=[target])["positions"]
        np.testing.assert_allclose(got, np.concatenate([markers, lesion]), atol=1e-4, err_msg=f"{d} mm, {beta} deg")
    assert np.linalg.norm(got[8] - target) > 0.5  # at 5 mm the target moved: the check above can fail


def _refused_poses(guide: Guide) -> dict:
    off_axis = guide.pose(5.0, 0.0)
    off_axis[0, 3] += 0.5  # 0.5 mm across the axis
    b = np.deg2rad(1.0)  # 1 deg about x: a tilt the model does not know
    about_x = guide.pose(5.0, 0.0) @ np.array([[1, 0, 0, 0], [0, np.cos(b), -np.sin(b), 0],
                                               [0, np.sin(b), np.cos(b), 0], [0, 0, 0, 1]])
    return {"off the guide axis": off_axis, "outside the model's envelope": guide.pose(10.5, 0.0),
            "about an axis other than the tilt normal": about_x}


@pytest.mark.parametrize("message", ["off the guide axis", "outside the model's envelope",
                                     "about an axis other than the tilt normal"])
def test_off_axis_and_out_of_envelope_poses_are_refused_with_a_status(peer, tiny_folder, message):  # noqa: F811
    guide = Guide.of(tiny_folder.manifest)
    assert message in _ask(peer, _refused_poses(guide)[message], STATUS_NAME).string
    assert len(_ask(peer, guide.pose(1.0, 1.0)).positions) == 9  # the connection reads on


def _raw(port: int) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


def _with_body(packed: bytes, body: bytes, crc: int | None = None) -> bytes:
    """A packed message's header with another body (and its CRC unless one is given)."""
    return packed[:42] + struct.pack(">QQ", len(body), CRC64(body) if crc is None else crc) + body


def test_malformed_messages_get_a_status_and_never_stop_the_server(served, tiny_folder):  # noqa: F811
    port = served[1]
    good = pyigtl.TransformMessage(Guide.of(tiny_folder.manifest).pose(3.0, 2.0), device_name="NeedleGuide").pack()
    cases = [(_with_body(good, good[58:], crc=12345), "CRC does not match"),
             (_with_body(good, good[58:70]), "malformed body"),
             (pyigtl.StringMessage("hello", device_name="chat").pack(), "this server reads TRANSFORM"),
             (_with_body(good[:2] + b"NOSUCHTYPE\0\0" + good[14:58], b""), "unsupported message type")]
    with _raw(port) as sock:
        for data, message in cases:
            sock.sendall(data)
            reply = read_message(sock)
            assert reply.device_name == STATUS_NAME and message in reply.string, reply.string
        sock.sendall(good)
        assert read_message(sock).message_type == "POINT"
    with _raw(port) as sock:  # framing lost: this connection closes with a status, the server serves on
        sock.sendall(_with_body(good, b"", crc=0)[:42] + struct.pack(">QQ", 1 << 40, 0))
        assert "closing the connection" in read_message(sock).string
        assert read_message(sock) is None
    with _raw(port) as sock:
        sock.sendall(good)
        assert read_message(sock).message_type == "POINT"


def test_prostate_surface_as_polydata(tiny_folder, tiny_predictor):  # noqa: F811
    """The POLYDATA body decoded by hand (OpenIGTLink v2 layout): points, then [3, i, j, k] per triangle."""
    responder = Responder(tiny_folder, surface=True)
    pose = pyigtl.TransformMessage(Guide.of(tiny_folder.manifest).pose(4.5, -6.0), device_name="NeedleGuide")
    points, polydata = responder.answer(tiny_predictor, pose)
    kinds = (points.message_type, polydata.message_type, polydata.device_name)
    assert kinds == ("POINT", "POLYDATA", "ProstateSurface")
    body = polydata.pack()[58:]
    n_points, _, _, _, _, n_polygons, size_polygons, _, _, n_attributes = struct.unpack(">10I", body[:40])
    xyz = np.frombuffer(body, ">f4", 3 * n_points, 40).reshape(-1, 3)
    cells = np.frombuffer(body, ">u4", size_polygons // 4, 40 + 12 * n_points).reshape(-1, 4)
    ids = np.unique(tiny_folder.surfaces["prostate"])
    assert n_attributes == 0 and n_polygons == len(tiny_folder.surfaces["prostate"]) and (cells[:, 0] == 3).all()
    u = tiny_predictor.displacement(4.5, -6.0, ids)
    np.testing.assert_allclose(xyz, tiny_folder.nodes[ids] + u, atol=1e-4)
    np.testing.assert_array_equal(ids[cells[:, 1:]], tiny_folder.surfaces["prostate"])


def test_a_target_outside_the_mesh_stops_the_start(tiny_model):  # noqa: F811
    run = subprocess.run([sys.executable, "-m", "service", "--model", str(tiny_model), "--igtl", "true",
                          "--igtl-targets", '{"far": [0, 0, 500]}'], capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "--igtl-targets: 'far'" in run.stderr and "outside the mesh" in run.stderr
    assert len(run.stderr.strip().splitlines()) == 1


def test_a_material_model_sends_its_2_sigma_spheres_over_the_socket(tiny_material_model):
    """Over a real socket (pyigtl packs the diameters: a list, since it tests `not diameters`), after
    NeedleGuideMaterials: each point's diameter is 4 |std| of /predict's markers at those stiffnesses."""
    import json

    from service.app import create_app
    from service.model import read_model_folder
    from service.settings import Settings
    from tools.loadtest import free_port

    folder = read_model_folder(tiny_material_model)
    materials = {"prostate": {"youngs_kpa": 80.0, "std_percent": 10.0}}
    settings = Settings(model=tiny_material_model, igtl=True, igtl_port=free_port())
    with TestClient(create_app(settings)) as client:
        peer = pyigtl.OpenIGTLinkClient(host="127.0.0.1", port=settings.igtl_port)
        try:
            peer.send_message(pyigtl.StringMessage(json.dumps(materials), device_name="NeedleGuideMaterials"),
                              wait=True)
            assert peer.wait_for_message(STATUS_NAME, timeout=10).string.startswith("materials set")
            points = _ask(peer, Guide.of(folder.manifest).pose(4.0, 3.0))
        finally:
            peer.stop()
        reply = predict_json(client, displacement_mm=4.0, angle_deg=3.0, region="markers", materials=materials)
    sigma = np.linalg.norm(reply["std_mm"], axis=1)
    assert sigma.min() > 1e-3
    np.testing.assert_allclose(points.positions, reply["positions"], atol=1e-4)
    np.testing.assert_allclose(points.diameters, 4 * sigma, rtol=1e-5)
