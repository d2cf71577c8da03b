"""A linear sweep pushed until elements turn inside out reports it (stability suite): true det F per
snapshot, at the solver's quadrature points and at the probe points between them, the inverted ones
listed in the manifest, a warning from the CLI, no silent resume."""

import json
import shutil

import numpy as np
import pytest

from contracts import sweep as folder
from contracts.mesh import read_mesh
from fem_offline.__main__ import main
from fem_offline.fe.linear import det_f, linear_modes, min_det_f, superpose
from fem_offline.fe.problem import build_problem
from fem_offline.scene import SceneError, load_scene, parse_scene
from fem_offline.sweep import run_sweep
from fem_offline.fe.validity import corners, det_f_bound, min_det_f_bound, probe, resampled

from ..cli_helpers import LINEAR, scene_file

GRID = """[sweep]
displacement_step_mm = 2.0
displacement_max_mm = 10.0
angle_min_deg = -10.0
angle_max_deg = 10.0
angle_step_deg = 10.0
"""


@pytest.fixture(scope="module")
def inverted_sweep(tmp_path_factory):
    """tiny.toml linear, 2, 4 ... 10 mm x -10, 0, 10 deg, through the CLI. On this mesh det F first reaches 0
    at 6.33 to 6.40 mm at the solver's 4 quadrature points per tet, at 5.80 to 5.86 mm at the 11 probe points
    (measured, linear_validity.det_f_curves), so 6 mm is inverted between the solver's points only (min det F
    0.12 there, -0.07 at the probe points), and 8 and 10 mm at both, at every angle."""
    tmp = tmp_path_factory.mktemp("inverted")
    out = tmp / "sweep"
    assert main(["sweep", "--scene", str(scene_file(tmp, "lin", LINEAR + GRID)), "--out", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def sweep_problem(inverted_sweep):
    manifest = folder.read_manifest(inverted_sweep)
    return build_problem(parse_scene(manifest.scene), read_mesh(inverted_sweep / folder.MESH_FILE))


def test_each_snapshot_records_its_true_min_det_f(inverted_sweep, sweep_problem):
    """min_det_f of every file = Problem.min_jacobian of its displacement: <= 0 for the inverted, > 0 for the rest."""
    manifest = folder.read_manifest(inverted_sweep)
    for row in manifest.snapshots:
        with np.load(inverted_sweep / row.file) as z:
            expected = sweep_problem.min_jacobian(z["displacement"].ravel())
            assert float(z["min_det_f"]) == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert row.min_det_f == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert (row.min_det_f > 0) == (row.displacement_mm <= 6.0), (row.file, row.min_det_f)


def test_each_snapshot_records_its_true_min_det_f_between_the_quadrature_points(inverted_sweep, sweep_problem):
    """min_det_f_probe of every file = min det F of its displacement at the 11 probe points per tet (from the
    cubic in d, so against a direct evaluation): <= 0 from 6 mm on, where min_det_f is still > 0."""
    manifest, probed = folder.read_manifest(inverted_sweep), probe(sweep_problem)
    assert probed.G.shape[1] == 11 and sweep_problem.G.shape[1] == 4
    for row in manifest.snapshots:
        with np.load(inverted_sweep / row.file) as z:
            expected = probed.min_jacobian(z["displacement"].ravel())
        assert row.min_det_f_probe == pytest.approx(expected, rel=1e-9, abs=1e-12)
        assert (row.min_det_f_probe > 0) == (row.displacement_mm <= 4.0), (row.file, row.min_det_f_probe)
    between = [r for r in manifest.snapshots if r.displacement_mm == 6.0]
    assert len(between) == 3 and all(r.min_det_f > 0.1 and r.min_det_f_probe < -0.05 for r in between)


def test_the_manifest_lists_the_inverted_and_where_every_angle_is_valid(inverted_sweep):
    """Inverted at any set of points: 6 mm (between the solver's points only), 8 and 10 mm, at 3 angles."""
    manifest = folder.read_manifest(inverted_sweep)
    v = manifest.validity
    inverted = sorted(r.file for r in manifest.snapshots if min(r.min_det_f, r.min_det_f_probe, r.min_det_f_bound) <= 0)
    assert sorted(v.inverted) == inverted and v.n_inverted == len(inverted) == 9
    assert {r.file for r in manifest.snapshots if r.displacement_mm == 6.0} <= set(v.inverted)
    assert v.first_inverted_mm == [6.0, 6.0, 6.0]
    assert v.valid_up_to_mm == 4.0 and v.n_unprobed == 0 and v.n_unbounded == 0
    at_qp, at_probe, bound = (min(getattr(r, k) for r in manifest.snapshots)
                              for k in ("min_det_f", "min_det_f_probe", "min_det_f_bound"))
    assert v.min_det_f == bound < at_probe < at_qp < -1.0


def test_the_sweep_cli_warns_with_the_count_and_the_valid_range(tmp_path, inverted_sweep, capsys):
    """Re-running the finished sweep solves nothing and warns again from the manifest."""
    out = tmp_path / "again"
    shutil.copytree(inverted_sweep, out)
    scene = tmp_path / "lin.toml"
    scene.write_text((inverted_sweep.parent / "lin.toml").read_text())
    assert main(["sweep", "--scene", str(scene), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert "warning: 9 of 15 snapshots turn an element inside out" in err
    assert "the first at 6 mm." in err and "Every angle is valid up to 4 mm" in err and "note:" not in err


def test_a_linear_folder_written_before_the_check_is_not_resumed(tmp_path, inverted_sweep):
    """Its snapshots say min_det_f 1.0 without having measured it: resuming would pass them off as checked."""
    out = tmp_path / "old"
    shutil.copytree(inverted_sweep, out)
    data = json.loads((out / folder.MANIFEST).read_text())
    del data["validity"]
    (out / folder.MANIFEST).write_text(json.dumps(data))
    with pytest.raises(ValueError, match="this linear sweep was written before det"):
        folder.sweep_validity(folder.read_manifest(out))
    with pytest.raises(SceneError, match="linear snapshots written before det.*use a new --out"):
        run_sweep(load_scene(inverted_sweep.parent / "lin.toml"), out)


def test_a_format_2_folder_resumes_with_its_unprobed_snapshots_counted(tmp_path, inverted_sweep, capsys):
    """A folder written before the probe (no min_det_f_probe or min_det_f_bound in its files; format 2) still
    resumes: the new snapshot is probed and bounded, the old ones are judged at the solver's points only, counted
    and named by the CLI."""
    out = tmp_path / "format2"
    shutil.copytree(inverted_sweep, out)
    for f in (out / folder.SNAPSHOTS).glob("*.npz"):
        with np.load(f) as z:
            old = {k: z[k] for k in z.files if k not in ("min_det_f_probe", "min_det_f_bound")}
        np.savez(f, **old)
    data = json.loads((out / folder.MANIFEST).read_text())
    data["format_version"] = 2
    (out / folder.MANIFEST).write_text(json.dumps(data))
    assert folder.read_manifest(out).format_version == 2
    (out / folder.snapshot_file(1, 2)).unlink()  # 0 deg, 6 mm: inverted between the solver's points only
    scene = tmp_path / "lin.toml"
    scene.write_text((inverted_sweep.parent / "lin.toml").read_text())
    assert main(["sweep", "--scene", str(scene), "--out", str(out)]) == 0
    manifest = folder.read_manifest(out)
    v = manifest.validity
    assert manifest.format_version == 4 and v.n_unprobed == 14 and v.n_unbounded == 14
    assert [r.file for r in manifest.snapshots if r.min_det_f_probe is not None] == [folder.snapshot_file(1, 2)]
    assert [r.file for r in manifest.snapshots if r.min_det_f_bound is not None] == [folder.snapshot_file(1, 2)]
    assert v.first_inverted_mm == [8.0, 6.0, 8.0] and v.valid_up_to_mm == 4.0  # the probed one caught, the others not
    assert "note: 14 snapshots were written before det F was probed" in capsys.readouterr().err


def test_a_format_3_folder_resumes_with_its_unbounded_snapshots_counted(tmp_path, inverted_sweep, capsys):
    """A folder written before the bound (format 3) resumes: the new snapshot is bounded, the old ones are judged at
    their 15 points per tet, counted and named by the CLI."""
    out = tmp_path / "format3"
    shutil.copytree(inverted_sweep, out)
    for f in (out / folder.SNAPSHOTS).glob("*.npz"):
        with np.load(f) as z:
            old = {k: z[k] for k in z.files if k != "min_det_f_bound"}
        np.savez(f, **old)
    data = json.loads((out / folder.MANIFEST).read_text())
    data["format_version"] = 3
    (out / folder.MANIFEST).write_text(json.dumps(data))
    (out / folder.snapshot_file(1, 2)).unlink()
    scene = tmp_path / "lin.toml"
    scene.write_text((inverted_sweep.parent / "lin.toml").read_text())
    assert main(["sweep", "--scene", str(scene), "--out", str(out)]) == 0
    v = folder.read_manifest(out).validity
    assert v.n_unprobed == 0 and v.n_unbounded == 14 and v.valid_up_to_mm == 4.0
    assert "note: 14 snapshots were written before det F was bounded everywhere" in capsys.readouterr().err


def test_each_snapshot_records_a_bound_of_det_f_everywhere(inverted_sweep, sweep_problem):
    """min_det_f_bound holds at 60 random points of every tet (never above the lowest) and has the sign of det F:
    > 0 up to 4 mm (a lower bound within 0.2 of the lowest sampled value), <= 0 from 6 mm on, where it is det F at
    a tet's corner, below every one of the 15 points the solver and the probe sample."""
    rng = np.random.default_rng(7)
    lam = rng.dirichlet(np.ones(4), 60).T  # barycentric coordinates (4, 60)
    dense, at_corners = resampled(sweep_problem, quadrature=(lam[1:], np.full(60, 1 / 360))), corners(sweep_problem)
    manifest = folder.read_manifest(inverted_sweep)
    for row in manifest.snapshots:
        with np.load(inverted_sweep / row.file) as z:
            u = z["displacement"].ravel()
        assert row.min_det_f_bound == pytest.approx(min_det_f_bound(at_corners, u), rel=1e-12)
        sampled = dense.min_jacobian(u)
        assert row.min_det_f_bound <= sampled + 1e-12, row.file
        if row.displacement_mm <= 4.0:
            assert 0 < row.min_det_f_bound and sampled - row.min_det_f_bound < 0.2, row.file
        else:
            assert row.min_det_f_bound == pytest.approx(at_corners.min_jacobian(u), rel=1e-12)
            assert row.min_det_f_bound < row.min_det_f_probe and row.min_det_f_bound < 0, row.file


def _corner_fields(*blocks):
    """F (1, 4, 3, 3) at a simplex's corners: the given 3 x 3 matrices, then the identity."""
    F = [np.asarray(b, dtype=np.float64) for b in blocks] + [np.eye(3)] * (4 - len(blocks))
    return np.stack(F)[None]


def _dense_min(F, n=200_000, seed=0):
    """min det F at n random points of the simplex, F affine (1, 4, 3, 3) at its corners."""
    lam = np.random.default_rng(seed).dirichlet(np.ones(4), n)
    return np.linalg.det(np.einsum("ni,iab->nab", lam, F[0])).min()


def test_the_bound_of_an_affine_field_is_its_det_f():
    """F constant over the tet: every Bernstein coefficient is det F, so the bound is exact."""
    A = np.array([[1.1, 0.2, -0.1], [0.05, 0.8, 0.3], [0.0, -0.2, 0.95]])
    assert det_f_bound(_corner_fields(A, A, A, A)) == pytest.approx(np.linalg.det(A), rel=1e-13)


def test_the_bound_of_a_field_with_nan_is_nan():
    """A NaN in F (a diverged field) is not a deformation: NaN, which contracts.sweep counts as inverted."""
    F = _corner_fields(np.eye(3), np.full((3, 3), np.nan))
    assert np.isnan(det_f_bound(np.concatenate([_corner_fields(), F])))


def test_the_bound_subdivides_until_it_proves_det_f_positive():
    """Rotations by +-80 deg about z at two corners: det F is 1 at every corner and cos^2(80 deg) = 0.030 at
    the edge's midpoint, the least; its least Bernstein coefficient is -0.29. Subdivided, the bound is
    > 0 and below the true minimum."""
    c, s = np.cos(np.radians(80)), np.sin(np.radians(80))
    F = _corner_fields([[c, -s, 0], [s, c, 0], [0, 0, 1]], [[c, s, 0], [-s, c, 0], [0, 0, 1]])
    bound = det_f_bound(F)
    assert 0 < bound <= c**2 + 1e-15 and bound <= _dense_min(F)
    assert bound > 0.5 * c**2


def test_the_bound_finds_an_inversion_inside_a_tet_whose_corners_are_positive():
    """diag(1, 1, 1) and diag(-1.2, -1, 1) at two corners: det F is 1 and 1.2 there, and at 0.52 / 0.48 of the
    way (-0.056 x 0.04 x 1) below 0. No corner sees it; the bound is <= 0."""
    F = _corner_fields(np.eye(3), np.diag([-1.2, -1.0, 1.0]))
    assert np.linalg.det(F[0]).min() > 0 and _dense_min(F) < 0
    assert det_f_bound(F) <= 0


def test_det_f_is_the_cubic_in_d_that_superposition_gives(tiny_linear_problem):
    """det(I + grad u(d)) at every quadrature point, from the cubic, equals the determinant of the superposed field."""
    from fem_offline.fe import elasticity as el

    p = tiny_linear_problem
    modes = linear_modes(p)
    d = np.array([0.0, 3.3, 8.0, 25.0])
    for beta in (-10.0, 4.0):
        cubic = det_f(p, modes, d, beta)  # (n_d, n_active, n_qp)
        for k, dk in enumerate(d):
            H = el.displacement_gradient(p.G, p.element_displacement(superpose(modes, dk, beta).ravel()))
            np.testing.assert_allclose(cubic[k], np.linalg.det(np.eye(3) + H), rtol=1e-9, atol=1e-9 * max(1.0, dk**3))
        np.testing.assert_array_equal(min_det_f(p, modes, d, beta), cubic.min(axis=(1, 2)))
