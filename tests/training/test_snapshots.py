"""Reading a sweep folder in training: no FE stack needed."""

import subprocess
import sys

import numpy as np

from training.snapshots import read_sweep, snapshots_of, sub_grid


def test_training_reads_a_sweep_without_gmsh_scikit_fem_or_fem_offline(tiny_sweep):
    code = ("import sys; from training.snapshots import read_sweep; s = read_sweep(sys.argv[1]); "
            "print(len(s.inputs), sorted(m for m in ('gmsh', 'skfem', 'fem_offline', 'meshio') if m in sys.modules))")
    run = subprocess.run([sys.executable, "-c", code, str(tiny_sweep)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.split() == ["110", "[]"]


def test_snapshots_keep_the_sweep_order_and_reference_nodes(tiny_sweep):
    sweep = read_sweep(tiny_sweep)
    data = snapshots_of(sweep)
    assert [tuple(x) for x in data.inputs] == [(r.displacement_mm, r.angle_deg) for r in sweep.manifest.snapshots]
    assert data.reference_positions is sweep.mesh.nodes and data.displacement.shape == (110, len(sweep.mesh.nodes), 3)


def test_sub_grid_keeps_every_kth_angle_and_displacement_and_the_envelope():
    """`python -m studies sweep-density`'s coarser sweeps: on the paper's 21 x 40 grid, every 2nd angle keeps both
    ends (11 angles, as fem_offline/scenes/patient.toml's 2 deg); every 2nd displacement keeps 10 mm."""
    d, b = np.meshgrid(0.25 * np.arange(1, 41), np.arange(-10.0, 11.0), indexing="ij")
    inputs = np.stack([d.ravel(), b.ravel()], axis=1)
    for (a, s), angles, disps in (((1, 1), np.arange(-10.0, 11.0), 0.25 * np.arange(1, 41)),
                                  ((2, 1), np.arange(-10.0, 11.0, 2.0), 0.25 * np.arange(1, 41)),
                                  ((4, 2), np.arange(-10.0, 11.0, 4.0), 0.5 * np.arange(1, 21))):
        kept = inputs[sub_grid(inputs, a, s)]
        np.testing.assert_array_equal(np.unique(kept[:, 1]), angles)
        np.testing.assert_array_equal(np.unique(kept[:, 0]), disps)
        assert len(kept) == len(angles) * len(disps)
