"""Segmentation label maps: read and write NIfTI (.nii, .nii.gz) and NRRD (.nrrd, .seg.nrrd); map labels to tissues.

A label map is an integer image and an affine A (4, 4) taking a voxel's index (i, j, k, 1) to the
position of the voxel's centre in patient coordinates, mm, RAS+ (+x towards the patient's right,
+y anterior, +z superior): the frame NIfTI stores and 3D Slicer displays. NRRD files in LPS+
(Slicer's default for .seg.nrrd) are converted, (x, y, z)_RAS = (-x, -y, z)_LPS, so a NIfTI and an
NRRD export of one segmentation give the same mesh. Meshes and scene coordinates (the guide tip)
are in this frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from contracts.files import sha256
from contracts.sweep import LabelMapSource

LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0])
NIFTI_SUFFIXES = (".nii", ".nii.gz")
NRRD_SUFFIXES = (".nrrd", ".seg.nrrd")
OUTSIDE = -1  # tissue index of a voxel that is not tissue (air, the rectal lumen)


@dataclass(frozen=True)
class LabelImage:
    labels: np.ndarray  # (ni, nj, nk) integer label values
    affine: np.ndarray  # (4, 4) voxel index -> RAS mm of the voxel centre

    @property
    def spacing_mm(self) -> np.ndarray:
        """Voxel size along i, j, k (3,)."""
        return np.linalg.norm(self.affine[:3, :3], axis=0)

    @property
    def voxel_volume_mm3(self) -> float:
        return float(abs(np.linalg.det(self.affine[:3, :3])))

    def to_physical(self, index: np.ndarray) -> np.ndarray:
        """RAS mm (k, 3) of (continuous) voxel indices (k, 3)."""
        return index @ self.affine[:3, :3].T + self.affine[:3, 3]

    def to_index(self, points_mm: np.ndarray) -> np.ndarray:
        """Continuous voxel indices (k, 3) of RAS points (k, 3) mm; voxel centres are integers."""
        return (points_mm - self.affine[:3, 3]) @ np.linalg.inv(self.affine[:3, :3]).T


def _suffix(path: Path) -> str:
    name = path.name.lower()
    for s in sorted(NIFTI_SUFFIXES + NRRD_SUFFIXES, key=len, reverse=True):
        if name.endswith(s):
            return s
    return path.suffix


def read_label_map(path: str | Path, field: str = "label_map.path") -> LabelImage:
    """Read a label map; ValueError naming `field` when it is missing, not integer, 4-D or has no spacing."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{field}: no such file {path}")
    suffix = _suffix(path)
    if suffix in NIFTI_SUFFIXES:
        labels, affine = _read_nifti(path, field)
    elif suffix in NRRD_SUFFIXES:
        labels, affine = _read_nrrd(path, field)
    else:
        raise ValueError(f"{field}: {path.name}: use a NIfTI (.nii, .nii.gz) or NRRD (.nrrd, .seg.nrrd) label map")
    if labels.ndim != 3:
        raise ValueError(f"{field}: {path.name} is {labels.ndim}-D with shape {labels.shape}; a label map is 3-D")
    if not np.issubdtype(labels.dtype, np.integer):
        if not np.all(np.isfinite(labels)) or not np.array_equal(labels, np.round(labels)):
            raise ValueError(f"{field}: {path.name} holds non-integer values; a label map holds integer labels")
        labels = labels.astype(np.int64)
    if np.linalg.matrix_rank(affine[:3, :3]) < 3 or not np.isfinite(affine).all():
        raise ValueError(f"{field}: {path.name} has a singular or non-finite voxel-to-patient matrix")
    return LabelImage(np.ascontiguousarray(labels), affine)


