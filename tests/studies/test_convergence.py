"""Grid-convergence arithmetic on exact sequences, and the resumable path a study level runs on."""

from dataclasses import replace

import numpy as np
import pytest

from studies.convergence import P_FORMAL, SAFETY, field_gci, richardson, scaled_scene, solve_resumable
from fem_offline.fe.solve import solve_case


@pytest.mark.parametrize("order", [1.0, 1.5, 2.0])
def test_richardson_recovers_order_and_limit_of_an_exact_power_law(order):
    """f(h) = f0 + C h^p on h = r^2, r, 1: p and f0 come back exactly, and the fine GCI is Fs |f1 - f0|."""
    f0, c, r = 4.0, -0.3, 1.3
    f3, f2, f1 = (f0 + c * h**order for h in (r**2, r, 1.0))
    out = richardson(f3, f2, f1, r)
    assert out.kind == "monotonic"
    assert out.order == pytest.approx(order, rel=1e-10) and out.extrapolated == pytest.approx(f0, rel=1e-12)
    assert out.gci_fine == pytest.approx(SAFETY * abs(f1 - f0), rel=1e-10)
    assert out.gci_medium == pytest.approx(SAFETY * abs(f2 - f0), rel=1e-10)


@pytest.mark.parametrize("order", [1.0, 2.0, 3.0])
def test_unequal_ratios_recover_order_and_limit(order):
    """h = r32 r21, r21, 1 with r32 != r21 (a level at sizes x 0.769 after 1.3, 1):
    Celik's fixed point gives p exactly."""
    f0, c, r32, r21 = 4.0, -0.3, 1.3, 1 / 0.769
    f3, f2, f1 = (f0 + c * h**order for h in (r32 * r21, r21, 1.0))
    out = richardson(f3, f2, f1, (r32, r21))
    assert out.kind == "monotonic" and out.order == pytest.approx(order, rel=1e-9)
    assert out.extrapolated == pytest.approx(f0, rel=1e-12)
    q = min(order, P_FORMAL)
    assert out.gci_fine == pytest.approx(SAFETY * abs(f2 - f1) / (r21**q - 1), rel=1e-9)
    assert out.gci_medium == pytest.approx(SAFETY * abs(f3 - f2) / (r32**q - 1), rel=1e-9)
    assert richardson(f3, f2, f1, (r32, r21)).order != pytest.approx(richardson(f3, f2, f1, r32).order, rel=1e-6)


def test_an_order_above_the_schemes_is_capped_in_the_band_not_in_the_estimate():
    f0, r = 2.0, 1.3
    f3, f2, f1 = (f0 + 0.5 * h**4 for h in (r**2, r, 1.0))
    out = richardson(f3, f2, f1, r)
    assert out.order == pytest.approx(4.0) and out.extrapolated == pytest.approx(f0)
    assert (out.gci_fine == pytest.approx(SAFETY * abs(f2 - f1) / (r**P_FORMAL - 1))
            and out.gci_fine > SAFETY * abs(f1 - f0))


@pytest.mark.parametrize(("values", "kind"), [((1.0, 1.2, 1.1), "oscillatory"), ((1.0, 1.1, 1.3), "divergent")])
def test_without_monotonic_convergence_there_is_no_order_and_the_band_is_the_spread(values, kind):
    out = richardson(*values, 1.3)
    assert out.kind == kind and np.isnan(out.order) and np.isnan(out.extrapolated)
    assert out.gci_fine == pytest.approx(SAFETY * (max(values) - min(values)))


