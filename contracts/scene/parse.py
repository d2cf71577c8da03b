"""A scene from its JSON: a user's (parse_scene, each bad field named in a SceneError) or one a manifest recorded
(recorded_scene, RecordedScene: the later fields it lacks at their value from before, recorded.py)."""

from __future__ import annotations

from typing import Annotated

from pydantic import BeforeValidator, ValidationError

from .recorded import fill
from .schema import RECORDED, Scene


class SceneError(ValueError):
    """A scene that cannot be used; the message names the field."""


def _field_path(loc: tuple) -> str:
    return ".".join(str(p) for p in loc if p not in ("function-after",)) or "<root>"


def _validated(data: dict, *, source: str, context: dict | None = None) -> Scene:
    try:
        return Scene.model_validate(data, context=context)
    except ValidationError as exc:
        lines = [f"{_field_path(e['loc'])}: {e['msg']}" for e in exc.errors()]
        raise SceneError(f"{source}: " + "; ".join(lines)) from None


def parse_scene(data: dict, *, source: str = "scene") -> Scene:
    """Validate a scene dict; raise SceneError naming each bad field."""
    return _validated(data, source=source)


def recorded_scene(data: dict | Scene, *, source: str = "scene") -> Scene:
    """The scene a manifest holds, as it was solved: a later field it lacks at its value from before (not today's
    default), written back without it; its structure validated, but not judged again as a user's scene would be
    (schema.RECORDED). A Scene is returned as it is; SceneError naming each bad field."""
    if isinstance(data, Scene) or not isinstance(data, dict):
        return data  # a Scene as it is; anything else for pydantic to refuse
    filled, absent = fill(data)
    scene = _validated(filled, source=source, context={RECORDED: True})
    scene._absent = absent
    return scene


# A manifest's scene field: JSON read as recorded_scene, a Scene taken as it is
RecordedScene = Annotated[Scene, BeforeValidator(recorded_scene)]
