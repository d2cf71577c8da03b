// The 3-D viewer: reference surfaces from /viewer/scene.json once, then per frame POST /predict
// for the few regions holding every drawn node (binary float32 little-endian, count x 3); each
// drawn node's position is gathered from those replies, and each target is interpolated from them
// with its tet's P2 weights (/viewer/targets, once per target).
// At most one frame's requests are in flight: slider moves during a fetch are coalesced, and the
// next frame shows the latest value. Slider-to-frame latency, from the input event whose value the
// frame shows to WebGL finished, is shown bottom left and kept in window.__viewer; so is the time
// from the first input the frame answers (the older, coalesced ones).
// Each target is a lesion: its reference position, where the tissue carries it (with a 2-sigma halo for a material
// model), and on request the pose POST /plan aims the needle with (plan.js draws it and the needle paths).
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/OrbitControls.js';
import { describePlan, direction, GUIDE_LENGTH_MM, NeedlePath, parseLesions, placeGuideBody, PlannedPose } from './plan.js';

const BINARY = 'application/octet-stream';
const COLOURS = { prostate: 0xd6604d, rectal_wall: 0xa6611a, bladder: 0x6a9fd4, pubic_bone: 0xe6e2d2,
  spine: 0xe6e2d2, adipose: 0xf5d77a };
// viridis at 0, 1/4, 1/2, 3/4, 1: the prostate's displacement magnitude, 0 .. colour_scale_mm (scene.json)
const COLOUR_MAP = [[0.267, 0.005, 0.329], [0.229, 0.322, 0.546], [0.128, 0.567, 0.551], [0.369, 0.789, 0.383],
  [0.993, 0.906, 0.144]];
// see-through: the fat around everything, and the rectal wall around the guide
const OPACITY = { adipose: 0.1, rectal_wall: 0.45 };
const $ = (id) => document.getElementById(id);

const viewer = window.__viewer = {
  ready: false, frames: 0, lastFrameMs: null, lastFirstInputMs: null, lastInputs: null, lastFetchMs: null,
  lastRenderMs: null, lastRequests: null, errors: [], targets: [], lastFrame: null, webgl: null, antialias: null,
  dragScale: 1, stillFrames: 0, lastBuffer: null, plans: 0,
};
// pendingSince: the first input not yet drawn (null: nothing to draw); latestInput: the last one,
// whose values (d, a) the next frame shows; inputs: how many the next frame answers.
const state = { d: 0, a: 0, inflight: false, pendingSince: null, latestInput: null, inputs: 0, layers: [], targets: [],
  stillTimer: null };
Object.defineProperty(viewer, 'busy', { get: () => state.inflight || state.pendingSince !== null });
// whether the view on screen is drawn at full resolution (a drag's frames may not be: setScale)
Object.defineProperty(viewer, 'still', { get: () => renderer?.getPixelRatio() === window.devicePixelRatio });
let scene, camera, renderer, controls, gl, markers, guide, info, needle, planned;

function colourInto(out, at, t) {  // viridis at t in 0..1, written to out[at .. at + 2]
  const x = Math.min(Math.max(t, 0), 1) * (COLOUR_MAP.length - 1);
  const i = Math.min(Math.floor(x), COLOUR_MAP.length - 2);
  const f = x - i, lo = COLOUR_MAP[i], hi = COLOUR_MAP[i + 1];
  for (let k = 0; k < 3; k++) out[at + k] = lo[k] + f * (hi[k] - lo[k]);
}

function showError(err) {
  viewer.errors.push(String(err));
  $('error').hidden = false;
  $('error').textContent = String(err);
}

// A material model's stiffness sliders (E in kPa) go with every request; its replies carry X-Std-Max-Mm,
// the largest 1-sigma length at the returned points, kept on the array as stdMaxMm.
function withMaterials(body) {
  if (info.materials) {
    body.materials = Object.fromEntries(info.materials.map((m) => [m.tissue, { youngs_kpa: state.youngs[m.tissue] }]));
  }
  return body;
}

