"""The guards of every request: the Host and Origin checks, the access token (off loopback), the
cross-site request check, and path confinement.

A path in a request is either MimicKit style (`data/motions/x.pkl`, looked up in each data folder in
turn, the user's first) or absolute. Either way the file it resolves to, symlinks followed, must lie
inside one of the allowed folders; `..` is refused outright so that no probing is possible.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
import socket
from collections.abc import Iterable
from pathlib import Path, PurePosixPath
from urllib.parse import parse_qsl, urlsplit

from starlette.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

MAX_PATH_CHARS = 4096  # Linux's PATH_MAX: no longer path names a file
MAX_NAME_CHARS = 255  # NAME_MAX of the usual file systems: no longer name is a file or folder
SHOWN_CHARS = 100  # of a path quoted in an error
MAX_MESSAGE_CHARS = 400  # of a PathError's message, whatever its raiser quoted


class PathError(Exception):
    """A request named a file outside the allowed folders (403), one that is missing (404) or a path
    no file can have (400). The message is one line of at most `MAX_MESSAGE_CHARS` characters."""

    def __init__(self, message: str, status: int) -> None:
        message = message.replace("\r", "\\r").replace("\n", "\\n")
        if len(message) > MAX_MESSAGE_CHARS:
            message = message[: MAX_MESSAGE_CHARS - 1] + "…"
        super().__init__(message)
        self.status = status


def shown_path(path: str) -> str:
    """`path` as an error quotes it: at most `SHOWN_CHARS` characters, and its length when cut."""
    return path if len(path) <= SHOWN_CHARS else f"{path[:SHOWN_CHARS]}... ({len(path):,} chars)"


def confine(path: str, roots: Iterable[Path], *, must_exist: bool = True) -> Path:
    """The resolved file that `path` names inside one of `roots`; PathError otherwise."""
    roots = [Path(r).resolve() for r in roots]
    if not path or "\x00" in path:
        raise PathError("empty or invalid path", 400)
    p = PurePosixPath(path.replace("\\", "/"))
    if len(path) > MAX_PATH_CHARS or any(len(part) > MAX_NAME_CHARS for part in p.parts):
        limits = f"at most {MAX_PATH_CHARS:,} characters, {MAX_NAME_CHARS} per name"
        raise PathError(f"path too long ({limits}): {shown_path(path)}", 400)
    if ".." in p.parts:
        raise PathError(f"'..' is not allowed in paths: {shown_path(path)}", 403)
    if p.is_absolute():
        candidates = [Path(p)]
    else:
        rest = PurePosixPath(*p.parts[1:]) if p.parts[0] == "data" and len(p.parts) > 1 else p
        candidates = [root / rest for root in roots] + [root / p for root in roots]
    try:
        found, inside = _lookup(candidates, roots)
    except OSError as e:  # ENAMETOOLONG once joined to a root, ELOOP, EACCES: no file it can name
        raise PathError(f"not a usable path ({e.strerror or type(e).__name__}): {shown_path(path)}", 400) from None
    if found is not None:
        return found
    if not inside:
        raise PathError(f"path is outside the data and runs folders: {shown_path(path)}", 403)
    if must_exist:
        raise PathError(f"not found: {shown_path(path)}", 404)
    return inside[0]


def _lookup(candidates: list[Path], roots: list[Path]) -> tuple[Path | None, list[Path]]:
    """The first candidate that resolves to an existing file inside `roots`, else None and those that
    resolve inside without existing (none when one leads out through a symlink)."""
    inside, escapes = [], False
    for c in candidates:
        r = c.resolve()
        if _inside(r, roots):
            if r.exists():
                return r, []
            inside.append(r)
        elif c.is_symlink() or c.exists():
            escapes = True  # the name is inside, but a symlink on the way leads out
    return None, [] if escapes else inside


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


# ------------------------------------------------------------------ cross-site requests, DNS rebinding
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
CUSTOM_HEADER = "x-studio-request"
"""A header no cross-site form or simple request can carry: the page sends `X-Studio-Request: 1`."""
LOOPBACK_NAMES = frozenset({"127.0.0.1", "localhost", "::1"})
PROTECTED_PREFIXES = ("/api", "/scene")
"""What the token guards: the API and the 3D scene's proxy (the page and its scripts hold no data)."""


def host_name(value: str) -> str:
    """The name part of a Host header (`[::1]:8000` -> `::1`, `Example.org.:80` -> `example.org`)."""
    value = value.strip().lower()
    if value.startswith("["):
        return value[1 : value.find("]")] if "]" in value else value
    name = value.rsplit(":", 1)[0] if value.count(":") == 1 else value
    return name.rstrip(".")


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class HostPolicy:
    """Which Host header names a request may use. Bound to loopback: the loopback names; bound to one
    address or name: that one; bound to every interface (0.0.0.0, ::): IP literals, this machine's
    names and localhost (a DNS-rebinding page always reaches the server under its own DNS name, never
    an IP literal). `extra` (`--allowed-hosts`) adds names; `*` allows any."""

    def __init__(self, bound_host: str, extra: Iterable[str] = ()) -> None:
        extra = [host_name(e) if e != "*" else "*" for e in extra]
        self.any = "*" in extra
        self.any_ip = bound_host in ("0.0.0.0", "::")
        names = set(extra) - {"*"}
        if bound_host in ("0.0.0.0", "::"):
            names |= {"localhost", socket.gethostname().lower(), socket.getfqdn().lower()}
        elif host_name(bound_host) in LOOPBACK_NAMES or bound_host.startswith("127."):
            names |= LOOPBACK_NAMES | {host_name(bound_host)}
        else:
            names.add(host_name(bound_host))
        self.names = frozenset(names)

    def allows(self, host_header: str) -> bool:
        name = host_name(host_header)
        return bool(name) and (self.any or name in self.names or (self.any_ip and _is_ip(name)))

    def describe(self) -> str:
        shown = sorted(f"[{n}]" if ":" in n else n for n in self.names)
        return ", ".join(shown + (["any IP address"] if self.any_ip else []))


