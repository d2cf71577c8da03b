"""Scene files: TOML with `extends` (load.py), validated into the scene contract (contracts.scene: the schema,
the phantom's anatomy checks, the sha256), whose names are re-exported here. Imports nothing from the FE."""

from contracts.scene import (PHANTOM_TISSUES, SNAP_MM, VOLUMETRIC, Effects, Guide, LabelMap, MaterialInput, MeshSize,
                             Phantom, Scene, SceneError, Solver, Sweep, Tissue, UserMesh, parse_scene)
from fem_offline.scene.load import load_scene

__all__ = ["PHANTOM_TISSUES", "SNAP_MM", "VOLUMETRIC", "Effects", "Guide", "LabelMap", "MaterialInput", "MeshSize",
           "Phantom", "Scene", "SceneError", "Solver", "Sweep", "Tissue", "UserMesh", "load_scene", "parse_scene"]