async function predict(body) {
  const reply = await fetch('/predict', { method: 'POST', body: JSON.stringify(withMaterials(body)),
    headers: { 'content-type': 'application/json', accept: BINARY } });
  if (!reply.ok) throw new Error(`/predict ${reply.status}: ${await reply.text()}`);
  const positions = new Float32Array(await reply.arrayBuffer());  // little-endian on every WebGL platform
  if (positions.length !== 3 * Number(reply.headers.get('X-Count'))) throw new Error('/predict: short reply');
  positions.stdMaxMm = Number(reply.headers.get('X-Std-Max-Mm') ?? NaN);
  return positions;
}

// A material model's targets, as JSON: their positions and each one's 1-sigma length |std_mm| (kept as sigmaMm),
// which the binary reply does not carry (it has only their largest, X-Std-Max-Mm).
async function predictPoints(body) {
  const reply = await fetch('/predict', { method: 'POST', body: JSON.stringify(withMaterials(body)),
    headers: { 'content-type': 'application/json', accept: 'application/json' } });
  if (!reply.ok) throw new Error(`/predict ${reply.status}: ${await reply.text()}`);
  const json = await reply.json();
  const positions = Float32Array.from(json.positions.flat());
  positions.sigmaMm = json.std_mm.map((s) => Math.hypot(...s));
  positions.stdMaxMm = Math.max(...positions.sigmaMm, 0);
  return positions;
}

function buildLayer(layer) {
  const geometry = new THREE.BufferGeometry();
  const reference = Float64Array.from(layer.reference);  // (k * 3) mm, the surface's own nodes
  geometry.setAttribute('position', new THREE.BufferAttribute(Float32Array.from(reference), 3));
  geometry.setIndex(new THREE.BufferAttribute(Uint32Array.from(layer.triangles), 1));
  const adipose = layer.name === 'adipose';
  const prostate = layer.name === 'prostate';
  const opacity = OPACITY[layer.name] ?? 1;
  if (prostate) geometry.setAttribute('color', new THREE.BufferAttribute(new Float32Array(reference.length), 3));
  geometry.computeVertexNormals();
  const material = new THREE.MeshPhongMaterial({
    color: prostate ? 0xffffff : COLOURS[layer.name] ?? 0xa0a0a0, vertexColors: prostate, shininess: 20,
    transparent: opacity < 1, opacity, depthWrite: !adipose, side: adipose ? THREE.DoubleSide : THREE.FrontSide,
  });
  const mesh = new THREE.Mesh(geometry, material);
  mesh.name = layer.name;
  scene.add(mesh);
  return { ...layer, reference, mesh };
}

function gatherInto(out, replies, { source, row }) {  // node k's position is row[k] of reply source[k]
  for (let k = 0; k < source.length; k++) {
    const from = replies[source[k]], i = 3 * row[k];
    out[3 * k] = from[i];
    out[3 * k + 1] = from[i + 1];
    out[3 * k + 2] = from[i + 2];
  }
  return out;
}

// The WebGL renderer's name, from a probe context (null where the browser hides it), and whether it
// is a software rasteriser. In software, multisampling is most of a frame's cost: with llvmpipe at
// 1280 x 800 its clears and resolves took about 110 ms of CPU a frame against 70 ms without, and
// stalled some frames for seconds (README, "Browser viewer").
const SOFTWARE_GL = /llvmpipe|softpipe|swiftshader/i;
const DRAG_SCALE = 0.5, STILL_MS = 250;
function probeWebgl() {
  const probe = document.createElement('canvas').getContext('webgl2');
  if (!probe) return null;
  const info = probe.getExtension('WEBGL_debug_renderer_info');
  const name = info ? probe.getParameter(info.UNMASKED_RENDERER_WEBGL) : null;
  probe.getExtension('WEBGL_lose_context')?.loseContext();
  return name;
}

