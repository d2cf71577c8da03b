"""The sweep folder: what fem_offline writes and training reads.

    manifest.json               SweepManifest: format, the full scene (contracts.scene), grid, envelope,
                                counts, one record per snapshot (with its sha256), errors, and
                                validity: which snapshots turn an element inside out
    mesh.npz                    the P2 mesh (contracts.mesh)
    snapshots/aIII_dJJJ.npz     one case: displacement (n_nodes, 3) float64 mm, displacement_mm,
                                angle_deg and the solver's record (CaseRecord fields); for a scene
                                with [materials], sensitivity_<tissue> (n_nodes, 3) float64 mm per
                                unit ln E: S_i = du/d ln E_i at that case (contracts.materials),
                                one per tissue the manifest's `materials` lists
A solved off-grid case (`fem_offline solve` / `cases`) is the same .npz, plus reference_positions.

A snapshot with det(I + grad u) <= 0 somewhere is not a deformation: an element is inside out. Each
snapshot records min det F three times: `min_det_f` at the quadrature points the solver integrates at
(4 per tet); `min_det_f_probe` at the denser probe points (fem_offline.fe.validity.PROBE_INTORDER: the
11 points per tet of the degree-4 rule), because a P2 field can invert between the solver's points
while positive at them; and `min_det_f_bound` over every point of every tet (fem_offline.fe.validity.
det_f_bound): > 0, a proven lower bound; <= 0, det F at a point where it is <= 0 (often a tet's corner,
which no quadrature point reaches). The nonlinear solver never returns a state with min_det_f <= 0, but
the other two can be; the linear model's superposition turns all three <= 0 once the guide pushes far
enough. Such snapshots are written (they are the model's answer) but listed in `validity`, which
counts a snapshot as inverted when any value is <= 0, and training reads `valid_up_to_mm` from it.

Formats: 4 records min_det_f_bound; 3 (still read) did not, 2 (still read) lacked min_det_f_probe too.
A folder of an older format resumed by a sweep becomes format 4 with its old snapshots judged at the
points they recorded (`validity.n_unprobed` and `n_unbounded` count them). Folders written before the check have no
`validity` at all: `sweep_validity` derives it from a nonlinear folder's records (the solver measured them) and refuses
a linear one (its records say 1.0 without having measured).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from .envelope import Envelope
from .files import atomic_savez, atomic_write_text, read_manifest_json, sha256
from .materials import sensitivity_key
from .mesh import TetMesh, read_mesh
from .scene import RecordedScene

SWEEP_FORMAT = 4  # what this code writes
READ_FORMATS = (2, 3, 4)  # what it reads: format 3 lacks min_det_f_bound, 2 min_det_f_probe too
MANIFEST = "manifest.json"
MESH_FILE = "mesh.npz"
SNAPSHOTS = "snapshots"


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CaseRecord(_Frozen):
    """What the solver reports with every solved case."""

    newton_iterations: int
    factorizations: int = 0
    cg_iterations: int = 0
    residual: float  # final ||r_free|| / ||reactions||
    min_det_f: float  # at the solver's quadrature points
    seconds: float
    min_det_f_probe: float | None = None  # at the probe points between them; None: not measured (not stored)
    min_det_f_bound: float | None = None  # everywhere (> 0: a lower bound; <= 0: a value); None: not measured


class SnapshotRecord(_Frozen):
    file: str
    sha256: str
    displacement_mm: float
    angle_deg: float
    newton_iterations: int
    residual: float
    min_det_f: float  # at the solver's quadrature points (4 per tet)
    seconds: float
    mirrored_from: str | None = None
    min_det_f_probe: float | None = None  # at the probe points (11 per tet); None: written before format 3
    min_det_f_bound: float | None = None  # everywhere (fem_offline.fe.validity.det_f_bound); None: before format 4

    @property
    def lowest_det_f(self) -> float:
        """The lowest of min_det_f, min_det_f_probe and min_det_f_bound recorded (NaN if any is): <= 0 or NaN means
        inverted."""
        values = [v for v in (self.min_det_f, self.min_det_f_probe, self.min_det_f_bound) if v is not None]
        return float(np.min(values))


class Grid(_Frozen):
    """Guide displacements x angles; each angle is one path of increasing displacement."""

    displacements_mm: list[float]
    angles_deg: list[float]

    @property
    def envelope(self) -> Envelope:
        return Envelope.of_grid(self.displacements_mm, self.angles_deg)


class LabelMapSource(_Frozen):
    """The segmentation a label-map scene's mesh was built from: which file, its grid and its label table."""

    file: str
    sha256: str
    shape: tuple[int, int, int]
    spacing_mm: tuple[float, float, float]
    affine: list[list[float]]  # (4, 4) voxel index -> patient RAS mm
    labels: dict[str, int]  # tissue -> label value
    background: str  # tissue of label 0 ("" = outside)
    outside: list[int]


