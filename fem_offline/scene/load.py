"""Reading scene files: TOML, `extends` chains merged table by table, validation into a ``Scene`` (contracts.scene)."""

from __future__ import annotations

import tomllib
from pathlib import Path

from contracts.scene import Scene, SceneError, parse_scene


def _merged(base: dict, over: dict) -> dict:
    """`over` on top of `base`, table by table: a key in both tables is merged, any other value replaced."""
    out = dict(base)
    for key, value in over.items():
        out[key] = _merged(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def _read_scene_toml(path: Path, chain: tuple[Path, ...] = ()) -> dict:
    """A scene file's data with its file paths made absolute and the scene it `extends` merged underneath."""
    if path.resolve() in chain:
        raise SceneError(f"{path}: extends itself ({' -> '.join(p.name for p in (*chain, path))})")
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise SceneError(f"{path}: no such scene file") from None
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(f"{path}: not valid TOML ({exc})") from None
    for section in ("mesh_file", "label_map"):
        if isinstance(data.get(section), dict) and "path" in data[section]:
            file = Path(data[section]["path"])
            data[section]["path"] = str(file if file.is_absolute() else path.parent / file)
            data.setdefault("phantom", None)
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise SceneError(f"{path}: extends: expected the file name of a scene, got {base!r}")
    return _merged(_read_scene_toml(path.parent / base, (*chain, path.resolve())), data)


def load_scene(path: str | Path, **overrides) -> Scene:
    """Read and validate a TOML scene; relative file paths resolve against the scene's folder.

    `extends = "default.toml"` (relative to the file) starts from another scene: the file's own
    tables are merged over it key by key, so a variant states only what differs. `overrides` (section -> table
    or value) are merged over the file the same way.
    """
    path = Path(path)
    data = _read_scene_toml(path)
    data = _merged(data, overrides)
    return parse_scene(data, source=str(path))
