"""`python -m pipeline build`: bad input is one line naming the field, exit 2, before any work starts."""

import pytest

from pipeline.__main__ import main

SCENES = __import__("pathlib").Path(__file__).resolve().parents[2] / "fem_offline" / "scenes"


@pytest.mark.parametrize("argv, message", [
    (["--scene", "missing.toml"], "missing.toml: no such scene file"),
    (["--scene", str(SCENES / "tiny.toml"), "--offgrid", "0"], "--offgrid: must be at least 1"),
    (["--scene", str(SCENES / "tiny.toml"), "--width", "0"], "--width: must be at least 1"),
    (["--scene", str(SCENES / "tiny.toml"), "--fe-estimate", "nowhere.json"],
     "--fe-estimate: no such file nowhere.json"),
])
def test_bad_input_is_one_line_and_exit_2(argv, message, tmp_path, capsys):
    assert main(["build", "--out", str(tmp_path / "m"), "--work", str(tmp_path / "w"), *argv]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"error: {message}"
    assert not (tmp_path / "w").exists() and not (tmp_path / "m").exists()
