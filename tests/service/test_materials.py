"""A material model served: the `materials` request field (E or shear-wave speed, ranges, the 422 naming the field,
nominal by default), std_mm and the error budget on every answer, /model's inputs; a model without materials
refuses the field."""

import math
from pathlib import Path

import jsonschema_rs  # schemathesis's validator
import numpy as np
import pytest

from contracts.model import onnx_session, read_model_folder
from tests.conftest import TINY_MATERIALS, tiny_material_scene

from .helpers import served

GUIDE = {"displacement_mm": 4.0, "angle_deg": 3.0}


@pytest.fixture(scope="module")
def mat_client(tiny_material_model):
    with served(tiny_material_model) as client:
        yield client


@pytest.fixture(scope="module")
def graph(tiny_material_model):
    sess = onnx_session(tiny_material_model / "model.onnx")
    folder = read_model_folder(tiny_material_model)

    def run(theta, sigma, nodes):
        return sess.run(None, {"guide": np.array([[4.0, 3.0]], np.float32), "materials": np.array([theta], np.float32),
                               "materials_std": np.array([sigma], np.float32), "nodes": nodes})
    return run, folder


def _post(client, **body):
    return client.post("/predict", json={**GUIDE, **body})


def test_model_lists_the_material_inputs(mat_client):
    info = mat_client.get("/model").json()["materials"]
    assert info["parameter"] == "ln(E/E_nominal)" and info["units"]["youngs_kpa"] == "kPa"
    assert [m["tissue"] for m in info["inputs"]] == list(TINY_MATERIALS)
    prostate = info["inputs"][0]
    assert prostate["youngs_kpa_range"] == [50.0, 85.0] and prostate["nominal_youngs_kpa"] == 65.89
    assert prostate["std_percent"] == 20.0 and prostate["shear_wave_range_m_s"][0] < prostate["shear_wave_range_m_s"][1]


def test_an_old_client_gets_the_nominal_materials_and_the_scenes_uncertainty(mat_client, graph):
    run, folder = graph
    markers = folder.regions["markers"]
    reply = _post(mat_client, region="markers").json()
    u, std = run([0, 0, 0, 0], [0.2] * 4, markers)
    np.testing.assert_allclose(reply["displacements"], u[0], atol=1e-6)
    np.testing.assert_allclose(reply["std_mm"], std[0], atol=1e-6)
    assert np.abs(std).max() > 1e-3


def test_youngs_modulus_and_shear_wave_speed_give_the_same_answer(mat_client, graph):
    """E = 80 kPa for the prostate, or the v_s that eq. 1 maps to it (nu 0.495, rho 1008): theta = ln(80 / 65.89)."""
    run, folder = graph
    markers = folder.regions["markers"]
    v = math.sqrt(80.0e3 / (2 * 1.495 * 1008.0))
    by_e = _post(mat_client, region="markers", materials={"prostate": {"youngs_kpa": 80.0, "std_percent": 10.0}}).json()
    by_v = _post(mat_client, region="markers", materials={"prostate": {"shear_wave_speed_m_s": v, "std_percent": 5.0}}).json()
    u, std = run([math.log(80.0 / 65.89), 0, 0, 0], [0.1, 0.2, 0.2, 0.2], markers)
    np.testing.assert_allclose(by_e["displacements"], u[0], atol=1e-6)
    np.testing.assert_allclose(by_v["displacements"], u[0], atol=1e-5)
    np.testing.assert_allclose(by_e["std_mm"], std[0], atol=1e-6)
    np.testing.assert_allclose(by_v["std_mm"], std[0], atol=1e-6)  # 5 % in v_s is 10 % in E


@pytest.mark.parametrize("materials, field", [
    ({"prostate": {"youngs_kpa": 90.0}}, "materials.prostate.youngs_kpa"),
    ({"adipose": {"youngs_kpa": 8.0}}, "materials.adipose.youngs_kpa"),
    ({"prostate": {"shear_wave_speed_m_s": 9.0}}, "materials.prostate.shear_wave_speed_m_s"),
    ({"liver": {"youngs_kpa": 5.0}}, "materials.liver"),
    ({"prostate": {"youngs_kpa": 60.0, "shear_wave_speed_m_s": 4.5}}, "materials.prostate"),
    ({"prostate": {"std": 5.0}}, "materials.prostate"),
])
def test_a_material_outside_its_range_is_refused_naming_the_field(mat_client, materials, field):
    reply = _post(mat_client, materials=materials)
    assert reply.status_code == 422, reply.text
    assert reply.json()["detail"][0]["field"] == field