def snapshot_file(angle_index: int, displacement_index: int) -> str:
    """Path of a grid case's snapshot inside the sweep folder."""
    return f"{SNAPSHOTS}/a{angle_index:03d}_d{displacement_index:03d}.npz"


class Validity(_Frozen):
    """Where the snapshots stop being deformations: det(I + grad u) <= 0 at a quadrature point or a probe point."""

    min_det_f: float | None  # over every quadrature and probe point of every snapshot; None: no snapshot yet
    n_inverted: int
    inverted: list[str] = []  # snapshot files with min_det_f, min_det_f_probe or min_det_f_bound <= 0, grid order
    first_inverted_mm: list[float | None]  # per grid angle (grid.angles_deg order); None: none inverted
    valid_up_to_mm: float  # the largest grid displacement up to which every angle's snapshots are valid (0: none)
    # snapshots without min_det_f_probe, judged at the solver's points only; None: format 2
    n_unprobed: int | None = None
    n_unbounded: int | None = None  # snapshots without min_det_f_bound, judged at their points only; None: format <= 3


class SweepManifest(_Frozen):
    format_version: Literal[2, 3, 4] = SWEEP_FORMAT
    scene_name: str
    scene_sha256: str
    scene: RecordedScene  # the validated scene, as solved (contracts.scene; read as recorded_scene)
    mesh: str = MESH_FILE
    mesh_sha256: str
    n_nodes: int
    n_tets: int
    nonlinear: bool
    grid: Grid
    envelope: Envelope
    n_expected: int
    n_done: int
    n_mirrored: int = 0
    wall_seconds_this_run: float = 0.0
    errors: list[str] = []
    snapshots: list[SnapshotRecord] = []
    source: LabelMapSource | None = None  # label-map scenes only
    validity: Validity | None = None  # None: written before det(I + grad u) was checked (see sweep_validity)
    materials: list[str] = []  # tissues whose sensitivity_<tissue> every snapshot holds (the scene's [materials])


def write_case(path: str | Path, displacement: np.ndarray, *, displacement_mm: float, angle_deg: float,
               record: CaseRecord, **extra) -> Path:
    """One solved case, atomically (a record field that is None is left out of the file)."""
    return atomic_savez(path, displacement=displacement, displacement_mm=displacement_mm, angle_deg=angle_deg,
                        **record.model_dump(exclude_none=True), **extra)


def read_cases(files: list[Path]) -> tuple[np.ndarray, np.ndarray]:
    """Inputs (n, 2) (displacement_mm, angle_deg) and displacements (n, n_nodes, 3) of solved cases, in file order."""
    if not files:
        raise ValueError("no case files")
    inputs, disp = [], []
    for f in files:
        with np.load(f) as z:
            inputs.append((float(z["displacement_mm"]), float(z["angle_deg"])))
            disp.append(z["displacement"])
    return np.asarray(inputs), np.stack(disp)


def read_sensitivities(files: list[Path], tissues: list[str]) -> dict[str, np.ndarray]:
    """S_i (n, n_nodes, 3) per tissue of solved cases, in file order; KeyError naming a file that lacks one."""
    out = {}
    for name in tissues:
        fields = []
        for f in files:
            with np.load(f) as z:
                if sensitivity_key(name) not in z.files:
                    raise KeyError(f"{f} holds no {sensitivity_key(name)}")
                fields.append(z[sensitivity_key(name)])
        out[name] = np.stack(fields)
    return out


def snapshot_record(folder: Path, name: str) -> SnapshotRecord:
    """The manifest row of a snapshot file on disk."""
    with np.load(folder / name) as z:
        return SnapshotRecord(
            file=name, sha256=sha256(folder / name), displacement_mm=float(z["displacement_mm"]),
            angle_deg=float(z["angle_deg"]), newton_iterations=int(z["newton_iterations"]),
            residual=float(z["residual"]), min_det_f=float(z["min_det_f"]), seconds=float(z["seconds"]),
            mirrored_from=str(z["mirrored_from"]) if "mirrored_from" in z.files else None,
            min_det_f_probe=float(z["min_det_f_probe"]) if "min_det_f_probe" in z.files else None,
            min_det_f_bound=float(z["min_det_f_bound"]) if "min_det_f_bound" in z.files else None)