def origin_matches(origin: str, host_header: str) -> bool:
    """Whether an Origin header names this server as the request reached it (scheme, host, port)."""
    parts = urlsplit(origin)
    return parts.scheme in ("http", "https") and parts.netloc.lower() == host_header.strip().lower()


def token_cookie_name(port: int) -> str:
    """One cookie per studio port: two studios on one machine must not share their tokens."""
    return f"mimickit_studio_{port}"


class RequestGuard:
    """Every request's checks, in order, before any handler runs:

    1. the Host header names this server (else 403): a DNS-rebinding page reaches the server under
       the attacker's name, so it is refused before it can read or change anything;
    2. with a token (off loopback): `/api` and `/scene` (the 3D scene's proxy, HTTP and websocket)
       need it (401); the scene also takes it from a cookie that its first `?token=` sets, because
       viser's page opens its websocket without the query string;
    3. a state-changing `/api` request (POST, PUT, PATCH, DELETE) needs a JSON content type or the
       `X-Studio-Request` header (403): neither can be sent cross-site without a CORS preflight,
       which the studio never grants; and when it carries an Origin, that must be this server's
       (403). A websocket's Origin is checked the same way (cross-site websocket hijacking).

    A plain ASGI middleware (not BaseHTTPMiddleware) so that the metrics event stream and the scene's
    websocket pass through untouched.
    """

    def __init__(self, app: ASGIApp, hosts: HostPolicy, token: str | None = None) -> None:
        self.app = app
        self.hosts = hosts
        self._token = token.encode() if token else None

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1"): v.decode("latin-1") for k, v in scope["headers"]}
        problem, status = self._check(scope, headers)
        if problem is not None:
            await _refuse(scope, receive, send, status, problem)
            return
        if self._token and scope["type"] == "http" and scope["path"].startswith("/scene"):
            send = self._setting_cookie(scope, send)
        await self.app(scope, receive, send)

    def _check(self, scope: Scope, headers: dict[str, str]) -> tuple[str | None, int]:
        host = headers.get("host", "")
        if not self.hosts.allows(host):
            return (
                f"Host {host[:100]!r} is not a name of this server (allowed: {self.hosts.describe()}; "
                "add names with --allowed-hosts)",
                403,
            )
        path = scope["path"]
        if self._token and path.startswith(PROTECTED_PREFIXES):
            query = dict(parse_qsl(scope.get("query_string", b"").decode("latin-1")))
            given = request_token(headers, query)
            if given is None and path.startswith("/scene"):
                given = _cookies(headers).get(token_cookie_name(_port(scope)))
            if not hmac.compare_digest((given or "").encode(), self._token):
                return "a valid token is required (header or ?token=)", 401
        origin = headers.get("origin")
        changing = scope["type"] == "websocket" or (scope.get("method") in STATE_CHANGING and path.startswith("/api"))
        if changing and origin is not None and not origin_matches(origin, host):
            return f"cross-site request refused: Origin {origin[:100]!r} is not this server ({host[:100]})", 403
        if scope["type"] == "http" and changing:
            ctype = headers.get("content-type", "").split(";", 1)[0].strip().lower()
            if ctype != "application/json" and not headers.get(CUSTOM_HEADER):
                return (
                    f"{scope['method']} {path} needs Content-Type: application/json or the header "
                    "X-Studio-Request: 1 (a guard against cross-site requests)",
                    403,
                )
        return None, 200

    def _setting_cookie(self, scope: Scope, send: Send) -> Send:
        """Remember a `?token=` given to the scene in an HttpOnly cookie for the scene's websocket."""
        query = dict(parse_qsl(scope.get("query_string", b"").decode("latin-1")))
        if "token" not in query:
            return send
        cookie = (f"{token_cookie_name(_port(scope))}={query['token']}; Path=/scene; HttpOnly; SameSite=Strict").encode(
            "latin-1"
        )

        async def send_with_cookie(message: dict) -> None:
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message.get("headers", []), (b"set-cookie", cookie)]}
            await send(message)

        return send_with_cookie


def _port(scope: Scope) -> int:
    server = scope.get("server") or ("", 0)
    return int(server[1] or 0)


def _cookies(headers: dict[str, str]) -> dict[str, str]:
    out = {}
    for part in headers.get("cookie", "").split(";"):
        name, _, value = part.strip().partition("=")
        if name:
            out[name] = value
    return out


async def _refuse(scope: Scope, receive: Receive, send: Send, status: int, detail: str) -> None:
    if scope["type"] == "websocket":
        # Before the handshake is accepted: uvicorn answers the upgrade with HTTP 403.
        await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
        return
    await JSONResponse({"detail": detail}, status_code=status)(scope, receive, send)
