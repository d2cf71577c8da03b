"""Fit a design model: a material design (contracts.design) -> PCA + a Sobolev-fitted network -> one ONNX graph.

`python -m training fit-design --design DIR --out models/NAME [--held-out DIR]`. The model answers
u(d, beta, theta) over the design's box (not first order around the nominal): the network takes (d, beta, theta),
its coefficients decode u / d, and its own Jacobian in theta decodes the S_i / d that give the std (sobolev.py,
material_graph.py with jacobian=True). The graph's inputs and outputs are a material model's, so the service serves
it unchanged.

The basis: u / d's own `rank` modes, then `sensitivity_rank` modes of what they leave of the S_i / d rows (S_i are
derivatives, so no mean is taken from them). Accuracy is measured against a held-out design (`fem_offline design
--held-out`: the box's corners and Sobol points of another seed, fresh FE that no training path used), every
snapshot of it and at the largest push alone, per region; without one the manifest says the model is unchecked.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from contracts import model as folder
from contracts.design import DesignData, read_design
from contracts.envelope import Envelope
from contracts.model import FitOptions, onnx_session

from .export import OPSET, folded_layers
from .material_graph import build_material_graph, reference_decode_design
from .materials import materials_info
from .metrics import ANGLE_FLOOR_MM, REGIONS, case_errors, summarise
from .pca import Pca, _modes, _orthonormal, fit_pca

log = logging.getLogger(__name__)


def design_rows(data: DesignData) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(inputs (n, 2 + m), u / d rows (n, 3 n_nodes), has S (n,) bool, S_i / d (n_with, m, 3 n_nodes)) of the
    snapshots with d > 0 (u = 0 at rest for every theta)."""
    d = data.inputs[:, 0]
    keep = d > 0
    position = np.cumsum(data.has_sensitivity) - 1  # row -> its index in data.sensitivity
    with_s = keep & data.has_sensitivity
    sens = data.sensitivity[position[with_s]].reshape(int(with_s.sum()), len(data.design.tissues), -1)
    return (data.inputs[keep], data.displacement[keep].reshape(int(keep.sum()), -1) / d[keep, None],
            data.has_sensitivity[keep], sens / d[with_s, None, None])


def design_pca(rows: np.ndarray, sens: np.ndarray, rank: int, sensitivity_rank: int) -> Pca:
    """u / d's own `rank` modes, then `sensitivity_rank` of what they leave of the S_i / d rows (no mean)."""
    primary = fit_pca(rows, rank)
    if not len(sens) or sensitivity_rank == 0:
        return primary
    rest = sens.reshape(-1, sens.shape[-1])
    rest = rest - (rest @ primary.basis.T) @ primary.basis
    more, _ = _modes(rest, min(sensitivity_rank, len(rest) - 1))
    return Pca(mean=primary.mean, basis=_orthonormal(np.vstack([primary.basis, more])),
               singular_values=primary.singular_values, n_primary=primary.rank)


def theta_rms(box: dict[str, tuple[float, float]], tissues: list[str]) -> np.ndarray:
    """Per tissue the rms of theta over its range (uniform): the size of the theta an S_i error is multiplied by."""
    return np.array([np.sqrt((lo * lo + lo * hi + hi * hi) / 3) for lo, hi in (box[t] for t in tissues)])


def fit_design_surrogate(data: DesignData, options: FitOptions, progress=None):
    """(layers, pca, info): the PCA and the Sobolev-fitted network of a design's snapshots."""
    from .sobolev import train_sobolev

    inputs, rows, has, sens = design_rows(data)
    t0 = time.perf_counter()
    pca = design_pca(rows, sens, options.rank, options.sensitivity_rank)
    pca_seconds = time.perf_counter() - t0
    m = len(data.design.tissues)
    targets = [sens[:, i] @ pca.basis.T for i in range(m)]  # dc / dtheta_i (n_with, R)
    weights = theta_rms(data.design.log_box, data.design.tissues) ** 2
    net, scaling, info = train_sobolev(inputs, pca.encode(rows), grad_rows=has, grad_columns=list(range(2, 2 + m)),
                                       grad_targets=targets, grad_weights=weights, width=options.width,
                                       max_iterations=options.max_iterations, seed=options.seed, progress=progress)
    info.update(pca_seconds=pca_seconds, n_train=len(inputs), n_with_sensitivity=int(has.sum()))
    return folded_layers(net, scaling), pca, scaling, info


