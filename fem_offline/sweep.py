"""Snapshot sweep over guide displacement x angle: resumable, atomic, on a process pool or Dask.

The output folder's format is contracts.sweep (manifest.json, mesh.npz, snapshots/*.npz).
Each nonlinear (or contact) angle is one path, warm-started from one displacement to the next. A path that was
interrupted resumes from its last written snapshot; finished snapshots are never recomputed, and a
folder of another scene is refused.
On a mirror-symmetric scene (mirror.py) only the paths with beta >= 0 are solved; each beta < 0
snapshot is the reflection of its beta > 0 twin (marked `mirrored_from` in the file).
A linear sweep writes every snapshot by superposition, inverted ones included (the manifest's
`validity` lists those with det(I + grad u) <= 0 and the displacement up to which all angles are valid).

Every snapshot records min det F three times: at the solver's 4 quadrature points per tet (`min_det_f`,
which Newton keeps > 0 on a nonlinear path), at the 11 points per tet of the degree-4 rule
(`min_det_f_probe`, validity.probe), where a P2 field can invert between the solver's points, and
over every point of every tet (`min_det_f_bound`, validity.det_f_bound: > 0 proves it a deformation,
<= 0 is det F at a point where it is not). Any <= 0 counts as inverted.

What the probe adds on the default mesh (9,030 tets; `python -m bench fem --mesh
runs/default_contact/mesh.npz --steps 1`, run twice, the 2 cores shared with another FE job): its
basis, once per process, 0.08 s; per nonlinear snapshot one det F at 11 points, 23 ms (the contact
sweep's snapshots take a median 12 s: 0.2 %); per linear snapshot, det F's cubic in d evaluated at
the 11 points too, 1.5 ms more (the 4 points' take 0.55 ms): 1.3 s per 840-case linear sweep.
Memory: the probe's basis gradients, 11 x 10 x 3 float64 per tet (24 MB here, 0.6 GB at paper scale).
"""

from __future__ import annotations

import json
import logging
import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from multiprocessing import get_context
from pathlib import Path

import numpy as np

from contracts import sweep as folder
from contracts.files import atomic_savez, sha256
from contracts.materials import SENSITIVITY_PREFIX, sensitivity_key
from contracts.mesh import TetMesh, read_mesh

from fem_offline.fe.continuation import PathState, solve_path
from fem_offline.fe.guide import is_mirrored
from fem_offline.labelmap.io import source_of
from fem_offline.fe.linear import LinearModes, linear_modes, min_det_f, superpose
from fem_offline.geometry.meshing import kept_mesh
from fem_offline.geometry.mirror import mirror_map, reflect
from fem_offline.fe.newton import ConvergenceError, Stats
from fem_offline.fe.problem import Problem, build_problem
from fem_offline.fe.sensitivity import Stiffened, sensitivities, stiffened
from fem_offline.scene import Scene, SceneError, parse_scene
from fem_offline.fe.validity import DetFCheck, corners, min_det_f_bound, probe

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Case:
    angle_index: int
    displacement_index: int
    angle_deg: float
    displacement_mm: float

    @property
    def file(self) -> str:
        """Path inside the sweep folder."""
        return folder.snapshot_file(self.angle_index, self.displacement_index)


def grid(scene: Scene) -> list[list[Case]]:
    """Cases grouped by angle (one path each), displacements increasing."""
    sw = scene.sweep
    return [
        [Case(i, j, float(b), float(d)) for j, d in enumerate(sw.displacements_mm)]
        for i, b in enumerate(sw.angles_deg)
    ]


def write_snapshot(out: Path, case: Case, displacement: np.ndarray, stats: Stats, *, between: dict[str, float],
                   sensitivity: dict[str, np.ndarray] | None = None) -> None:
    """One snapshot: the solver's record, det F between its points (validity.DetFCheck; contracts.sweep) and,
    for a scene with [materials], S_i = du/d ln E_i per material tissue (contracts.materials.sensitivity_key)."""
    extra = {sensitivity_key(name): s for name, s in (sensitivity or {}).items()}
    folder.write_case(out / case.file, displacement, displacement_mm=case.displacement_mm, angle_deg=case.angle_deg,
                      record=folder.CaseRecord(**stats.record(), **between), **extra)


def prepare(scene: Scene, out: Path) -> TetMesh:
    """Create the output folder and its mesh, or check that it belongs to this scene (resume)."""
    out.mkdir(parents=True, exist_ok=True)
    if (out / folder.MANIFEST).exists():
        old = folder.read_manifest(out)
        if old.scene_sha256 != scene.sha256():
            raise SceneError(f"{out} holds a sweep of another scene (sha256 {old.scene_sha256[:12]}); use a new --out")
        if old.source is not None and old.source.sha256 != sha256(scene.label_map.path):
            raise SceneError(f"{out} holds a sweep of another label map (sha256 {old.source.sha256[:12]}); "
                             "use a new --out")
        if old.validity is None and not old.nonlinear and old.snapshots:
            raise SceneError(f"{out} holds linear snapshots written before det(I + grad u) was checked; "
                             "use a new --out")
    return kept_mesh(scene, out / folder.MESH_FILE)


