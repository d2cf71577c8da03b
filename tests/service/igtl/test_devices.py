"""The OpenIGTLink devices are one table: each name fits OpenIGTLink's 20 bytes, and the docs and the CLI's help
list every one."""

from pathlib import Path

from service.igtl import DEVICES

DOCS = Path(__file__).resolve().parents[3] / "docs" / "viewer.md"


def test_device_names_fit_the_header_and_are_unique_per_direction():
    for d in DEVICES:
        assert 0 < len(d.name.encode()) <= 20 and d.direction in ("in", "out"), d
    pairs = [(d.direction, d.name) for d in DEVICES]
    assert len(set(pairs)) == len(pairs)


def test_the_docs_table_lists_every_device_with_its_type_and_direction():
    rows = {tuple(cell.strip() for cell in line.strip("|").split("|")[:2])
            for line in DOCS.read_text().splitlines() if line.startswith("| in ") or line.startswith("| out ")}
    assert rows == {(d.direction, f"{d.type} `{d.name}`") for d in DEVICES}


def test_the_cli_help_lists_every_device(capsys):
    from service.__main__ import main

    try:
        main(["--help"])
    except SystemExit as exc:
        assert exc.code == 0
    shown = capsys.readouterr().out
    for d in DEVICES:
        assert f"{d.direction:<3} {d.type} {d.name} " in shown, d.name
