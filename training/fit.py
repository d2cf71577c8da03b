"""Fit pipeline: sweep -> PCA -> network -> ONNX -> held-out metrics -> model folder.

`fit_surrogate` is the pure part (arrays in, a fitted surrogate out) that `training fit` and the
trade-off study share; `fit` adds the files around it.

A sweep whose snapshots turn an element inside out (det(I + grad u) <= 0, the linear model's
answer to a large push) is never served as valid: `fit` trains only on the snapshots up to the
largest displacement at which every angle is valid, cuts the model's envelope there (so the
service refuses anything beyond it with its 422 envelope error) and records the cut in the
manifest (`envelope_cut`: how many snapshots were left out and why). Held-out and off-grid cases
beyond the cut are not evaluated and are counted there too.
"""

from __future__ import annotations

import logging
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts import model as folder
from contracts.model import PAPER_TEST_CASES, FitOptions, onnx_session
from contracts.scene import MeshSize

from .export import OPSET, build_graph, folded_layers, reference_decode
from .material_graph import build_material_graph, reference_decode_materials
from .materials import materials_info, sensitivity_rows, theta_rms
from .metrics import ANGLE_FLOOR_MM, REGIONS, case_errors, summarise
from .pca import Pca, fit_pca, fit_pca_with_extra
from .report import PAPER_TABLE3
from .snapshots import Snapshots, read_offgrid, read_sweep, valid_part
from .tradeoff import gci_bands

log = logging.getLogger(__name__)

__all__ = ["PAPER_TEST_CASES", "FitOptions", "Surrogate", "fit", "fit_surrogate", "summary_line", "training_set"]


def _held_out_mask(inputs: np.ndarray, cases) -> np.ndarray:
    mask = np.zeros(len(inputs), dtype=bool)
    for d, a in cases:
        hit = (np.abs(inputs[:, 0] - d) < 1e-9) & (np.abs(inputs[:, 1] - a) < 1e-9)
        if not hit.any():
            raise ValueError(f"--test-case {d}/{a}: not a snapshot of this sweep")
        mask |= hit
    return mask


