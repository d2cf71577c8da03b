"""Scene file: anatomy, tissues, needle guide, physical effects and the sweep grid.

A scene is TOML validated by pydantic. Unknown keys and out-of-range values are errors that name
the field (``SceneError``). Units: lengths in mm, moduli in kPa, densities in kg/m^3, angles in
degrees.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path
from typing import Annotated, Literal, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from .anatomy import problems as anatomy_problems
from .anatomy import tip_problem
from .guide import direction as guide_direction
from .materials import youngs_from_shear_wave_kpa

Vec3 = tuple[float, float, float]
Positive = Annotated[float, Field(gt=0)]


class SceneError(ValueError):
    """A scene file that cannot be used; the message names the field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Tissue(_Strict):
    """Linear elastic tissue: E and nu, or shear-wave speed and density (paper eq. 1)."""

    youngs_kpa: Positive | None = None
    shear_wave_speed_m_s: Positive | None = None
    density_kg_m3: Annotated[float, Field(gt=0, le=5000)] = 1008.0
    poisson: Annotated[float, Field(ge=0.0, lt=0.5)] = 0.495
    bone: bool = False  # held fixed when effects.fixed_bones is on

    @model_validator(mode="after")
    def _one_stiffness(self) -> Tissue:
        if (self.youngs_kpa is None) == (self.shear_wave_speed_m_s is None):
            raise ValueError("give exactly one of youngs_kpa or shear_wave_speed_m_s")
        return self

    @property
    def youngs(self) -> float:
        """Young's modulus in kPa; from v_s by eq. 1, E = 2 (1 + nu) v_s^2 rho (Pa -> kPa)."""
        if self.youngs_kpa is not None:
            return self.youngs_kpa
        return youngs_from_shear_wave_kpa(
            shear_wave_speed_m_s=self.shear_wave_speed_m_s, density_kg_m3=self.density_kg_m3, poisson=self.poisson)


class Phantom(_Strict):
    """Synthetic male pelvis; x lateral (mirror plane x = 0), y posterior -> anterior, z up."""

    block_mm: tuple[Positive, Positive, Positive] = (100.0, 90.0, 80.0)
    prostate_center_mm: Vec3 = (0.0, 0.0, 35.0)
    prostate_semi_axes_mm: tuple[Positive, Positive, Positive] = (20.0, 10.0, 10.0)
    bladder_center_mm: Vec3 = (0.0, 4.0, 60.0)
    bladder_radius_mm: Positive = 13.0
    rectum_center_xy_mm: tuple[float, float] = (0.0, -21.0)
    rectum_inner_radius_mm: Positive = 7.0
    rectum_outer_radius_mm: Positive = 12.0
    pubic_center_mm: Vec3 = (0.0, 30.0, 40.0)
    pubic_radius_mm: Positive = 6.0
    pubic_length_mm: Positive = 60.0
    spine_box_mm: tuple[Vec3, Vec3] = ((-15.0, -41.0, 8.0), (15.0, -36.0, 72.0))

    @model_validator(mode="after")
    def _anatomy(self) -> Phantom:
        """Shapes inside the block, a rectal wall around the lumen, no organ cut by another (anatomy.problems)."""
        if self.rectum_inner_radius_mm >= self.rectum_outer_radius_mm:
            raise ValueError("rectum_inner_radius_mm must be below rectum_outer_radius_mm")
        found = anatomy_problems(self)
        if found:
            raise ValueError("; ".join(found))
        return self


class UserMesh(_Strict):
    """A user's tetrahedral mesh (anything meshio reads) with a cell tag per tissue."""

    path: Path
    tag_field: str = "gmsh:physical"
    tags: dict[str, int]  # tissue name -> tag value