def _predict(session, inputs: np.ndarray) -> np.ndarray:
    """The ONNX model's u (n, n_nodes, 3) at design inputs (d, beta, theta...)."""
    x = inputs.astype(np.float32)
    return np.concatenate([session.run(["displacement"], {"guide": x[i:i + 1, :2], "materials": x[i:i + 1, 2:]})[0]
                           for i in range(len(x))]).astype(np.float64)


def held_out_errors(session, data: DesignData, node_sets: dict) -> dict:
    """Per region the largest nodal error (mm) over every held-out snapshot and at the largest push alone, and the
    per-case errors at the largest push."""
    u = _predict(session, data.inputs)
    err = np.linalg.norm(u - data.displacement, axis=2)  # (n, n_nodes)
    largest = np.isclose(data.inputs[:, 0], data.inputs[:, 0].max())
    regions = {}
    for name in REGIONS:
        ids = slice(None) if name == "all_nodes" else node_sets[name]
        regions[name] = {"all_mm": float(err[:, ids].max()), "largest_push_mm": float(err[largest][:, ids].max())}
    cases = [folder.CaseErrors(displacement_mm=float(x[0]), angle_deg=float(x[1]), **case_errors(p, r))
             for x, p, r in zip(data.inputs[largest], u[largest], data.displacement[largest])]
    return {"regions": regions, "cases": cases, "n_snapshots": len(u), "n_points": len(data.design.points),
            "unfinished": data.unfinished}


