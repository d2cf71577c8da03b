"""The scene's schema: anatomy, tissues, needle guide, physical effects, the sweep grid, mesh sizes, solver.

Pydantic models; unknown keys and out-of-range values are errors that name the field (parse.py turns
them into ``SceneError``). Units: lengths in mm, moduli in kPa, densities in kg/m^3, angles in degrees.
A scene a manifest recorded is read with the context RECORDED (parse.recorded_scene): the checks on what a user
states (anatomy, the guide tip on the lumen, the material ranges) are not run again on it.
"""

from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path
from typing import Annotated, Literal, get_args

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, PrivateAttr, ValidationInfo, model_serializer, model_validator

from contracts.guide import push_direction
from contracts.materials import sigma_ln_e, youngs_from_shear_wave_kpa

from .anatomy import problems as anatomy_problems
from .anatomy import tip_problem
from .recorded import LATER_FIELDS, drop

Vec3 = tuple[float, float, float]
Positive = Annotated[float, Field(gt=0)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


RECORDED = "recorded"  # validation context: a scene read back from a manifest, valid when it was solved


def _user_checks(info: ValidationInfo) -> bool:
    """Whether to judge what a user states: not for a recorded scene, so a check made stricter since it was solved
    does not make its sweep or model unreadable."""
    return not (info.context or {}).get(RECORDED, False)


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


MEASURED_BOX_SIGMAS = 2.0  # a measured E's box: this many std of ln E either side of the measurement


class MaterialInput(_Strict):
    """A tissue whose stiffness the model takes as input: the range it answers for and the default uncertainty.

    The nominal E (theta = 0) is the tissue's own stiffness in [tissues]; it must lie inside the range. A patient's
    scene may state the measured E instead of a range, `measured_youngs_kpa` with its `std_percent`: the range is
    then the measurement x exp(-/+ 2 sigma), sigma = std_percent / 100 (contracts.materials.sigma_ln_e), replacing
    the range and source the scene inherits; the scene keeps the range, not the measurement (it states what the
    sweep solves). Set the tissue's E in [tissues] to the measurement too: it is the nominal, inside the range.
    """

    youngs_kpa_range: tuple[Positive, Positive]
    std_percent: Annotated[float, Field(gt=0, le=100)]  # default 1-sigma measurement uncertainty of E, %
    source: str = ""  # where the range and the uncertainty come from (docs/materials.md)

    @model_validator(mode="before")
    @classmethod
    def _measured(cls, data):
        """measured_youngs_kpa and std_percent -> youngs_kpa_range of +- MEASURED_BOX_SIGMAS sigma of ln E."""
        if not isinstance(data, dict) or "measured_youngs_kpa" not in data:
            return data
        # it replaces a youngs_kpa_range and source, which a patient's scene inherits from the one it extends
        data = {k: v for k, v in data.items() if k not in ("youngs_kpa_range", "source")}
        measured = data.pop("measured_youngs_kpa")
        percent = data.get("std_percent")
        if not (isinstance(measured, (int, float)) and measured > 0 and isinstance(percent, (int, float))
                and 0 < percent <= 100):
            raise ValueError("measured_youngs_kpa must be a positive E in kPa, with std_percent "
                             "(0 < % <= 100) its 1-sigma")
        half = MEASURED_BOX_SIGMAS * sigma_ln_e(std=percent, value=100.0)
        data["youngs_kpa_range"] = (measured * math.exp(-half), measured * math.exp(half))
        data["source"] = (f"measured {measured:g} kPa, std {percent:g} %: the range is +- {MEASURED_BOX_SIGMAS:g} "
                          "sigma of ln E")
        return data

    @model_validator(mode="after")
    def _ordered(self) -> MaterialInput:
        if not self.youngs_kpa_range[0] < self.youngs_kpa_range[1]:
            raise ValueError(f"youngs_kpa_range: lower bound {self.youngs_kpa_range[0]} must be below the upper")
        return self


MaterialInputs = dict[str, MaterialInput]  # soft tissue -> its input, in the model's input order


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
    def _anatomy(self, info: ValidationInfo) -> Phantom:
        """Shapes inside the block, a rectal wall around the lumen, no organ cut by another (anatomy.problems)."""
        if self.rectum_inner_radius_mm >= self.rectum_outer_radius_mm:
            raise ValueError("rectum_inner_radius_mm must be below rectum_outer_radius_mm")
        found = anatomy_problems(self) if _user_checks(info) else []
        if found:
            raise ValueError("; ".join(found))
        return self


class UserMesh(_Strict):
    """A user's tetrahedral mesh (anything meshio reads) with a cell tag per tissue."""

    path: Path
    tag_field: str = "gmsh:physical"
    tags: dict[str, int]  # tissue name -> tag value


class LabelMap(_Strict):
    """A segmentation label map (NIfTI or NRRD, fem_offline.labelmap.io) and the tissue of each label value.

    Voxels of label 0 are `background` tissue (adipose unless the scene says otherwise), or outside
    the body when `background` is empty; voxels of an `outside` value (the rectal lumen, air) are
    not meshed. Any other value in the image must be in `labels`.
    """

    path: Path
    labels: dict[str, Annotated[int, Field(gt=0)]]  # tissue name -> label value
    background: str = "adipose"  # tissue of label-0 voxels; "" = label 0 is outside the body
    outside: tuple[Annotated[int, Field(gt=0)], ...] = ()
    mesher: Literal["cgal", "ftetwild", "tetgen"] = "cgal"  # `python -m studies compare-meshers` measures them
    # CGAL only: how far a surface facet may stray from the labels' boundary, in voxels (the smallest
    # spacing). It sets the surface triangles, and so most of the tets: 0.5 gives 21,900 tets on the
    # medium variant's 1 mm map, 1.0 13,900 (`python -m studies labelmap-truth` measures what it costs).
    facet_distance_voxels: Annotated[float, Field(gt=0, le=4)] = 0.5

    @model_validator(mode="after")
    def _distinct(self) -> LabelMap:
        # a dumped scene carries the default, so only another value is refused
        default = LabelMap.model_fields["facet_distance_voxels"].default
        if self.facet_distance_voxels != default and self.mesher != "cgal":
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
    # When set, k = contact_stiffness_per_mm x the stiffest deforming tissue's E instead (kPa/mm): the penalty scales
    # with the tissues, so every E x s (k x s with it) gives the same u and the sensitivities sum to zero
    # (fe/sensitivity.py); fe/contact.penalty says why the stiffest. None: the fixed contact_stiffness_kpa_mm.
    contact_stiffness_per_mm: Annotated[float, Field(gt=0, le=1e6)] | None = None
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
        """Unit push direction a(beta) (3,): axis rotated by beta about tilt_normal (contracts.guide)."""
        return push_direction(self.axis, self.tilt_normal, angle_deg)


class Effects(_Strict):
    """Physical effects; only those switched on are assembled."""

    geometric_nonlinearity: bool = True
    table: bool = True  # frictionless table: bottom face slides, u_z = 0
    fixed_bones: bool = True  # pubic bone and spine held fixed
    gravity: bool = False
    # The guide tip as a rigid sphere in frictionless contact with the wall (fe/contact.py). False: the
    # glued patch, which does not converge near the tip under mesh refinement (docs: Grid convergence);
    # it stays for fast tests, where the linear model is superposable and no case is load-stepped.
    guide_contact: bool = True

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
    # volume ratio (P2/P0, against volumetric locking at nu -> 0.5; fem_offline/fe/elasticity.py);
    # "taylor_hood": a P1 pressure per tissue, eliminated in Newton (P2/P1, fem_offline/fe/mixed.py)
    # The default: at nu = 0.495 the pointwise P2 element locks in volume change (studies locking-check).
    volumetric: Volumetric = "taylor_hood"


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
    # Tissue stiffnesses as model inputs (the sweep then stores du/d ln E per tissue); None: no material inputs
    materials: MaterialInputs | None = None
    # The later fields the manifest this scene was read from lacked (parse.recorded_scene); empty for any other scene
    _absent: frozenset[tuple[str | None, str]] = PrivateAttr(frozenset())

    @model_validator(mode="before")
    @classmethod
    def _file_geometry_defaults(cls, data):
        """A mesh-file or label-map scene has no phantom; a label map's guide tip snaps to the lumen surface by default;
        `materials = false` drops the material inputs a scene `extends` (TOML has no null)."""
        if not isinstance(data, dict):
            return data
        if data.get("materials") is False:  # `materials = false`: a variant without its base's material inputs
            data = {**data, "materials": None}
        if data.get("mesh_file") is not None or data.get("label_map") is not None:
            data = {**data, "phantom": data.get("phantom")}
        if data.get("label_map") is not None:
            guide = data.get("guide", {})
            if isinstance(guide, dict):
                data["guide"] = {"snap_mm": SNAP_MM, "snap_to": "axis", **guide}
        return data

    @model_validator(mode="after")
    def _geometry_source(self, info: ValidationInfo) -> Scene:
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
            problem = tip_problem(self.phantom, self.guide) if _user_checks(info) else None
            if problem:
                raise ValueError(problem)
        if _user_checks(info):
            self._check_materials()
        return self

    def _check_materials(self) -> None:
        """Each material input names a soft tissue of the scene whose E lies inside its range."""
        for name, m in (self.materials or {}).items():
            tissue = self.tissues.get(name)
            if tissue is None:
                raise ValueError(f"materials.{name}: not a tissue of [tissues]")
            if tissue.bone:
                raise ValueError(f"materials.{name}: a bone is held fixed; its stiffness moves nothing")
            lo, hi = m.youngs_kpa_range
            if not lo <= tissue.youngs <= hi:
                raise ValueError(f"materials.{name}.youngs_kpa_range: [{lo:g}, {hi:g}] kPa must hold the tissue's E "
                                 f"{tissue.youngs:g} kPa (the nominal)")

    def sha256(self) -> str:
        """Hash of the validated scene (canonical JSON), recorded with every artifact."""
        return hashlib.sha256(json.dumps(self._canonical(), sort_keys=True).encode()).hexdigest()

    def content_sha256(self) -> str:
        """Hash of what the scene states, its name left out: two files that say the same physics share it."""
        data = self._canonical()
        data.pop("name")
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()

    def _canonical(self) -> dict:
        # Fields added later are left out while at the value they had before they existed, so the scenes,
        # sweeps and models made before them keep their hashes (also after a default changed; recorded.py).
        return drop(self.model_dump(mode="json"), LATER_FIELDS)

    @model_serializer(mode="wrap")
    def _as_recorded(self, handler):
        """The fields; a recorded scene leaves out again the later fields its manifest lacked while they still hold
        their value from before, so the manifest is written back as the same bytes (recorded.py)."""
        return drop(handler(self), self._absent)

    def __eq__(self, other: object) -> bool:
        """The same fields: how a manifest spelled the scene (the later fields it lacked) is no part of it."""
        return self.__dict__ == other.__dict__ if isinstance(other, Scene) else NotImplemented


PHANTOM_TISSUES = ("adipose", "rectal_wall", "prostate", "bladder", "pubic_bone", "spine")