function buildScene() {
  scene = new THREE.Scene();
  scene.background = new THREE.Color(0x1d2127);
  const view = $('view');
  viewer.webgl = probeWebgl();
  const query = new URLSearchParams(window.location.search);
  const asked = query.get('antialias');  // ?antialias=1 or 0 overrides
  viewer.antialias = asked === '1' || (asked !== '0' && !SOFTWARE_GL.test(viewer.webgl ?? ''));
  renderer = new THREE.WebGLRenderer({ antialias: viewer.antialias });
  // While the sliders move, a software renderer draws at DRAG_SCALE of the resolution (a quarter of
  // the pixels at 0.5), and the view is drawn again at full resolution STILL_MS after the last
  // frame, as VTK's interactive and still update rates do; ?scale=1 keeps full resolution throughout.
  const scale = Number(query.get('scale'));
  viewer.dragScale = scale > 0 && scale <= 1 ? scale : SOFTWARE_GL.test(viewer.webgl ?? '') ? DRAG_SCALE : 1;
  renderer.setPixelRatio(window.devicePixelRatio);
  renderer.setSize(view.clientWidth, view.clientHeight);
  view.appendChild(renderer.domElement);
  gl = renderer.getContext();
  state.layers = info.tissues.map(buildLayer);
  const prostate = state.layers.find((l) => l.name === 'prostate').mesh;
  prostate.geometry.computeBoundingSphere();
  const centre = prostate.geometry.boundingSphere.center.clone();
  camera = new THREE.PerspectiveCamera(30, view.clientWidth / view.clientHeight, 1, 5000);
  camera.up.set(0, 0, 1);
  camera.position.copy(centre).add(new THREE.Vector3(250, -20, 110));  // from the right, above: the guide pushes across the view
  scene.add(camera);
  scene.add(new THREE.HemisphereLight(0xffffff, 0x404040, 1.6));
  const light = new THREE.DirectionalLight(0xffffff, 1.6);
  light.position.set(0.3, 0.4, 1);
  camera.add(light);  // a head light: the lit side follows the view
  controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(centre);
  controls.update();
  controls.addEventListener('change', render);
  state.markerPositions = new Float32Array(info.markers.reference.length);
  markers = new THREE.InstancedMesh(new THREE.SphereGeometry(1.2, 16, 12),
    new THREE.MeshPhongMaterial({ color: 0xffdc00 }), info.markers.reference.length / 3);
  scene.add(markers);
  // the guide's tip end, GUIDE_LENGTH_MM long, half as wide as the wall patch it drags
  const radius = info.guide.radius_mm / 2;
  guide = new THREE.Mesh(new THREE.CylinderGeometry(radius, radius, GUIDE_LENGTH_MM, 32),
    new THREE.MeshPhongMaterial({ color: 0x8fd18f, transparent: true, opacity: 0.85 }));
  scene.add(guide, motionLine(info.guide.tip_mm, info.guide.tip_mm));
  // the needle paths reach through the prostate and past it
  const needleMm = new THREE.Vector3(...info.guide.tip_mm).distanceTo(centre) + prostate.geometry.boundingSphere.radius + 10;
  needle = new NeedlePath(scene, needleMm);
  planned = new PlannedPose(scene, guide.geometry, needleMm);
  window.addEventListener('resize', () => {
    renderer.setSize(view.clientWidth, view.clientHeight);
    camera.aspect = view.clientWidth / view.clientHeight;
    camera.updateProjectionMatrix();
    render();
  });
}

function render() {
  renderer.render(scene, camera);
}

// The resolution of the frames a drag draws (viewer.dragScale), then one still frame at full resolution.
function setScale(scale) {
  const ratio = window.devicePixelRatio * scale;
  if (renderer.getPixelRatio() !== ratio) renderer.setPixelRatio(ratio);
}

function scheduleStill() {
  clearTimeout(state.stillTimer);
  if (viewer.dragScale === 1) return;
  state.stillTimer = setTimeout(() => {
    if (viewer.busy) return;  // the frame in flight schedules the next still frame
    setScale(1);
    render();
    gl.finish();
    viewer.stillFrames += 1;
  }, STILL_MS);
}

function placeGuide(d, a) {
  const dir = direction(info.guide, a);  // the tip moves by d a(beta)
  const tip = new THREE.Vector3(...info.guide.tip_mm).addScaledVector(dir, d);
  placeGuideBody(guide, tip, dir);
  needle.place(tip, dir);
}

function applyLayer(layer, replies) {
  const attribute = layer.mesh.geometry.attributes.position;
  const positions = gatherInto(attribute.array, replies, layer);
  attribute.needsUpdate = true;
  if (layer.name === 'prostate') {
    const colours = layer.mesh.geometry.attributes.color;
    const scale = info.colour_scale_mm;
    for (let i = 0; i < positions.length; i += 3) {
      const u = Math.hypot(positions[i] - layer.reference[i], positions[i + 1] - layer.reference[i + 1],
        positions[i + 2] - layer.reference[i + 2]);
      colourInto(colours.array, i, u / scale);
    }
    colours.needsUpdate = true;
  }
  layer.mesh.geometry.computeVertexNormals();
  layer.mesh.geometry.computeBoundingSphere();  // the picking ray tests against it
}

