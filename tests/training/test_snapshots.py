"""Reading a sweep folder in training: no FE stack needed."""

import subprocess
import sys

from training.snapshots import read_sweep, snapshots_of


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
