"""The console entry points in pyproject.toml: one per stage, each the `main` its `python -m` runs."""

import importlib
import tomllib
from pathlib import Path

import pytest

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
SCRIPTS = tomllib.loads(PYPROJECT.read_text())["project"]["scripts"]


def test_every_stage_has_one():
    packages = {target.split(".")[0] for target in SCRIPTS.values()}
    assert packages == {"fem_offline", "training", "service", "pipeline", "studies", "bench"}


@pytest.mark.parametrize("name", sorted(SCRIPTS))
def test_each_resolves_to_its_packages_main_and_prints_help(name, capsys):
    module, attr = SCRIPTS[name].split(":")
    assert module.endswith(".__main__") and attr == "main"
    main = getattr(importlib.import_module(module), attr)
    if module.startswith(("studies", "bench")):
        import sys

        argv, sys.argv = sys.argv, [name, "--list"]
        try:
            assert main() == 0
        finally:
            sys.argv = argv
    else:
        with pytest.raises(SystemExit) as exit_:
            main(["--help"])
        assert exit_.value.code == 0
    assert "usage" in capsys.readouterr().out.lower()
