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
    by_v = _post(mat_client, region="markers",
                 materials={"prostate": {"shear_wave_speed_m_s": v, "std_percent": 5.0}}).json()
    u, std = run([math.log(80.0 / 65.89), 0, 0, 0], [0.1, 0.2, 0.2, 0.2], markers)
    np.testing.assert_allclose(by_e["displacements"], u[0], atol=1e-6)
    np.testing.assert_allclose(by_v["displacements"], u[0], atol=1e-5)
    np.testing.assert_allclose(by_e["std_mm"], std[0], atol=1e-6)
    np.testing.assert_allclose(by_v["std_mm"], std[0], atol=1e-6)  # 5 % in v_s is 10 % in E


@pytest.fixture(scope="module")
def absolute_model(tiny_material_model, tmp_path_factory) -> Path:
    """tiny_material_model as a model judged by absolute E (by_ratios false in its manifest: what a scene with a
    soft tissue that is not an input gets); the manifest's hashes cover the other files, which are the same."""
    import json
    import shutil

    out = tmp_path_factory.mktemp("absolute") / "tiny_absolute"
    shutil.copytree(tiny_material_model, out)
    manifest = json.loads((out / "manifest.json").read_text())
    manifest["materials"]["by_ratios"] = False
    (out / "manifest.json").write_text(json.dumps(manifest))
    return out


@pytest.fixture(scope="module")
def abs_client(absolute_model):
    with served(absolute_model) as client:
        yield client


@pytest.mark.parametrize("materials, field", [
    ({"prostate": {"youngs_kpa": 90.0}}, "materials.prostate.youngs_kpa"),
    ({"adipose": {"youngs_kpa": 8.0}}, "materials.adipose.youngs_kpa"),
    ({"prostate": {"shear_wave_speed_m_s": 9.0}}, "materials.prostate.shear_wave_speed_m_s"),
    ({"liver": {"youngs_kpa": 5.0}}, "materials.liver"),
    ({"prostate": {"youngs_kpa": 60.0, "shear_wave_speed_m_s": 4.5}}, "materials.prostate"),
    ({"prostate": {"std": 5.0}}, "materials.prostate"),
])
def test_judged_by_absolute_e_a_material_outside_its_range_is_refused_naming_the_field(abs_client, materials, field):
    reply = _post(abs_client, materials=materials)
    assert reply.status_code == 422, reply.text
    assert reply.json()["detail"][0]["field"] == field


@pytest.mark.parametrize("materials, field, kind", [
    ({"prostate": {"youngs_kpa": 200.0}}, "materials.prostate", "outside_box"),
    ({"adipose": {"youngs_kpa": 4.0}}, "materials.adipose", "outside_box"),
    ({"prostate": {"shear_wave_speed_m_s": 15.0}}, "materials.prostate", "outside_box"),
    ({"prostate": {"youngs_kpa": 0.0}}, "materials.prostate.youngs_kpa", "greater_than_equal"),
    # past 1e6 x the nominal either way (service.materials.RATIO_SPAN): ln E and the ratios stay finite
    ({"prostate": {"youngs_kpa": 1e308}}, "materials.prostate.youngs_kpa", "less_than_equal"),
    ({"adipose": {"shear_wave_speed_m_s": 5e-324}}, "materials.adipose.shear_wave_speed_m_s", "greater_than_equal"),
    ({"liver": {"youngs_kpa": 5.0}}, "materials.liver", "extra_forbidden"),
    ({"prostate": {"youngs_kpa": 60.0, "shear_wave_speed_m_s": 4.5}}, "materials.prostate", "value_error"),
    ({"prostate": {"std": 5.0}}, "materials.prostate", "value_error"),
    ({"prostate": {"youngs_kpa": 70.0, "std": 70.5}}, "materials.prostate", "std_over_value"),
])
def test_judged_by_ratios_a_request_outside_the_box_is_refused_naming_the_field(mat_client, materials, field, kind):
    reply = _post(mat_client, materials=materials)
    assert reply.status_code == 422, reply.text
    error = reply.json()["detail"][0]
    assert (error["field"], error["type"]) == (field, kind)