@pytest.mark.parametrize("tissue, valid", [
    ({"youngs_kpa": 70.0, "std": 5.0}, True),
    ({"youngs_kpa": 70.0, "shear_wave_speed_m_s": None, "std": 5.0}, True),  # null is not given
    ({"shear_wave_speed_m_s": None, "std": 5.0}, False),  # std with no value to be in the unit of
    ({"std": 5.0}, False),
    ({"youngs_kpa": 70.0, "shear_wave_speed_m_s": 4.5}, False),
    ({"std_percent": 10.0, "std": None}, True),
    ({"youngs_kpa": 70.0, "std": 85.0}, True),  # the tiny scene's prostate: 50..85 kPa
    ({"youngs_kpa": 70.0, "std": 85.5}, False),  # a std over the range's upper end (1e308 gave inf std_mm)
    ({"shear_wave_speed_m_s": 4.5, "std": 85.0}, False),  # ... in m/s when the value is a speed
])
def test_the_schema_and_the_service_agree_on_which_tissue_values_are_given(mat_client, tissue, valid):
    """The OpenAPI schema says what the validator does, null fields included (a client generated from the
    schema must not send what the service refuses)."""
    schema = mat_client.get("/openapi.json").json()
    prostate = schema["components"]["schemas"]["Material_prostate"]
    assert jsonschema_rs.validator_for(prostate).is_valid(tissue) is valid
    reply = _post(mat_client, region="markers", materials={"prostate": tissue})
    assert (reply.status_code == 200) is valid, reply.text


def test_a_model_without_material_inputs_refuses_materials(tiny_client):
    reply = tiny_client.post("/predict", json={**GUIDE, "materials": {"prostate": {"youngs_kpa": 70.0}}})
    assert reply.status_code == 422
    error = reply.json()["detail"][0]
    assert error["field"] == "materials" and "this model takes no material inputs" in error["message"]
    assert "std_mm" not in tiny_client.post("/predict", json={**GUIDE, "region": "markers"}).json()


def test_the_served_default_model_takes_the_default_scenes_materials(client):
    """models/default lists the four soft tissues of default.toml's [materials], with their ranges; an old client
    (guide only) gets the nominal answer with the scene's std, and a value outside a range is a 422 naming it."""
    from fem_offline.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[2] / "fem_offline" / "scenes" / "default.toml")
    inputs = client.get("/model").json()["materials"]["inputs"]
    assert [m["tissue"] for m in inputs] == list(scene.materials)
    for m in inputs:
        assert tuple(m["youngs_kpa_range"]) == pytest.approx(scene.materials[m["tissue"]].youngs_kpa_range)
    old = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers"}).json()
    nominal = {m["tissue"]: {"youngs_kpa": m["nominal_youngs_kpa"]} for m in inputs}
    given = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers",
                                          "materials": nominal}).json()
    assert given["positions"] == old["positions"] and np.asarray(old["std_mm"]).max() > 0
    low = inputs[0]["youngs_kpa_range"][0] * 0.9
    refused = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0,
                                            "materials": {inputs[0]["tissue"]: {"youngs_kpa": low}}})
    assert refused.status_code == 422
    assert refused.json()["detail"][0]["field"] == f"materials.{inputs[0]['tissue']}.youngs_kpa"


def test_the_error_budget_names_its_terms_and_adds_them_up(mat_client):
    reply = _post(mat_client, region="markers", materials={"bladder": {"youngs_kpa": 110.0, "std": 22.0}}).json()
    b = reply["error_budget"]
    std_max = np.linalg.norm(np.asarray(reply["std_mm"]), axis=1).max()
    assert b["region"] == "markers" and b["material_std_mm_max"] == pytest.approx(std_max, rel=1e-6)
    known = [b[k] for k in ("surrogate_mm", "fe_discretisation_mm", "material_first_order_mm") if b[k] is not None]
    assert b["total_mm"] == pytest.approx(sum(known) + 2 * std_max)
    assert set(b["measured_against"]) >= {"surrogate_and_fe", "material_first_order", "material_std", "total"}


