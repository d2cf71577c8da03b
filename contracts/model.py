"""The model folder: what training writes and the service reads.

    model.onnx     guide float32 [batch, 2] (+ optional nodes int64 [k]) -> displacement float32 [batch, k, 3] mm;
                   a material model (manifest `materials`) also takes materials and materials_std float32
                   [batch, m] (ln(E/E_nominal) and its std, in the manifest's order) and gives displacement_std
                   float32 [batch, k, 3] mm (training/material_graph.py)
    mesh.npz       the reference mesh (contracts.mesh) + region/<name> node ids + surface/<tissue> triangles
    report.md      the held-out accuracy, laid out like the paper's Table 3
    manifest.json  ModelManifest: what produced the model and how accurate it is, sha256 of every file

The folder is assembled beside its destination and swapped in by rename, so a crash while writing
leaves the previous model as it was; the reader checks every hash and refuses a corrupt folder.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, model_validator

from .envelope import Envelope
from .materials import MaterialsInfo
from .files import read_manifest_json, sha256
from .mesh import TetMesh, mesh_arrays, read_mesh
from .scene import RecordedScene, Scene
from .sweep import LabelMapSource
from .tet10 import outward_triangles

MODEL_FORMAT = 2
FILES = ("model.onnx", "mesh.npz", "report.md")
# The paper's five left-out samples (Table 3): displacement_mm, angle_deg.
PAPER_TEST_CASES = ((7.75, -5.0), (4.25, -3.0), (5.25, -2.0), (1.5, -1.0), (2.5, 2.0))


class ModelError(ValueError):
    """The model folder is missing, corrupt or of another format."""


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class FitOptions(_Frozen):
    """How `training fit` was asked to fit (the CLI's flags)."""

    rank: int = 16
    sensitivity_rank: int = 32  # a material model's extra modes for the sensitivities (training/pca.py)
    width: int = 60
    depth: int = 1
    max_iterations: int = 1000
    seed: int = 0
    test_cases: tuple[tuple[float, float], ...] = PAPER_TEST_CASES


class CaseErrors(_Frozen):
    """Errors of one held-out case over all nodes (training/metrics.py defines them)."""

    displacement_mm: float
    angle_deg: float
    e_nn_mm: float
    alpha_deg: float
    e_r_percent: float
    mean_mm: float
    p99_mm: float
    max_displacement_mm: float


class ErrorSummary(_Frozen):
    e_nn_mm: float
    alpha_deg: float
    e_r_percent: float
    mean_mm: float
    p99_mm: float
    n_cases: int


class Metrics(_Frozen):
    """The float32 ONNX model against the FE snapshots of its own mesh (held out of training)."""

    angle_floor_mm: float
    table3: list[CaseErrors]
    table3_summary: ErrorSummary
    offgrid: list[CaseErrors] = []
    offgrid_summary: ErrorSummary | None = None
    onnx_vs_float64_max_abs_mm: float


class RegionAccuracy(_Frozen):
    """Error bounds at one region, mm (max over points and cases)."""

    surrogate_mm: float  # the model against its own mesh's FE, held-out cases (Table 3 + off-grid)
    fe_discretisation_mm: float | None = None  # that FE against the converged estimate (GCI band); None: not measured
    end_to_end_mm: float | None = None  # surrogate + discretisation: the model against the converged estimate


class Accuracy(_Frozen):
    """What a user's answer is off by, per region, and against what."""

    reference: str
    regions: dict[str, RegionAccuracy]  # markers, prostate_surface, all_nodes


class SceneInfo(_Frozen):
    name: str
    sha256: str
    spec: RecordedScene  # the validated scene the sweep was solved for (contracts.scene)


class SweepInfo(_Frozen):
    n_snapshots: int
    nonlinear: bool


class MeshInfo(_Frozen):
    file: str = "mesh.npz"
    n_nodes: int
    n_tets: int
    n_dofs: int
    tissues: list[str]


class PcaInfo(_Frozen):
    rank: int
    energy: float
    energy_by_rank: list[float]
    method: str
    n_primary: int | None = None  # a material model: the first n_primary modes are u's own (training/pca.py)


class NetworkInfo(_Frozen):
    inputs: list[str]
    width: int
    depth: int
    activation: str
    optimizer: str
    iterations: int
    final_loss: float
    seconds: float
    seed: int
    n_train: int
    restarts: int = 0  # L-BFGS restarts after early stops (training/network.py); absent before them
    output: str  # how the graph forms the displacement from the network's output


class Normalisation(_Frozen):
    input_center: list[float]
    input_scale: list[float]


class OnnxInfo(_Frozen):
    opset: int
    inputs: dict[str, str]
    outputs: dict[str, str]
    basis_dtype: str


class Timing(_Frozen):
    pca_seconds: float
    train_seconds: float
    total_seconds: float


class EnvelopeCut(_Frozen):
    """Why the model answers for less than its sweep covers: beyond valid_up_to_mm the sweep's snapshots
    turn an element inside out (det(I + grad u) <= 0) at some angle, so training left them out."""

    sweep_envelope: Envelope  # what the sweep covered; the manifest's `envelope` is the cut one
    valid_up_to_mm: float  # the largest grid displacement up to which every angle's snapshots are valid
    n_excluded: int  # snapshots beyond it, left out of training and evaluation (valid ones at other angles too)
    n_inverted: int  # of those, the ones with an inverted element
    min_det_f: float  # the lowest det(I + grad u) in the sweep
    dropped_test_cases: list[tuple[float, float]] = []  # held-out cases asked for beyond the cut, not evaluated
    n_dropped_offgrid: int = 0  # off-grid cases beyond the cut, not evaluated


class ModelManifest(_Frozen):
    format_version: Literal[2] = MODEL_FORMAT
    name: str
    created_utc: str
    scene: SceneInfo
    sweep: SweepInfo
    mesh: MeshInfo
    fit: FitOptions
    pca: PcaInfo
    network: NetworkInfo
    normalisation: Normalisation
    envelope: Envelope  # what the model answers for; the service refuses anything outside it (422)
    envelope_cut: EnvelopeCut | None = None  # None: every snapshot of the sweep is a deformation
    onnx: OnnxInfo
    metrics: Metrics
    accuracy: Accuracy
    timing: Timing
    versions: dict[str, str]
    source: LabelMapSource | None = None  # the segmentation of a label-map scene (from the sweep's manifest)
    materials: MaterialsInfo | None = None  # the tissue stiffnesses the model takes as inputs; None: none
    regions: dict[str, int] = {}  # name -> node count; filled by the writer
    files: dict[str, str] = {}  # name -> sha256; filled by the writer

    @model_validator(mode="after")
    def _materials_by_ratios(self):
        """A manifest from before MaterialsInfo.by_ratios gets it from its scene (judged_by_ratios)."""
        if self.materials is not None and self.materials.by_ratios is None:
            by = judged_by_ratios(self.scene.spec, tissues=self.mesh.tissues, inputs=self.materials.tissues)
            object.__setattr__(self, "materials", self.materials.model_copy(update={"by_ratios": by}))
        return self


def judged_by_ratios(scene: Scene, *, tissues: list[str], inputs: list[str]) -> bool:
    """Whether only the inputs' stiffness ratios move the answer (contracts.materials): no force load (gravity)
    and every tissue of the mesh an input or a bone held fixed. A soft tissue left at its nominal E makes E x k
    of the inputs another patient."""
    if scene.effects.gravity:
        return False
    fixed = {t for t, tissue in scene.tissues.items() if scene.effects.fixed_bones and tissue.bone}
    return set(tissues) - fixed <= set(inputs)


def regions(mesh: TetMesh) -> dict[str, np.ndarray]:
    """Named node sets the service can decode alone: each tissue, then the mesh's own sets."""
    out = {name: np.unique(mesh.tets[mesh.tissue == t]) for t, name in enumerate(mesh.tissue_names)}
    out.update({name: np.asarray(ids) for name, ids in mesh.node_sets.items()})
    return {name: ids.astype(np.int64) for name, ids in out.items() if len(ids)}


def tissue_surfaces(mesh: TetMesh) -> dict[str, np.ndarray]:
    """Outward corner triangles (k, 3) bounding each tissue, for drawing."""
    return {name: outward_triangles(mesh.nodes, mesh.tets[mesh.tissue == t]).astype(np.int32)
            for t, name in enumerate(mesh.tissue_names) if (mesh.tissue == t).any()}


def _write_mesh(mesh: TetMesh, path: Path) -> dict[str, int]:
    sets = regions(mesh)
    arrays = {**mesh_arrays(mesh), **{f"region/{k}": v for k, v in sets.items()},
              **{f"surface/{k}": v for k, v in tissue_surfaces(mesh).items()}}
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
    return {k: int(len(v)) for k, v in sets.items()}


def write_model_folder(out: str | Path, *, onnx_bytes: bytes, mesh: TetMesh, manifest: ModelManifest,
                       report: str) -> ModelManifest:
    """Write everything into a temporary sibling folder, then swap it in; returns the final manifest."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.tmp-", dir=out.parent))
    try:
        tmp.chmod(0o755)  # mkdtemp makes it private; a served model folder is read by the service's user
        (tmp / "model.onnx").write_bytes(onnx_bytes)
        counts = _write_mesh(mesh, tmp / "mesh.npz")
        (tmp / "report.md").write_text(report)
        manifest = manifest.model_copy(update={"regions": counts, "files": {n: sha256(tmp / n) for n in FILES}})
        (tmp / "manifest.json").write_text(manifest.model_dump_json(indent=2) + "\n")
        for f in tmp.iterdir():
            with open(f, "rb") as fh:
                os.fsync(fh.fileno())
        old = out.with_name(f".{out.name}.old-{os.getpid()}")
        if out.exists():
            os.rename(out, old)
        os.rename(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return manifest


def onnx_session(model: bytes | str | Path, *, threads: int = 1):
    """An onnxruntime CPU session for a model.onnx (path or bytes) with `threads` intra-op threads.

    onnxruntime is imported here, not at module level: readers of the folder's files need only numpy.
    """
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3  # the optional `nodes` input is an initializer by design
    # Idle intra-op threads sleep instead of spinning. A batching service runs two lanes on one session's
    # threads: spinning, they burned the cores the other lane and the replies needed (312k nodes, 2 cores,
    # 8 clients: 5.8 to 6.5 ms of server CPU a request, 3.8 to 4.2 without), and a single call is no
    # slower without it (312k, 2 threads, batch 1 and 8: within the run-to-run spread).
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(model if isinstance(model, bytes) else str(model), so,
                                providers=["CPUExecutionProvider"])


MATERIAL_INPUTS = frozenset({"materials", "materials_std"})


def check_graph(folder: "ModelFolder", session=None) -> None:
    """ModelError unless model.onnx takes the inputs its manifest promises: `guide`, and `materials` and
    `materials_std` exactly when the manifest declares materials (a request's materials need both)."""
    session = session or onnx_session(folder.path / "model.onnx")
    # an optional input (`nodes`, the materials) is an overridable initializer, which get_inputs() leaves out
    names = {i.name for i in (*session.get_inputs(), *session.get_overridable_initializers())}
    if "guide" not in names:
        raise ModelError(f"{folder.path}: model.onnx takes no `guide` input")
    declared = folder.manifest.materials is not None
    if declared and not MATERIAL_INPUTS <= names:
        raise ModelError(f"{folder.path}: the manifest declares materials, but model.onnx takes no "
                         f"{' or '.join(sorted(MATERIAL_INPUTS - names))} input; rebuild the model or drop `materials`")
    if not declared and names & MATERIAL_INPUTS:
        raise ModelError(f"{folder.path}: model.onnx takes materials, but the manifest declares none (their ranges)")


@dataclass(frozen=True)
class ModelFolder:
    path: Path
    manifest: ModelManifest
    mesh: TetMesh
    regions: dict[str, np.ndarray]  # name -> node ids
    surfaces: dict[str, np.ndarray]  # tissue -> (k, 3) corner triangles

    @property
    def nodes(self) -> np.ndarray:
        return self.mesh.nodes

    @property
    def tets(self) -> np.ndarray:
        return self.mesh.tets


def read_manifest(path: str | Path) -> ModelManifest:
    """The folder's manifest, or ModelError saying why it cannot be used."""
    return read_manifest_json(Path(path) / "manifest.json", ModelManifest, version=MODEL_FORMAT, error=ModelError,
                              kind="model", missing="is this a model folder written by `python -m training fit`?",
                              stale="rebuild the model with `python -m training fit`")


def read_model_folder(path: str | Path) -> ModelFolder:
    """Read a model folder; refuse it if a file is missing, its sha256 differs or the mesh disagrees."""
    path = Path(path)
    manifest = read_manifest(path)
    missing = sorted(set(FILES) - set(manifest.files))
    if missing:
        raise ModelError(f"{path}: the manifest must list {', '.join(missing)}")
    for name, digest in manifest.files.items():
        if not (path / name).is_file():
            raise ModelError(f"{path}: {name} is listed in the manifest but missing")
        if sha256(path / name) != digest:
            raise ModelError(f"{path}: {name} does not match its sha256 in manifest.json (corrupt or replaced)")
    mesh = read_mesh(path / "mesh.npz")
    with np.load(path / "mesh.npz") as z:
        regions_ = {k.split("/", 1)[1]: z[k] for k in z.files if k.startswith("region/")}
        surfaces = {k.split("/", 1)[1]: z[k] for k in z.files if k.startswith("surface/")}
    if len(mesh.nodes) != manifest.mesh.n_nodes:
        raise ModelError(f"{path}: mesh.npz has {len(mesh.nodes)} nodes, the manifest says {manifest.mesh.n_nodes}")
    if {k: len(v) for k, v in regions_.items()} != manifest.regions:
        raise ModelError(f"{path}: the regions in mesh.npz differ from the manifest's")
    return ModelFolder(path, manifest, mesh, regions_, surfaces)
