"""Voxelise a phantom scene into a label map and write the label-map scene that reads it.

    python -m studies make-labelmap --scene fem_offline/scenes/tiny.toml --spacing-mm 1 --out runs/lm_tiny
    -> runs/lm_tiny/labels.nii.gz (or --format seg.nrrd) and runs/lm_tiny/scene.toml
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import tomli_w

from contracts.cli import number
from fem_offline.labelmap.io import write_label_map
from fem_offline.scene import SceneError, load_scene
from studies.phantom_labelmap import labelmap_scene, voxelise


def write_labelmap(scene, spacing_mm: float, folder: Path, *, fmt: str = "nii.gz", name: str | None = None):
    """Voxelise the phantom `scene` into folder/labels.<fmt> and write folder/scene.toml, the label-map scene
    that reads it (named `name`, else the labelmap_scene default); returns the voxel image."""
    image = voxelise(scene.phantom, spacing_mm)
    folder.mkdir(parents=True, exist_ok=True)
    labels = write_label_map(folder / f"labels.{fmt}", image)
    (folder / "scene.toml").write_text(tomli_w.dumps(labelmap_scene(scene, labels.name, name=name)))
    return image


def main(argv: list[str] | None = None) -> int | None:
    ap = argparse.ArgumentParser(prog="python -m studies make-labelmap", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", required=True, type=Path, help="a phantom scene")
    ap.add_argument("--spacing-mm", type=number("--spacing-mm", minimum=0.05), default=1.0)
    ap.add_argument("--out", required=True, type=Path, help="folder for labels.<format> and scene.toml")
    ap.add_argument("--format", choices=("nii.gz", "nii", "nrrd", "seg.nrrd"), default="nii.gz")
    args = ap.parse_args(argv)
    try:
        scene = load_scene(args.scene)
        if scene.phantom is None:
            raise SceneError(f"{args.scene}: not a phantom scene")
        image = write_labelmap(scene, args.spacing_mm, args.out, fmt=args.format)
    except (SceneError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    labels = args.out / f"labels.{args.format}"
    counts = np.bincount(image.labels.ravel())
    print(f"{labels}: {image.labels.shape} voxels of {args.spacing_mm} mm, label counts {counts.tolist()}; "
          f"{args.out / 'scene.toml'}")
    return 0
