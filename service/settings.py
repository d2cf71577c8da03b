"""Service settings: CLI flags or DEFORM_* environment variables, checked at start."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

from pydantic import Field, FiniteFloat, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

DEFAULT_MODEL = Path(__file__).resolve().parents[1] / "models" / "default"


class Settings(BaseSettings):
    """Everything the service reads at start; a bad value stops it with a message naming the field."""

    model_config = SettingsConfigDict(env_prefix="DEFORM_", extra="forbid")

    model: Path = DEFAULT_MODEL
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 8000
    threads: Annotated[int, Field(ge=1, le=64, description="onnxruntime intra-op threads")] = 1
    max_points: Annotated[int, Field(ge=1, le=1_000_000, description="most points in one request")] = 10_000
    max_body_bytes: Annotated[int, Field(ge=1024, le=1 << 30, description="largest request body")] = 1 << 20
    log_level: str = "info"
    # OpenIGTLink (service/igtl.py), off by default; it binds to `host` like the HTTP server
    igtl: Annotated[bool, Field(description="serve OpenIGTLink: NeedleGuide poses in, deformed points out")] = False
    igtl_port: Annotated[int, Field(ge=1, le=65535, description="OpenIGTLink port")] = 18944
    igtl_targets: Annotated[dict[str, tuple[FiniteFloat, FiniteFloat, FiniteFloat]], Field(
        description='named target points sent with the markers, JSON {"name": [x, y, z]} in reference mm')] = {}
    igtl_surface: Annotated[bool, Field(description="also send the deformed prostate surface (POLYDATA)")] = False

    @field_validator("model")
    @classmethod
    def _model_folder(cls, value: Path) -> Path:
        if not (value / "manifest.json").is_file():
            raise ValueError(f"{value} is not a model folder (no manifest.json)")
        return value

    @field_validator("igtl_targets", mode="before")
    @classmethod
    def _targets(cls, value):
        """A flag arrives as JSON text; names must fit OpenIGTLink's 64-byte point name."""
        if isinstance(value, str):
            try:
                value = json.loads(value) if value.strip() else {}
            except json.JSONDecodeError as exc:
                raise ValueError(f'not JSON ({exc.msg}); give {{"name": [x, y, z], ...}} in mm') from None
        if isinstance(value, dict):
            for name in value:
                if not 0 < len(str(name).encode()) <= 64:
                    raise ValueError(f"{name!r}: a target name has 1 to 64 bytes")
        return value

    @field_validator("log_level")
    @classmethod
    def _level(cls, value: str) -> str:
        if value.lower() not in {"critical", "error", "warning", "info", "debug", "trace"}:
            raise ValueError(f"unknown log level {value!r}")
        return value.lower()