def test_field_band_is_the_pointwise_distance_to_the_limit():
    """u(h) = u0 + h^2 a u0/|u0| at every point (|u| follows the power law exactly): the band is
    Fs |u1 - u0| point by point, with the order p = 2 observed on the mean."""
    rng = np.random.default_rng(0)
    u0, a, r = rng.normal(size=(50, 3)), rng.uniform(0.1, 1.0, size=(50, 1)), 1.4
    v = a * u0 / np.linalg.norm(u0, axis=1, keepdims=True)
    coarse, medium, fine = (u0 + h**2 * v for h in (r**2, r, 1.0))
    band, mean = field_gci(coarse, medium, fine, r)
    assert mean.kind == "monotonic" and mean.order == pytest.approx(2.0, rel=1e-10)
    np.testing.assert_allclose(band, SAFETY * np.linalg.norm(fine - u0, axis=1), rtol=1e-10)
    medium_band, _ = field_gci(coarse, medium, fine, r, level="medium")  # p = 2 = P_FORMAL: exact for the medium too
    np.testing.assert_allclose(medium_band, SAFETY * np.linalg.norm(medium - u0, axis=1), rtol=1e-10)


def test_scaled_scene_scales_every_size_together(tiny_scene):
    s = scaled_scene(tiny_scene, 1.3).mesh
    m = tiny_scene.mesh
    scaled = (1.3 * m.max_mm, 1.3 * m.prostate_mm, 1.3 * m.guide_mm)
    assert (s.max_mm, s.prostate_mm, s.guide_mm) == pytest.approx(scaled)


def test_interrupted_path_resumes_to_the_uninterrupted_answer(tiny_problem, tmp_path):
    """Stop at 1 mm (its checkpoint on disk), go on to 2 mm from it: the same field as one solve from rest."""
    checkpoint = tmp_path / "path.npz"
    solve_resumable(tiny_problem, 1.0, 5.0, checkpoint)
    u, _ = solve_resumable(tiny_problem, 2.0, 5.0, checkpoint)
    direct, _ = solve_case(tiny_problem, 2.0, 5.0)
    np.testing.assert_allclose(u, direct, atol=1e-9 * np.abs(direct).max())
    again, _ = solve_resumable(tiny_problem, 2.0, 5.0, checkpoint)  # finished: read back, not solved
    np.testing.assert_array_equal(again, u)
    other = replace(tiny_problem, scene=scaled_scene(tiny_problem.scene, 1.3))  # another scene's physics
    with pytest.raises(ValueError, match=r"path\.npz is a path of another scene .*delete it or use another folder"):
        solve_resumable(other, 3.0, 5.0, checkpoint)


def _raw(scales, n_points=5):
    """run_study's result for levels at `scales`: u = (1 + h^2) e_x at every probe point, h = the scale."""
    probes = {k: np.zeros((n_points, 3)) for k in ("markers", "interior", "prostate_surface", "nodes")}
    probes["prostate_surface"][2:, 0] = 50.0  # two surface points at the tip, the rest far from it
    levels = [{"scale": s, "n_tets": 1000, "n_nodes": 2000,
               "cases": {"c": {"seconds": 1.0, **{k: np.tile([1.0 + s * s, 0, 0], (n_points, 1)) for k in probes}}}}
              for s in scales]
    return {"probes": probes, "levels": levels, "tip_mm": np.zeros(3)}


def test_levels_written_to_four_digits_pass_the_ratio_check_and_a_smaller_ratio_does_not():
    from studies.convergence import analyse

    result = analyse(_raw([1.0, 0.769, 0.5917]))  # 1.3004 and 1.2996: the ratio 1.3, rounded
    assert result["cases"]["c"]["all_nodes"]["mean_kind"] == "monotonic"
    assert result["cases"]["c"]["markers"][0]["order"] == pytest.approx(2.0, abs=0.01)
    with pytest.raises(ValueError, match="need size ratios"):
        analyse(_raw([1.0, 0.8, 0.64]))  # 1.25


def test_coarse_and_medium_bounds_are_the_distance_to_the_fine_level_plus_its_band():
    """u = (1 + h^2) e_x, limit 1: the fine band is Fs |u1 - 1|, and a coarser level's bound, |u_L - u1| + that
    band, holds its true error (h_L^2) at every point and in every region (the coarse bound judges
    models/default, built on a study's coarse level)."""
    from studies.convergence import SAFETY, analyse

    scales = (1.69, 1.3, 1.0)
    row = analyse(_raw(list(scales)))["cases"]["c"]
    band = SAFETY * 1.0
    for level, h in (("coarse", scales[0]), ("medium", scales[1])):
        bound, truth = (1 + h * h - 2.0) + band, h * h
        assert all(r[f"bound_{level}_mm"] == pytest.approx(bound) for r in row["markers"] + row["interior"])
        for region in ("all_nodes", "surface_near_tip", "surface_rest"):
            assert row[region][f"bound_{level}_mm"]["max"] == pytest.approx(bound)
        assert bound >= truth