def validity_of(grid: Grid, rows: list[SnapshotRecord]) -> Validity:
    """Summarise the snapshots' det F over the grid (the rows on disk; an unfinished sweep's part): a
    snapshot is inverted when min_det_f, min_det_f_probe or min_det_f_bound is <= 0."""
    bad = [r for r in rows if not r.lowest_det_f > 0]  # NaN counts as inverted
    first = [min((r.displacement_mm for r in bad if r.angle_deg == a), default=None) for a in grid.angles_deg]
    return Validity(min_det_f=min((r.lowest_det_f for r in rows), default=None), n_inverted=len(bad),
                    inverted=[r.file for r in bad], first_inverted_mm=first,
                    valid_up_to_mm=valid_up_to_mm(grid.displacements_mm, [r.displacement_mm for r in bad]),
                    n_unprobed=sum(r.min_det_f_probe is None for r in rows),
                    n_unbounded=sum(r.min_det_f_bound is None for r in rows))


def valid_up_to_mm(displacements_mm, inverted_mm) -> float:
    """The largest grid displacement below every inverted one (all of the grid's if none; 0.0 if not even the first)."""
    limit = min(inverted_mm, default=np.inf)
    return float(max((d for d in displacements_mm if d < limit), default=0.0))


def sweep_validity(manifest: SweepManifest) -> Validity:
    """The manifest's validity; for a folder written before it was recorded, derived from a nonlinear
    sweep's records, or ValueError for a linear one (its snapshots' min_det_f was never measured)."""
    if manifest.validity is not None:
        return manifest.validity
    if not manifest.nonlinear:
        raise ValueError("validity: this linear sweep was written before det(I + grad u) was checked (its snapshots "
                         "record min_det_f 1.0 unmeasured); run `fem_offline sweep` again into a new folder")
    return validity_of(manifest.grid, manifest.snapshots)


def write_manifest(folder: str | Path, manifest: SweepManifest) -> Path:
    return atomic_write_text(Path(folder) / MANIFEST, manifest.model_dump_json(indent=2) + "\n")


def read_manifest(folder: str | Path) -> SweepManifest:
    """The folder's manifest; ValueError saying why when it is missing, of another format or invalid."""
    return read_manifest_json(Path(folder) / MANIFEST, SweepManifest, version=READ_FORMATS, error=ValueError,
                              kind="sweep", missing="is it a `fem_offline sweep` output folder?",
                              stale="run the sweep again into a new folder")


@dataclass(frozen=True)
class Sweep:
    manifest: SweepManifest
    mesh: TetMesh
    inputs: np.ndarray  # (n, 2): displacement_mm, angle_deg
    displacement: np.ndarray  # (n, n_nodes, 3) mm, float64
    # tissue -> S_i (n, n_nodes, 3) mm per unit ln E; None: no materials
    sensitivity: dict[str, np.ndarray] | None = None


def read_sweep(folder: str | Path) -> Sweep:
    """A finished sweep, every file checked against its sha256; refuse an unfinished or altered one."""
    folder = Path(folder)
    manifest = read_manifest(folder)
    present = sum((folder / r.file).is_file() for r in manifest.snapshots)
    if present != manifest.n_expected:
        raise ValueError(f"{folder} holds {present} of {manifest.n_expected} snapshots; "
                         "finish the sweep first (rerun the same `fem_offline sweep` command)")
    for name, digest in [(manifest.mesh, manifest.mesh_sha256), *((r.file, r.sha256) for r in manifest.snapshots)]:
        if not (folder / name).is_file():
            raise ValueError(f"{folder}: {name} is listed in the manifest but missing")
        if sha256(folder / name) != digest:
            raise ValueError(f"{folder}: {name} does not match its sha256 in {MANIFEST} (corrupt or replaced)")
    mesh = read_mesh(folder / manifest.mesh)
    files = [folder / r.file for r in manifest.snapshots]
    inputs, disp = read_cases(files)
    if disp.shape[1] != len(mesh.nodes):
        raise ValueError(f"{folder}: snapshots have {disp.shape[1]} nodes, the mesh {len(mesh.nodes)}")
    try:
        sens = read_sensitivities(files, manifest.materials) if manifest.materials else None
    except KeyError as exc:
        raise ValueError(f"{folder}: the manifest lists materials {manifest.materials}, but {exc.args[0]}") from None
    return Sweep(manifest, mesh, inputs, disp, sens)