def test_points_and_the_whole_mesh_carry_std(mat_client, tiny_material_model):
    folder = read_model_folder(tiny_material_model)
    tissue = folder.manifest.mesh.tissues.index("prostate")
    tets = folder.tets[np.flatnonzero(folder.mesh.tissue == tissue)[:3]]
    points = [folder.nodes[t[:4]].mean(axis=0).tolist() for t in tets]
    at_points = _post(mat_client, points=points).json()
    assert np.asarray(at_points["std_mm"]).shape == (3, 3) and np.min(at_points["std_mm"]) >= 0
    whole = _post(mat_client).json()
    assert np.asarray(whole["std_mm"]).shape == (len(folder.nodes), 3)
    assert whole["error_budget"]["region"] == "all_nodes"


def test_the_std_is_the_fe_finite_difference_times_the_materials_std(mat_client, tiny_material_model):
    """std at the markers for a prostate std of 10 % (others 0) = |u(E e^h) - u(E e^-h)| / 2h x 0.1 from fresh FE solves
    of the tiny scene (linear: its S is exact to the solve; the surrogate's error aside)."""
    from contracts.mesh import read_mesh
    from fem_offline.fe.problem import build_problem
    from fem_offline.fe.solve import solve_case
    from fem_offline.material_cases import scaled_scene

    scene, h = tiny_material_scene(), 0.05
    mesh = read_mesh(tiny_material_model / "mesh.npz")
    markers = read_model_folder(tiny_material_model).regions["markers"]
    u = [solve_case(build_problem(scaled_scene(scene, ("prostate",), np.array([s * h])), mesh), 4.0, 3.0)[0][markers]
         for s in (1, -1)]
    expected = np.abs(u[0] - u[1]) / (2 * h) * 0.1
    zero = {n: {"std_percent": 0.0} for n in TINY_MATERIALS if n != "prostate"}
    reply = _post(mat_client, region="markers", materials={"prostate": {"std_percent": 10.0}, **zero}).json()
    assert expected.max() > 1e-3
    np.testing.assert_allclose(reply["std_mm"], expected, atol=0.02 * expected.max())


def test_openigtlink_takes_the_materials_and_sends_the_std_as_each_points_diameter(tiny_material_model, mat_client):
    """STRING NeedleGuideMaterials sets the stiffnesses for later poses (as /predict's materials); the POINT reply's
    diameters are 2 |std| of /predict's markers; a bad value is refused by its field and changes nothing."""
    import pyigtl

    from service.guide import Guide
    from service.igtl import MATERIALS_NAME, Responder
    from service.model import Predictor

    folder = read_model_folder(tiny_material_model)
    responder, predictor = Responder(folder), Predictor(folder)
    pose = pyigtl.TransformMessage(Guide.of(folder.manifest).pose(4.0, 3.0), device_name="NeedleGuide")
    materials = {"prostate": {"youngs_kpa": 80.0, "std_percent": 10.0}}
    said = responder.answer(predictor, pyigtl.StringMessage(__import__("json").dumps(materials), device_name=MATERIALS_NAME))
    assert said[0].string.startswith("materials set")
    points = responder.answer(predictor, pose)[0]
    reply = _post(mat_client, region="markers", materials=materials).json()
    np.testing.assert_allclose(points.positions, reply["positions"], atol=1e-5)
    np.testing.assert_allclose(points.diameters, 2 * np.linalg.norm(reply["std_mm"], axis=1), atol=1e-5)
    refused = responder.answer(predictor, pyigtl.StringMessage('{"prostate": {"youngs_kpa": 200}}', device_name=MATERIALS_NAME))
    assert "materials.prostate.youngs_kpa" in refused[0].string
    np.testing.assert_allclose(responder.answer(predictor, pose)[0].positions, points.positions)


def test_an_export_with_materials_is_refused_rather_than_answered_at_the_nominal(mat_client):
    """?format= exports the nominal materials' mesh (service/export.py): materials with it are a 422, not ignored."""
    reply = mat_client.post("/predict?format=vtu", json={**GUIDE, "materials": {"prostate": {"youngs_kpa": 70.0}}})
    assert reply.status_code == 422 and reply.json()["detail"][0]["field"] == "materials"
    assert mat_client.post("/predict?format=vtu", json=GUIDE).status_code == 200