const MARKER_MATRIX = new THREE.Matrix4();
function applyMarkers(replies) {
  const positions = gatherInto(state.markerPositions, replies, info.markers);
  for (let i = 0; i < positions.length / 3; i++) {
    markers.setMatrixAt(i, MARKER_MATRIX.makeTranslation(positions[3 * i], positions[3 * i + 1], positions[3 * i + 2]));
  }
  markers.instanceMatrix.needsUpdate = true;
  markers.computeBoundingSphere();
  if (state.halos) applyUncertainty(positions, replies);
}

// A material model: a translucent halo around each marker of radius halo_sigmas (scene.json: 2) x sigma, sigma the
// largest 1-sigma length of the frame's replies (X-Std-Max-Mm); OpenIGTLink sends the same sphere (service/igtl.py)
// and the error budget counts the same multiple. The number in the panel.
function applyUncertainty(positions, replies) {
  const sigma = Math.max(...replies.map((r) => r.stdMaxMm).filter((v) => Number.isFinite(v)), 0);
  const r = Math.max(info.halo_sigmas * sigma, 1e-3);
  for (let i = 0; i < positions.length / 3; i++) {
    state.halos.setMatrixAt(i, MARKER_MATRIX.makeScale(r, r, r).setPosition(positions[3 * i], positions[3 * i + 1],
      positions[3 * i + 2]));
  }
  state.halos.instanceMatrix.needsUpdate = true;
  state.halos.computeBoundingSphere();
  viewer.stdMaxMm = sigma;
  viewer.haloRadiusMm = r;
  $('uncertainty').textContent = `uncertainty from the stiffnesses: 1σ up to ${sigma.toFixed(3)} mm (halo: ${info.halo_sigmas}σ)`;
}

// One slider per tissue stiffness of a material model, E in kPa inside its range, starting at the nominal.
function setupMaterials() {
  if (!info.materials) return;
  state.youngs = Object.fromEntries(info.materials.map((m) => [m.tissue, m.nominal_youngs_kpa]));
  const box = $('materials');
  for (const m of info.materials) {
    const id = `E-${m.tissue}`, [lo, hi] = m.youngs_kpa_range;
    const label = document.createElement('label'), out = document.createElement('output'), slider = document.createElement('input');
    label.htmlFor = id;
    out.id = `${id}-value`;
    label.append(`${m.tissue.replace('_', ' ')} E `, out, ' kPa');
    Object.assign(slider, { id, type: 'range', min: lo, max: hi, step: 'any', value: m.nominal_youngs_kpa });  // 'any': the nominal exactly
    out.textContent = m.nominal_youngs_kpa.toFixed(1);
    slider.addEventListener('input', (event) => {
      state.youngs[m.tissue] = Math.min(Math.max(Number(slider.value), lo), hi);
      out.textContent = state.youngs[m.tissue].toFixed(1);
      request(event.timeStamp || performance.now());
    });
    box.append(label, slider);
  }
  box.hidden = $('uncertainty').hidden = false;
  state.halos = new THREE.InstancedMesh(new THREE.SphereGeometry(1, 16, 12), new THREE.MeshPhongMaterial(
    { color: 0xffdc00, transparent: true, opacity: 0.25, depthWrite: false }), info.markers.reference.length / 3);
  scene.add(state.halos);
}

// x = X + sum_i w_i (x_i - X_i) over the target's tet nodes, from the frame's replies
// (what /predict `points` computes, contracts.interpolate)
function interpolateTarget(target, replies) {
  const { source, row, weights, reference } = target.tet, out = target.now;
  out.set(target.reference);
  for (let i = 0; i < weights.length; i++) {
    const from = replies[source[i]], r = 3 * row[i];
    for (let k = 0; k < 3; k++) out[k] += weights[i] * (from[r + k] - reference[3 * i + k]);
  }
  return out;
}