class LabelMap(_Strict):
    """A segmentation label map (NIfTI or NRRD, fem_offline.labelmap) and the tissue of each label value.

    Voxels of label 0 are `background` tissue (adipose unless the scene says otherwise), or outside
    the body when `background` is empty; voxels of an `outside` value (the rectal lumen, air) are
    not meshed. Any other value in the image must be in `labels`.
    """

    path: Path
    labels: dict[str, Annotated[int, Field(gt=0)]]  # tissue name -> label value
    background: str = "adipose"  # tissue of label-0 voxels; "" = label 0 is outside the body
    outside: tuple[Annotated[int, Field(gt=0)], ...] = ()
    mesher: Literal["cgal", "ftetwild", "tetgen"] = "cgal"  # scripts/compare_meshers.py measures them
    # CGAL only: how far a surface facet may stray from the labels' boundary, in voxels (the smallest
    # spacing). It sets the surface triangles, and so most of the tets: 0.5 gives 21,900 tets on the
    # medium variant's 1 mm map, 1.0 13,900 (scripts/labelmap_truth.py measures what it costs).
    facet_distance_voxels: Annotated[float, Field(gt=0, le=4)] = 0.5

    @model_validator(mode="after")
    def _distinct(self) -> LabelMap:
        # a dumped scene carries the default, so only another value is refused
        if self.facet_distance_voxels != LabelMap.model_fields["facet_distance_voxels"].default and self.mesher != "cgal":
            raise ValueError(f"facet_distance_voxels is CGAL's; mesher {self.mesher!r} does not use it")
        values = list(self.labels.values())
        if len(set(values)) != len(values):
            raise ValueError(f"each tissue needs its own label value, got {self.labels}")
        both = sorted(set(values) & set(self.outside))
        if both:
            raise ValueError(f"label values {both} are both tissue and outside")
        return self

    @property
    def tissue_names(self) -> tuple[str, ...]:
        """The tissues the label map can hold: the labelled ones, then the background."""
        names = tuple(self.labels)
        return names + ((self.background,) if self.background and self.background not in names else ())


class Guide(_Strict):
    """Rigid needle-guide tip pushing the rectal wall (its geometry and prescribed field: guide.py).

    The tip moves by d * a(beta), a(beta) = axis rotated by beta about tilt_normal. By default wall
    nodes within patch_radius_mm of the tip are glued to it with the rounded-tip weight
    w(r) = cos^2(pi r / (2 R)), so the prescribed field is smooth at the patch rim. With
    effects.guide_contact the tip is instead a rigid sphere of tip_radius_mm in frictionless contact
    with the wall (contact.py).
    """

    tip_mm: Vec3 = (0.0, -14.0, 35.0)
    axis: Vec3 = (0.0, 1.0, 0.0)
    tilt_normal: Vec3 = (0.0, 0.0, 1.0)
    patch_radius_mm: Annotated[float, Field(gt=0, le=50)] = 6.0
    # When set, the tip seats on the rectal wall's lumen surface of the mesh, which must lie within
    # snap_mm of tip_mm (guide.seat): where the axis through tip_mm crosses it (snap_to = "axis"), or
    # at the lumen node nearest tip_mm ("node", what label-map scenes did before snap_to existed).
    # Label-map scenes default to SNAP_MM and "axis"; the phantom's tip is exact and snap_to unused.
    snap_mm: Annotated[float, Field(gt=0, le=20)] | None = None
    snap_to: Literal["node", "axis"] = "node"
    # effects.guide_contact (contact.py): the rigid rounded tip, a sphere touching the wall at the tip
    tip_radius_mm: Annotated[float, Field(gt=0, le=50)] = 6.0
    contact_stiffness_kpa_mm: Annotated[float, Field(gt=0, le=1e8)] = 3e4  # augmented-Lagrangian penalty k
    contact_tol_mm: Annotated[float, Field(gt=0, le=1)] = 0.005  # largest penetration left in a solution

    @model_validator(mode="after")
    def _axes(self) -> Guide:
        a, n = np.asarray(self.axis), np.asarray(self.tilt_normal)
        if np.linalg.norm(a) < 1e-9 or np.linalg.norm(n) < 1e-9:
            raise ValueError("axis and tilt_normal must be non-zero")
        if abs(a @ n) > 1e-6 * np.linalg.norm(a) * np.linalg.norm(n):
            raise ValueError("tilt_normal must be perpendicular to axis")
        return self

    def direction(self, angle_deg: float) -> np.ndarray:
        """Unit push direction a(beta): axis rotated by beta about tilt_normal (guide.direction)."""
        return guide_direction(self, angle_deg)


class Effects(_Strict):
    """Physical effects; only those switched on are assembled."""

    geometric_nonlinearity: bool = True
    table: bool = True  # frictionless table: bottom face slides, u_z = 0
    fixed_bones: bool = True  # pubic bone and spine held fixed
    gravity: bool = False
    # The guide tip as a rigid sphere in frictionless contact with the wall (contact.py), instead of
    # the glued patch. The linear model then is no longer superposable: each case is load-stepped.
    guide_contact: bool = False

    @model_validator(mode="after")
    def _constrained(self) -> Effects:
        if not self.fixed_bones:
            raise ValueError(
                "fixed_bones=false leaves the phantom free to translate in x and y; "
                "keep it on (the paper fixes the spine and pubic bone)"
            )
        return self


