"""Fit pipeline: sweep -> PCA -> network -> ONNX -> held-out metrics -> model folder."""

from __future__ import annotations

import logging
import platform
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .metrics import ANGLE_FLOOR_MM, case_errors, summarise
from .snapshots import read_cases, read_sweep

log = logging.getLogger(__name__)

# The paper's five left-out samples (Table 3): displacement_mm, angle_deg.
PAPER_TEST_CASES = ((7.75, -5.0), (4.25, -3.0), (5.25, -2.0), (1.5, -1.0), (2.5, 2.0))
PAPER_TABLE3 = {"e_nn_mm": 0.03, "alpha_deg": 0.01, "e_r_percent": 1.41, "train_minutes": 38.5}


@dataclass(frozen=True)
class FitOptions:
    rank: int = 16
    width: int = 60
    depth: int = 1
    max_iterations: int = 1000
    seed: int = 0
    test_cases: tuple[tuple[float, float], ...] = PAPER_TEST_CASES


def _held_out_mask(inputs: np.ndarray, cases) -> np.ndarray:
    mask = np.zeros(len(inputs), dtype=bool)
    for d, a in cases:
        hit = (np.abs(inputs[:, 0] - d) < 1e-9) & (np.abs(inputs[:, 1] - a) < 1e-9)
        if not hit.any():
            raise ValueError(f"--test-case {d}/{a}: not a snapshot of this sweep")
        mask |= hit
    return mask