def _ratio_box(client) -> dict:
    return client.get("/model").json()["materials"]["box"]


def test_the_model_states_its_box_as_ratios_and_in_kpa(mat_client, abs_client):
    """GET /model: the ranges as E / E_nominal and, at the nominal scale (the adipose at its nominal E), in kPa; how
    far each tissue alone may go with the others nominal; and which judgement the model takes."""
    inputs = {m["tissue"]: m for m in mat_client.get("/model").json()["materials"]["inputs"]}
    box = _ratio_box(mat_client)
    assert box["judged_by"] == "ratios" and _ratio_box(abs_client)["judged_by"] == "absolute E"
    for t, m in inputs.items():
        lo, hi = m["youngs_kpa_range"]
        assert box["youngs_kpa_at_nominal_scale"][t] == [lo, hi]
        nominal = m["nominal_youngs_kpa"]
        np.testing.assert_allclose(box["ratio_to_nominal"][t], [lo / nominal, hi / nominal])
        alone = box["youngs_kpa_alone"][t]
        assert alone[0] < lo and alone[1] > hi  # the others' ranges let one tissue go further
    assert "youngs_kpa_alone" not in _ratio_box(abs_client)


@pytest.mark.parametrize("k", [1e-3, 0.5, 3.7, 1e3])
def test_every_stiffness_times_k_gets_the_answer_of_the_stiffness_it_was_scaled_from(mat_client, graph, k):
    """Judged by ratios: E_i x k for every input tissue (E or a shear-wave speed, their std scaled along) is the same
    request, answered at the box's point with its ratios nearest the nominal: here theta itself (its mean is 0)."""
    run, folder = graph
    markers = folder.regions["markers"]
    theta = np.array([0.1, -0.1, 0.05, -0.05])
    nominal = {m.tissue: m.nominal_youngs_kpa for m in folder.manifest.materials.inputs}
    youngs = {t: nominal[t] * math.exp(th) for t, th in zip(TINY_MATERIALS, theta)}
    v = math.sqrt(youngs["bladder"] * 1e3 / (2 * 1.495 * 1008.0))

    def body(scale: float) -> dict:
        return {"prostate": {"youngs_kpa": youngs["prostate"] * scale, "std_percent": 10.0},
                "rectal_wall": {"youngs_kpa": youngs["rectal_wall"] * scale,
                                "std": 0.3 * youngs["rectal_wall"] * scale},
                "adipose": {"youngs_kpa": youngs["adipose"] * scale},
                "bladder": {"shear_wave_speed_m_s": v * math.sqrt(scale), "std_percent": 5.0}}

    scaled = _post(mat_client, region="markers", materials=body(k))
    assert scaled.status_code == 200, scaled.text  # k far outside every range at the nominal scale
    reply = _post(mat_client, region="markers", materials=body(1.0)).json()
    np.testing.assert_allclose(scaled.json()["positions"], reply["positions"], atol=1e-6)
    np.testing.assert_allclose(scaled.json()["std_mm"], reply["std_mm"], atol=1e-6)
    u, std = run(theta, [0.1, 0.3, 0.2, 0.1], markers)
    np.testing.assert_allclose(reply["displacements"], u[0], atol=1e-6)
    np.testing.assert_allclose(reply["std_mm"], std[0], atol=1e-6)


def test_scaling_only_the_given_tissues_changes_their_ratio_to_the_ones_left_nominal(mat_client):
    """A tissue left out stays at its nominal E: the prostate alone x 1.2 is a stiffer prostate, not the nominal."""
    prostate = _post(mat_client, region="markers", materials={"prostate": {"youngs_kpa": 65.89 * 1.2}}).json()
    nominal = _post(mat_client, region="markers").json()
    assert np.abs(np.subtract(prostate["positions"], nominal["positions"])).max() > 1e-3


