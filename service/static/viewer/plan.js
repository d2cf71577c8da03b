// The needle path and the planned pose. The needle leaves the guide's tip along the guide's axis: after the push
// (d, beta) its path is the ray N(s) = T + (d + s) a(beta), s >= 0 (service/estimate/aim.py), drawn for the sliders'
// pose and, beside it, for the pose POST /plan chose for a lesion, with that lesion where the tissue carries it there.
import * as THREE from 'three';

export const GUIDE_LENGTH_MM = 12;
const NEEDLE = new THREE.LineBasicMaterial({ color: 0x9dff9d, depthTest: false });
const PLANNED_NEEDLE = new THREE.LineBasicMaterial({ color: 0x5ec8ff, depthTest: false });
const PLANNED_GUIDE = new THREE.MeshPhongMaterial({ color: 0x5ec8ff, transparent: true, opacity: 0.35, depthWrite: false });
const PLANNED_LESION = new THREE.MeshPhongMaterial({ color: 0x5ec8ff, depthTest: false });

export function direction(guide, angleDeg) {  // a(beta) = axis cos b + (n x axis) sin b
  const b = THREE.MathUtils.degToRad(angleDeg);
  const axis = new THREE.Vector3(...guide.axis);
  const side = new THREE.Vector3(...guide.tilt_normal).cross(axis);
  return axis.multiplyScalar(Math.cos(b)).addScaledVector(side, Math.sin(b));
}

// The guide's tip end as a cylinder: the body lies behind the tip, along -a(beta).
export function placeGuideBody(mesh, tip, dir) {
  mesh.position.copy(tip).addScaledVector(dir, -GUIDE_LENGTH_MM / 2);
  mesh.quaternion.setFromUnitVectors(new THREE.Vector3(0, 1, 0), dir);
}

function line(name, material) {
  const geometry = new THREE.BufferGeometry();
  geometry.setAttribute('position', new THREE.BufferAttribute(new Float32Array(6), 3));
  const out = new THREE.Line(geometry, material);
  out.name = name;
  out.renderOrder = 1;
  return out;
}

function placeLine(path, from, dir, lengthMm) {
  const at = path.geometry.attributes.position;
  at.array.set([from.x, from.y, from.z, from.x + lengthMm * dir.x, from.y + lengthMm * dir.y, from.z + lengthMm * dir.z]);
  at.needsUpdate = true;
  path.geometry.computeBoundingSphere();
}

// The sliders' needle path: from the pushed tip, lengthMm long (through the prostate and past it).
export class NeedlePath {
  constructor(scene, lengthMm) {
    this.lengthMm = lengthMm;
    this.line = line('needle-path', NEEDLE);
    scene.add(this.line);
  }

  place(tip, dir) {
    placeLine(this.line, tip, dir, this.lengthMm);
  }
}

// The planned pose of the selected lesion: the guide there, its needle path, and the lesion displaced there.
export class PlannedPose {
  constructor(scene, guideGeometry, lengthMm) {
    this.lengthMm = lengthMm;
    this.guide = new THREE.Mesh(guideGeometry, PLANNED_GUIDE);
    this.guide.name = 'planned-guide';
    this.line = line('planned-needle-path', PLANNED_NEEDLE);
    this.lesion = new THREE.Mesh(new THREE.SphereGeometry(0.7, 12, 8), PLANNED_LESION);
    this.lesion.name = 'planned-lesion';
    this.lesion.renderOrder = 2;
    this.group = new THREE.Group();
    this.group.name = 'plan';
    this.group.visible = false;
    this.group.add(this.guide, this.line, this.lesion);
    scene.add(this.group);
  }

  // reply: a POST /plan reply (needle_tip_mm, needle_direction, plan.lesion_mm)
  show(reply) {
    const tip = new THREE.Vector3(...reply.needle_tip_mm), dir = new THREE.Vector3(...reply.needle_direction);
    placeGuideBody(this.guide, tip, dir);
    placeLine(this.line, tip, dir, Math.max(this.lengthMm, reply.plan.depth_mm + 10));
    this.lesion.position.set(...reply.plan.lesion_mm);
    this.group.visible = true;
  }

  hide() {
    this.group.visible = false;
  }
}

// ?lesions=x,y,z;x,y,z (reference mm): the lesions to add and plan at start.
export function parseLesions(text) {
  if (!text) return [];
  return text.split(';').filter((s) => s.trim()).map((s) => {
    const xyz = s.split(',').map(Number);
    if (xyz.length !== 3 || !xyz.every(Number.isFinite)) throw new Error(`?lesions: "${s}" is not x,y,z in mm`);
    return xyz;
  });
}

// The plan in words, for the lesion's line in the panel.
export function describePlan(reply) {
  const p = reply.plan;
  const pose = `d ${p.displacement_mm.toFixed(2)} mm, β ${p.angle_deg.toFixed(2)}°`;
  const miss = `miss ${p.miss_mm.toFixed(2)} mm (1σ ${reply.miss_std_mm.toFixed(2)}; naive aim ${reply.naive.miss_mm.toFixed(2)})`;
  return reply.reachable ? `plan ${pose}, ${miss}` : `unreachable: closest ${pose}, ${miss}`;
}
