"""The two guards of every request: the access token (off loopback) and path confinement.

A path in a request is either MimicKit style (`data/motions/x.pkl`, looked up in each data folder in
turn, the user's first) or absolute. Either way the file it resolves to, symlinks followed, must lie
inside one of the allowed folders; `..` is refused outright so that no probing is possible.
"""

from __future__ import annotations

import hmac
import secrets
from collections.abc import Iterable
from pathlib import Path, PurePosixPath
from urllib.parse import parse_qsl

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send


class PathError(Exception):
    """A request named a file outside the allowed folders (403) or one that is missing (404)."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


def confine(path: str, roots: Iterable[Path], *, must_exist: bool = True) -> Path:
    """The resolved file that `path` names inside one of `roots`; PathError otherwise."""
    roots = [Path(r).resolve() for r in roots]
    if not path or "\x00" in path:
        raise PathError("empty or invalid path", 400)
    p = PurePosixPath(path.replace("\\", "/"))
    if ".." in p.parts:
        raise PathError(f"'..' is not allowed in paths: {path}", 403)
    if p.is_absolute():
        candidates = [Path(p)]
    else:
        rest = PurePosixPath(*p.parts[1:]) if p.parts[0] == "data" and len(p.parts) > 1 else p
        candidates = [root / rest for root in roots] + [root / p for root in roots]
    inside, escapes = [], False
    for c in candidates:
        r = c.resolve()
        if _inside(r, roots):
            if r.exists():
                return r
            inside.append(r)
        elif c.is_symlink() or c.exists():
            escapes = True  # the name is inside, but a symlink on the way leads out
    if escapes or not inside:
        raise PathError(f"path is outside the data and runs folders: {path}", 403)
    if must_exist:
        raise PathError(f"not found: {path}", 404)
    return inside[0]


def _inside(p: Path, roots: list[Path]) -> bool:
    return any(p == r or p.is_relative_to(r) for r in roots)


def display_path(p: Path, data_dirs: Iterable[Path]) -> str:
    """`data/...` for a file in a data folder (MimicKit's convention), else the absolute path."""
    for d in data_dirs:
        if p.is_relative_to(d):
            return str(PurePosixPath("data", *p.relative_to(d).parts))
    return str(p)


def new_token() -> str:
    return secrets.token_urlsafe(24)


def request_token(headers: dict[str, str], query: dict[str, str]) -> str | None:
    """The token a request carries: `Authorization: Bearer T`, `X-Studio-Token: T` or `?token=T`."""
    auth = headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return headers.get("x-studio-token") or query.get("token")


class TokenMiddleware:
    """Refuses every `/api` request without the token (401). The page and /docs stay open: they hold
    no data, and the page must load before it can send the token.

    A plain ASGI middleware (not BaseHTTPMiddleware) so that the metrics event stream passes through
    untouched.
    """

    def __init__(self, app: ASGIApp, token: str) -> None:
        self.app = app
        self._token = token.encode()

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["path"].startswith("/api"):
            headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
            query = dict(parse_qsl(scope.get("query_string", b"").decode("latin-1")))
            given = (request_token(headers, query) or "").encode()
            if not hmac.compare_digest(given, self._token):
                response = JSONResponse({"detail": "a valid token is required (header or ?token=)"}, status_code=401)
                await response(scope, receive, send)
                return
        await self.app(scope, receive, send)
