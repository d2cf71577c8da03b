"""The browser viewer: served offline by the service, deformed by /predict, and driven in Debian's chromium."""

import io
import re

import numpy as np
import pytest
from .helpers import predict_json, prostate_point, served

from service.viewer import STATIC
from tools.browser import (add_target, find_chromium, launch_chromium, open_viewer, serve_in_thread, set_slider,
                           wait_still)

needs_chromium = pytest.mark.skipif(find_chromium() is None,
                                    reason="no chromium on PATH (make system-deps installs Debian's chromium)")


def test_page_and_three_js_come_from_the_service(tiny_client):  # noqa: F811
    page = tiny_client.get("/viewer")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert '"three": "/viewer/vendor/three.module.js"' in page.text
    for name in ("viewer.js", "plan.js", "vendor/three.module.js", "vendor/three.core.js", "vendor/OrbitControls.js"):
        reply = tiny_client.get(f"/viewer/{name}")
        assert reply.status_code == 200 and reply.headers["content-type"].startswith("text/javascript"), name
        assert reply.content == (STATIC / name).read_bytes()
    for own in ("index.html", "viewer.js", "plan.js", "viewer.css"):  # nothing fetched from elsewhere at run time
        assert not re.search(r"https?://|//cdn|@import", (STATIC / own).read_text()), own
    assert tiny_client.get("/viewer/../settings.py").status_code == 404
    assert tiny_client.get("/viewer/nothing.js").status_code == 404


def _replies(client, regions, case) -> list[np.ndarray]:
    return [np.asarray(predict_json(client, **case, **({} if r is None else {"region": r}))["positions"])
            for r in regions]


def test_scene_gathers_every_drawn_node_from_the_requests_it_makes(tiny_client, tiny_folder):  # noqa: F811
    """Positions gathered from the page's replies are /predict's positions of each surface node and marker."""
    scene = tiny_client.get("/viewer/scene.json").json()
    case = {"displacement_mm": 4.5, "angle_deg": -7.0}
    replies = _replies(tiny_client, scene["regions"], case)
    full = np.asarray(predict_json(tiny_client, **case)["positions"])
    assert {t["name"] for t in scene["tissues"]} == set(tiny_folder.surfaces)
    for layer in [*scene["tissues"], scene["markers"]]:
        reference = np.asarray(layer["reference"]).reshape(-1, 3)
        ids = np.array([np.flatnonzero((tiny_folder.nodes == p).all(axis=1))[0] for p in reference])
        gathered = np.array([replies[s][r] for s, r in zip(layer["source"], layer["row"])])
        np.testing.assert_allclose(gathered, full[ids], atol=1e-6)
    assert tuple(scene["envelope"]["displacement_mm"]) == tiny_folder.manifest.envelope.displacement_mm
    assert scene["colour_scale_mm"] >= np.linalg.norm(full - tiny_folder.nodes, axis=1)[
        tiny_folder.regions["prostate"]].max()


def test_region_cover_holds_the_drawn_nodes_and_gather_finds_them(tiny_client, tiny_folder):  # noqa: F811
    from service.viewer import frame_requests, gather, region_cover

    drawn = np.unique(np.concatenate([s.ravel() for s in tiny_folder.surfaces.values()]))
    cover = region_cover(tiny_folder, drawn)
    assert None not in cover and np.isin(drawn, np.concatenate([tiny_folder.regions[r] for r in cover])).all()
    # the tiny mesh's drawn regions hold most of it: one whole-mesh request instead
    assert frame_requests(tiny_folder, drawn) == [None]
    case = {"displacement_mm": 4.0, "angle_deg": 3.0}
    replies, full = _replies(tiny_client, cover, case), _replies(tiny_client, [None], case)[0]
    source, row = gather(tiny_folder, cover, drawn)
    np.testing.assert_allclose([replies[s][r] for s, r in zip(source, row)], full[drawn], atol=1e-6)
    others = np.setdiff1d(np.arange(len(tiny_folder.nodes)), tiny_folder.regions["markers"])[:5]
    assert (gather(tiny_folder, ["markers"], others)[0] == -1).all()  # in no requested region: arrives nowhere


