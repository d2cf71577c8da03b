"""The model folder contract: the committed default model reads back; a stale or altered folder is refused, saying why."""

import json
import shutil
from pathlib import Path

import pytest

from contracts.model import ModelError, ModelManifest, read_model_folder

DEFAULT = Path(__file__).resolve().parents[2] / "models" / "default"


def test_manifest_round_trips_through_its_json():
    folder = read_model_folder(DEFAULT)
    assert ModelManifest.model_validate_json(folder.manifest.model_dump_json()) == folder.manifest
    assert folder.manifest.envelope.displacement_mm[0] == 0.0  # the model answers from rest
    assert {k: len(v) for k, v in folder.regions.items()} == folder.manifest.regions


@pytest.mark.parametrize(("change", "message"), [
    ({"format_version": 1}, "model format 1, this code reads 2; rebuild the model"),
    ({"envelope": {"displacement_mm": [0, 10]}}, "envelope.angle_deg: Field required"),
    ({"regions": {"markers": 8}}, "the regions in mesh.npz differ from the manifest's"),
])
def test_a_stale_or_edited_manifest_is_refused_with_its_reason(tmp_path, change, message):
    bad = tmp_path / "m"
    shutil.copytree(DEFAULT, bad)
    data = json.loads((bad / "manifest.json").read_text())
    (bad / "manifest.json").write_text(json.dumps({**data, **change}))
    with pytest.raises(ModelError, match=message):
        read_model_folder(bad)
