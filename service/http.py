"""HTTP plumbing: the JSON response class, the one error reply (its schema and the routes' documented errors),
content negotiation, the body limit and CORS."""

from __future__ import annotations

import json
from typing import Iterable, Literal

import orjson
from fastapi import HTTPException, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.middleware.cors import CORSMiddleware

BINARY = "application/octet-stream"
JSON = "application/json"
ReplyFormat = Literal["json", "binary"]


class OrjsonResponse(JSONResponse):
    def render(self, content) -> bytes:
        return orjson.dumps(content, option=orjson.OPT_SERIALIZE_NUMPY)


class FieldError(BaseModel):
    field: str = Field(description="the offending field, dotted (points.3.0), body, or a header (content-type)")
    message: str = Field(description="what is wrong and what the field accepts")
    type: str


class ErrorReply(BaseModel):
    detail: list[FieldError]


# The error replies a POST route documents, each an ErrorReply, in the order their OpenAPI entries list them.
ERROR_REPLIES = {
    400: "the body is not UTF-8 text",
    406: "the Accept header allows neither JSON nor application/octet-stream",
    401: "no bearer token (when the service requires one)",
    403: "the bearer token is not accepted",
    413: "request body too large",
    415: "the body is not sent as application/json",
    422: "a field is invalid, out of the model's envelope, or outside the mesh",
    429: "over the client's rate limit; see Retry-After",
}
NEGOTIATED = frozenset({406, 415})  # only a route that reads Content-Type and Accept itself (/predict) answers these


def error_responses(*, unavailable: str, negotiates: bool = False) -> dict[int, dict]:
    """A POST route's error replies for its OpenAPI `responses`: ERROR_REPLIES (406 and 415 where it `negotiates`),
    then 503 with the route's own reason (`unavailable`)."""
    statuses = [s for s in ERROR_REPLIES if negotiates or s not in NEGOTIATED]
    return {**{s: {"model": ErrorReply, "description": ERROR_REPLIES[s]} for s in statuses},
            503: {"model": ErrorReply, "description": unavailable}}


def error_reply(status: int, errors: Iterable[tuple[str, str, str]], headers: dict | None = None) -> OrjsonResponse:
    """Every error reply: {"detail": [{"field", "message", "type"}]} from (field, message, type) triples."""
    return OrjsonResponse({"detail": [{"field": f, "message": m, "type": t} for f, m, t in errors]},
                          status_code=status, headers=headers)


class RequestProblem(HTTPException):
    """An error reply naming the part of the request that is wrong (a field, the body or a header)."""

    def __init__(self, status: int, *, field: str, message: str, type: str, headers: dict | None = None):
        super().__init__(status, detail=message, headers=headers)
        self.field, self.type = field, type


def _media_ranges(header: str) -> list[tuple[str, str, float]]:
    """(type, subtype, q) of each media range of an Accept header, lower-cased; a bad q counts as 0."""
    ranges = []
    for item in header.split(","):
        media, *params = [part.strip() for part in item.split(";")]
        kind, _, sub = media.lower().partition("/")
        if not kind or not sub:
            continue
        q = 1.0
        for param in params:
            name, _, value = param.partition("=")
            if name.strip().lower() == "q":
                try:
                    q = min(max(float(value), 0.0), 1.0)
                except ValueError:
                    q = 0.0
        ranges.append((kind, sub, q))
    return ranges


def _quality(ranges: list[tuple[str, str, float]], media_type: str) -> float:
    """q of `media_type` under the most specific matching range (type/subtype over type/* over */*)."""
    kind, sub = media_type.split("/")
    specificity = {(kind, sub): 2, (kind, "*"): 1, ("*", "*"): 0}
    matches = [(specificity[(k, s)], q) for k, s, q in ranges if (k, s) in specificity]
    return max(matches)[1] if matches else 0.0


def reply_format(accept: str | None) -> ReplyFormat:
    """The reply's format from the Accept header (RFC 9110 q-values): JSON unless binary has a strictly
    higher q; 406 when neither is acceptable. No header, or an empty one, accepts anything."""
    ranges = _media_ranges(accept or "*/*") or [("*", "*", 1.0)]
    q_json, q_binary = _quality(ranges, JSON), _quality(ranges, BINARY)
    if q_json == 0 and q_binary == 0:
        raise RequestProblem(406, field="accept", type="not_acceptable", message=(
            f"accept: {accept!r} accepts neither reply format; ask for {JSON} (the default) or {BINARY} "
            "(raw float32 positions)"))
    return "binary" if q_binary > q_json else "json"