def test_targets_interpolated_from_a_frame_equal_predict_points(tiny_client, tiny_folder):  # noqa: F811
    """x = X + sum_i w_i (x_i - X_i) over /viewer/targets' nodes, read from the frame's replies,
    is /predict `points`."""
    scene = tiny_client.get("/viewer/scene.json").json()
    rng = np.random.default_rng(3)
    tets = tiny_folder.tets[rng.choice(len(tiny_folder.tets), 5, replace=False)]
    points = tiny_folder.nodes[tets[:, :4]].mean(axis=1)  # tet centroids: inside the mesh
    reply = tiny_client.post("/viewer/targets", json={"points": points.tolist()})
    assert reply.status_code == 200
    case = {"displacement_mm": 4.5, "angle_deg": -7.0}
    replies = [r.astype(np.float32) for r in _replies(tiny_client, scene["regions"], case)]
    expected = np.asarray(predict_json(tiny_client, **case, points=points.tolist())["positions"])
    for point, target, want in zip(points, reply.json()["targets"], expected):
        nodes = np.array([replies[s][r] for s, r in zip(target["source"], target["row"])])  # (10, 3) deformed
        u = np.asarray(target["weights"]) @ (nodes - np.asarray(target["reference"]).reshape(10, 3))
        np.testing.assert_allclose(point + u, want, atol=1e-4)
        assert sum(target["weights"]) == pytest.approx(1.0)


def test_targets_outside_the_mesh_or_malformed_get_422(tiny_client, tiny_folder):  # noqa: F811
    far = (tiny_folder.nodes.max(axis=0) + 50.0).tolist()
    outside = tiny_client.post("/viewer/targets", json={"points": [far]})
    assert outside.status_code == 422 and outside.json()["detail"][0]["type"] == "outside_mesh"
    for body in ({"points": [[1e300, 0, 0]]}, {"points": []}, {"points": [[1, 2]]}, {"points": [["1", 2, 3]]},
                 {"point": [1, 2, 3]}):
        assert tiny_client.post("/viewer/targets", json=body).status_code == 422, body


@pytest.fixture(scope="module")
def browser():
    with launch_chromium() as launched:  # one per module: Playwright's sync API runs one at a time
        yield launched


@pytest.fixture(scope="module")
def viewer(tiny_model, browser):  # noqa: F811
    from service.app import create_app
    from service.settings import Settings

    with serve_in_thread(create_app(Settings(model=tiny_model))) as url, \
            open_viewer(url, browser=browser) as (page, problems):
        yield page, problems, url


def _pixels(page, box) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.screenshot(clip=box))).convert("RGB"), dtype=np.int16)


@needs_chromium
def test_page_loads_without_errors_with_the_envelope_on_its_sliders(viewer, tiny_folder):  # noqa: F811
    page, problems, _ = viewer
    envelope = tiny_folder.manifest.envelope
    for slider, (lo, hi) in (("displacement", envelope.displacement_mm), ("angle", envelope.angle_deg)):
        assert page.eval_on_selector(f"#{slider}", "s => [Number(s.min), Number(s.max)]") == [lo, hi]
    state = page.evaluate("({errors: __viewer.errors, ms: __viewer.lastFrameMs})")
    assert problems == [] and state["errors"] == []
    assert 0 < state["ms"] < 60_000  # measured and exposed (the figure itself comes from `python -m bench viewer`)


@needs_chromium
def test_webgl_runs_on_the_software_backend_chosen_and_multisamples_only_on_hardware(viewer):
    from tools.browser import LLVMPIPE_FLAGS, webgl_flags

    page, _, _ = viewer
    state = page.evaluate("({webgl: __viewer.webgl, antialias: __viewer.antialias, "
                          "context: __viewer.contextAntialias()})")
    expected = "llvmpipe" if webgl_flags() == LLVMPIPE_FLAGS else "SwiftShader"
    assert expected in state["webgl"]
    # software: no multisampling (its clears and resolves stalled frames), and the context has none
    assert state["antialias"] is False and state["context"] is False


@needs_chromium
def test_antialias_in_the_url_overrides_the_renderer_check(viewer, browser):
    _, _, url = viewer
    for query, expected in (("antialias=1", True), ("antialias=0", False)):
        with open_viewer(url, browser=browser, query=query) as (page, problems):
            assert page.evaluate("[__viewer.antialias, __viewer.contextAntialias()]") == [expected, expected]
            assert problems == []