class Sweep(_Strict):
    """Grid of guide displacements x angles (paper: 40 x 21 = 840 cases)."""

    displacement_step_mm: Annotated[float, Field(gt=0, le=10)] = 0.25
    displacement_max_mm: Annotated[float, Field(gt=0, le=30)] = 10.0
    angle_min_deg: Annotated[float, Field(ge=-45, le=45)] = -10.0
    angle_max_deg: Annotated[float, Field(ge=-45, le=45)] = 10.0
    angle_step_deg: Annotated[float, Field(gt=0)] = 1.0

    @model_validator(mode="after")
    def _grid(self) -> Sweep:
        if self.angle_max_deg < self.angle_min_deg:
            raise ValueError("angle_max_deg must not be below angle_min_deg")
        if self.displacement_step_mm > self.displacement_max_mm:
            raise ValueError("displacement_step_mm must not exceed displacement_max_mm")
        return self

    @property
    def displacements_mm(self) -> np.ndarray:
        n = int(round(self.displacement_max_mm / self.displacement_step_mm))
        return self.displacement_step_mm * np.arange(1, n + 1)

    @property
    def angles_deg(self) -> np.ndarray:
        n = int(round((self.angle_max_deg - self.angle_min_deg) / self.angle_step_deg))
        return self.angle_min_deg + self.angle_step_deg * np.arange(n + 1)


class MeshSize(_Strict):
    """Target element sizes (mm) of the gmsh size field."""

    max_mm: Annotated[float, Field(gt=0.05, le=100)] = 12.0
    prostate_mm: Annotated[float, Field(gt=0.05, le=100)] = 4.0
    guide_mm: Annotated[float, Field(gt=0.05, le=100)] = 2.0
    # On the prostate's surface within 2 patch radii of the guide tip (growing to max_mm over 5 mm off the
    # surface and 1 patch radius beyond that ball), where the surface's discretisation error is largest
    # (docs/convergence.md, "A fifth level"); None: no such zone. The phantom's gmsh mesh only.
    surface_near_tip_mm: Annotated[float, Field(gt=0.05, le=100)] | None = None


Volumetric = Literal["pointwise", "mean_dilatation", "taylor_hood"]
VOLUMETRIC: tuple[str, ...] = get_args(Volumetric)  # the choices of solver.volumetric, for the scripts' --volumetric


class Solver(_Strict):
    """Newton and load-stepping controls."""

    rtol: Annotated[float, Field(gt=0, lt=1)] = 1e-6  # ||r_free|| / ||reactions||
    max_iterations: Annotated[int, Field(ge=1, le=500)] = 40
    max_halvings: Annotated[int, Field(ge=0, le=12)] = 6
    max_step_mm: Annotated[float, Field(gt=0, le=10)] = 0.25  # guide increment per load step
    # "pointwise": the P2 element as it is; "mean_dilatation": the volumetric term at each tet's mean
    # volume ratio (P2/P0, against volumetric locking at nu -> 0.5; fem_offline/elasticity.py);
    # "taylor_hood": a P1 pressure per tissue, eliminated in Newton (P2/P1, fem_offline/mixed.py)
    volumetric: Volumetric = "pointwise"


SNAP_MM = 2.0  # default guide.snap_mm of a label-map scene: about two voxels of a clinical T2 segmentation


