"""A sweep with inverted snapshots is never served as valid (stability suite): training fits the part
where every angle is valid, cuts the envelope there and says so; what it cannot fit it refuses."""

import json
import shutil

import pytest

from contracts import sweep as folder
from contracts.model import read_model_folder
from training.__main__ import main
from training.fit import FitOptions, fit


@pytest.fixture(scope="module")
def sweep_copy(tiny_sweep, tmp_path_factory):
    """A copy of the tiny sweep whose manifest a test may edit (the snapshot files stay as hashed)."""
    out = tmp_path_factory.mktemp("edited") / "sweep"
    shutil.copytree(tiny_sweep, out)
    return out


def _edit_manifest(path, **change):
    data = json.loads((path / folder.MANIFEST).read_text())
    data.update(change)
    (path / folder.MANIFEST).write_text(json.dumps(data))


def test_the_model_answers_only_where_every_angle_is_valid(tiny_model, tiny_sweep):
    """The tiny linear sweep (0..10 mm every 1 mm) inverts from 6 mm on (between the solver's quadrature
    points; at them from 7 mm): the model is fitted on, and answers for, 0..5 mm, and its manifest counts
    what was left out and why."""
    sweep = folder.read_manifest(tiny_sweep)
    cut_mm = sweep.validity.valid_up_to_mm
    assert 0 < cut_mm < 10.0 and sweep.validity.n_inverted > 0
    assert all(r.min_det_f > 0 and r.min_det_f_probe > 0 for r in sweep.snapshots if r.displacement_mm <= cut_mm)
    m = read_model_folder(tiny_model).manifest
    assert m.envelope.displacement_mm == (0.0, cut_mm) and m.envelope.angle_deg == (-10.0, 10.0)
    cut = m.envelope_cut
    beyond = sum(r.displacement_mm > cut_mm for r in sweep.snapshots)
    assert cut.valid_up_to_mm == cut_mm and cut.sweep_envelope.displacement_mm == (0.0, 10.0)
    assert cut.n_excluded == beyond and cut.n_inverted == sweep.validity.n_inverted
    assert cut.min_det_f == sweep.validity.min_det_f <= 0
    assert m.network.n_train == len(sweep.snapshots) - beyond - len(m.metrics.table3)
    assert "Envelope cut" in (tiny_model / "report.md").read_text()


def test_the_cut_follows_det_f_between_the_quadrature_points(tiny_model, tiny_sweep):
    """Just beyond the cut every snapshot is positive at the solver's 4 points per tet; what stops the
    envelope there is det F <= 0 at the 11 probe points between them."""
    sweep = folder.read_manifest(tiny_sweep)
    cut_mm = sweep.validity.valid_up_to_mm
    beyond = [r for r in sweep.snapshots if r.displacement_mm == cut_mm + 1.0]
    assert len(beyond) == 11 and all(r.min_det_f > 0 for r in beyond)
    assert any(r.min_det_f_probe <= 0 for r in beyond)
    assert read_model_folder(tiny_model).manifest.envelope.displacement_mm == (0.0, cut_mm)


def test_held_out_cases_beyond_the_cut_are_counted_not_evaluated(tiny_sweep, tmp_path):
    out, cut_mm = tmp_path / "m", folder.read_manifest(tiny_sweep).validity.valid_up_to_mm
    m = fit(tiny_sweep, out, FitOptions(rank=4, max_iterations=20, test_cases=((5.0, -2.0), (9.0, 0.0))),
            progress=False)
    assert [(r.displacement_mm, r.angle_deg) for r in m.metrics.table3] == [(5.0, -2.0)]
    assert m.envelope_cut.dropped_test_cases == [(9.0, 0.0)]
    with pytest.raises(ValueError, match=rf"--test-case: every held-out case lies beyond {cut_mm:g} mm"):
        fit(tiny_sweep, out, FitOptions(rank=4, max_iterations=20, test_cases=((9.0, 0.0),)), progress=False)


def test_a_sweep_with_no_valid_displacement_is_refused(tiny_sweep, sweep_copy, tmp_path):
    validity = folder.read_manifest(tiny_sweep).validity
    _edit_manifest(sweep_copy, validity={**validity.model_dump(), "valid_up_to_mm": 0.0})
    with pytest.raises(ValueError, match=r"--snapshots: the sweep turns an element inside out .* no valid snapshot"):
        fit(sweep_copy, tmp_path / "m", FitOptions(rank=4, max_iterations=20, test_cases=((5.0, -2.0),)),
            progress=False)


def test_a_linear_sweep_never_checked_is_refused(sweep_copy, tmp_path):
    """Written before det F was measured: its min_det_f 1.0 would pass every snapshot as valid."""
    data = json.loads((sweep_copy / folder.MANIFEST).read_text())
    data.pop("validity")
    (sweep_copy / folder.MANIFEST).write_text(json.dumps(data))
    with pytest.raises(ValueError, match="written before det.*run `fem_offline sweep` again"):
        fit(sweep_copy, tmp_path / "m", FitOptions(rank=4, max_iterations=20, test_cases=((5.0, -2.0),)),
            progress=False)


def test_the_cli_says_where_the_envelope_was_cut(tiny_sweep, tmp_path, capsys):
    cut_mm = folder.read_manifest(tiny_sweep).validity.valid_up_to_mm
    assert main(["fit", "--snapshots", str(tiny_sweep), "--out", str(tmp_path / "m"), "--rank", "4",
                 "--iterations", "20", "--test-case", "5/-2"]) == 0
    assert f"envelope cut to 0..{cut_mm:g} mm (the sweep covers 0..10)" in capsys.readouterr().out
    assert read_model_folder(tmp_path / "m").manifest.envelope.displacement_mm == (0.0, cut_mm)