def _read_nifti(path: Path, field: str) -> tuple[np.ndarray, np.ndarray]:
    import nibabel

    try:
        img = nibabel.load(path)
    except Exception as exc:  # nibabel raises several types for a corrupt file
        raise ValueError(f"{field}: cannot read {path.name} as NIfTI: {exc}") from None
    header = img.header
    if int(header["qform_code"]) == 0 and int(header["sform_code"]) == 0:
        raise ValueError(f"{field}: {path.name} has no spacing or orientation (qform_code = sform_code = 0)")
    if any(z <= 0 for z in header.get_zooms()[:3]):
        raise ValueError(f"{field}: {path.name} has no spacing (pixdim {header.get_zooms()[:3]})")
    data = np.asanyarray(img.dataobj)
    if data.ndim == 4 and data.shape[3] == 1:
        data = data[..., 0]
    return data, np.asarray(img.affine, dtype=np.float64)


def _read_nrrd(path: Path, field: str) -> tuple[np.ndarray, np.ndarray]:
    import nrrd

    try:
        data, header = nrrd.read(str(path))
    except Exception as exc:  # pynrrd raises NRRDError and others for a corrupt file
        raise ValueError(f"{field}: cannot read {path.name} as NRRD: {exc}") from None
    if "space directions" in header:
        rows = np.asarray(header["space directions"], dtype=np.float64)
        spatial = ~np.isnan(rows).any(axis=1)
        if data.ndim == 4 and spatial.sum() == 3:  # .seg.nrrd with a layer axis: (layers, i, j, k)
            layer_axis = int(np.flatnonzero(~spatial)[0])
            if data.shape[layer_axis] != 1:
                raise ValueError(f"{field}: {path.name} has overlapping segments in {data.shape[layer_axis]} layers; "
                                 "export a labelmap (Segmentations > Export to files, or a labelmap volume)")
            data = np.squeeze(data, axis=layer_axis)
        directions = rows[spatial].T  # column a = axis a's step in mm
    elif "spacings" in header:
        directions = np.diag(np.asarray(header["spacings"], dtype=np.float64)[:3])
    else:
        raise ValueError(f"{field}: {path.name} has no spacing (neither 'space directions' nor 'spacings')")
    if directions.shape != (3, 3):
        raise ValueError(f"{field}: {path.name} has no 3-D spacing (space directions {directions.tolist()})")
    origin = np.asarray(header.get("space origin", np.zeros(3)), dtype=np.float64)
    if str(header.get("space", "")).lower() in ("left-posterior-superior", "lps"):
        directions, origin = LPS_TO_RAS @ directions, LPS_TO_RAS @ origin
    affine = np.eye(4)
    affine[:3, :3], affine[:3, 3] = directions, origin
    return data, affine


def write_label_map(path: str | Path, image: LabelImage) -> Path:
    """Write a label map: NIfTI (RAS affine, sform and qform set) or NRRD (LPS, as 3D Slicer writes it)."""
    path = Path(path)
    suffix = _suffix(path)
    labels = image.labels.astype(np.uint8 if image.labels.max() < 256 and image.labels.min() >= 0 else np.int16)
    if suffix in NIFTI_SUFFIXES:
        import nibabel

        img = nibabel.Nifti1Image(labels, image.affine)
        img.set_qform(image.affine, code=1)
        img.set_sform(image.affine, code=1)
        img.header.set_xyzt_units("mm")
        nibabel.save(img, path)
    elif suffix in NRRD_SUFFIXES:
        import nrrd

        header = {"space": "left-posterior-superior", "space directions": (LPS_TO_RAS @ image.affine[:3, :3]).T,
                  "space origin": LPS_TO_RAS @ image.affine[:3, 3], "kinds": ["domain"] * 3, "encoding": "gzip"}
        nrrd.write(str(path), labels, header)
    else:
        raise ValueError(f"--out: {path.name}: use .nii, .nii.gz, .nrrd or .seg.nrrd")
    return path


def source_of(spec) -> LabelMapSource:
    """What the sweep and model manifests record of a scene's label map (contracts.sweep.LabelMapSource)."""
    image = read_label_map(spec.path)
    return LabelMapSource(file=Path(spec.path).name, sha256=sha256(spec.path), shape=image.labels.shape,
                          spacing_mm=tuple(float(s) for s in image.spacing_mm), affine=image.affine.tolist(),
                          labels=dict(spec.labels), background=spec.background, outside=list(spec.outside))