@needs_chromium
def test_a_drag_draws_at_half_resolution_in_software_then_a_still_frame_at_full(viewer, browser):
    page, problems, url = viewer
    assert page.evaluate("__viewer.dragScale") == 0.5  # the tests' WebGL is a software renderer
    full = page.evaluate("__viewer.fullBuffer()")
    stills = page.evaluate("__viewer.stillFrames")
    for value in (1.0, 2.0):
        set_slider(page, "displacement", value)
        assert page.evaluate("__viewer.lastBuffer") == [n // 2 for n in full]  # the frame the move drew
    wait_still(page)
    assert page.evaluate("(n) => [__viewer.buffer(), __viewer.stillFrames > n]", stills) == [full, True]
    with open_viewer(url, browser=browser, query="scale=1") as (other, other_problems):  # full resolution throughout
        set_slider(other, "displacement", 1.0)
        assert other.evaluate("[__viewer.dragScale, __viewer.lastBuffer, __viewer.still]") == [
            1, other.evaluate("__viewer.fullBuffer()"), True]
        assert other_problems == []
    assert problems == []


@needs_chromium
def test_displacement_slider_moves_the_prostate_and_keeps_the_camera(viewer, tiny_folder, tmp_path):  # noqa: F811
    page, problems, _ = viewer
    top = tiny_folder.manifest.envelope.displacement_mm[1]  # the linear sweep's valid part (tests/conftest.py)
    set_slider(page, "displacement", 0.0)
    point = page.evaluate("__viewer.prostateScreenPoint()")
    box = {"x": point["x"] - 80, "y": point["y"] - 80, "width": 160, "height": 160}
    camera = page.evaluate("__viewer.cameraPosition()")
    before = _pixels(page, box)
    state = set_slider(page, "displacement", top)
    after = _pixels(page, box)
    changed = (np.abs(after - before).max(axis=2) > 30).mean()
    assert changed > 0.02, f"only {changed:.1%} of the prostate's pixels changed from 0 to {top} mm"
    assert state["lastFrame"]["displacement_mm"] == top
    np.testing.assert_allclose(page.evaluate("__viewer.cameraPosition()"), camera, atol=1e-9)
    assert problems == []


@needs_chromium
def test_a_click_on_the_prostate_adds_a_target_that_moves_as_predict_says(viewer, tiny_client, tiny_folder, tmp_path):  # noqa: F811
    page, problems, _ = viewer
    top = tiny_folder.manifest.envelope.displacement_mm[1]
    set_slider(page, "displacement", top)
    set_slider(page, "angle", 6.0)
    target = add_target(page)
    reply = predict_json(tiny_client, displacement_mm=top, angle_deg=6.0, points=[target["reference"]])
    assert target["motionMm"] == pytest.approx(np.linalg.norm(reply["displacements"][0]), abs=0.01)
    np.testing.assert_allclose(target["position"], reply["positions"][0], atol=0.01)
    assert f"moved {target['motionMm']:.2f} mm" in page.inner_text("#targets")
    # interpolated on the page from the frame's own reply: still one /predict request a frame
    assert page.evaluate("__viewer.lastRequests") == 1
    shot = tmp_path / "viewer.png"  # the test's artifact (docs/img/viewer.png comes from the viewer screenshot study)
    wait_still(page)
    page.screenshot(path=shot)
    assert shot.stat().st_size > 10_000 and problems == []


# Counts /predict fetches in flight (the page calls the global fetch), then fires `input` n times
# in one task, as a burst of pointer moves that arrive while the first frame is being fetched.
BURST = """async ([values]) => {
  const inner = window.fetch;
  let now = 0, most = 0;
  window.fetch = (url, options) => {
    if (url !== '/predict') return inner(url, options);
    now += 1; most = Math.max(most, now);
    return inner(url, options).finally(() => { now -= 1; });
  };
  const frames = [], listen = (e) => frames.push(e.detail);
  window.addEventListener('viewer-frame', listen);
  const slider = document.getElementById('displacement');
  for (const value of values) {
    slider.value = String(value);
    slider.dispatchEvent(new Event('input', { bubbles: true }));
  }
  while (window.__viewer.busy) await new Promise((r) => setTimeout(r, 1));
  window.removeEventListener('viewer-frame', listen);
  window.fetch = inner;
  return { most, frames, shown: window.__viewer.lastFrame.displacement_mm }; }"""


@needs_chromium
def test_slider_moves_during_a_fetch_are_coalesced_into_one_frame_showing_the_latest(viewer, tiny_folder):  # noqa: F811
    page, problems, _ = viewer
    set_slider(page, "displacement", 0.0)
    values = np.round(np.linspace(0.1, tiny_folder.manifest.envelope.displacement_mm[1], 20), 2).tolist()
    burst = page.evaluate(BURST, [values])
    assert burst["most"] == 1  # never two frames' requests in flight
    # the first move's frame, then one frame for the 19 that came during its fetch, showing the last
    assert [f["inputs"] for f in burst["frames"]] == [1, 19] and burst["shown"] == values[-1]
    last = burst["frames"][-1]
    assert 0 < last["frameMs"] <= last["firstInputMs"]  # timed from the latest input shown; the first one is older
    assert problems == []


@needs_chromium
def test_with_a_region_cover_frames_and_targets_still_match_predict(tiny_model, tiny_client, tiny_folder, browser,  # noqa: F811
                                                                    monkeypatch):
    """Where a frame asks for the region cover, a target whose tet leaves it is asked of /predict `points` as well."""
    import service.viewer
    from service.app import create_app
    from service.settings import Settings

    monkeypatch.setattr(service.viewer, "WHOLE_MESH_FRACTION", 2.0)  # never the whole mesh
    with serve_in_thread(create_app(Settings(model=tiny_model))) as url, \
            open_viewer(url, browser=browser) as (page, problems):
        regions = page.evaluate("fetch('/viewer/scene.json').then((r) => r.json()).then((s) => s.regions)")
        assert None not in regions
        covered = np.isin(tiny_folder.tets, np.concatenate([tiny_folder.regions[r] for r in regions])).all(axis=1)
        inside, outside = (tiny_folder.nodes[tiny_folder.tets[np.flatnonzero(c)[0], :4]].mean(axis=0).tolist()
                           for c in (covered, ~covered))  # a tet centroid whose nodes all arrive, and one whose don't
        set_slider(page, "displacement", 4.0)
        for n, point in enumerate((inside, outside), start=1):
            page.evaluate("(p) => __viewer.addTarget(p)", point)
            page.wait_for_function("(n) => __viewer.targets.length === n && __viewer.targets[n - 1].motionMm !== null "
                                   "&& !__viewer.busy", arg=n)
        targets = page.evaluate("__viewer.targets")
        reply = predict_json(tiny_client, displacement_mm=4.0, angle_deg=0.0, points=[inside, outside])
        np.testing.assert_allclose([t["position"] for t in targets], reply["positions"], atol=0.01)
        assert page.evaluate("__viewer.targetsLocal()") == [True, False]
        assert page.evaluate("__viewer.lastRequests") == len(regions) + 1 and problems == []


@pytest.fixture(scope="module")
def material_viewer(tiny_material_model, browser):  # noqa: F811
    from service.app import create_app
    from service.settings import Settings

    with serve_in_thread(create_app(Settings(model=tiny_material_model))) as url, \
            open_viewer(url, browser=browser) as (page, problems):
        yield page, problems, url


@needs_chromium
def test_a_material_model_gets_one_stiffness_slider_per_tissue_and_shows_its_uncertainty(material_viewer,
                                                                                        tiny_material_model):
    """Each slider spans its tissue's declared range from the nominal; moving the prostate's redraws the markers where
    /predict puts them for that E, with the 1-sigma readout the replies' X-Std-Max-Mm gives and a halo of radius
    2 sigma."""
    from fastapi.testclient import TestClient

    from contracts.model import read_model_folder
    from service.app import create_app
    from service.settings import Settings

    page, problems, _ = material_viewer
    inputs = read_model_folder(tiny_material_model).manifest.materials.inputs
    for m in inputs:
        lo, hi, value = page.eval_on_selector(f"#E-{m.tissue}", "s => [Number(s.min), Number(s.max), Number(s.value)]")
        assert (lo, hi) == m.youngs_kpa_range and value == pytest.approx(m.nominal_youngs_kpa)
    set_slider(page, "displacement", 4.0)  # a push: at rest nothing moves and the std is 0
    frames = page.evaluate("__viewer.frames")
    page.fill("#E-prostate", "80")
    page.wait_for_function("(n) => __viewer.frames > n && !__viewer.busy", arg=frames, timeout=30_000)
    d, a = page.evaluate("[__viewer.lastFrame.displacement_mm, __viewer.lastFrame.angle_deg]")
    nominal = {m.tissue: {"youngs_kpa": m.nominal_youngs_kpa} for m in inputs}
    with TestClient(create_app(Settings(model=tiny_material_model))) as client:
        reply = predict_json(client, displacement_mm=d, angle_deg=a, region="markers",
                             materials={**nominal, "prostate": {"youngs_kpa": page.evaluate(
                                 "Number(document.getElementById('E-prostate').value)")}})
    np.testing.assert_allclose(np.reshape(page.evaluate("__viewer.markerPositions()"), (-1, 3)), reply["positions"],
                               atol=1e-4)
    sigma = page.evaluate("__viewer.stdMaxMm")
    assert sigma >= np.linalg.norm(reply["std_mm"], axis=1).max() - 1e-6 and sigma > 1e-3
    # the halo is the 2-sigma sphere, as OpenIGTLink's points (test_materials) and the error budget count it
    assert page.evaluate("__viewer.haloRadiusMm") == pytest.approx(2 * sigma, rel=1e-6)
    assert "1σ up to" in page.inner_text("#uncertainty") and "halo: 2σ" in page.inner_text("#uncertainty")
    assert problems == []


def _ray_distance(line: list[float], point) -> float:
    """Distance of `point` from the ray a drawn needle path starts (its first point, towards its second)."""
    start, end = np.reshape(line, (2, 3))
    a = (end - start) / np.linalg.norm(end - start)
    v = np.asarray(point) - start
    return float(np.linalg.norm(v - max(v @ a, 0.0) * a))


def _lesions(folder) -> list[list[float]]:
    """A prostate point moved onto the needle's tilt plane (a ray reaches it) and the point itself."""
    from service.guide import Guide

    guide, p = Guide.of(folder.manifest), np.array(prostate_point(folder))
    return [(p - ((p - guide.tip_mm) @ guide.tilt_normal) * guide.tilt_normal).round(3).tolist(), p.round(3).tolist()]


@needs_chromium
def test_lesions_in_the_url_are_drawn_before_and_after_with_their_plan_and_the_needle_paths(
        viewer, browser, tiny_client, tiny_folder, tmp_path):
    """?lesions= adds each lesion and asks /plan: its reference and displaced positions, the sliders' needle path and
    the planned pose are in the scene; "Go to plan" moves the guide there, where the drawn needle path passes the drawn
    lesion at the miss /plan states."""
    _, _, url = viewer
    lesions = _lesions(tiny_folder)
    query = "lesions=" + ";".join(",".join(map(str, p)) for p in lesions)
    with open_viewer(url, browser=browser, query=query) as (page, problems):
        page.wait_for_function("__viewer.plans === 2 && __viewer.ready && !__viewer.busy", timeout=60_000)
        objects, targets = page.evaluate("__viewer.objects()"), page.evaluate("__viewer.targets")
        for name in ("needle-path", "planned-guide", "planned-needle-path", "planned-lesion", "T1-reference",
                     "T1-displaced", "T2-reference", "T2-displaced"):
            assert objects[name]["visible"], name
        np.testing.assert_allclose([objects["T1-reference"]["position"], objects["T2-reference"]["position"]], lesions,
                                   atol=1e-4)
        plans = [tiny_client.post("/plan", json={"lesion_mm": p}).json() for p in lesions]
        assert [t["plan"] for t in targets] == plans  # at the best push: /plan's reply, as the page got it
        shown = plans[1]  # the last planned is drawn: its needle path from the pushed tip along a(beta)
        path = np.reshape(objects["planned-needle-path"]["points"], (2, 3))
        np.testing.assert_allclose(path[0], shown["needle_tip_mm"], atol=1e-4)
        np.testing.assert_allclose((path[1] - path[0]) / np.linalg.norm(path[1] - path[0]), shown["needle_direction"],
                                   atol=1e-5)
        np.testing.assert_allclose(objects["planned-lesion"]["position"], shown["plan"]["lesion_mm"], atol=1e-4)

        # at the push the clinician wants (the slider's, 4 mm), the lesion moves before the needle meets it
        set_slider(page, "displacement", 4.0)
        page.check("#plan-at-push")
        page.click("#targets li:nth-child(1) button.plan")
        page.wait_for_function("__viewer.plans === 3 && !__viewer.busy")
        at_push = tiny_client.post("/plan", json={"lesion_mm": lesions[0], "displacement_mm": 4.0}).json()
        assert page.evaluate("__viewer.targets[0].plan") == at_push and at_push["reachable"]
        plan = at_push["plan"]
        set_slider(page, "displacement", 0.0)
        page.click("#targets li:nth-child(1) button.go")
        page.wait_for_function("(d) => __viewer.lastFrame.displacement_mm === d && !__viewer.busy",
                               arg=plan["displacement_mm"])
        moved = page.evaluate("__viewer.targets[0].position")
        case = {"displacement_mm": plan["displacement_mm"], "angle_deg": plan["angle_deg"]}
        np.testing.assert_allclose(moved, predict_json(tiny_client, points=[lesions[0]], **case)["positions"][0],
                                   atol=0.01)
        assert np.linalg.norm(np.subtract(moved, lesions[0])) > 0.1  # before and after differ
        needle = page.evaluate("__viewer.objects()['needle-path'].points")
        assert _ray_distance(needle, moved) == pytest.approx(plan["miss_mm"], abs=0.01) and plan["miss_mm"] < 0.05
        assert "plan d " in page.inner_text("#targets li:nth-child(1)")

        wait_still(page)  # not blank: the displaced lesion, drawn over the prostate, is red where it projects
        shot = _pixels(page, {"x": 0, "y": 0, "width": 980, "height": 800})
        assert shot.std() > 10
        at = page.evaluate("(p) => __viewer.screenPoint(p)", moved)
        x, y = int(round(at["x"])), int(round(at["y"]))
        near = shot[y - 2:y + 3, x - 2:x + 3].reshape(-1, 3)
        assert ((near[:, 0] > 180) & (near[:, 1] < 90) & (near[:, 2] < 90)).any(), near
        page.screenshot(path=tmp_path / "lesions.png")
        assert problems == []


@needs_chromium
def test_a_lesion_typed_into_the_form_is_added_and_planned(viewer, browser, tiny_folder):
    _, _, url = viewer
    lesion = _lesions(tiny_folder)[0]
    with open_viewer(url, browser=browser) as (page, problems):
        for axis, value in zip("xyz", lesion):
            page.fill(f"#lesion-{axis}", str(value))
        page.click("#add-lesion")
        page.wait_for_function("__viewer.plans === 1 && __viewer.targets.length === 1 && !__viewer.busy")
        target = page.evaluate("__viewer.targets[0]")
        assert target["reference"] == lesion and target["plan"]["plan"]["miss_mm"] < 2.5
        assert page.evaluate("__viewer.objects()['plan'].visible")
        page.click("#clear-targets")
        objects = page.evaluate("__viewer.objects()")
        assert "T1-displaced" not in objects and not objects["plan"]["visible"] and problems == []


@needs_chromium
def test_a_material_models_lesion_has_a_2_sigma_halo_of_its_own_std(material_viewer, browser, tiny_material_model):
    """A lesion's halo has radius 2 |std| of /predict `points` at the sliders' stiffnesses (the markers' convention,
    for the lesion's own std)."""
    from contracts.model import read_model_folder

    _, _, url = material_viewer
    folder = read_model_folder(tiny_material_model)
    lesion = _lesions(folder)[1]
    with open_viewer(url, browser=browser) as (page, problems):
        set_slider(page, "displacement", 4.0)
        page.evaluate("(p) => __viewer.addTarget(p, { plan: true })", lesion)
        page.wait_for_function("__viewer.plans === 1 && __viewer.targets[0].sigmaMm !== null && !__viewer.busy")
        target, halo = page.evaluate("__viewer.targets[0]"), page.evaluate("__viewer.objects()['T1-halo']")
        nominal = {m.tissue: {"youngs_kpa": m.nominal_youngs_kpa} for m in folder.manifest.materials.inputs}
        with served(tiny_material_model) as client:
            reply = predict_json(client, displacement_mm=4.0, angle_deg=0.0, points=[lesion], materials=nominal)
        sigma = float(np.linalg.norm(reply["std_mm"][0]))
        assert sigma > 1e-3 and target["sigmaMm"] == pytest.approx(sigma, rel=1e-6)
        assert halo["visible"] and halo["scale"] == pytest.approx(2 * sigma, rel=1e-6)
        np.testing.assert_allclose(halo["position"], reply["positions"][0], atol=1e-4)
        assert "1σ" in page.inner_text("#targets") and problems == []