// `points`: a /predict points reply for all targets, or null where each is interpolated from `replies`.
// A material model's reply carries each target's sigma: its halo has radius halo_sigmas x sigma, as the markers'.
function applyTargets(targets, replies, points) {
  targets.forEach((target, i) => {
    const now = points ? points.subarray(3 * i, 3 * i + 3) : interpolateTarget(target, replies);
    target.position = Array.from(now);
    target.motionMm = Math.hypot(now[0] - target.reference[0], now[1] - target.reference[1], now[2] - target.reference[2]);
    target.sphere.position.set(now[0], now[1], now[2]);
    const line = target.line.geometry.attributes.position;
    line.array.set(now, 3);
    line.needsUpdate = true;
    let text = `${target.label}: moved ${target.motionMm.toFixed(2)} mm`;
    if (target.halo && points?.sigmaMm) {
      target.sigmaMm = points.sigmaMm[i];
      const r = Math.max(info.halo_sigmas * target.sigmaMm, 1e-3);
      target.halo.position.set(now[0], now[1], now[2]);
      target.halo.scale.set(r, r, r);
      text += ` (1σ ${target.sigmaMm.toFixed(3)} mm)`;
    }
    target.text.textContent = text;
  });
  publishTargets();
}

function publishTargets() {
  viewer.targets = state.targets.map(({ reference, position, motionMm, frame, sigmaMm, halo, plan }) => ({
    reference, position, motionMm, frame, sigmaMm: sigmaMm ?? null, haloRadiusMm: halo ? halo.scale.x : null,
    plan: plan ?? null }));
}

// One frame: the latest slider values, every drawn region (and, only for a target the regions
// cannot interpolate, the targets' points) in parallel, then render. Never two frames in flight:
// inputs that arrive meanwhile wait, coalesced, for the next.
async function frame() {
  if (state.inflight || state.pendingSince === null) return;
  const first = state.pendingSince, latest = state.latestInput, inputs = state.inputs;
  state.pendingSince = state.latestInput = null;
  state.inputs = 0;
  state.inflight = true;
  const d = state.d, a = state.a, targets = state.targets.slice();
  try {
    const regions = info.regions;
    const fetchStart = performance.now();
    const asked = regions.map((region) => predict(region === null ? { displacement_mm: d, angle_deg: a }
      : { displacement_mm: d, angle_deg: a, region }));  // null: the whole mesh
    // a target the regions cannot interpolate, or a material model's (for its sigma): /predict `points`
    const askPoints = targets.length > 0 && (Boolean(info.materials) || targets.some((t) => !t.local));
    if (askPoints) {
      asked.push((info.materials ? predictPoints : predict)({ displacement_mm: d, angle_deg: a,
        points: targets.map((t) => t.reference) }));
    }
    const replies = await Promise.all(asked);
    const fetchMs = performance.now() - fetchStart;
    state.layers.forEach((layer) => applyLayer(layer, replies));
    applyMarkers(replies);
    targets.forEach((t) => { t.frame = viewer.frames + 1; });
    applyTargets(targets, replies, askPoints ? replies[replies.length - 1] : null);
    placeGuide(d, a);
    const renderStart = performance.now();
    setScale(viewer.dragScale);
    render();
    gl.finish();  // count the frame when it is drawn, not when its commands are queued
    const end = performance.now();
    Object.assign(viewer, { lastBuffer: [gl.drawingBufferWidth, gl.drawingBufferHeight],
      lastRenderMs: end - renderStart, lastFrameMs: end - latest, lastFirstInputMs: end - first,
      lastInputs: inputs, lastFetchMs: fetchMs, lastRequests: asked.length, frames: viewer.frames + 1,
      lastFrame: { displacement_mm: d, angle_deg: a } });
    const coalesced = inputs > 1 ? `; ${inputs} moves, first ${viewer.lastFirstInputMs.toFixed(1)} ms` : '';
    $('latency').textContent = `frame ${viewer.lastFrameMs.toFixed(1)} ms (fetch ${fetchMs.toFixed(1)} ms, `
      + `${asked.length} request${asked.length > 1 ? 's' : ''}${coalesced}`
      + `${viewer.dragScale < 1 ? `; drawn at ${Math.round(100 * viewer.dragScale)} %, then full` : ''})`;
    window.dispatchEvent(new CustomEvent('viewer-frame', { detail: {
      frameMs: viewer.lastFrameMs, firstInputMs: viewer.lastFirstInputMs, inputs, fetchMs, renderMs: viewer.lastRenderMs,
      requests: asked.length } }));
  } catch (err) {
    showError(err);
  } finally {
    state.inflight = false;
    if (state.pendingSince !== null) frame();
    else scheduleStill();
  }
}

