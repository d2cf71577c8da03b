"""File primitives both folders use: sha256 and atomic writes (readers never see half a file)."""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ValidationError


def sha256(path: str | Path) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


@contextmanager
def _atomic(path: Path, mode: str):
    """A temporary file beside `path`, renamed over it only if the block finishes."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, mode) as fh:
            yield fh
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_savez(path: str | Path, *, compressed: bool = False, **arrays) -> Path:
    """np.savez to a temporary file beside `path`, then rename."""
    path = Path(path)
    with _atomic(path, "wb") as fh:
        (np.savez_compressed if compressed else np.savez)(fh, **arrays)
    return path


def atomic_write_bytes(path: str | Path, data: bytes) -> Path:
    path = Path(path)
    with _atomic(path, "wb") as fh:
        fh.write(data)
    return path


def atomic_write_text(path: str | Path, text: str) -> Path:
    path = Path(path)
    with _atomic(path, "w") as fh:
        fh.write(text)
    return path


def read_manifest_json(path: Path, model: type[BaseModel], *, version: int | tuple[int, ...], error: type[Exception],
                       kind: str, missing: str, stale: str):
    """A folder's versioned manifest as `model`; `error` says why not: missing, not JSON, another format
    (with `stale`, what to do about it) or a field that does not validate. `version`: the format, or
    the formats, this code reads."""
    if not path.is_file():
        raise error(f"{path.parent}: no {path.name}; {missing}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc})") from None
    found = data.get("format_version", "unversioned") if isinstance(data, dict) else "unversioned"
    versions = version if isinstance(version, tuple) else (version,)
    if found not in versions:
        raise error(f"{path.parent}: {kind} format {found!r}, "
                    f"this code reads {' and '.join(map(str, versions))}; {stale}")
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        e = exc.errors()[0]
        raise error(f"{path}: {'.'.join(map(str, e['loc']))}: {e['msg']}") from None