def test_outside_the_box_a_422_names_the_tissue_and_the_bound_it_crossed(mat_client):
    """The prostate alone with the others nominal is answered up to youngs_kpa_alone's upper end (GET /model) and
    refused just past it, naming the prostate, the tissue it is judged against and the box's largest ratio."""
    box = _ratio_box(mat_client)
    top = box["youngs_kpa_alone"]["prostate"][1]
    assert _post(mat_client, region="markers", materials={"prostate": {"youngs_kpa": top * 0.999}}).status_code == 200
    error = _post(mat_client, region="markers", materials={"prostate": {"youngs_kpa": top * 1.001}}).json()["detail"][0]
    assert error["field"] == "materials.prostate" and error["type"] == "outside_box"
    ratios = box["ratio_to_nominal"]
    # the tissue that limits it: the one whose lower end leaves the prostate least room
    other = min((t for t in ratios if t != "prostate"), key=lambda t: 1 / ratios[t][0])
    most = ratios["prostate"][1] / ratios[other][0]
    assert other in error["message"] and f"the box's {most:.4g} x" in error["message"]
    assert f"up to x{ratios['prostate'][1]:.4g}" in error["message"]
    bottom = box["youngs_kpa_alone"]["adipose"][0]
    assert _post(mat_client, materials={"adipose": {"youngs_kpa": bottom * 1.001}}).status_code == 200
    soft = _post(mat_client, materials={"adipose": {"youngs_kpa": bottom * 0.999}}).json()["detail"][0]
    assert soft["field"] == "materials.adipose" and "down to x" in soft["message"]


def test_judged_by_absolute_e_scaling_every_stiffness_is_another_request(abs_client, mat_client, graph):
    """The same tiny model judged by absolute E: every tissue at 0.9 x its lower end is a 422 there and answered by
    ratios; at 1.02 x its lower end the graph is fed theta itself, unshifted."""
    run, folder = graph
    low = {t: {"youngs_kpa": v["youngs_kpa_range"][0] * 0.9} for t, v in TINY_MATERIALS.items()}
    assert _post(abs_client, materials=low).status_code == 422 and _post(mat_client, materials=low).status_code == 200
    inside = {t: {"youngs_kpa": v["youngs_kpa_range"][0] * 1.02} for t, v in TINY_MATERIALS.items()}
    reply = _post(abs_client, region="markers", materials=inside).json()
    theta = [math.log(inside[m.tissue]["youngs_kpa"] / m.nominal_youngs_kpa) for m in folder.manifest.materials.inputs]
    u, _ = run(theta, [0.2] * 4, folder.regions["markers"])
    np.testing.assert_allclose(reply["displacements"], u[0], atol=1e-6)


