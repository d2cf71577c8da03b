"""The scene: what a user states about anatomy, tissues, guide, effects, sweep and mesh, and what every artifact made
from it records (a sweep's and a model's manifest hold it whole, with its sha256).

    schema.py    the pydantic models, their checks and the scene's sha256
    anatomy.py   the phantom's anatomy in numbers: clearances and the checks that keep a variant valid
    recorded.py  the fields added later, and what a scene recorded before each meant by its absence
    parse.py     a scene from JSON: a user's (parse_scene) or a manifest's (recorded_scene, RecordedScene)

Needs only numpy and pydantic. Reading scene files (TOML, `extends`) is fem_offline.scene's.
"""

from . import anatomy
from .parse import RecordedScene, SceneError, parse_scene, recorded_scene
from .schema import (MEASURED_BOX_SIGMAS, PHANTOM_TISSUES, SNAP_MM, VOLUMETRIC, Effects, Guide, LabelMap, MaterialInput,
                     MeshSize, Phantom, Scene, Solver, Sweep, Tissue, UserMesh, Volumetric)

__all__ = ["MEASURED_BOX_SIGMAS", "PHANTOM_TISSUES", "SNAP_MM", "VOLUMETRIC", "Effects", "Guide", "LabelMap",
           "MaterialInput", "MeshSize", "Phantom", "RecordedScene", "Scene", "SceneError", "Solver", "Sweep", "Tissue",
           "UserMesh", "Volumetric", "anatomy", "parse_scene", "recorded_scene"]
