"""`python -m service estimate|plan`: the routes' replies offline, and their refusals as one line per field, exit 2."""

import json

from service.__main__ import main

from ..helpers import predict_json, prostate_point


def test_plan_offline_is_the_routes_reply(tiny_client, tiny_model, tiny_folder, capsys):
    lesion = prostate_point(tiny_folder)
    assert main(["plan", "--model", str(tiny_model), "--lesion-mm", *map(str, lesion), "--displacement-mm", "3"]) == 0
    offline = json.loads(capsys.readouterr().out)
    served = tiny_client.post("/plan", json={"lesion_mm": lesion, "displacement_mm": 3.0}).json()
    assert offline == served


def test_estimate_offline_reads_the_body_from_a_file(tiny_client, tiny_model, tmp_path, capsys):
    at = predict_json(tiny_client, region="markers", displacement_mm=3.0, angle_deg=1.0)["positions"]
    body = {"markers": [{"index": i, "position_mm": p, "std_mm": 0.05} for i, p in enumerate(at)]}
    (tmp_path / "body.json").write_text(json.dumps(body))
    assert main(["estimate", "--model", str(tiny_model), "--body", str(tmp_path / "body.json")]) == 0
    offline = json.loads(capsys.readouterr().out)
    assert offline == tiny_client.post("/estimate", json=body).json()


def test_a_refused_body_names_the_field_and_exits_2(tiny_model, capsys):
    assert main(["plan", "--model", str(tiny_model), "--lesion-mm", "0", "0", "500"]) == 2
    assert capsys.readouterr().err.startswith("error: lesion_mm.2:")
    assert main(["estimate", "--model", str(tiny_model)]) == 2
    assert "--body" in capsys.readouterr().err