@pytest.mark.parametrize("tissue, valid", [
    ({"youngs_kpa": 70.0, "std": 5.0}, True),
    ({"youngs_kpa": 70.0, "shear_wave_speed_m_s": None, "std": 5.0}, True),  # null is not given
    ({"shear_wave_speed_m_s": None, "std": 5.0}, False),  # std with no value to be in the unit of
    ({"std": 5.0}, False),
    ({"youngs_kpa": 70.0, "shear_wave_speed_m_s": 4.5}, False),
    ({"std_percent": 10.0, "std": None}, True),
    ({"youngs_kpa": 70.0, "std": 70.0}, True),
    ({"youngs_kpa": 0.0}, False),
])
def test_the_schema_and_the_service_agree_on_which_tissue_values_are_given(mat_client, tissue, valid):
    """The OpenAPI schema says what the validator does, null fields included (a client generated from the
    schema must not send what the service refuses). A std over its value (std_over_value) and ratios outside the
    box (outside_box) are bounds between fields, which JSON schema cannot state: the tests above cover them."""
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
    (guide only) gets the nominal answer with the scene's std, so does every E halved (only ratios count), and ratios
    outside the box are a 422 naming the tissue."""
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
    halved = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0, "region": "markers", "materials": {
        t: {"youngs_kpa": v["youngs_kpa"] / 2} for t, v in nominal.items()}}).json()  # judged by ratios: nominal
    assert halved["positions"] == old["positions"]
    first = inputs[0]["tissue"]
    low = client.get("/model").json()["materials"]["box"]["youngs_kpa_alone"][first][0] * 0.99
    refused = client.post("/predict", json={"displacement_mm": 5.0, "angle_deg": 2.0,
                                            "materials": {first: {"youngs_kpa": low}}})
    assert refused.status_code == 422
    assert refused.json()["detail"][0]["field"] == f"materials.{first}"


def test_the_error_budget_names_its_terms_and_adds_them_up(mat_client):
    reply = _post(mat_client, region="markers", materials={"bladder": {"youngs_kpa": 110.0, "std": 22.0}}).json()
    b = reply["error_budget"]
    std_max = np.linalg.norm(np.asarray(reply["std_mm"]), axis=1).max()
    assert b["region"] == "markers" and b["material_std_mm_max"] == pytest.approx(std_max, rel=1e-6)
    bounds = ("surrogate_bound_mm", "fe_discretisation_bound_mm", "material_first_order_bound_mm")
    known = [b[k] for k in bounds if b[k] is not None]
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


def test_openigtlink_takes_the_materials_and_sends_the_2_sigma_sphere_of_predicts_std(tiny_material_model, mat_client):
    """STRING NeedleGuideMaterials sets the stiffnesses for later poses (as /predict's materials); the POINT reply's
    spheres have radius 2 sigma (diameter 4 |std|) of /predict's markers, the std convention GET /model states and
    the viewer's scene.json draws its halo by; ratios outside the box are refused by their field and change nothing."""
    import pyigtl

    from service.guide import Guide
    from service.igtl import MATERIALS_NAME, Responder
    from service.model import Predictor

    folder = read_model_folder(tiny_material_model)
    responder, predictor = Responder(folder), Predictor(folder)
    pose = pyigtl.TransformMessage(Guide.of(folder.manifest).pose(4.0, 3.0), device_name="NeedleGuide")
    materials = {"prostate": {"youngs_kpa": 80.0, "std_percent": 10.0}}
    message = pyigtl.StringMessage(__import__("json").dumps(materials), device_name=MATERIALS_NAME)
    said = responder.answer(predictor, message)
    assert said[0].string.startswith("materials set")
    points = responder.answer(predictor, pose)[0]
    reply = _post(mat_client, region="markers", materials=materials).json()
    np.testing.assert_allclose(points.positions, reply["positions"], atol=1e-5)
    sigma = np.linalg.norm(reply["std_mm"], axis=1)
    assert sigma.min() > 1e-3
    np.testing.assert_allclose(np.asarray(points.diameters) / 2, 2 * sigma, atol=1e-5)  # radius 2 sigma
    halo = mat_client.get("/model").json()["materials"]["std"]["halo_sigmas"]
    assert halo == 2 and mat_client.get("/viewer/scene.json").json()["halo_sigmas"] == halo
    assert reply["error_budget"]["total_mm"] == pytest.approx(
        sum(v for k, v in reply["error_budget"].items()
            if k.endswith("_mm") and k not in ("total_mm", "material_std_mm_max")
            and v is not None) + halo * sigma.max(), rel=1e-6)
    too_stiff = pyigtl.StringMessage('{"prostate": {"youngs_kpa": 200}}', device_name=MATERIALS_NAME)
    refused = responder.answer(predictor, too_stiff)
    assert "materials.prostate: " in refused[0].string and "the box's" in refused[0].string
    np.testing.assert_allclose(responder.answer(predictor, pose)[0].positions, points.positions)


def test_an_export_with_materials_is_refused_rather_than_answered_at_the_nominal(mat_client):
    """?format= exports the nominal materials' mesh (service/predict/export.py): materials with it are a 422,
    not ignored."""
    reply = mat_client.post("/predict?format=vtu", json={**GUIDE, "materials": {"prostate": {"youngs_kpa": 70.0}}})
    assert reply.status_code == 422 and reply.json()["detail"][0]["field"] == "materials"
    assert mat_client.post("/predict?format=vtu", json=GUIDE).status_code == 200