@lru_cache(maxsize=2)
def _problem(scene_json: str, mesh_path: str):
    """Per-process cache: workers build the problem once and reuse it for every path they get."""
    scene = parse_scene(json.loads(scene_json))
    return build_problem(scene, read_mesh(mesh_path))


@lru_cache(maxsize=2)
def _check(scene_json: str, mesh_path: str) -> DetFCheck:
    """The worker's det F check (validity.DetFCheck), built once per process like _problem."""
    return DetFCheck.of(_problem(scene_json, mesh_path))


@lru_cache(maxsize=2)
def _stiffened(scene_json: str, mesh_path: str) -> Stiffened | None:
    """The worker's doubled-E problems of the scene's material tissues (fe.sensitivity), or None without [materials]."""
    problem = _problem(scene_json, mesh_path)
    materials = problem.scene.materials
    return stiffened(problem, tuple(materials)) if materials else None


def path_sensitivities(models: Stiffened | None, problem: Problem, case: Case, state: PathState) -> dict | None:
    """S_i (n_nodes, 3) per material tissue at a converged path state (its contact multipliers included)."""
    if models is None:
        return None
    loaded = problem.at_guide(case.displacement_mm, case.angle_deg, state.multipliers)
    return sensitivities(models, loaded, state.u)


def _resume_state(out: Path, path: list[Case]) -> tuple[PathState | None, list[Case]]:
    """Start after the last contiguous finished snapshot of the path, warm from its displacement."""
    done = 0
    while done < len(path) and (out / path[done].file).exists():
        done += 1
    if done == 0:
        return None, path

    def load(case: Case) -> np.ndarray:
        with np.load(out / case.file) as z:
            return z["displacement"].ravel()

    history = tuple((c.displacement_mm, load(c)) for c in path[max(0, done - 3) : done - 1])
    state = PathState(load(path[done - 1]), path[done - 1].displacement_mm, history)
    return state, path[done:]


def run_path(scene_json: str, out: str, path: list[Case], sensitivity_every: int = 1) -> dict:
    """Solve the pending cases of one angle, writing each snapshot as soon as it converges; with [materials], S_i
    at every `sensitivity_every`-th displacement counted from the first (a design's gradients need fewer)."""
    out = Path(out)
    problem = _problem(scene_json, str(out / folder.MESH_FILE))
    check = _check(scene_json, str(out / folder.MESH_FILE))
    models = _stiffened(scene_json, str(out / folder.MESH_FILE))
    state, todo = _resume_state(out, path)
    if not todo:
        return {"written": 0}
    written, parent = 0, os.getppid()
    try:
        steps = solve_path(problem, [c.displacement_mm for c in todo], todo[0].angle_deg, state, with_state=True)
        for case, (_, u, stats, reached) in zip(todo, steps):
            with_s = models if (case.displacement_index + 1) % sensitivity_every == 0 else None
            write_snapshot(out, case, u, stats, between=check(u),
                           sensitivity=path_sensitivities(with_s, problem, case, reached))
            written += 1
            if os.getppid() != parent:  # the sweep was killed: stop after this (saved) snapshot
                return {"written": written, "error": "sweep process ended"}
    except ConvergenceError as exc:
        failed = todo[written]
        return {"written": written, "error": f"angle {failed.angle_deg:g} deg, {failed.displacement_mm:g} mm: {exc}"}
    return {"written": written}


def _write_linear(scene: Scene, mesh: TetMesh, out: Path, pending: list[Case], progress) -> None:
    """Linear model: one factorisation, two unit solves, every snapshot by superposition.

    Each snapshot records its true min det(I + grad u) over the assembled tets' quadrature points
    and over the probe points, one cubic in d per angle for each (linear.min_det_f on the problem and
    on validity.probe of it), and its bound everywhere (validity.min_det_f_bound). An inverted snapshot
    (any <= 0) is written all the same: it is the linear model's answer, and the manifest's `validity`
    lists it.
    """
    t0 = time.perf_counter()
    problem = build_problem(scene, mesh)
    probed, at_corners, modes = probe(problem), corners(problem), linear_modes(problem)
    det = {}  # case -> (min det F at the solver's points, at the probe points)
    for angle in sorted({c.angle_deg for c in pending}):
        cases = [c for c in pending if c.angle_deg == angle]
        d = [c.displacement_mm for c in cases]
        det.update(zip(cases, zip(min_det_f(problem, modes, d, angle), min_det_f(probed, modes, d, angle))))
    sens_modes = linear_sensitivity_modes(problem, modes)
    per = (time.perf_counter() - t0) / max(len(pending), 1)
    for case in pending:
        u = superpose(modes, case.displacement_mm, case.angle_deg)
        at_qp, at_probe = det[case]
        sens = {n: superpose(m, case.displacement_mm, case.angle_deg) for n, m in sens_modes.items()}
        write_snapshot(out, case, u, Stats(iterations=1, seconds=per, min_det_f=float(at_qp)),
                       between={"min_det_f_probe": float(at_probe), "min_det_f_bound": min_det_f_bound(at_corners, u)},
                       sensitivity=sens or None)
        progress.update(1)


