"""Reply bodies: raw float32 positions without a copy, and JSON written in pieces that never stall the event loop.

orjson holds the GIL while it serialises. A 312k-node JSON reply (936k numbers, about 20 MB) takes
tens of ms in one call (`json_reply_ms` in docs/results/bench_service.json), and the event loop,
waiting for the GIL, answers nothing meanwhile (not even /healthz). So large arrays are serialised
`CHUNK_ROWS` rows per call, in a worker thread that offers the GIL back between calls, and the
pieces are sent as they are, one body message each, under one Content-Length: no join, no copy of
the whole body. At most `JSON_WRITERS` large arrays are serialised at once: the event loop waits
for the GIL behind every thread that wants it, so each writer more delays /healthz, and each fewer
costs JSON throughput (why: CHANGELOG, "At most two large JSON arrays are serialised at once").
"""

from __future__ import annotations

import threading
import time

import numpy as np
import orjson
from starlette.responses import Response

from ..http import BINARY, JSON
from .decode import Prediction
from .schemas import PredictRequestBase

CHUNK_ROWS = 8192  # rows of a (k, 3) float32 array per orjson call: short enough that the loop gets the GIL often
JSON_WRITERS = threading.BoundedSemaphore(2)  # large arrays serialised at once (module docstring)
SMALL_JSON_ROWS = 2048  # at most this many rows in all: serialised on the event loop in one call
LAYOUT = "float32 little-endian, count x 3 (x, y, z) mm, deformed positions"


def binary_reply(positions: np.ndarray) -> Response:
    """Raw little-endian float32 positions (count x 3); the array's memory is sent as it is."""
    # float32 arrays are little-endian on every platform onnxruntime ships for; Starlette casts the view, no copy
    return Response(memoryview(np.ascontiguousarray(positions, dtype="<f4")), media_type=BINARY,
                    headers={"X-Count": str(len(positions)), "X-Layout": LAYOUT})


def array_chunks(array: np.ndarray, *, rows: int = CHUNK_ROWS) -> list[bytes]:
    """The JSON of `array` (a list of its rows), as pieces whose concatenation is orjson's own text of it.

    Between pieces the thread sleeps for 0 s, which releases the GIL: a thread waiting for it
    (the event loop) runs then, not after the whole array. A large array waits for one of the
    JSON_WRITERS first.
    """
    if len(array) <= rows:
        return [orjson.dumps(array, option=orjson.OPT_SERIALIZE_NUMPY)]
    pieces = [b"["]
    with JSON_WRITERS:
        for start in range(0, len(array), rows):
            text = orjson.dumps(array[start:start + rows], option=orjson.OPT_SERIALIZE_NUMPY)
            pieces.append(text[1:-1] if start == 0 else b"," + text[1:-1])
            time.sleep(0)
    pieces.append(b"]")
    return pieces


def json_chunks(scalars: dict, arrays: dict[str, np.ndarray]) -> list[bytes]:
    """The JSON object {**scalars, **arrays} as pieces, the arrays serialised in CHUNK_ROWS-row calls."""
    head = orjson.dumps(scalars)
    pieces = [head[:-1]]  # without its closing brace
    for i, (name, array) in enumerate(arrays.items()):
        separator = b"," if scalars or i else b""
        pieces.append(separator + orjson.dumps(name) + b":")
        pieces.extend(array_chunks(np.ascontiguousarray(array)))
    pieces.append(b"}")
    return pieces


def rows_of(arrays: dict[str, np.ndarray]) -> int:
    return sum(len(a) for a in arrays.values())


class ChunkedResponse(Response):
    """A body sent as the given pieces, one ASGI body message each, with their total as Content-Length."""

    def __init__(self, pieces: list[bytes], *, status_code: int = 200, media_type: str = JSON,
                 headers: dict | None = None):
        self.pieces = [p for p in pieces if p]
        size = sum(map(len, self.pieces))
        super().__init__(None, status_code=status_code, media_type=media_type,
                         headers={**(headers or {}), "content-length": str(size)})

    async def __call__(self, scope, receive, send) -> None:
        await send({"type": "http.response.start", "status": self.status_code, "headers": self.raw_headers})
        last = len(self.pieces) - 1
        if last < 0:
            await send({"type": "http.response.body", "body": b"", "more_body": False})
        for i, piece in enumerate(self.pieces):
            await send({"type": "http.response.body", "body": piece, "more_body": i < last})


def reply(request: PredictRequestBase, prediction: Prediction, *, fmt: str, model: str) -> Response:
    """A prediction as JSON, or as raw little-endian float32 positions (count x 3); large JSON in pieces:
    call it off the event loop unless `small_reply` says it is cheap."""
    if fmt == "binary":
        response = binary_reply(prediction.positions)
        if prediction.budget is not None:  # a material model: the largest 1-sigma length at the returned points
            response.headers["X-Std-Max-Mm"] = f"{prediction.budget['material_std_mm_max']:.6g}"
        return response
    scalars = {"model": model, "displacement_mm": request.displacement_mm, "angle_deg": request.angle_deg,
               "region": prediction.region, "count": len(prediction.positions)}
    if prediction.budget is not None:
        scalars["error_budget"] = prediction.budget
    return ChunkedResponse(json_chunks(scalars, reply_arrays(prediction)))


def reply_arrays(prediction: Prediction) -> dict[str, np.ndarray]:
    arrays = {"positions": prediction.positions}
    if prediction.displacements is not None:
        arrays["displacements"] = prediction.displacements
    if prediction.node_ids is not None:
        arrays["node_ids"] = prediction.node_ids
    if prediction.std is not None:
        arrays["std_mm"] = prediction.std
    return arrays


def small_reply(prediction: Prediction, fmt: str) -> bool:
    """Whether the reply costs so little to build that a thread hop would cost more: binary (no copy, no work)
    or JSON of a few rows."""
    return fmt == "binary" or rows_of(reply_arrays(prediction)) <= SMALL_JSON_ROWS
