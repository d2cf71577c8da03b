"""The one-command build: scene -> mesh + sweep -> off-grid cases -> fit -> model folder.

Each step is fem_offline's or training's own, and each resumes: the sweep skips finished snapshots,
the cases skip finished files, and the fit writes the model folder by rename. Re-running the same
command after an interruption continues where it stopped. This package calls both stages; neither
stage imports it (data flows one way).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.model import PAPER_TEST_CASES, FitOptions, ModelManifest

log = logging.getLogger(__name__)


# The label-map FE error estimates (`python -m studies labelmap-truth`): the model's manifest states the row of
# its voxel size and mesher as its FE error, an estimate said to be one; none where no row matches. Package data,
# a copy of docs/results/labelmap_truth.json (tests/pipeline/test_package_data.py checks that the two agree), so an
# installed pipeline does not read the docs folder.
FE_ESTIMATE = Path(__file__).resolve().parent / "data" / "labelmap_fe_error.json"


@dataclass(frozen=True)
class BuildOptions:
    offgrid_cases: int = 8  # held-out FE solves at random (d, beta) inside the envelope
    seed: int = 0
    rank: int = 32
    # 1 x 30 hidden: on the patient sweep's 6 angles (4 deg) 1 x 60 misses the angles between them by
    # 0.11 mm at the markers, 1 x 30 by 0.005 (docs/results/sweep_density_patient.json)
    width: int = 30
    workers: int = 2
    fe_estimate: Path | None = FE_ESTIMATE


def held_out_cases(displacements_mm, angles_deg) -> tuple[tuple[float, float], ...]:
    """The grid point nearest each of the paper's five Table 3 samples (distinct, never the largest push)."""
    d = np.asarray(displacements_mm[:-1] if len(displacements_mm) > 1 else displacements_mm)
    b = np.asarray(angles_deg)
    picks = []
    for d0, b0 in PAPER_TEST_CASES:
        case = (float(d[np.abs(d - d0).argmin()]), float(b[np.abs(b - b0).argmin()]))
        if case not in picks:
            picks.append(case)
    return tuple(picks)


def _valid_part(scene, manifest, say):
    """(scene, grid displacements) that the model will answer for: all of them, or, when the sweep
    inverts elements (training fits only up to its valid_up_to_mm), those up to it, with the
    scene's sweep cut there so the off-grid cases are drawn inside the model's envelope."""
    v = manifest.validity
    if not v.n_inverted:
        return scene, manifest.grid.displacements_mm
    valid = [d for d in manifest.grid.displacements_mm if d <= v.valid_up_to_mm]
    if not valid:
        raise RuntimeError(f"sweep: its first displacement already turns an element inside out "
                           f"(det(I + grad u) <= 0, {v.n_inverted} snapshots): nothing valid to fit")
    say(f"      {v.n_inverted} snapshots turn an element inside out: the model answers up to {valid[-1]:g} mm")
    cut = scene.sweep.model_copy(update={"displacement_max_mm": valid[-1]})
    return scene.model_copy(update={"sweep": cut}), valid


def build(scene_path: str | Path, out: str | Path, *, work: str | Path | None = None,
          options: BuildOptions = BuildOptions(), say=print) -> ModelManifest:
    """Run every step for the scene file and write the model folder `out`; `work` holds the sweep and cases."""
    from contracts.mesh import read_mesh
    from fem_offline.cases import mesh_for_cases, solve_cases
    from fem_offline.scene import load_scene
    from fem_offline.sweep import run_sweep
    from training.fit import fit, summary_line

    out = Path(out)
    work = Path(work) if work is not None else Path("runs") / out.name
    scene = load_scene(scene_path)
    t0 = time.perf_counter()
    say(f"[1/3] mesh + sweep of {scene.name} into {work / 'sweep'}")
    manifest = run_sweep(scene, work / "sweep", workers=options.workers)
    if manifest.errors:
        raise RuntimeError(f"sweep: {len(manifest.errors)} paths failed, first: {manifest.errors[0]}")
    say(f"      {manifest.n_tets} tets, {manifest.n_nodes} nodes, {manifest.n_done} snapshots "
        f"({'nonlinear' if manifest.nonlinear else 'linear'}), {time.perf_counter() - t0:.0f} s so far")
    scene, displacements = _valid_part(scene, manifest, say)
    say(f"[2/3] {options.offgrid_cases} off-grid cases into {work / 'offgrid'}")
    mesh_path = mesh_for_cases(read_mesh(work / "sweep" / "mesh.npz"), work / "offgrid")
    failures = solve_cases(scene, mesh_path, work / "offgrid", options.offgrid_cases, options.seed,
                           workers=options.workers,
                           sweep=work / "sweep")  # each case starts from the sweep's fields around it
    if failures:
        raise RuntimeError(f"off-grid cases: {len(failures)} failed, first: {failures[0]}")
    say(f"[3/3] fit into {out}")
    test_cases = held_out_cases(displacements, manifest.grid.angles_deg)
    n_train = sum(r.displacement_mm in displacements for r in manifest.snapshots) - len(test_cases)
    if n_train < 2:
        raise RuntimeError(f"sweep: {n_train} snapshot(s) up to {displacements[-1]:g} mm are left to train on once the "
                           f"{len(test_cases)} Table 3 cases are held out; a fit needs 2: sweep finer steps below the "
                           "inversion (sweep.displacement_step_mm) or more angles")
    fit_options = FitOptions(rank=min(options.rank, max(n_train - 1, 1)), width=options.width, seed=options.seed,
                             test_cases=test_cases)
    estimate = options.fe_estimate if options.fe_estimate is not None and Path(options.fe_estimate).exists() else None
    model = fit(work / "sweep", out, fit_options, offgrid=work / "offgrid", fe_estimate=estimate)
    say(f"{out}: {summary_line(model)}; whole build {time.perf_counter() - t0:.0f} s")
    return model