def linear_sensitivity_modes(problem: Problem, modes: LinearModes) -> dict[str, LinearModes]:
    """Per material tissue, S_i of the three linear fields: S_i is linear in u for the linear model (K S_i =
    -f_i(u), f_i linear in u), so S_i(d, beta) superposes like u (linear.superpose). {} without [materials]."""
    materials = problem.scene.materials
    if not materials:
        return {}
    models = stiffened(problem, tuple(materials))
    per_field = [sensitivities(models, problem, field) for field in modes]  # u0, u_axis, u_perp
    return {n: LinearModes(*(s[n].ravel() for s in per_field)) for n in materials}


def _mirror_pairs(scene: Scene, mesh: TetMesh, paths: list[list[Case]]):
    """(node mirror map, {negative-angle path index: its positive twin's index}), or (None, {})."""
    if not is_mirrored(scene.guide):
        return None, {}
    angles = [p[0].angle_deg for p in paths]
    twins = {i: angles.index(-a) for i, a in enumerate(angles) if a < 0 and -a in angles}
    if not twins:
        return None, {}
    image = mirror_map(mesh)
    return (image, twins) if image is not None else (None, {})


def _write_mirrored(out: Path, paths, twins: dict[int, int], image: np.ndarray) -> int:
    """Reflect every finished beta > 0 snapshot into its missing beta < 0 twin."""
    written = 0
    for neg, pos in twins.items():
        for case, src in zip(paths[neg], paths[pos]):
            target, source = out / case.file, out / src.file
            if target.exists() or not source.exists():
                continue
            with np.load(source) as z:
                extra = {k: reflect(z[k], image) if k.startswith(SENSITIVITY_PREFIX) else z[k]  # S mirrors as u
                         for k in z.files if k not in ("displacement", "angle_deg", "displacement_mm")}
                atomic_savez(target, displacement=reflect(z["displacement"], image),
                             displacement_mm=case.displacement_mm,
                             angle_deg=case.angle_deg, mirrored_from=src.file, **extra)
            written += 1
    return written


def _count(out: Path) -> int:
    snapshots = out / folder.SNAPSHOTS
    return sum(1 for _ in snapshots.glob("a*_d*.npz")) if snapshots.exists() else 0


def single_threaded_pool(workers: int) -> ProcessPoolExecutor:
    """A spawned process pool whose workers run MKL/OpenMP on one thread each (one core per job)."""
    saved = {k: os.environ.get(k) for k in ("MKL_NUM_THREADS", "OMP_NUM_THREADS")}
    os.environ.update(MKL_NUM_THREADS="1", OMP_NUM_THREADS="1")  # inherited by the spawned workers
    try:
        return ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"))
    finally:
        for k, v in saved.items():
            os.environ.pop(k) if v is None else os.environ.__setitem__(k, v)


def run_jobs(jobs, *, workers: int, scheduler: str | None, progress, sensitivity_every: int = 1,
             on_path_done=lambda out: None) -> dict[str, list[str]]:
    """Solve the pending paths of every (scene, folder, paths) job on one local process pool or a Dask cluster,
    reflecting each mirrored folder's beta > 0 paths into their beta < 0 twins as each path finishes, then calling
    `on_path_done(str(folder))` (a caller rewrites the folder's manifest there, so a run that is stopped leaves usable
    folders); progress from the files written. Returns each folder's errors (paths that stopped) by str(folder)."""
    submitted, mirrors = [], {}
    for scene, out, paths in jobs:
        out = Path(out)
        image, twins = _mirror_pairs(scene, read_mesh(out / folder.MESH_FILE), paths)
        # a beta < 0 path is solved only if its twin is not; otherwise it is reflected
        pending = [p for i, p in enumerate(paths) if i not in twins and not all((out / c.file).exists() for c in p)]
        submitted += [(scene.model_dump_json(), str(out), p, sensitivity_every) for p in pending]
        if twins:
            mirrors[str(out)] = (out, paths, twins, image)
    mirror = lambda out: _write_mirrored(*mirrors[out]) if out in mirrors else 0  # noqa: E731
    for out in mirrors:  # what an earlier run finished
        if written := mirror(out):
            progress.update(written)
            on_path_done(out)
    errors: dict[str, list[str]] = {str(Path(out)): [] for _, out, _ in jobs}
    if submitted:
        stops = _run_pool(submitted, workers, scheduler, progress, [Path(o) for _, o, _ in jobs],
                          on_done=lambda job: (mirror(job[1]), on_path_done(job[1])))
        for out, error in stops:
            errors[out].append(error)
    for out in mirrors:  # what a stopped path wrote
        progress.update(mirror(out))
    return errors