// Something to draw since `at` (an input event's time): the next frame shows it.
function request(at) {
  state.pendingSince ??= at;
  state.latestInput = at;
  state.inputs += 1;
  frame();
}

function setupSlider(id, [lo, hi], step, key) {
  const slider = $(id), out = $(`${id}-value`);
  Object.assign(slider, { min: lo, max: hi, step, value: Math.min(Math.max(0, lo), hi) });
  state[key] = Number(slider.value);
  out.textContent = Number(slider.value).toFixed(2);
  slider.addEventListener('input', (event) => {
    state[key] = Number(slider.value);
    out.textContent = state[key].toFixed(2);
    request(event.timeStamp || performance.now());
  });
}

// Phong like the markers (one shader program); the line's program is compiled with the first frame
// (a zero-length line at the tip), so adding a target never waits for a shader compile.
// A lesion inside the prostate would be hidden by its surface: targets are drawn over it (no depth test).
const TARGET = new THREE.MeshPhongMaterial({ color: 0xff3030, depthTest: false });
const TARGET_ORIGIN = new THREE.MeshPhongMaterial({ color: 0xbbbbbb, depthTest: false });
const MOTION_LINE = new THREE.LineBasicMaterial({ color: 0xff3030, depthTest: false });
const TARGET_HALO = new THREE.MeshPhongMaterial({ color: 0xff3030, transparent: true, opacity: 0.25, depthTest: false,
  depthWrite: false });
const UNIT_SPHERE = new THREE.SphereGeometry(1, 16, 12);

function motionLine(from, to) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array([...from, ...to]), 3));
  const line = new THREE.Line(geometry, MOTION_LINE);
  line.renderOrder = 1;
  return line;
}

// A target (a lesion): its reference position (grey), where the tissue carries it (red, with a material model's
// halo), the line between; `plan`: ask /plan for it at once (else its Plan button does).
async function addTarget(reference, { plan = false } = {}) {
  const reply = await fetch('/viewer/targets', { method: 'POST', body: JSON.stringify({ points: [reference] }),
    headers: { 'content-type': 'application/json' } });
  if (!reply.ok) throw new Error(`/viewer/targets ${reply.status}: ${await reply.text()}`);
  const [tet] = (await reply.json()).targets;  // its tet's nodes: where they arrive in a frame, and their weights
  const local = tet.source.every((s) => s >= 0);  // else the frame asks /predict points for it
  const label = `T${state.targets.length + 1}`;
  const sphere = new THREE.Mesh(new THREE.SphereGeometry(1.0, 16, 12), TARGET);
  const origin = new THREE.Mesh(new THREE.SphereGeometry(0.6, 12, 8), TARGET_ORIGIN);
  origin.position.set(...reference);
  sphere.position.set(...reference);
  const line = motionLine(reference, reference);
  const halo = info.materials ? new THREE.Mesh(UNIT_SPHERE, TARGET_HALO) : null;
  Object.assign(sphere, { name: `${label}-displaced`, renderOrder: 3 });
  Object.assign(origin, { name: `${label}-reference`, renderOrder: 2 });
  Object.assign(line, { name: `${label}-motion` });
  if (halo) halo.renderOrder = 4;
  const target = { label, reference, tet, local, now: new Float64Array(3), sphere, origin, line, halo,
    motionMm: null, position: null, frame: null, plan: null };
  target.item = targetItem(target);
  scene.add(sphere, origin, line, ...(halo ? [Object.assign(halo, { name: `${label}-halo` })] : []));
  state.targets.push(target);
  request(performance.now());
  if (plan) await planTarget(target);
}