def require_json(content_type: str | None) -> None:
    """Refuse (415) a body that is not `application/json`, with at most a UTF-8 charset parameter."""
    media, *params = [part.strip() for part in (content_type or "").split(";")]
    utf8 = all(name.strip().lower() == "charset" and value.strip().strip('"').lower() in ("utf-8", "utf8")
               for name, _, value in (param.partition("=") for param in params if param))
    if media.lower() == JSON and utf8:
        return
    sent = f"{content_type!r} is not accepted" if content_type else "no Content-Type header was sent"
    raise RequestProblem(415, field="content-type", type="unsupported_media_type",
                         message=f"content-type: {sent}; send the body as {JSON} (charset utf-8, if given)")


def parse_json(body: bytes):
    """The body as JSON: orjson, or the standard parser where orjson refuses (NaN and Infinity literals,
    which the schema then refuses as not finite; the error message for malformed JSON)."""
    try:
        return orjson.loads(body)
    except orjson.JSONDecodeError:
        pass
    try:
        return json.loads(body)
    except UnicodeDecodeError:
        raise RequestProblem(400, field="body", type="not_utf8",
                             message="body: not UTF-8 text, as JSON must be") from None


class JsonRequest(Request):
    """A request whose json() is parse_json's, parsed once."""

    async def json(self):
        if not hasattr(self, "_json"):
            self._json = parse_json(await self.body())
        return self._json


def _hints(request: Request) -> dict[str, str]:
    return request.app.state.field_hints


async def invalid_request(request: Request, exc: RequestValidationError) -> OrjsonResponse:
    """422 naming each bad field and what it accepts; never echoes the input (it may be NaN)."""
    hints, errors = _hints(request), []
    for err in exc.errors():
        loc = [str(p) for p in err["loc"] if p != "body"]
        if err["type"] == "json_invalid":
            errors.append(("body", f"body: malformed JSON ({err.get('ctx', {}).get('error', 'cannot parse')})",
                           err["type"]))
            continue
        field = ".".join(loc) or "body"
        hint = hints.get(loc[0] if loc else "", "")
        errors.append((field, f"{field}: {err['msg']}" + (f" ({hint})" if hint else ""), err["type"]))
    return error_reply(422, errors)


async def http_problem(request: Request, exc: StarletteHTTPException) -> OrjsonResponse:
    """Any HTTPException (ours, FastAPI's 400 for an unreadable body, 404, 405, 503) in the one error format."""
    if isinstance(exc, RequestProblem):
        error = (exc.field, exc.detail, exc.type)
    else:
        error = ("body" if exc.status_code == 400 else "request", str(exc.detail), f"http_{exc.status_code}")
    return error_reply(exc.status_code, [error], headers=exc.headers)


class BodyLimit:
    """Read each request body up to `max_bytes`, then hand it on; over the limit, reply 413 at once.

    Whether the size is announced (Content-Length) or not (chunked transfer), the body is counted
    as it arrives and the app never sees an oversize one.
    """

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = dict(scope["headers"]).get(b"content-length", b"")
        if length.isdigit() and int(length) > self.max_bytes:
            return await self._too_large(scope, receive, send)
        chunks, size, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] != "http.request":  # the client went away
                return
            chunks.append(message.get("body", b""))
            size, more = size + len(chunks[-1]), message.get("more_body", False)
            if size > self.max_bytes:
                return await self._too_large(scope, receive, send)
        body, replayed = b"".join(chunks), False

        async def replay():
            nonlocal replayed
            if replayed:
                return await receive()  # waits for the disconnect, as the server's receive would
            replayed = True
            return {"type": "http.request", "body": body, "more_body": False}

        await self.app(scope, replay, send)

    async def _too_large(self, scope, receive, send):
        reply = error_reply(413, [("body", f"request body over the limit of {self.max_bytes} bytes", "too_large")])
        await reply(scope, receive, send)


class Cors(CORSMiddleware):
    """Starlette's CORS middleware for an explicit list of origins; a refused preflight gets the house error format."""

    def __init__(self, app, *, origins: list[str]):
        super().__init__(app, allow_origins=origins, allow_methods=["GET", "POST"],
                         allow_headers=["authorization", "content-type", "accept"],
                         expose_headers=["X-Count", "X-Layout", "Retry-After"])

    def preflight_response(self, request_headers) -> Response:
        reply = super().preflight_response(request_headers)
        if reply.status_code == 200:
            return reply
        refused = reply.body.decode().removeprefix("Disallowed CORS ")  # origin, method, headers
        headers = {k: v for k, v in reply.headers.items() if k.lower().startswith(("access-control", "vary"))}
        return error_reply(400, [("origin", f"CORS preflight refused: {refused} not allowed "
                                  f"(allowed origins: {', '.join(self.allow_origins)})", "cors_refused")], headers)