def test_a_level_under_the_three_analysed_gets_the_same_bound_by_its_scale():
    """A fourth, coarser level (the default's, under a study refined past it): |u_L - u1| + the fine band,
    keyed by its scale, in every region; it holds that level's true error h_L^2 and leaves the GCI of the
    three finest unchanged."""
    from studies.convergence import SAFETY, analyse

    three, four = analyse(_raw([1.69, 1.3, 1.0])), analyse(_raw([2.197, 1.69, 1.3, 1.0]))
    assert [lv["scale"] for lv in four["coarser_levels"]] == [2.197] and three["coarser_levels"] == []
    row, h = four["cases"]["c"], 2.197
    bound = (1 + h * h - 2.0) + SAFETY * 1.0
    assert all(r["bound_by_scale_mm"] == {"2.197": pytest.approx(bound)} for r in row["markers"] + row["interior"])
    for region in ("all_nodes", "surface_near_tip", "surface_rest"):
        assert row[region]["bound_by_scale_mm"]["2.197"]["max"] == pytest.approx(bound)
    assert bound >= h * h
    assert row["markers"][0]["gci_vector_mm"] == three["cases"]["c"]["markers"][0]["gci_vector_mm"]


def _study_folder(folder, mesh, solved_to):
    """A study folder as run_study leaves it: the tiny mesh at every level, and u = (1 + h^2) g(x) with g
    linear (P2 interpolates it exactly) on each level h; solved_to: {scale: the path's last displacement}."""
    from contracts.mesh import write_mesh

    g = np.zeros_like(mesh.nodes)
    g[:, 0] = mesh.nodes[:, 0] + 100.0
    for h, d in solved_to.items():
        write_mesh(folder / f"mesh_{h:g}.npz", mesh)
        np.savez(folder / f"path_{h:g}_10_0.npz", u=((1 + h * h) * g).ravel(), d_mm=d)
    return lambda p: np.stack([p[:, 0] + 100.0, 0 * p[:, 0], 0 * p[:, 0]], axis=1)


def test_converged_estimate_is_the_fine_level_and_its_band_at_any_point(tiny_mesh, tmp_path):
    """Levels 1.69 / 1.3 / 1 (ratio 1.3, order 2 exactly): at points between the nodes, u1 = 2 g and the band is
    Fs |u1 - u2| / (1.3^2 - 1) = Fs |g|, which holds the true error |u1 - g| = |g|; a finer level whose path stopped
    short is passed over, and a case on fewer than three levels is refused by name."""
    from studies.convergence import converged_estimate

    g = _study_folder(tmp_path, tiny_mesh, {1.69: 10.0, 1.3: 10.0, 1.0: 10.0, 0.769: 7.5})
    points = tiny_mesh.nodes[tiny_mesh.tets[:20, :4]].mean(axis=1)  # tet centroids: no node among them
    used, u1, band, order = converged_estimate(tmp_path, [1.69, 1.3, 1.0, 0.769], (10.0, 0.0), points)
    assert used == [1.69, 1.3, 1.0] and order.kind == "monotonic" and order.order == pytest.approx(2.0, rel=1e-9)
    np.testing.assert_allclose(u1, 2 * g(points), rtol=1e-9)
    np.testing.assert_allclose(band, SAFETY * np.linalg.norm(g(points), axis=1), rtol=1e-9)
    assert np.all(band >= np.linalg.norm(u1 - g(points), axis=1))
    (tmp_path / "path_1.3_10_0.npz").unlink()
    with pytest.raises(ValueError, match=r"10 mm, 0 deg: solved on levels \[1\.69, 1\.0\] .*needs three"):
        converged_estimate(tmp_path, [1.69, 1.3, 1.0, 0.769], (10.0, 0.0), points)
