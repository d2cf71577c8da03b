"""The model folder contract: the committed default model reads back; a stale or altered folder is refused,
saying why."""

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


def test_a_manifest_promising_inputs_its_graph_lacks_is_refused(tmp_path, tiny_model, tiny_material_model):
    """A material manifest over a plain graph would answer every request with a 500: refused at start instead."""
    from contracts.model import check_graph

    check_graph(read_model_folder(tiny_model))
    check_graph(read_model_folder(tiny_material_model))
    for graph, manifest, message in ((tiny_model, tiny_material_model, "takes no materials or materials_std input"),
                                     (tiny_material_model, tiny_model, "the manifest declares none")):
        bad = tmp_path / graph.name
        shutil.copytree(graph, bad)
        data = json.loads((bad / "manifest.json").read_text())
        data["materials"] = json.loads((manifest / "manifest.json").read_text()).get("materials")
        (bad / "manifest.json").write_text(json.dumps(data))
        with pytest.raises(ModelError, match=message):
            check_graph(read_model_folder(bad))
