"""Service settings: CLI flags or DEFORM_* environment variables, checked at start."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, FiniteFloat, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

from .cores import defaults

DEFAULT_MODEL = Path(__file__).resolve().parents[1] / "models" / "default"
# A comma-separated list in a flag or an env var (DEFORM_CORS_ORIGINS=https://a.org,https://b.org), not JSON.
CommaList = Annotated[list[str], NoDecode]
CommaInts = Annotated[list[Annotated[int, Field(ge=1, le=256)]], NoDecode]


class Settings(BaseSettings):
    """Everything the service reads at start; a bad value stops it with a message naming the field."""

    model_config = SettingsConfigDict(env_prefix="DEFORM_", extra="forbid")

    model: Path = DEFAULT_MODEL
    host: str = "127.0.0.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 8000
    # Process and thread counts default from the cores this process may use (service/cores.py)
    threads: Annotated[int, Field(
        ge=1, le=64, default_factory=lambda data: defaults(data.get('model')).threads, description=(
            "onnxruntime intra-op threads per worker (default: from the usable cores and the model's size)"))]
    max_points: Annotated[int, Field(ge=1, le=1_000_000, description="most points in one request")] = 10_000
    max_body_bytes: Annotated[int, Field(ge=1024, le=1 << 30, description="largest request body")] = 1 << 20
    log_level: str = "info"
    workers: Annotated[int, Field(
        ge=1, le=64, default_factory=lambda data: defaults(data.get('model')).workers, description=(
            "uvicorn worker processes (default: from the usable cores and the model's size)"))]
    access_log: Literal["text", "json", "off"] = Field(
        "text", description="one line per request: uvicorn's text, JSON lines on stdout, or none")

    # Dynamic batching (service/predict/batching.py): requests that arrive together decode in one onnxruntime call.
    batching: bool = Field(True, description="decode concurrent requests with the same node set together")
    # 16: at 312k nodes a decode reads the whole basis once per call, so a batch of 16 costs far less than two of
    # 8 (python -m bench service's decode table; CHANGELOG); at 10k nodes batches rarely pass 8
    batch_max_size: Annotated[int, Field(ge=1, le=256, description="most requests in one batch")] = 16
    batch_preferred_sizes: CommaInts = Field([], description=(
        "batch sizes worth waiting for (as Triton's preferred_batch_size), comma-separated; none: only the largest"))
    batch_max_delay_ms: Annotated[float, Field(
        ge=0, le=100, default_factory=lambda data: defaults(data.get('model')).max_delay_ms, description=(
            "most a batch may wait to grow once a lane is free, ms, when the last batch had company; "
            "capped at a quarter of the recent batch run time (default: 5, or 0 for a large model on 2 to 7 cores)"))]
    batch_lanes: Annotated[int, Field(
        ge=1, le=64, default_factory=lambda data: defaults(data.get('model')).lanes, description=(
            "batches decoded at once, each in its own thread (default: from the usable cores and the model's size)"))]
    inline_max_ms: Annotated[float, Field(ge=0, le=10, description=(
        "decode on the event loop, with no thread hop, a request whose decode measured at start takes at most "
        "this long, when no batch is waiting or running; 0: never"))] = 1.0
    max_pending: Annotated[int, Field(ge=1, le=100_000, description=(
        "most /predict requests in the service at once (decoding or waiting); more get 503"))] = 256

    # Locked down when deployed; all off by default, so `make serve` on loopback stays one command.
    auth_tokens: CommaList = Field([], repr=False, description="bearer tokens accepted, comma-separated")
    auth_token_file: Path | None = Field(None, description="a file of bearer tokens, one a line (# comments)")
    public_metrics: bool = Field(False, description="with tokens set, leave /metrics open")
    public_docs: bool = Field(False, description="with tokens set, leave /docs, /redoc and /openapi.json open")
    rate_limit: Annotated[float, Field(ge=0, description="requests per second per client; 0: no limit")] = 0.0
    rate_burst: Annotated[int, Field(ge=1, description="requests a client may send at once above its rate")] = 20
    cors_origins: CommaList = Field([], description="origins allowed to call the API from a browser, comma-separated")
    ssl_certfile: Path | None = Field(None, description="TLS certificate (PEM); with ssl_keyfile, serve HTTPS")
    ssl_keyfile: Path | None = Field(None, description="TLS private key (PEM)")
    # OpenIGTLink (service/igtl/), off by default; it binds to `host` like the HTTP server
    igtl: Annotated[bool, Field(description=(
        "serve OpenIGTLink: guide poses in, deformed points out; tracked points and lesions in, the estimate and "
        "the plan out (the devices are listed below)"))] = False
    igtl_port: Annotated[int, Field(ge=1, le=65535, description="OpenIGTLink port")] = 18944
    igtl_targets: Annotated[dict[str, tuple[FiniteFloat, FiniteFloat, FiniteFloat]], Field(
        description='the lesions at start, sent with the markers, JSON {"name": [x, y, z]} in reference mm '
                    '(POINT Lesions replaces them)')] = {}
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

    @field_validator("auth_tokens", "cors_origins", "batch_preferred_sizes", mode="before")
    @classmethod
    def _comma_list(cls, value):
        if isinstance(value, str):
            return [item.strip() for item in value.split(",") if item.strip()]
        return value

    @field_validator("cors_origins")
    @classmethod
    def _origins(cls, value: list[str]) -> list[str]:
        for origin in value:
            if not re.fullmatch(r"https?://[^/*\s]+", origin):
                raise ValueError(f"{origin!r} is not an origin: give each as scheme://host[:port], no wildcard")
        return value

    @field_validator("auth_token_file", "ssl_certfile", "ssl_keyfile")
    @classmethod
    def _readable(cls, value: Path | None) -> Path | None:
        if value is not None and not value.is_file():
            raise ValueError(f"{value} is not a file")
        return value

    @model_validator(mode="after")
    def _pairs(self):
        if (self.ssl_certfile is None) != (self.ssl_keyfile is None):
            raise ValueError("give ssl_certfile and ssl_keyfile together")
        if self.auth_token_file is not None and not read_tokens(self.auth_token_file):
            raise ValueError(f"auth_token_file {self.auth_token_file} holds no token")
        return self

    def tokens(self) -> frozenset[str]:
        """Every accepted bearer token: auth_tokens and the lines of auth_token_file; empty means no auth."""
        from_file = read_tokens(self.auth_token_file) if self.auth_token_file else []
        return frozenset([*self.auth_tokens, *from_file])


def read_tokens(path: Path) -> list[str]:
    """The tokens of a token file: one a line; blank lines and lines starting with # are skipped."""
    lines = (line.strip() for line in path.read_text().splitlines())
    return [line for line in lines if line and not line.startswith("#")]
