"""End-to-end error of a configuration, its Pareto front and build-cost arithmetic, on hand-made inputs."""

import json
import shlex

import numpy as np
import pytest

from contracts.model import onnx_session
from training.tradeoff import (end_to_end, gci_bands, level_errors, makespan, pareto_mask, shaped_graph,
                               sweep_estimate)

CASES = ("10 mm, 0 deg", "5 mm, 5 deg")


def _level(scale, n_tets, offset, seconds):
    """Two markers per case: marker i of case c at (offset, i, c) mm."""
    return {"scale": scale, "n_tets": n_tets, "n_nodes": 2 * n_tets,
            "cases": {case: {"seconds": s, "markers": [[offset, 0.0, c], [offset, 1.0, c]]}
                      for c, (case, s) in enumerate(zip(CASES, seconds))}}


def _surface(change, band):
    return {"gci_mm": {"max": band, "p95": band / 2, "mean": band / 4}, "change_fine_medium_mm": {"max": change},
            "bound_medium_mm": {"max": change + band}}


def study():
    """Four levels, the three finest analysed (like a study resumed with a finer level)."""
    levels = [_level(2.0, 100, 0.9, (10.0, 4.0)), _level(1.69, 200, 0.5, (20.0, 8.0)),
              _level(1.3, 400, 0.2, (40.0, 16.0)), _level(1.0, 800, 0.0, (60.0, 40.0))]
    # the second-finest level (1.3) is 0.2 mm from the finest at every marker: its bound is that plus the band
    cases = {case: {"markers": [{"gci_vector_mm": 0.01 * (c + 1), "bound_medium_mm": 0.2 + 0.01 * (c + 1)},
                                {"gci_vector_mm": 0.05, "bound_medium_mm": 0.25}],
                    "surface_near_tip": _surface(1.0 + c, 0.7), "surface_rest": _surface(0.3, 0.2 + c),
                    "all_nodes": {"gci_mm": {"max": 2.0 + c}, "bound_medium_mm": {"max": 2.5 + c}}}
             for c, case in enumerate(CASES)}
    return {"levels": levels, "analysis": {"ratio": 1.3, "levels": [{k: lv[k] for k in ("scale", "n_tets", "n_nodes")}
                                                                    for lv in levels[1:]], "cases": cases}}


def test_finest_level_is_its_band():
    fine = level_errors(study())[-1]
    assert fine.fe_mm == pytest.approx({"markers": 0.05, "prostate_surface": 1.2, "all_nodes": 3.0})
    assert fine.fe_mm == pytest.approx(gci_bands(study()["analysis"]))


def test_coarser_level_is_distance_plus_the_finest_band():
    """Markers sit 0.5 mm (x) from the finest's on level 1.69: 0.5 + the largest band 0.05."""
    errs = level_errors(study())
    assert errs[1].fe_mm["markers"] == pytest.approx(0.55)
    assert errs[0].fe_mm["markers"] == pytest.approx(0.95)
    assert errs[2].fe_mm["markers"] == pytest.approx(0.25)


def test_surface_and_nodes_only_where_the_study_stores_them():
    """Second finest = the analysis's pointwise bound, distance + band (surface, case 1 near the tip: 2.0 + 0.7;
    every node 2.5 + 1); the coarser levels have markers only."""
    errs = level_errors(study())
    assert [sorted(e.fe_mm) for e in errs] == [["markers"], ["markers"], ["all_nodes", "markers", "prostate_surface"],
                                               ["all_nodes", "markers", "prostate_surface"]]
    assert errs[2].fe_mm == pytest.approx({"markers": 0.25, "prostate_surface": 2.7, "all_nodes": 3.5})
    assert errs[2].fe_mm == pytest.approx(gci_bands(study()["analysis"], "medium"))


def test_path_seconds_is_the_full_push_mean():
    assert [e.path_seconds for e in level_errors(study())] == [10.0, 20.0, 40.0, 60.0]


