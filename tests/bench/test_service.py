"""The service benchmark names the models it measured relative to the repository, in its result and in the committed
ones: a result holds no machine's paths."""

import json
from pathlib import Path

import pytest

from bench.service import model_name
from studies.results import DOCS_RESULTS, ROOT


def test_a_model_in_the_repository_is_named_from_its_root_however_it_was_given(monkeypatch):
    assert model_name(ROOT / "models" / "default") == "models/default"
    monkeypatch.chdir(ROOT / "docs")
    assert model_name(Path("../runs/paper_decoder/model")) == "runs/paper_decoder/model"


def test_a_model_outside_the_repository_is_named_as_given(tmp_path):
    assert model_name(tmp_path / "patient_a") == str(tmp_path / "patient_a")


@pytest.mark.parametrize("name", ["bench_service", "bench_service_defaults"])
def test_the_committed_results_name_their_models_relative_to_the_repository(name):
    data = json.loads((DOCS_RESULTS / f"{name}.json").read_text())
    named = list(data.get("models", {})) + [row["model"] for row in data.get("rows", [])]
    assert named and all(not Path(m).is_absolute() and ".." not in Path(m).parts for m in named)