function targetItem(target) {
  const item = document.createElement('li'), text = document.createElement('span'), planText = document.createElement('div');
  const planButton = document.createElement('button'), go = document.createElement('button');
  text.textContent = `${target.label}: …`;
  Object.assign(planButton, { type: 'button', textContent: 'Plan', className: 'plan', title: 'POST /plan: the guide pose whose needle path passes closest to this lesion once the tissue has moved' });
  Object.assign(go, { type: 'button', textContent: 'Go to plan', className: 'go', disabled: true, title: 'move the sliders to the planned pose' });
  planButton.addEventListener('click', () => planTarget(target).catch(showError));
  go.addEventListener('click', () => target.plan && setGuide(target.plan.plan.displacement_mm, target.plan.plan.angle_deg));
  planText.className = 'plan-text';
  item.append(text, ' ', planButton, ' ', go, planText);
  $('targets').appendChild(item);
  Object.assign(target, { text, planText, go });
  return item;
}

// POST /plan for a target at the stiffness sliders (and, when asked, at the slider's push: the push the clinician
// wants); its planned pose is drawn (the selected plan) and stated.
async function planTarget(target) {
  const body = withMaterials({ lesion_mm: target.reference });
  if ($('plan-at-push').checked) body.displacement_mm = state.d;
  const reply = await fetch('/plan', { method: 'POST', body: JSON.stringify(body),
    headers: { 'content-type': 'application/json' } });
  if (!reply.ok) throw new Error(`/plan ${reply.status}: ${await reply.text()}`);
  if (!state.targets.includes(target)) return;  // cleared meanwhile
  target.plan = await reply.json();
  target.planText.textContent = describePlan(target.plan);
  target.go.disabled = false;
  state.selected = target;
  planned.show(target.plan);
  viewer.plans += 1;
  publishTargets();
  render();
}

// Move both guide sliders (to a planned pose) and draw the frame.
function setGuide(d, a) {
  for (const [id, key, value] of [['displacement', 'd', d], ['angle', 'a', a]]) {
    $(id).value = String(value);  // shown at the slider's step; drawn exactly
    state[key] = value;
    $(`${id}-value`).textContent = value.toFixed(2);
  }
  request(performance.now());
}

// A click (not a drag) on the prostate: the hit point's barycentric coordinates on the deformed
// triangle, applied to the same triangle at rest, give the reference point /predict interpolates.
function pickTarget(event) {
  const rect = renderer.domElement.getBoundingClientRect();
  const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1,
    -((event.clientY - rect.top) / rect.height) * 2 + 1);
  const hit = firstHit(ndc);
  if (!hit || hit.object.name !== 'prostate') return;
  const layer = state.layers.find((l) => l.name === 'prostate');
  const position = layer.mesh.geometry.attributes.position;
  const corners = [hit.face.a, hit.face.b, hit.face.c];
  const [A, B, C] = corners.map((k) => new THREE.Vector3().fromBufferAttribute(position, k));
  const w = THREE.Triangle.getBarycoord(hit.point, A, B, C, new THREE.Vector3());
  const R = layer.reference;
  addTarget([0, 1, 2].map((k) => w.x * R[3 * corners[0] + k] + w.y * R[3 * corners[1] + k] + w.z * R[3 * corners[2] + k]))
    .catch(showError);
}

const raycaster = new THREE.Raycaster();
function firstHit(ndc) {
  raycaster.setFromCamera(ndc, camera);
  const solid = state.layers.filter((l) => l.name !== 'adipose').map((l) => l.mesh);
  return raycaster.intersectObjects(solid, false)[0] ?? null;
}

// For tests: the client coordinates of a prostate vertex that the first hit of its ray is the prostate's.
viewer.prostateScreenPoint = () => {
  const layer = state.layers.find((l) => l.name === 'prostate');
  const rect = renderer.domElement.getBoundingClientRect();
  const used = layer.source.map((_, k) => k);
  const centre = layer.mesh.geometry.boundingSphere.center;
  const p = new THREE.Vector3();
  const candidates = used.map((k) => p.fromBufferAttribute(layer.mesh.geometry.attributes.position, k).clone())
    .sort((u, v) => u.distanceTo(camera.position) - v.distanceTo(camera.position))
    .map((v) => v.lerp(centre, 0.02));  // just inside the outline
  for (const v of candidates) {
    const ndc = v.clone().project(camera);
    const hit = firstHit(new THREE.Vector2(ndc.x, ndc.y));
    if (hit && hit.object.name === 'prostate') {
      return { x: rect.left + (ndc.x + 1) / 2 * rect.width, y: rect.top + (1 - ndc.y) / 2 * rect.height };
    }
  }
  return null;
};
viewer.screenPoint = (xyz) => {  // for tests: the client coordinates of a point (mm) in the view
  const rect = renderer.domElement.getBoundingClientRect(), ndc = new THREE.Vector3(...xyz).project(camera);
  return { x: rect.left + (ndc.x + 1) / 2 * rect.width, y: rect.top + (1 - ndc.y) / 2 * rect.height };
};
viewer.contextAntialias = () => gl.getContextAttributes().antialias;  // for tests: what the context got
viewer.fullBuffer = () => [renderer.domElement.clientWidth, renderer.domElement.clientHeight].map(
  (n) => Math.floor(n * window.devicePixelRatio));  // the drawing buffer at full resolution