def test_end_to_end_at_least_each_part_and_only_where_both_are_known():
    surrogate = {"markers": 0.003, "prostate_surface": 0.02, "all_nodes": 0.04}
    for lv in level_errors(study()):
        e2e = end_to_end(surrogate, lv.fe_mm)
        assert set(e2e) == set(lv.fe_mm)
        for region, value in e2e.items():
            assert value >= surrogate[region] and value >= lv.fe_mm[region]
            assert value == pytest.approx(surrogate[region] + lv.fe_mm[region])


def test_pareto_marks_exactly_the_undominated():
    cost = [1.0, 2.0, 3.0, 4.0, 2.0, 5.0, 4.0]
    error = [5.0, 3.0, 4.0, 1.0, 3.0, 1.0, 2.0]
    # (3, 4) is beaten by (2, 3); (5, 1) and (4, 2) by (4, 1); the two equal (2, 3) points do not beat each other
    assert pareto_mask(cost, error).tolist() == [True, True, False, True, True, False, False]


def test_makespan_and_sweep_estimate():
    assert makespan([3.0, 3.0, 3.0], 2) == 6.0
    assert makespan([5.0, 1.0, 1.0, 1.0], 2) == 5.0
    assert sweep_estimate(10.0, 11, 2) == 60.0  # 11 equal paths on 2 workers: 6 rounds


def test_shaped_graph_decodes_the_level_shape():
    rng = np.random.default_rng(1)
    layers = [(rng.standard_normal((2, 7)), rng.standard_normal(7)),
              (rng.standard_normal((7, 5)), rng.standard_normal(5))]
    sess = onnx_session(shaped_graph(layers, 123))
    guide = np.array([[3.0, 1.0]], dtype=np.float32)
    assert sess.run(None, {"guide": guide})[0].shape == (1, 123, 3)
    assert sess.run(None, {"guide": guide, "nodes": np.arange(10, dtype=np.int64)})[0].shape == (1, 10, 3)


def test_a_coarse_level_with_a_stored_bound_gets_surface_and_nodes():
    """Studies analysed since the coarse bound is stored (convergence.analyse): the third-finest level,
    where models/default is built, gets its surface and every-node errors from that bound."""
    s = study()
    for c, row in enumerate(s["analysis"]["cases"].values()):
        for i, r in enumerate(row["markers"]):
            r["bound_coarse_mm"] = 0.5 + 0.01 * (c + i)
        for zone in ("near_tip", "rest"):
            row[f"surface_{zone}"]["bound_coarse_mm"] = {"max": 3.0 + c}
        row["all_nodes"]["bound_coarse_mm"] = {"max": 4.0 + c}
    errs = level_errors(s)
    assert errs[1].fe_mm == pytest.approx({"markers": 0.52, "prostate_surface": 4.0, "all_nodes": 5.0})
    assert errs[0].fe_mm == level_errors(study())[0].fe_mm  # below the analysed levels: markers only


def test_a_level_under_the_analysed_three_with_a_stored_bound_gets_every_region():
    """Studies with a fourth level (convergence.analyse's bound_by_scale_mm): the level under the three, where
    models/default is built, is judged by its own pointwise bound in every region, not by markers alone."""
    s = study()
    for c, row in enumerate(s["analysis"]["cases"].values()):
        for i, r in enumerate(row["markers"]):
            r["bound_by_scale_mm"] = {"2": 0.9 + 0.01 * (c + i)}
        for zone in ("near_tip", "rest"):
            row[f"surface_{zone}"]["bound_by_scale_mm"] = {"2": {"max": 5.0 + c}}
        row["all_nodes"]["bound_by_scale_mm"] = {"2": {"max": 6.0 + c}}
    errs = level_errors(s)
    assert errs[0].fe_mm == pytest.approx({"markers": 0.92, "prostate_surface": 6.0, "all_nodes": 7.0})
    assert errs[0].fe_mm == pytest.approx(gci_bands(s["analysis"], "2"))


