"""A paper-scale decoder for timing the service: models/default's field on the 312,089-node paper_scale mesh.

No paper-scale sweep exists (hours of solving on 2 cores), and decode time depends on the node
count, the rank and the network, not on the values. So: decode the source model on its own
envelope grid (coarse nodes), fit PCA rank 40 + a 1x120 network to those fields
(training.fit.fit_surrogate), then carry the PCA's mean and basis to the fine mesh with the
coarse mesh's P2 shape functions, W (n_fine, n_coarse) sparse:

    u_fine(d, beta) = W u_coarse(d, beta) = d (W mean + sum_i c_i(d, beta) W basis_i)

W is linear, so the fine graph decodes exactly the interpolated coarse surrogate. Fine nodes just
outside the coarse mesh (its curved surfaces are chords of the fine ones) take the value at their
projection onto the nearest coarse tet. The folder is for timing only: its accuracy is that of the
source model's field interpolated, and its manifest says so.

The mesh comes from `python -m fem_offline mesh` (gmsh; about 15 s here), run as a subprocess.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAPER_SCENE = ROOT / "fem_offline" / "scenes" / "paper_scale.toml"
SOURCE_MODEL = ROOT / "models" / "default"
PAPER_DECODER = ROOT / "runs" / "paper_decoder" / "model"
RANK, WIDTH = 40, 120

log = logging.getLogger(__name__)


def mesh_file(work: Path, scene: Path = PAPER_SCENE) -> Path:
    """The scene's mesh as work/mesh.npz, meshed by `python -m fem_offline mesh` when missing."""
    out = Path(work) / "mesh.npz"
    if not out.is_file():
        log.info("meshing %s -> %s", scene, out)
        subprocess.run([sys.executable, "-m", "fem_offline", "mesh", "--scene", str(scene), "--out", str(out)],
                       cwd=ROOT, check=True)
    return out


def grid_fields(source, *, step_mm: float = 0.25, step_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(inputs (n, 2), rows (n, 3 n_coarse) of f = u / d) of the source model on a grid over its envelope, d > 0."""
    from contracts.model import onnx_session

    env = source.manifest.envelope
    d = np.arange(step_mm, env.displacement_mm[1] + 1e-9, step_mm)
    a = np.arange(env.angle_deg[0], env.angle_deg[1] + 1e-9, step_deg)
    inputs = np.array([(di, ai) for ai in a for di in d])
    u = onnx_session(source.path / "model.onnx").run(None, {"guide": inputs.astype(np.float32)})[0]
    return inputs, u.reshape(len(inputs), -1).astype(np.float64) / inputs[:, :1]


def on_fine_mesh(pca, W):
    """The PCA with its mean and basis (3 n_coarse each) carried to the fine nodes by W (n_fine, n_coarse)."""
    from training.pca import Pca

    def carry(v: np.ndarray) -> np.ndarray:  # (3 n_coarse,) -> (3 n_fine,)
        return np.asarray(W @ v.reshape(-1, 3)).ravel()

    return Pca(mean=carry(pca.mean), basis=np.stack([carry(b) for b in pca.basis]), singular_values=pca.singular_values)


def build(out: Path = PAPER_DECODER, *, source: Path = SOURCE_MODEL, scene: Path = PAPER_SCENE, rank: int = RANK,
          width: int = WIDTH, max_iterations: int = 300) -> Path:
    """Write the paper-scale model folder `out` (its mesh beside it); returns `out`."""
    from contracts.interpolate import interpolation_matrix
    from contracts.mesh import read_mesh
    from contracts.model import FitOptions, read_model_folder, write_model_folder
    from training.export import build_graph
    from training.fit import fit_surrogate

    t0 = time.perf_counter()
    out = Path(out)
    fine = read_mesh(mesh_file(out.parent, scene))
    src = read_model_folder(source)
    inputs, rows = grid_fields(src)
    options = FitOptions(rank=rank, width=width, max_iterations=max_iterations, test_cases=())
    surrogate = fit_surrogate(inputs, rows, options)
    W = interpolation_matrix(src.nodes, src.tets, fine.nodes, nearest=True)  # (n_fine, n_coarse)
    pca = on_fine_mesh(surrogate.pca, W)
    onnx_bytes = build_graph(surrogate.layers, pca).SerializeToString()
    manifest = _manifest(src.manifest, name=out.name, fine=fine, surrogate=surrogate, options=options,
                         n_train=len(inputs), seconds=time.perf_counter() - t0)
    report = (f"# {out.name}\n\nA decoder for timing only: {src.manifest.name}'s field, refitted (PCA rank {rank}, "
              f"1x{width}) and interpolated onto {len(fine.nodes):,} nodes (bench/paper_decoder.py). "
              "Its accuracy was not measured.\n")
    write_model_folder(out, onnx_bytes=onnx_bytes, mesh=fine, manifest=manifest, report=report)
    return out


def _manifest(src, *, name: str, fine, surrogate, options, n_train: int, seconds: float):
    """The source model's manifest, restated for the fine mesh, the new fit and what it is for."""
    from contracts import model as folder

    s2 = surrogate.pca.singular_values**2
    return src.model_copy(update={
        "name": name, "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "scene": folder.SceneInfo(name="paper_scale_interpolated", sha256=src.scene.sha256, spec=src.scene.spec),
        "mesh": folder.MeshInfo(n_nodes=len(fine.nodes), n_tets=len(fine.tets), n_dofs=3 * len(fine.nodes),
                                tissues=list(fine.tissue_names)),
        "fit": options,
        "pca": folder.PcaInfo(rank=surrogate.pca.rank, energy=surrogate.pca.energy, energy_by_rank=[
            float(v) for v in np.cumsum(s2)[:64] / s2.sum()], method=f"snapshots (Gram) of {src.name}'s decoded grid, "
            "carried to the fine mesh by P2 interpolation"),
        "network": src.network.model_copy(update={**surrogate.info, "width": options.width, "n_train": n_train}),
        "normalisation": folder.Normalisation(input_center=surrogate.input_center.tolist(),
                                              input_scale=surrogate.input_scale.tolist()),
        # metrics stay the source's (the manifest has no place for "not measured"); accuracy says it
        "accuracy": folder.Accuracy(reference=f"timing only: {src.name}'s field interpolated; not measured",
                                    regions={}),
        "timing": folder.Timing(pca_seconds=surrogate.pca_seconds, train_seconds=surrogate.info["seconds"],
                                total_seconds=seconds),
        "materials": None,  # the refitted graph takes (d, beta) alone: the source decoded at its nominal materials
        "regions": {}, "files": {}})


def ensure(out: Path = PAPER_DECODER) -> Path:
    """The paper-scale model folder, built first when `out` holds none."""
    if not (Path(out) / "manifest.json").is_file():
        build(out)
    return Path(out)