class Scene(_Strict):
    name: str = "scene"
    phantom: Phantom | None = Phantom()
    mesh_file: UserMesh | None = None
    label_map: LabelMap | None = None
    tissues: dict[str, Tissue]
    guide: Guide = Guide()
    effects: Effects = Effects()
    sweep: Sweep = Sweep()
    mesh: MeshSize = MeshSize()
    solver: Solver = Solver()

    @model_validator(mode="before")
    @classmethod
    def _file_geometry_defaults(cls, data):
        """A mesh-file or label-map scene has no phantom; a label map's guide tip snaps to the lumen surface by default."""
        if not isinstance(data, dict):
            return data
        if data.get("mesh_file") is not None or data.get("label_map") is not None:
            data = {**data, "phantom": data.get("phantom")}
        if data.get("label_map") is not None:
            guide = data.get("guide", {})
            if isinstance(guide, dict):
                data["guide"] = {"snap_mm": SNAP_MM, "snap_to": "axis", **guide}
        return data

    @model_validator(mode="after")
    def _geometry_source(self) -> Scene:
        sources = [n for n in ("phantom", "mesh_file", "label_map") if getattr(self, n) is not None]
        if len(sources) > 1:
            raise ValueError(f"give one geometry source, not {' and '.join(sources)}")
        if self.label_map is not None:
            missing = set(self.label_map.tissue_names) - set(self.tissues)
            if missing:
                raise ValueError(f"label_map names tissues not in [tissues]: {sorted(missing)}")
            if self.mesh.surface_near_tip_mm is not None:
                raise ValueError("mesh.surface_near_tip_mm: the label-map meshers do not grade by it; leave it out")
        elif self.mesh_file is not None:
            missing = set(self.mesh_file.tags) - set(self.tissues)
            if missing:
                raise ValueError(f"mesh_file.tags names tissues not in [tissues]: {sorted(missing)}")
        else:
            missing = set(PHANTOM_TISSUES) - set(self.tissues)
            if missing:
                raise ValueError(f"the phantom needs [tissues.{'], ['.join(sorted(missing))}]")
            problem = tip_problem(self.phantom, self.guide)
            if problem:
                raise ValueError(problem)
        return self

    def sha256(self) -> str:
        """Hash of the validated scene (canonical JSON), recorded with every artifact."""
        data = self.model_dump(mode="json")
        # Fields added later are left out while at their default, so the scenes, sweeps and models
        # made before them keep their hashes.
        for section, key in _LATER_FIELDS:
            parent = data if section is None else data.get(section)
            if parent is None:  # an optional section the scene does not have (label_map)
                continue
            model = type(self) if section is None else type(getattr(self, section))
            if parent.get(key) == model.model_fields[key].default:
                parent.pop(key, None)
        blob = json.dumps(data, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()


_LATER_FIELDS = ((None, "label_map"), ("guide", "snap_mm"), ("guide", "snap_to"), ("guide", "tip_radius_mm"),
                 ("guide", "contact_stiffness_kpa_mm"), ("guide", "contact_tol_mm"), ("effects", "guide_contact"),
                 ("label_map", "facet_distance_voxels"), ("solver", "volumetric"), ("mesh", "surface_near_tip_mm"))
PHANTOM_TISSUES = ("adipose", "rectal_wall", "prostate", "bladder", "pubic_bone", "spine")


def _field_path(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if p not in ("function-after",)) or "<root>"


def parse_scene(data: dict, *, source: str = "scene") -> Scene:
    """Validate a scene dict; raise SceneError naming each bad field."""
    try:
        return Scene.model_validate(data)
    except ValidationError as exc:
        lines = [f"{_field_path(e['loc'])}: {e['msg']}" for e in exc.errors()]
        raise SceneError(f"{source}: " + "; ".join(lines)) from None


def _merged(base: dict, over: dict) -> dict:
    """`over` on top of `base`, table by table: a key in both tables is merged, any other value replaced."""
    out = dict(base)
    for key, value in over.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def _read_scene_toml(path: Path, chain: tuple[Path, ...] = ()) -> dict:
    """A scene file's data with its file paths made absolute and the scene it `extends` merged underneath."""
    if path.resolve() in chain:
        raise SceneError(f"{path}: extends itself ({' -> '.join(p.name for p in (*chain, path))})")
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from None
    for section in ("mesh_file", "label_map"):
        if isinstance(data.get(section), dict) and "path" in data[section]:
            file = Path(data[section]["path"])
            data[section]["path"] = str(file if file.is_absolute() else path.parent / file)
            data.setdefault("phantom", None)
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise SceneError(f"{path}: extends: expected the file name of a scene, got {base!r}")
    return _merged(_read_scene_toml(path.parent / base, (*chain, path.resolve())), data)


def load_scene(path: str | Path, **overrides) -> Scene:
    """Read and validate a TOML scene; relative file paths resolve against the scene's folder.

    `extends = "default.toml"` (relative to the file) starts from another scene: the file's own
    tables are merged over it key by key, so a variant states only what differs.
    """
    path = Path(path)
    data = _read_scene_toml(path)
    data.update(overrides)
    return parse_scene(data, source=str(path))
