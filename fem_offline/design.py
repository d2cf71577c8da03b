"""Material design: paths over the guide push at space-filling points in (beta, stiffness ratios), resumable.

A scene with [materials] is answered over a box of log-stiffnesses theta_i = ln(E_i / E_i,nominal), judged by
ratios (contracts.materials). A grid over the box is out of reach (4 tissues x 21 angles), and a model that is
first order in theta is not right over a box this wide, so the design draws points

    (beta_k, theta_k),  k = 0 .. n - 1,   a scrambled Sobol sequence over [0, beta_max] x the box,

each theta_k moved to the box's point with its ratios nearest the nominal (contracts.materials.ratio_point: the
point the service feeds the graph), and solves one path from rest to the largest push at each. The scene is
mirror-symmetric, so the path at -beta_k is the reflection of the one at beta_k (sweep._write_mirrored): each
point gives two paths. With `sensitivities`, every snapshot also holds S_i = du/d ln E_i at its own theta_k (the
gradient a Sobolev fit uses) at every `sensitivity_every`-th displacement (they cost about as much as the
solve each; the gradients vary slowly with the push); without, the design is a held-out set (`--held-out`: the box's
corners first).

Layout: `design.json` (the points and what drew them), and one sweep folder per point (`p000/`, contracts.sweep:
manifest, mesh.npz, snapshots), each the scene with E_i x exp(theta_ik) and the angles (-beta_k, beta_k). Every
folder shares the one mesh (`mesh.npz` at the top, copied), so every snapshot has the same nodes. A path
that stops (no equilibrium) keeps what it wrote and is listed; the next run resumes every unfinished path.
"""

from __future__ import annotations

import itertools
import json
import shutil
import time
from pathlib import Path

import numpy as np
from contracts import sweep as folder
from contracts.design import DESIGN_FILE, Design, DesignPoint
from contracts.materials import ratio_point
from contracts.mesh import TetMesh, read_mesh, write_mesh

from fem_offline.material_cases import scaled_scene
from fem_offline.scene import Scene, SceneError
from fem_offline.sweep import grid, prepare, run_jobs, write_manifest

def log_box(scene: Scene) -> dict[str, tuple[float, float]]:
    """Each material tissue's range as theta = ln(E / E_nominal)."""
    if not scene.materials:
        raise SceneError("--scene: the scene has no [materials]; a material design needs a box to fill")
    return {t: (float(np.log(m.youngs_kpa_range[0] / scene.tissues[t].youngs)),
                float(np.log(m.youngs_kpa_range[1] / scene.tissues[t].youngs))) for t, m in scene.materials.items()}


def _canonical(theta: np.ndarray, box: dict[str, tuple[float, float]]) -> np.ndarray:
    """Every row moved to the box's point with its ratios nearest the nominal (what the service feeds the graph)."""
    lo, hi, tissues = [b[0] for b in box.values()], [b[1] for b in box.values()], list(box)
    return np.array([ratio_point(row, lo, hi, tissues) for row in theta])


def sobol_points(n: int, box: dict[str, tuple[float, float]], angle_max_deg: float, seed: int) -> np.ndarray:
    """(n, 1 + m): beta and theta from a scrambled Sobol sequence over [0, angle_max] x the box (n a power of 2
    keeps the sequence balanced; any n works)."""
    from scipy.stats import qmc

    lo = np.array([0.0] + [b[0] for b in box.values()])
    hi = np.array([angle_max_deg] + [b[1] for b in box.values()])
    u = qmc.Sobol(d=len(lo), scramble=True, seed=seed).random(n)
    x = lo + (hi - lo) * u
    x[:, 1:] = _canonical(x[:, 1:], box)
    return x


def held_out_points(n: int, box: dict[str, tuple[float, float]], angle_deg: float, seed: int) -> np.ndarray:
    """(n, 1 + m): every corner of the box at `angle_deg` (2^m of them; all-lower and all-upper have the nominal's
    ratios too, but not its stiffness against the fixed bones' contact), then Sobol points of the box until n."""
    corners = np.array(list(itertools.product(*box.values())))
    rest = max(n - len(corners), 0)
    inner = sobol_points(rest, box, angle_deg, seed)[:, 1:] if rest else np.empty((0, len(box)))
    theta = np.vstack([_canonical(corners, box), inner])[:n]
    return np.column_stack([np.full(len(theta), angle_deg), theta])


def design_scene(scene: Scene, point: DesignPoint, *, sensitivities: bool, step_mm: float | None = None) -> Scene:
    """The scene at the point's stiffnesses, swept at (-beta, beta) (one angle at beta 0) in pushes of `step_mm`
    (default: the scene's); with `sensitivities` it keeps [materials], so every snapshot holds S_i at this point."""
    tissues = tuple(point.theta)
    at = scaled_scene(scene, tissues, np.array([point.theta[t] for t in tissues]))
    b = point.angle_deg
    sweep = at.sweep.model_copy(update={"angle_min_deg": -b, "angle_max_deg": b,
                                        "angle_step_deg": 2 * b if b > 0 else 1.0,
                                        "displacement_step_mm": step_mm or at.sweep.displacement_step_mm})
    materials = None
    if sensitivities:  # the ranges as the base scene's, widened to hold a corner's E that rounding put just outside
        materials = {t: m.model_copy(update={"youngs_kpa_range": (min(m.youngs_kpa_range[0], at.tissues[t].youngs),
                                                                  max(m.youngs_kpa_range[1], at.tissues[t].youngs))})
                     for t, m in scene.materials.items()}
    return at.model_copy(update={"sweep": sweep, "materials": materials})