def _graded():
    """The graded-mesh study's result (python -m studies graded-mesh): one mesh,
    two cases (a full push and a half one)."""
    def case(m, s, n, seconds):
        return {"seconds": seconds, "markers_mm": m, "interior_mm": 0.0, "surface_probes_mm": {"max": s},
                "surface_own_nodes_mm": {"max": 0.0}, "all_nodes_mm": 0.0, "all_nodes_probes_mm": n}
    return {"kind": "graded_mesh",
            "meshes": [{"tag": "15.6_4_2", "sizes_mm": {"max": 15.6, "prostate": 4.0, "guide": 2.0},
                                               "n_tets": 6810, "n_nodes": 10123,
                                               "cases": {"10 mm, 0 deg": case(0.09, 0.15, 0.7, 120.0),
                                                         "10 mm, 10 deg": case(0.08, 0.16, 0.6, 150.0),
                                                         "5 mm, 5 deg": case(0.04, 0.08, 0.3, 90.0)}}]}


def test_a_graded_mesh_is_a_level_with_every_region_at_the_studys_points():
    """Max over the cases of each region's bound at the study's probe points (not at the mesh's own nodes), the
    full-push mean as its path time, named by its sizes; another file is refused."""
    from training.tradeoff import graded_levels

    (lv,) = graded_levels(_graded())
    assert lv.scale is None and lv.label == "graded 15.6:4:2 mm" and (lv.n_tets, lv.n_nodes) == (6810, 10123)
    assert lv.fe_mm == {"markers": 0.09, "prostate_surface": 0.16, "all_nodes": 0.7}
    assert lv.path_seconds == 135.0
    assert end_to_end({"markers": 0.001, "prostate_surface": 0.002, "all_nodes": 0.01},
                      lv.fe_mm)["markers"] == pytest.approx(0.091)
    with pytest.raises(ValueError, match="graded_mesh"):
        graded_levels({"kind": "model_vs_converged"})


def test_a_graded_mesh_judged_on_fewer_cases_is_left_out_and_named():
    """A mesh judged on one hard case only would report a max over less: it is no level; a shell size is named."""
    from training.tradeoff import graded_levels

    data = _graded()
    shell = json.loads(json.dumps(data["meshes"][0]))
    shell.update(tag="15.6_4_2_1.2", n_tets=8852,
                 sizes_mm={"max": 15.6, "prostate": 4.0, "guide": 2.0, "surface_near_tip": 1.2})
    partial = json.loads(json.dumps(shell))
    partial.update(tag="15.6_4_2_0.9", cases={"10 mm, 10 deg": shell["cases"]["10 mm, 10 deg"]})
    data["meshes"] += [shell, partial]
    skipped = []
    levels = graded_levels(data, skipped)
    assert [lv.label for lv in levels] == ["graded 15.6:4:2 mm", "graded 15.6:4:2:1.2 mm"]
    assert skipped == ["15.6_4_2_0.9"]


def test_each_committed_graded_mesh_names_the_command_that_judged_it():
    """The file merges meshes judged by several runs: each mesh's command, read by the study's own parser
    (python -m studies graded-mesh), asks for that mesh's sizes, the file's study levels and exactly the cases
    the mesh holds. The runs were of scripts/graded_mesh.py, which wrote the file itself (--json
    docs/graded_mesh_5levels.json, before docs/results/): their script path and --json are mapped to the
    command's form."""
    from pathlib import Path

    from studies import graded_mesh

    root = Path(__file__).resolve().parents[2]
    data = json.loads((root / "docs" / "results" / "graded_mesh.json").read_text())
    assert "command" not in data and data["commands"] == list(dict.fromkeys(m["command"] for m in data["meshes"]))
    for mesh in data["meshes"]:
        argv = shlex.split(mesh["command"])
        if argv[:2] == ["python", "scripts/graded_mesh.py"]:
            assert argv[-2:] == ["--json", "docs/graded_mesh_5levels.json"]
            argv = ["python", "-m", "studies", "graded-mesh", *argv[2:-2]]
        assert argv[:4] == ["python", "-m", "studies", "graded-mesh"]
        args = graded_mesh.parser().parse_args(argv[4:])
        assert [graded_mesh.tag(s) for s in args.sizes] == [mesh["tag"]]
        assert args.scales == data["scales"] and str(args.study) == data["study"]
        assert [f"{d:g} mm, {b:g} deg" for d, b in args.cases] == list(mesh["cases"])
