"""`python -m studies|bench NAME --help` for every command, and `--list`: each command parses its own flags."""

import pytest

import bench
import studies
from studies._cli import commands, dispatch

ALL = [(pkg, name) for pkg in (studies, bench) for name in sorted(commands(pkg))]


@pytest.mark.parametrize(("package", "name"), ALL, ids=[f"{p.__name__}-{n}" for p, n in ALL])
def test_every_command_prints_its_usage(package, name, capsys):
    """argparse's --help: exit 0, a usage line naming the command as a user types it."""
    with pytest.raises(SystemExit) as exit_:
        dispatch(package, [name, "--help"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: python -m {package.__name__} {name}")


@pytest.mark.parametrize("package", [studies, bench], ids=["studies", "bench"])
def test_list_names_every_command_with_its_summary(package, capsys):
    assert dispatch(package, ["--list"]) == 0
    lines = capsys.readouterr().out.splitlines()[2:]
    listed = {line.split()[0]: line.split(None, 1)[1] for line in lines if line.strip()}
    assert set(listed) == set(commands(package))
    assert all(len(summary) > 20 for summary in listed.values())


def test_no_command_is_a_library_module():
    """The modules the commands share are not listed: studies.LIBRARY_MODULES."""
    assert not {m.replace("_", "-") for m in studies.LIBRARY_MODULES} & set(commands(studies))


def test_a_bad_numeric_flag_names_the_flag(capsys):
    with pytest.raises(SystemExit) as exit_:
        dispatch(studies, ["profile-path", "--mesh", "m.npz", "--scale", "abc"])
    assert exit_.value.code == 2
    assert "--scale must be a number" in capsys.readouterr().err