def make_design(scene: Scene, *, n: int, seed: int, sensitivities: bool, held_out: bool,
                sensitivity_every: int = 4, step_mm: float | None = None) -> Design:
    if step_mm is not None:
        top = scene.sweep.displacement_max_mm
        if not 0 < step_mm <= top or abs(top / step_mm - round(top / step_mm)) > 1e-9:
            raise SceneError(f"--push-step: {step_mm:g} mm does not divide the largest push {top:g} mm")
    box = log_box(scene)
    beta_max = float(max(abs(scene.sweep.angle_min_deg), abs(scene.sweep.angle_max_deg)))
    rows = held_out_points(n, box, beta_max, seed) if held_out else sobol_points(n, box, beta_max, seed)
    points = [DesignPoint(folder=f"p{k:03d}", angle_deg=round(float(r[0]), 6),
                          theta={t: round(float(v), 9) for t, v in zip(box, r[1:])}) for k, r in enumerate(rows)]
    return Design(scene_name=scene.name, scene_sha256=scene.sha256(), kind="held_out" if held_out else "sobol",
                  seed=seed, sensitivities=sensitivities, sensitivity_every=sensitivity_every, angle_max_deg=beta_max,
                  tissues=list(box), log_box=box, points=points, scene=scene.model_dump(mode="json"),
                  displacement_step_mm=step_mm)


def open_design(scene: Scene, out: Path, design: Design) -> Design:
    """Write design.json, or check that `out` holds this very design (resume); return the design on disk."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / DESIGN_FILE
    if path.exists():
        old = Design.model_validate_json(path.read_text())
        if old.scene_sha256 != scene.sha256():
            raise SceneError(f"{out} holds a design of another scene (sha256 {old.scene_sha256[:12]}); use a new --out")
        if old.model_copy(update={"scene": design.scene}) != design:
            raise SceneError(f"{out} holds another design ({old.kind}, {len(old.points)} points, seed {old.seed}, "
                             f"sensitivities {old.sensitivities}); use a new --out or the same options")
        if old.scene is None:  # written before the base scene was recorded: record it
            path.write_text(design.model_dump_json(indent=1) + "\n")
        return design
    path.write_text(design.model_dump_json(indent=1) + "\n")
    return design


def _shared_mesh(scene: Scene, out: Path, mesh: Path | None) -> TetMesh:
    """The design's one mesh at out/mesh.npz: `mesh` copied there, else the scene meshed once."""
    from fem_offline.geometry.meshing import kept_mesh

    target = out / folder.MESH_FILE
    if mesh is not None and not target.exists():
        write_mesh(target, read_mesh(mesh))
    return kept_mesh(scene, target)


def run_design(scene: Scene, out: str | Path, *, n: int = 64, seed: int = 0, sensitivities: bool = True,
               sensitivity_every: int = 4, held_out: bool = False, mesh: Path | None = None, workers: int = 2,
               scheduler: str | None = None, step_mm: float | None = None) -> dict:
    """Solve every point of the design not finished in `out`; return a summary (points done, paths stopped,
    seconds, snapshots)."""
    from tqdm import tqdm

    out = Path(out)
    design = open_design(scene, out, make_design(scene, n=n, seed=seed, sensitivities=sensitivities,
                                                     held_out=held_out, sensitivity_every=sensitivity_every,
                                                     step_mm=step_mm))
    _shared_mesh(scene, out, mesh)
    jobs, folders = [], []
    for point in design.points:
        sub = out / point.folder
        if not (sub / folder.MESH_FILE).exists():
            sub.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(out / folder.MESH_FILE, sub / folder.MESH_FILE)
        at = design_scene(scene, point, sensitivities=design.sensitivities, step_mm=design.displacement_step_mm)
        point_mesh = prepare(at, sub)
        paths = grid(at)
        write_manifest(at, point_mesh, sub, paths, seconds=0.0, errors=[])
        folders.append((at, point_mesh, sub, paths))
        jobs.append((at, sub, paths))
    total = sum(len(p) for _, _, paths in jobs for p in paths)
    done = sum((sub / c.file).exists() for _, sub, paths in jobs for p in paths for c in p)
    t0 = time.perf_counter()
    by_folder = {str(sub): (at, point_mesh, sub, paths) for at, point_mesh, sub, paths in folders}

    def path_done(sub: str) -> None:  # the point's manifest lists what is on disk now: a stopped run loses nothing
        at, point_mesh, sub_, paths = by_folder[sub]
        write_manifest(at, point_mesh, sub_, paths, seconds=time.perf_counter() - t0, errors=[])

    with tqdm(total=total, initial=done, unit="snap", desc=f"design {out.name}") as progress:
        errors = run_jobs(jobs, workers=workers, scheduler=scheduler, progress=progress,
                          sensitivity_every=design.sensitivity_every, on_path_done=path_done)
    seconds = time.perf_counter() - t0
    for at, point_mesh, sub, paths in folders:
        write_manifest(at, point_mesh, sub, paths, seconds=seconds, errors=errors.get(str(sub), []))
    finished = [p.folder for p, (_, _, sub, paths) in zip(design.points, folders)
                if all((sub / c.file).exists() for path in paths for c in path)]
    summary = {"points": len(design.points), "finished": len(finished), "seconds": seconds,
               "snapshots": sum((sub / c.file).exists() for _, _, sub, paths in folders for p in paths for c in p),
               "expected": total, "stopped": {k: v for k, v in errors.items() if v}}
    (out / "run.json").write_text(json.dumps(summary, indent=1) + "\n")
    return summary