def _run_pool(submitted, workers: int, scheduler: str | None, progress, folders: list[Path],
              on_done=lambda job: None) -> list[tuple[str, str]]:
    """Run (scene_json, folder, path) on a local process pool or a Dask cluster, calling `on_done(job)` as each
    ends; (folder, error) of each stop."""
    if scheduler:
        from distributed import Client

        client = Client(scheduler)
        futures = [client.submit(run_path, *job, pure=False) for job in submitted]
        results = lambda: client.gather(futures)  # noqa: E731
        closer = client.close
    else:
        pool = single_threaded_pool(workers)
        futures = [pool.submit(run_path, *job) for job in submitted]
        results = lambda: [f.result() for f in futures]  # noqa: E731
        closer = pool.shutdown
    count = lambda: sum(_count(f) for f in folders)  # noqa: E731
    start, base, ended = count(), progress.n, set()  # the bar counts on from where it stands
    try:
        while len(ended) < len(futures):
            time.sleep(0.5)
            for i, f in enumerate(futures):
                if i not in ended and f.done():
                    ended.add(i)
                    on_done(submitted[i])
            progress.update(base + count() - start - progress.n)
        return [(job[1], r["error"]) for job, r in zip(submitted, results()) if "error" in r]
    finally:
        progress.update(base + count() - start - progress.n)
        closer()


def run_sweep(scene: Scene, out: str | Path, *, workers: int = 2, scheduler: str | None = None) -> folder.SweepManifest:
    """Solve every case of the scene's grid that is not on disk yet; return the manifest."""
    from tqdm import tqdm

    out = Path(out)
    mesh = prepare(scene, out)
    paths = grid(scene)
    write_manifest(scene, mesh, out, paths, seconds=0.0, errors=[])  # claims the folder for this scene at once
    total = sum(len(p) for p in paths)
    pending = [[c for c in p if not (out / c.file).exists()] for p in paths]
    n_pending = sum(len(p) for p in pending)
    t0 = time.perf_counter()
    errors: list[str] = []
    with tqdm(total=total, initial=total - n_pending, unit="snap", desc=scene.name) as progress:
        superposable = not (scene.effects.geometric_nonlinearity or scene.effects.guide_contact)
        if superposable and n_pending:
            _write_linear(scene, mesh, out, [c for p in pending for c in p], progress)
        elif n_pending:  # one path per angle: nonlinear, or linear with the guide in contact
            errors = run_jobs([(scene, out, paths)], workers=workers, scheduler=scheduler, progress=progress)[str(out)]
    return write_manifest(scene, mesh, out, paths, seconds=time.perf_counter() - t0, errors=errors)


def write_manifest(scene: Scene, mesh: TetMesh, out: Path, paths, *, seconds: float,
                   errors: list[str]) -> folder.SweepManifest:
    """Describe the folder as it is on disk: one record (with sha256) per finished snapshot."""
    rows = [folder.snapshot_record(out, c.file) for p in paths for c in p if (out / c.file).exists()]
    grid_ = folder.Grid(displacements_mm=scene.sweep.displacements_mm.tolist(),
                        angles_deg=scene.sweep.angles_deg.tolist())
    manifest = folder.SweepManifest(
        scene_name=scene.name, scene_sha256=scene.sha256(), scene=scene.model_dump(mode="json"),
        mesh_sha256=sha256(out / folder.MESH_FILE), n_nodes=len(mesh.nodes), n_tets=len(mesh.tets),
        nonlinear=scene.effects.geometric_nonlinearity, grid=grid_, envelope=grid_.envelope,
        n_expected=sum(len(p) for p in paths), n_done=len(rows),
        n_mirrored=sum(r.mirrored_from is not None for r in rows),
        wall_seconds_this_run=seconds, errors=errors, snapshots=rows,
        source=source_of(scene.label_map) if scene.label_map is not None else None,
        validity=folder.validity_of(grid_, rows), materials=list(scene.materials or {}))
    folder.write_manifest(out, manifest)
    return manifest