viewer.buffer = () => [gl.drawingBufferWidth, gl.drawingBufferHeight];
viewer.cameraPosition = () => camera.position.toArray();
viewer.cameraDistance = () => camera.position.distanceTo(controls.target);
viewer.addTarget = (reference, options) => addTarget(reference, options).catch(showError);  // for tests: a target at a reference point
// for tests: the scene graph's named objects, as drawn (world position, scale, visible along the parents)
viewer.objects = () => {
  const out = {};
  scene.traverse((o) => {
    if (!o.name) return;
    let visible = o.visible;
    for (let p = o.parent; p; p = p.parent) visible &&= p.visible;
    out[o.name] = { type: o.type, visible, position: o.getWorldPosition(new THREE.Vector3()).toArray(), scale: o.scale.x,
      points: o.isLine ? Array.from(o.geometry.attributes.position.array) : null };
  });
  return out;
};
viewer.targetsLocal = () => state.targets.map((t) => t.local);
viewer.markerPositions = () => Array.from(state.markerPositions);  // for tests: the markers as drawn (mm)  // each interpolated on the page, or asked by points

function setupLegend() {
  const stops = COLOUR_MAP.map((c, i) => `rgb(${c.map((v) => Math.round(255 * v)).join(',')}) ${100 * i / (COLOUR_MAP.length - 1)}%`);
  document.querySelector('#legend .bar').style.background = `linear-gradient(to right, ${stops.join(', ')})`;
  const top = info.colour_scale_mm;
  document.querySelector('#legend .ticks').innerHTML = [0, top / 2, top].map((v) => `<span>${v.toFixed(1)}</span>`).join('');
}

async function main() {
  const reply = await fetch('/viewer/scene.json');
  if (!reply.ok) throw new Error(`/viewer/scene.json ${reply.status}: ${await reply.text()}`);
  info = await reply.json();
  $('model').textContent = `model ${info.model}`;
  buildScene();
  setupSlider('displacement', info.envelope.displacement_mm, 0.05, 'd');
  setupSlider('angle', info.envelope.angle_deg, 0.1, 'a');
  setupMaterials();
  setupLegend();
  let down = null;
  renderer.domElement.addEventListener('pointerdown', (e) => { down = [e.clientX, e.clientY]; });
  renderer.domElement.addEventListener('pointerup', (e) => {
    if (down && Math.hypot(e.clientX - down[0], e.clientY - down[1]) < 4) pickTarget(e);
    down = null;
  });
  $('clear-targets').addEventListener('click', () => {
    state.targets.forEach((t) => scene.remove(t.sphere, t.origin, t.line, ...(t.halo ? [t.halo] : [])));
    state.targets = [];
    state.selected = null;
    planned.hide();
    viewer.targets = [];
    $('targets').replaceChildren();
    render();
  });
  $('lesion-form').addEventListener('submit', (event) => {
    event.preventDefault();
    addTarget(['lesion-x', 'lesion-y', 'lesion-z'].map((id) => Number($(id).value)), { plan: true }).catch(showError);
  });
  // the selected plan is made again at the stiffnesses a slider is released at
  $('materials').addEventListener('change', () => state.selected && planTarget(state.selected).catch(showError));
  request(performance.now());
  for (const lesion of parseLesions(new URLSearchParams(window.location.search).get('lesions'))) {
    await addTarget(lesion, { plan: true });
  }
  viewer.ready = true;
}

main().catch(showError);