def training_set(data, test_cases) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(held-out mask, inputs (n, 2), rows (n, 3 n_nodes)) for fitting: the snapshots not held out,
    plus the unloaded state (u = 0 at every sweep angle), known exactly, so the envelope starts at 0 mm."""
    test = _held_out_mask(data.inputs, test_cases)
    kept = data.select(~test)
    angles = np.unique(data.inputs[:, 1])
    inputs = np.concatenate([kept.inputs, np.stack([np.zeros_like(angles), angles], axis=1)])
    rows = np.concatenate([kept.displacement.reshape(len(kept), -1), np.zeros((len(angles), 3 * len(data.reference_positions)))])
    return test, inputs, rows


def _session(onnx_bytes: bytes):
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.log_severity_level = 3  # the optional `nodes` input is an initializer by design
    return ort.InferenceSession(onnx_bytes, so, providers=["CPUExecutionProvider"])


def _evaluate(session, inputs: np.ndarray, reference: np.ndarray) -> list[dict]:
    rows = []
    for x, u in zip(inputs, reference):
        pred = session.run(None, {"guide": x[None].astype(np.float32)})[0][0].astype(np.float64)
        rows.append({"displacement_mm": float(x[0]), "angle_deg": float(x[1]), **case_errors(pred, u)})
    return rows


def _versions() -> dict[str, str]:
    import onnx
    import onnxruntime
    import torch

    return {"python": platform.python_version(), "numpy": np.__version__, "torch": torch.__version__,
            "onnx": onnx.__version__, "onnxruntime": onnxruntime.__version__}


def fit(snapshots: Path, out: Path, options: FitOptions, *, offgrid: Path | None = None, progress: bool = True) -> dict:
    """Run the whole pipeline and write `out`; returns the manifest."""
    from tqdm import tqdm

    from .export import build_graph, folded_layers, reference_decode
    from .folder import write_model_folder
    from .network import train
    from .pca import fit_pca
    from .report import table3_markdown

    t_start = time.perf_counter()
    sweep = read_sweep(snapshots)
    data = sweep.snapshots
    offgrid_inputs = offgrid_disp = None
    if offgrid is not None:
        files = sorted(Path(offgrid).glob("*.npz"))
        if not files:
            raise ValueError(f"--offgrid: no .npz cases in {offgrid}")
        offgrid_inputs, offgrid_disp = read_cases(files)
        if offgrid_disp.shape[1] != len(sweep.mesh.nodes):
            raise ValueError(f"--offgrid: cases have {offgrid_disp.shape[1]} nodes, the sweep's mesh {len(sweep.mesh.nodes)}")

    test, inputs, x = training_set(data, options.test_cases)
    n_train, n_zero = int((~test).sum()), len(inputs) - int((~test).sum())

    t0 = time.perf_counter()
    pca = fit_pca(x, options.rank)
    coefficients = pca.encode(x)
    pca_seconds = time.perf_counter() - t0
    log.info("PCA rank %d captures %.8f of the variance (%.1f s)", pca.rank, pca.energy, pca_seconds)

    with tqdm(total=options.max_iterations, desc="training (L-BFGS iterations)", disable=not progress, leave=False) as bar:
        net, scaling, info = train(inputs, coefficients, width=options.width, depth=options.depth,
                                   max_iterations=options.max_iterations, seed=options.seed, progress=bar.update)
    layers = folded_layers(net, scaling)
    onnx_bytes = build_graph(layers, pca).SerializeToString()
    session = _session(onnx_bytes)

    table3 = _evaluate(session, data.inputs[test], data.displacement[test])
    offgrid_rows = _evaluate(session, offgrid_inputs, offgrid_disp) if offgrid_inputs is not None else []
    probe = np.concatenate([data.inputs[test], inputs[[0, -1]]])
    parity = float(np.abs(
        np.concatenate([session.run(None, {"guide": p[None].astype(np.float32)})[0] for p in probe])
        - reference_decode(layers, pca, probe)).max())

    s2 = pca.singular_values**2
    manifest = {
        "name": Path(out).name,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "scene": {"name": sweep.manifest.get("scene_name"), "sha256": sweep.manifest["scene_sha256"]},
        "sweep": {"n_snapshots": len(data), "nonlinear": sweep.manifest.get("nonlinear")},
        "mesh": {"file": "mesh.npz", "n_nodes": len(sweep.mesh.nodes), "n_tets": len(sweep.mesh.tets),
                 "n_dofs": 3 * len(sweep.mesh.nodes), "tissues": list(sweep.mesh.tissue_names)},
        "pca": {"rank": pca.rank, "energy": pca.energy,
                "energy_by_rank": [float(v) for v in np.cumsum(s2)[:64] / s2.sum()], "method": "snapshots (Gram), float64"},
        "network": {"inputs": ["displacement_mm", "angle_deg"], "width": options.width, "depth": options.depth,
                    "activation": "tanh", "optimizer": "L-BFGS, variable projection", **info,
                    "n_train": n_train, "n_zero_load": n_zero},
        "normalisation": {"input_center": scaling.input_center.tolist(), "input_scale": scaling.input_scale.tolist()},
        "envelope": {"displacement_mm": [0.0, float(data.inputs[:, 0].max())],
                     "angle_deg": [float(data.inputs[:, 1].min()), float(data.inputs[:, 1].max())]},
        "onnx": {"opset": 17, "inputs": {"guide": "float32 [batch, 2]", "nodes": "int64 [k], optional, empty = all"},
                 "outputs": {"displacement": "float32 [batch, k, 3] mm"}, "basis_dtype": "float32"},
        "metrics": {
            "angle_floor_mm": ANGLE_FLOOR_MM,
            "table3": table3, "table3_summary": summarise(table3),
            "offgrid": offgrid_rows, "offgrid_summary": summarise(offgrid_rows) if offgrid_rows else None,
            "onnx_vs_float64_max_abs_mm": parity,
        },
        "timing": {"pca_seconds": pca_seconds, "train_seconds": info["seconds"],
                   "total_seconds": time.perf_counter() - t_start},
        "versions": _versions(),
    }
    report = table3_markdown(manifest, PAPER_TABLE3)
    return write_model_folder(out, onnx_bytes=onnx_bytes, mesh=sweep.mesh, manifest=manifest, report=report)


def summary_line(manifest: dict) -> str:
    m = manifest["metrics"]
    line = (f"rank {manifest['pca']['rank']} (energy {manifest['pca']['energy']:.8f}), "
            f"train {manifest['timing']['train_seconds']:.1f} s; Table 3 samples: e_NN {m['table3_summary']['e_nn_mm']:.4f} mm, "
            f"alpha {m['table3_summary']['alpha_deg']:.3f} deg, e_r {m['table3_summary']['e_r_percent']:.3f} %")
    if m["offgrid_summary"]:
        line += f"; off-grid ({m['offgrid_summary']['n_cases']}): e_NN {m['offgrid_summary']['e_nn_mm']:.4f} mm"
    return line + f"; onnx vs float64 {m['onnx_vs_float64_max_abs_mm']:.2e} mm"