def fit_design(design: Path, out: Path, options: FitOptions, *, held_out: Path | None = None,
               progress: bool = True, points: int | None = None) -> folder.ModelManifest:
    """Fit on `design` (its first `points` points, default all), check against `held_out` (a `fem_offline design
    --held-out` folder on the same mesh), and write the model folder `out`."""
    from tqdm import tqdm

    t_start = time.perf_counter()
    data = read_design(design, points)
    if data.unfinished:
        log.warning("%d design points are unfinished (what they wrote is used): %s", len(data.unfinished),
                    ", ".join(data.unfinished))
    test = read_design(held_out) if held_out is not None else None
    if test is not None and test.design.tissues != data.design.tissues:
        raise ValueError(f"--held-out: it varies {test.design.tissues}, the design {data.design.tissues}")
    if test is not None and test.displacement.shape[1] != data.displacement.shape[1]:
        raise ValueError(f"--held-out: {test.displacement.shape[1]} nodes, the design's mesh "
                         f"{data.displacement.shape[1]}")
    with tqdm(total=options.max_iterations, desc="training (L-BFGS iterations)", disable=not progress,
              leave=False) as bar:
        layers, pca, scaling, info = fit_design_surrogate(data, options, progress=bar.update)
    m = len(data.design.tissues)
    onnx_bytes = build_material_graph(layers, pca, m, jacobian=True).SerializeToString()
    session = onnx_session(onnx_bytes)
    probe = data.inputs[[0, len(data.inputs) // 2, -1]]
    ref_u, ref_s = reference_decode_design(layers, pca, m, probe[:, :2], probe[:, 2:], np.full((3, m), 0.21))
    got = session.run(None, {"guide": probe[:, :2].astype(np.float32), "materials": probe[:, 2:].astype(np.float32),
                             "materials_std": np.full((3, m), 0.21, dtype=np.float32)})
    parity = float(max(np.abs(got[0] - ref_u).max(), np.abs(got[1] - ref_s).max()))
    checked = held_out_errors(session, test, data.mesh.node_sets) if test is not None else None
    manifest = _manifest(out, data, options, layers, pca, scaling, info, checked, parity,
                         seconds=time.perf_counter() - t_start)
    from .report import design_markdown

    return folder.write_model_folder(out, onnx_bytes=onnx_bytes, mesh=data.mesh, manifest=manifest,
                                     report=design_markdown(manifest, checked))


def _manifest(out: Path, data: DesignData, options: FitOptions, layers, pca: Pca, scaling, info: dict, checked,
              parity: float, *, seconds: float) -> folder.ModelManifest:
    from .fit import _versions, pca_method

    design, m = data.design, len(data.design.tissues)
    materials = materials_info(design.scene)
    if checked is not None:
        reference = (f"fresh FE at {checked['n_points']} held-out material points x (-beta, beta) of a `fem_offline "
                     f"design --held-out` folder, every push ({checked['n_snapshots']} snapshots), on the model's mesh")
        regions = {k: folder.RegionAccuracy(surrogate_mm=v["all_mm"]) for k, v in checked["regions"].items()}
        cases = checked["cases"]
    else:
        reference, regions, cases = "not checked: no --held-out design", {}, []
    summary = summarise(cases) if cases else folder.ErrorSummary(e_nn_mm=float("nan"), alpha_deg=float("nan"),
                                                                    e_r_percent=float("nan"), mean_mm=float("nan"),
                                                                    p99_mm=float("nan"), n_cases=0)
    s2 = pca.singular_values**2
    d_max = float(data.inputs[:, 0].max())
    return folder.ModelManifest(
        name=Path(out).name,
        created_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        scene=folder.SceneInfo(name=design.scene_name, sha256=design.scene_sha256, spec=design.scene),
        sweep=folder.SweepInfo(n_snapshots=len(data.inputs), nonlinear=design.scene.effects.geometric_nonlinearity),
        mesh=folder.MeshInfo(n_nodes=len(data.mesh.nodes), n_tets=len(data.mesh.tets), n_dofs=3 * len(data.mesh.nodes),
                             tissues=list(data.mesh.tissue_names)),
        fit=options,
        pca=folder.PcaInfo(rank=pca.rank, energy=pca.energy, method=pca_method(pca), n_primary=pca.n_primary,
                           energy_by_rank=[float(v) for v in np.cumsum(s2)[:64] / s2.sum()]),
        network=folder.NetworkInfo(
            inputs=["displacement_mm", "angle_deg", *(f"theta_{t}" for t in design.tissues)], width=options.width,
            depth=1, activation="tanh", optimizer="L-BFGS, variable projection, values and theta-derivatives (Sobolev)",
            iterations=info["iterations"], final_loss=info["final_loss"], seconds=info["seconds"], seed=info["seed"],
            n_train=info["n_train"], restarts=info["restarts"],
            output=(f"displacement = d x (mean + c(d, beta, theta) basis); displacement_std = d x sqrt(sum_i (sigma_i "
                    "(dc / dtheta_i) basis)^2), the network's own Jacobian; basis: u / d's "
                    f"{pca.n_primary or pca.rank} modes, then {pca.rank - (pca.n_primary or pca.rank)} for what they "
                    "leave of the S_i / d")),
        normalisation=folder.Normalisation(input_center=scaling.input_center.tolist(),
                                           input_scale=scaling.input_scale.tolist()),
        envelope=Envelope(displacement_mm=(0.0, d_max), angle_deg=(-design.angle_max_deg, design.angle_max_deg)),
        onnx=folder.OnnxInfo(opset=OPSET, inputs={
            "guide": "float32 [batch, 2]", "nodes": "int64 [k], optional, empty = all",
            "materials": f"float32 [batch, {m}], optional, {materials.parameter} per tissue in materials.inputs order",
            "materials_std": f"float32 [batch, {m}], optional, the std of ln E (0 = none)"},
            outputs={"displacement": "float32 [batch, k, 3] mm",
                     "displacement_std": "float32 [batch, k, 3] mm, d sqrt(sum_i (sigma_i s_i)^2), s_i the Jacobian's"},
            basis_dtype="float32"),
        metrics=folder.Metrics(angle_floor_mm=ANGLE_FLOOR_MM, table3=cases, table3_summary=summary,
                               onnx_vs_float64_max_abs_mm=parity),
        accuracy=folder.Accuracy(reference=reference, regions=regions),
        timing=folder.Timing(pca_seconds=info["pca_seconds"], train_seconds=info["seconds"], total_seconds=seconds),
        versions=_versions(),
        materials=materials,
    )