def training_set(data: Snapshots, test_cases) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(held-out mask, inputs (n, 2), rows (n, 3 n_nodes)) for fitting: the snapshots not held out, as
    f = u / d. The exported graph multiplies by d (export.py), so the unloaded state d = 0 needs no row:
    it is exactly zero, and the envelope starts at 0 mm."""
    test = _held_out_mask(data.inputs, test_cases)
    kept = data.select(~test & (data.inputs[:, 0] > 0))
    rows = kept.displacement.reshape(len(kept), -1) / kept.inputs[:, :1]
    return test, kept.inputs, rows


@dataclass(frozen=True)
class Surrogate:
    """A fitted PCA + MLP: the float64 layers (scalings folded in), the basis, how training went."""

    pca: Pca
    layers: list[tuple[np.ndarray, np.ndarray]]
    input_center: np.ndarray
    input_scale: np.ndarray
    info: dict  # iterations, final_loss, seconds, seed
    pca_seconds: float
    n_materials: int = 0  # material inputs (material_graph.py); 0: the plain graph (export.py)

    def onnx_bytes(self, dtype=np.float32) -> bytes:
        if self.n_materials:
            return build_material_graph(self.layers, self.pca, self.n_materials, dtype=dtype).SerializeToString()
        return build_graph(self.layers, self.pca, dtype=dtype).SerializeToString()

    def reference(self, guide: np.ndarray, theta=None, sigma=None) -> np.ndarray:
        """The float64 numpy displacement (batch, n_nodes, 3) the graph computes (nominal materials unless theta)."""
        if self.n_materials:
            return reference_decode_materials(self.layers, self.pca, self.n_materials, guide, theta, sigma)[0]
        return reference_decode(self.layers, self.pca, guide)


def fit_surrogate(inputs: np.ndarray, rows: np.ndarray, options: FitOptions, *, sensitivity: list[np.ndarray] = (),
                  sensitivity_weights: np.ndarray | None = None, progress=None) -> Surrogate:
    """PCA of the rows (n, 3 n_nodes) to options.rank modes, then the network from inputs (n, 2) to the coefficients.

    With `sensitivity` (per material tissue S_i / d rows like `rows`), one basis holds u / d's own options.rank modes
    and options.sensitivity_rank more for what they leave of the S_i / d rows (pca.fit_pca_with_extra), and the
    network gives the coefficients of u / d and of each S_i / d side by side ((1 + m) x basis rank outputs).
    `sensitivity_weights` (per tissue, default 1) scale each S_i's part of the loss: materials.theta_rms makes it
    the mean squared error of u + sum_i theta_i S_i over the declared ranges, not of S_i per unit of theta."""
    from .network import train

    t0 = time.perf_counter()
    pca = (fit_pca_with_extra(rows, np.vstack(sensitivity), options.rank, options.sensitivity_rank)
           if len(sensitivity) else fit_pca(rows, options.rank))
    pca_seconds = time.perf_counter() - t0
    log.info("PCA rank %d captures %.8f of the variance (%.1f s)", pca.rank, pca.energy, pca_seconds)
    weights = np.ones(pca.rank * (1 + len(sensitivity)))  # per output column
    if len(sensitivity) and sensitivity_weights is not None:
        weights[pca.rank:] = np.repeat(np.asarray(sensitivity_weights, dtype=np.float64), pca.rank)
    targets = np.hstack([pca.encode(r) for r in (rows, *sensitivity)]) if len(sensitivity) else pca.encode(rows)
    net, scaling, info = train(inputs, targets * weights, width=options.width, depth=options.depth,
                               max_iterations=options.max_iterations, seed=options.seed, progress=progress)
    layers = folded_layers(net, scaling)
    w, b = layers[-1]
    layers[-1] = (w / weights, b / weights)  # the outputs back to the coefficients themselves
    return Surrogate(pca, layers, scaling.input_center, scaling.input_scale, info, pca_seconds,
                     n_materials=len(sensitivity))


def evaluate(session, inputs: np.ndarray, reference: np.ndarray) -> list[folder.CaseErrors]:
    """Errors of the ONNX model on each case (inputs (n, 2), reference (n, n_nodes, 3))."""
    rows = []
    for x, u in zip(inputs, reference):
        pred = session.run(None, {"guide": x[None].astype(np.float32)})[0][0].astype(np.float64)
        rows.append(folder.CaseErrors(displacement_mm=float(x[0]), angle_deg=float(x[1]), **case_errors(pred, u)))
    return rows


def region_errors(session, inputs: np.ndarray, reference: np.ndarray, node_sets: dict) -> dict[str, float]:
    """Largest nodal error (mm) of the ONNX model over the cases, in each region of REGIONS."""
    worst = dict.fromkeys(REGIONS, 0.0)
    for x, u in zip(inputs, reference):
        err = np.linalg.norm(session.run(None, {"guide": x[None].astype(np.float32)})[0][0] - u, axis=1)
        for name in REGIONS:
            ids = node_sets.get(name, slice(None)) if name != "all_nodes" else slice(None)
            worst[name] = max(worst[name], float(err[ids].max()))
    return worst


def fe_discretisation(path: Path, mesh) -> tuple[dict[str, float], str]:
    """Per-region GCI band (mm) of the FE on `mesh`, max over the hard cases of a convergence study
    (`python -m studies convergence-study`'s JSON), and a sentence saying what it is measured against.

    `mesh` must be the study's finest level (its GCI band) or the one before it (its distance to the
    finest plus that band: tradeoff.gci_bands)."""
    import json

    study = json.loads(Path(path).read_text())["analysis"]
    finest = {"fine": study["levels"][-1], "medium": study["levels"][-2]}
    which = [k for k, lv in finest.items() if (lv["n_tets"], lv["n_nodes"]) == (len(mesh.tets), len(mesh.nodes))]
    if not which:
        sizes = " and ".join(f"{lv['n_tets']} tets / {lv['n_nodes']} nodes" for lv in finest.values())
        raise ValueError(f"--fe-error: the sweep's mesh ({len(mesh.tets)} tets, {len(mesh.nodes)} nodes) is neither of "
                         f"{path}'s two finest levels ({sizes}): not a mesh of that study")
    bands = gci_bands(study, which[0])
    levels = ", ".join(f"{lv['n_tets']:,}" for lv in study["levels"])
    how = ("grid convergence index (Fs 1.25) of this mesh, the study's fine level," if which[0] == "fine" else
           "this mesh (the study's medium level): its distance to the fine level plus that level's grid convergence "
           "index (Fs 1.25),")
    text = (f"FE discretisation: {how} against the Richardson estimate from 3 meshes ({levels} tets, size ratio "
            f"{study['ratio']:.2f}), max over the cases {', '.join(study['cases'])}")
    return bands, text


def fe_label_map_estimate(path: Path, sweep_manifest) -> tuple[dict[str, float], str] | None:
    """The FE error of a label-map model's mesh as estimated on the default phantom's label map
    (`python -m studies labelmap-truth`'s JSON): the row with the same voxel size, mesher, CGAL facet distance, mesh
    sizes and element (solver.volumetric), as (bands per region, what it is measured against); None for a
    phantom scene or when no row matches. It covers the voxels and the mesher, not this anatomy: an estimate,
    said so."""
    import json

    source, scene = sweep_manifest.source, sweep_manifest.scene
    if source is None:
        return None
    label_map = scene.label_map
    facet = label_map.facet_distance_voxels if label_map.mesher == "cgal" else None  # None: not CGAL's
    voxel = min(source.spacing_mm)
    data = json.loads(Path(path).read_text())
    element = scene.solver.volumetric
    # a row's sizes read as the scene's (a size the study's JSON predates is at its default, surface_near_tip_mm)
    row = next((r for r in data["rows"] if abs(r["spacing_mm"] - voxel) < 1e-6 and r["mesher"] == label_map.mesher
                and r["facet_distance_voxels"] == facet and "mesh_mm" in r
                and MeshSize.model_validate(r["mesh_mm"]) == scene.mesh
                and r.get("volumetric", "pointwise") == element), None)
    if row is None:
        return None
    bands = {k: row["regions"][k]["bound_max_mm"] for k in ("markers", "prostate_surface")}
    how = f"{row['mesher']}" + (f", facets within {facet:g} voxel" if facet is not None else "")
    text = (f"FE discretisation and voxelisation: estimated, not measured on this anatomy. The default phantom, "
            f"voxelised at {voxel:g} mm, meshed as this model was ({how}; {row['tets']:,} tets) and solved with its "
            f"element ({element}) at {data['case']}, is within these bounds of the phantom's converged estimate: its "
            f"distance to the grid-convergence study's finest level ({row['finest_level_tets']:,} tets) plus that "
            "level's grid convergence index (Fs 1.25), max over the points (`python -m studies labelmap-truth`, "
            f"{Path(path).name})")
    return bands, text


def fe_through_model(path: Path, model: folder.ModelFolder) -> tuple[dict[str, float], str]:
    """The FE discretisation error of a model's mesh bounded through the model itself, from
    `python -m studies model-vs-converged`'s JSON: per region, max over the cases of |model - u_fine| + GCI of
    another element's converged estimate, plus the measured model's own surrogate error (the triangle inequality:
    its FE is within that model's surrogate error of it). The bound is the mesh's, so it holds for `model`, any
    surrogate on the same mesh, whose own surrogate error is then added for the end-to-end bound."""
    import json

    data = json.loads(Path(path).read_text())
    if data.get("kind") != "model_vs_converged":
        raise ValueError(f"--fe-error: {path} is not `python -m studies model-vs-converged`'s output")
    mesh = data.get("model_mesh", {})
    if (mesh.get("n_tets"), mesh.get("n_nodes")) != (len(model.mesh.tets), len(model.mesh.nodes)):
        raise ValueError(f"--fe-error: {path} compares a model on {mesh.get('n_tets')} tets / {mesh.get('n_nodes')} "
                         f"nodes, not this one ({len(model.mesh.tets)} / {len(model.mesh.nodes)})")
    measured = data.get("model_surrogate_mm")
    if measured is None:
        raise ValueError(f"--fe-error: {path} does not record the surrogate error of the model it measured "
                         "(model_surrogate_mm); run `python -m studies model-vs-converged` again")
    bands = {k: v + measured[k] for k, v in data["max_over_cases"].items() if k in measured}
    tets = {float(lv["scale"]): lv["n_tets"] for lv in data["levels"]}
    groups: dict[str, list[str]] = {}  # the levels a case was judged on -> those cases (older files: one set for all)
    for case, row in data["cases"].items():
        used = row.get("scales", [lv["scale"] for lv in data["levels"]])
        groups.setdefault(" / ".join(f"{tets[float(s)]:,}" for s in used), []).append(case)
    on = "; ".join(f"levels of {levels} tets for {' and '.join(cases)}" for levels, cases in groups.items())
    text = (f"FE discretisation: this model against the converged estimate of a {data['element'].replace('_', '-')} "
            "grid-convergence study (the finest level plus its grid convergence index, Fs 1.25, "
            f"point by point; {on}), max over the cases, plus the surrogate error of the model it measured "
            f"({data['provenance']['commit'][:7] if 'provenance' in data else data.get('model', '?')}), which bounds "
            f"this mesh's FE from that model's answer (`python -m studies model-vs-converged`, {Path(path).name})")
    return bands, text


def restamp(model: Path, fe_error: Path) -> folder.ModelManifest:
    """A model folder's accuracy (manifest, report.md) stamped again with another FE estimate, without
    refitting: the ONNX graph and the mesh stay as they are, byte for byte."""
    from contracts.files import atomic_write_text, sha256

    from .report import table3_markdown

    current = folder.read_model_folder(model)
    surrogate = {k: r.surrogate_mm for k, r in current.manifest.accuracy.regions.items()}
    accuracy = _accuracy(surrogate, fe_through_model(fe_error, current))
    manifest = current.manifest.model_copy(update={"accuracy": accuracy})
    atomic_write_text(Path(model) / "report.md", table3_markdown(manifest, PAPER_TABLE3))
    manifest = manifest.model_copy(update={"files": {**manifest.files, "report.md": sha256(Path(model) / "report.md")}})
    atomic_write_text(Path(model) / "manifest.json", manifest.model_dump_json(indent=2) + "\n")
    return manifest


def _accuracy(surrogate: dict[str, float], fe: tuple[dict[str, float], str] | None) -> folder.Accuracy:
    if fe is None:
        return folder.Accuracy(reference="the surrogate against the FE of its own mesh only; the FE discretisation "
                               "error of that mesh is not measured for this model", regions={
                                   k: folder.RegionAccuracy(surrogate_mm=v) for k, v in surrogate.items()})
    bands, text = fe
    return folder.Accuracy(reference=f"the converged estimate. {text}", regions={
        k: folder.RegionAccuracy(surrogate_mm=v, fe_discretisation_mm=bands.get(k),
                                 end_to_end_mm=v + bands[k] if k in bands else None)
        for k, v in surrogate.items()})


def _versions() -> dict[str, str]:
    import onnx
    import onnxruntime
    import torch

    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__}


def _metrics(session, surrogate: Surrogate, data: Snapshots, test, inputs, offgrid) -> folder.Metrics:
    table3 = evaluate(session, data.inputs[test], data.displacement[test])
    offgrid_rows = evaluate(session, *offgrid) if offgrid is not None else []
    probe = np.concatenate([data.inputs[test], inputs[[0, -1]], [[0.0, data.inputs[0, 1]]]])
    parity = float(np.abs(
        np.concatenate([session.run(None, {"guide": p[None].astype(np.float32)})[0] for p in probe])
        - surrogate.reference(probe)).max())
    return folder.Metrics(angle_floor_mm=ANGLE_FLOOR_MM, table3=table3, table3_summary=summarise(table3),
                          offgrid=offgrid_rows, offgrid_summary=summarise(offgrid_rows) if offgrid_rows else None,
                          onnx_vs_float64_max_abs_mm=parity)


def _inside_cut(envelope, cut, test_cases, offgrid):
    """(held-out cases, off-grid cases, cut) inside a cut envelope; the ones left out are counted in the cut."""
    if cut is None:
        return test_cases, offgrid, None
    kept = tuple(c for c in test_cases if envelope.contains(*c))
    if not kept:
        raise ValueError(f"--test-case: every held-out case lies beyond {cut.valid_up_to_mm:g} mm, where the sweep "
                         "stops being valid (det(I + grad u) <= 0); hold out snapshots below it")
    cut = cut.model_copy(update={"dropped_test_cases": [c for c in test_cases if c not in kept]})
    if offgrid is not None:
        inside = np.array([envelope.contains(*x) for x in offgrid[0]], dtype=bool)
        cut = cut.model_copy(update={"n_dropped_offgrid": int((~inside).sum())})
        offgrid = (offgrid[0][inside], offgrid[1][inside]) if inside.any() else None
    log.warning("%s; held-out cases not evaluated: %s", cut_line(cut), cut.dropped_test_cases or "none")
    return kept, offgrid, cut


def fit(snapshots: Path, out: Path, options: FitOptions, *, offgrid: Path | None = None,
        fe_error: Path | None = None, fe_estimate: Path | None = None, progress: bool = True) -> folder.ModelManifest:
    """Run the whole pipeline and write `out`; returns the manifest. `fe_error`: a grid-convergence
    study of the sweep's mesh; else `fe_estimate`: `python -m studies labelmap-truth`'s JSON, for a label-map sweep."""
    from tqdm import tqdm

    from .report import table3_markdown

    t_start = time.perf_counter()
    sweep = read_sweep(snapshots)
    _held_out_mask(sweep.inputs, options.test_cases)  # each asked-for case is a snapshot of the sweep, cut or not
    data, envelope, cut = valid_part(sweep)
    cases = read_offgrid(offgrid, len(sweep.mesh.nodes)) if offgrid is not None else None
    test_cases, cases, cut = _inside_cut(envelope, cut, options.test_cases, cases)
    fe = fe_discretisation(fe_error, sweep.mesh) if fe_error is not None else None
    if fe is None and fe_estimate is not None:
        fe = fe_label_map_estimate(fe_estimate, sweep.manifest)
    materials = materials_info(sweep.manifest.scene)
    test, inputs, rows = training_set(data, test_cases)
    sens_rows = sensitivity_rows(data.sensitivity, data.inputs, ~test & (data.inputs[:, 0] > 0))
    if len(rows) <= options.rank:
        where = f" up to {cut.valid_up_to_mm:g} mm, where the sweep stops being valid," if cut is not None else ""
        raise ValueError(f"--rank: {len(rows)} snapshots{where} are left to train on once {int(test.sum())} are held "
                         f"out; {options.rank} modes need at least {options.rank + 1}")
    with tqdm(total=options.max_iterations, desc="training (L-BFGS iterations)", disable=not progress,
              leave=False) as bar:
        surrogate = fit_surrogate(inputs, rows, options, sensitivity=sens_rows, progress=bar.update,
                                  sensitivity_weights=theta_rms(materials) if materials is not None else None)
    onnx_bytes = surrogate.onnx_bytes()
    session = onnx_session(onnx_bytes)
    metrics = _metrics(session, surrogate, data, test, inputs, cases)
    held_in, held_ref = data.inputs[test], data.displacement[test]
    if cases is not None:
        held_in, held_ref = np.concatenate([held_in, cases[0]]), np.concatenate([held_ref, cases[1]])
    accuracy = _accuracy(region_errors(session, held_in, held_ref, sweep.mesh.node_sets), fe)
    s2 = surrogate.pca.singular_values**2
    m = sweep.manifest
    onnx_in = {"guide": "float32 [batch, 2]", "nodes": "int64 [k], optional, empty = all"}
    onnx_out = {"displacement": "float32 [batch, k, 3] mm"}
    output = "displacement = d x decoded field (exactly 0 at rest)"
    if materials is not None:
        onnx_in.update(materials=f"float32 [batch, {surrogate.n_materials}], optional, {materials.parameter} per "
                       "tissue in materials.inputs order (0 = nominal)",
                       materials_std=f"float32 [batch, {surrogate.n_materials}], optional, the std of ln E (0 = none)")
        onnx_out["displacement_std"] = "float32 [batch, k, 3] mm, sqrt(sum_i (S_i sigma_i)^2) per component"
        output = (f"displacement = d x (f0 + sum_i theta_i s_i), f0 and s_i = S_i / d decoded by one basis (u / d's "
                  f"{surrogate.pca.n_primary} modes, then {surrogate.pca.rank - surrogate.pca.n_primary} for what they "
                  "leave of the S_i / d) from (1 + m) x basis rank network outputs; displacement_std = d x sqrt(sum_i "
                  "(sigma_i s_i)^2) (exactly 0 at rest)")
    manifest = folder.ModelManifest(
        name=Path(out).name,
        created_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        scene=folder.SceneInfo(name=m.scene_name, sha256=m.scene_sha256, spec=m.scene),
        sweep=folder.SweepInfo(n_snapshots=len(sweep.inputs), nonlinear=m.nonlinear),
        mesh=folder.MeshInfo(n_nodes=len(sweep.mesh.nodes), n_tets=len(sweep.mesh.tets),
                             n_dofs=3 * len(sweep.mesh.nodes), tissues=list(sweep.mesh.tissue_names)),
        fit=options,
        pca=folder.PcaInfo(rank=surrogate.pca.rank, energy=surrogate.pca.energy, method=pca_method(surrogate.pca),
                           n_primary=surrogate.pca.n_primary,
                           energy_by_rank=[float(v) for v in np.cumsum(s2)[:64] / s2.sum()]),
        network=folder.NetworkInfo(inputs=["displacement_mm", "angle_deg"], width=options.width, depth=options.depth,
                                   activation="tanh", optimizer="L-BFGS, variable projection", **surrogate.info,
                                   n_train=len(inputs), output=output),
        normalisation=folder.Normalisation(input_center=surrogate.input_center.tolist(),
                                           input_scale=surrogate.input_scale.tolist()),
        envelope=envelope,
        envelope_cut=cut,
        onnx=folder.OnnxInfo(opset=OPSET, inputs=onnx_in, outputs=onnx_out, basis_dtype="float32"),
        metrics=metrics,
        accuracy=accuracy,
        timing=folder.Timing(pca_seconds=surrogate.pca_seconds, train_seconds=surrogate.info["seconds"],
                             total_seconds=time.perf_counter() - t_start),
        versions=_versions(),
        source=m.source,
        materials=materials,
    )
    report = table3_markdown(manifest, PAPER_TABLE3)
    return folder.write_model_folder(out, onnx_bytes=onnx_bytes, mesh=sweep.mesh, manifest=manifest, report=report)


def pca_method(pca: Pca) -> str:
    if pca.n_primary is None:
        return "snapshots (Gram), float64"
    return (f"snapshots (Gram), float64: u / d's own {pca.n_primary} modes (energy is theirs), then "
            f"{pca.rank - pca.n_primary} modes of what they leave of the sensitivities S_i / d")


def summary_line(manifest: folder.ModelManifest) -> str:
    m = manifest.metrics
    line = (f"rank {manifest.pca.rank} (energy {manifest.pca.energy:.8f}), train {manifest.timing.train_seconds:.1f} "
            f"s; Table 3 samples: e_NN {m.table3_summary.e_nn_mm:.4f} mm, alpha {m.table3_summary.alpha_deg:.3f} deg, "
            f"e_r {m.table3_summary.e_r_percent:.3f} %")
    if m.offgrid_summary:
        line += f"; off-grid ({m.offgrid_summary.n_cases}): e_NN {m.offgrid_summary.e_nn_mm:.4f} mm"
    line += f"; onnx vs float64 {m.onnx_vs_float64_max_abs_mm:.2e} mm"
    if manifest.envelope_cut is not None:
        line += f"; {cut_line(manifest.envelope_cut)}"
    markers = manifest.accuracy.regions["markers"]
    if markers.end_to_end_mm is not None:
        line += (f"; end to end at the markers {markers.end_to_end_mm:.3f} mm (surrogate {markers.surrogate_mm:.4f} + "
                 f"FE discretisation {markers.fe_discretisation_mm:.3f})")
    return line


def cut_line(cut: folder.EnvelopeCut) -> str:
    """One sentence on an envelope cut: where, how many snapshots were left out, and why."""
    d0, d1 = cut.sweep_envelope.displacement_mm
    return (f"envelope cut to 0..{cut.valid_up_to_mm:g} mm (the sweep covers {d0:g}..{d1:g}): {cut.n_excluded} "
            f"snapshots left out, {cut.n_inverted} of them inverted (det(I + grad u) <= 0, min {cut.min_det_f:.3g})")
