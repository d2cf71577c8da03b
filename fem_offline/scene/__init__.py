"""The scene: what a user states about anatomy, tissues, guide, effects, sweep and mesh (schema.py), read from
TOML with `extends` (load.py), with the phantom's anatomy checks (anatomy.py). Imports nothing from the FE."""

from fem_offline.scene.load import SceneError, load_scene, parse_scene
from fem_offline.scene.schema import (PHANTOM_TISSUES, SNAP_MM, VOLUMETRIC, Effects, Guide, LabelMap, MaterialInput,
                                      MeshSize, Phantom, Scene, Solver, Sweep, Tissue, UserMesh, youngs_from_shear_wave_kpa)

__all__ = ["PHANTOM_TISSUES", "SNAP_MM", "VOLUMETRIC", "Effects", "Guide", "LabelMap", "MaterialInput", "MeshSize", "Phantom", "Scene",
           "SceneError", "Solver", "Sweep", "Tissue", "UserMesh", "load_scene", "parse_scene", "youngs_from_shear_wave_kpa"]
