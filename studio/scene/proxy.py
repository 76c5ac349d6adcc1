"""The 3D scene through the studio's own port: viser listens on 127.0.0.1 only (an internal port) and
`/scene/` relays its page (HTTP) and its websocket, so that the scene sits behind the same Host,
Origin and token checks as the API (one port, one check; see `studio.security.RequestGuard`).

viser's client is one self-contained `index.html`; it opens its websocket at the page's URL without
the query string and the trailing slash (`/scene/` -> `ws://host:port/scene`), with the subprotocol
`viser-v<version>` that viser checks. The relay copies frames both ways unchanged.

The internal port itself is reachable only through the relay: `guarded_viser_server` starts viser
with a check before viser's own on every request (HTTP and websocket handshake) that refuses, with
403, one without the relay's secret (`RELAY_HEADER`, random per process), with an Origin (a
browser's: the relay sends none) or with a Host other than loopback. Any other local program or a
page in a browser on this machine could otherwise watch the scene and play or step it unasked.
"""

from __future__ import annotations

import contextlib
import hmac
import secrets
import threading
from collections.abc import Awaitable, Callable
from http import HTTPStatus
from typing import Any

import anyio
import httpx
import viser
import websockets
import websockets.asyncio.server
from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import JSONResponse, RedirectResponse, Response
from starlette.websockets import WebSocketDisconnect
from websockets.asyncio.client import ClientConnection
from websockets.http11 import Request as HandshakeRequest

from mimickit.util.errors import MimicKitError
from studio.security import LOOPBACK_NAMES, host_name

VISER_HOST = "127.0.0.1"
MAX_MESSAGE_BYTES = 64 * 1024 * 1024  # viser's own limit is 50 MB (e.g. a client's render)
_PASSED_HEADERS = ("content-type", "content-encoding", "content-length", "cache-control")
RELAY_HEADER = "X-Studio-Relay"
"""The header with which the relay proves itself to viser's internal port."""
_RELAY_SECRET = secrets.token_urlsafe(32)  # per process: only this process's relays know it
_serve_patch = threading.Lock()


def relay_refusal(request: HandshakeRequest) -> str | None:
    """Why a request to viser's internal port is refused, or None for the relay's own. Headers are
    read with `get_all`: a header given twice is a refusal, not an exception."""
    headers = request.headers
    if headers.get_all("Origin"):
        return "viser's internal port takes no browser (an Origin header): open the studio's /scene/"
    hosts = headers.get_all("Host")
    if len(hosts) != 1 or host_name(hosts[0]) not in LOOPBACK_NAMES:
        return "viser's internal port answers to loopback names only"
    secret = headers.get_all(RELAY_HEADER)
    if len(secret) != 1 or not hmac.compare_digest(secret[0].encode(), _RELAY_SECRET.encode()):
        return "viser's internal port is reachable only through the studio's /scene/ relay"
    return None


def guarded_viser_server(**kwargs: Any) -> viser.ViserServer:
    """`viser.ViserServer(**kwargs)` whose port refuses every request but the relay's (`relay_refusal`).

    viser 1.1 offers no hook for its websocket server's `process_request`; it calls
    `websockets.asyncio.server.serve` (looked up when its server thread starts, which the constructor
    waits for), so that is wrapped for the constructor's duration, under a lock. A viser that no longer
    starts its server that way is an error here, not an unguarded port."""
    original = websockets.asyncio.server.serve
    guarded: list[bool] = []

    def serve(*args: Any, process_request: Any = None, **serve_kwargs: Any) -> Any:
        def check_first(connection: websockets.asyncio.server.ServerConnection, request: HandshakeRequest) -> Any:
            refusal = relay_refusal(request)
            if refusal is not None:
                return connection.respond(HTTPStatus.FORBIDDEN, refusal + "\n")
            return process_request(connection, request) if process_request is not None else None

        guarded.append(True)
        return original(*args, process_request=check_first, **serve_kwargs)

    with _serve_patch:
        websockets.asyncio.server.serve = serve  # type: ignore[misc, assignment]
        try:
            server = viser.ViserServer(**kwargs)
        finally:
            websockets.asyncio.server.serve = original  # type: ignore[misc]
    if not guarded:
        server.stop()
        raise MimicKitError(f"viser {viser.__version__} did not start its server through websockets' serve(): "
                           "its internal port cannot be guarded")  # fmt: skip
    return server


def _relay_headers() -> dict[str, str]:
    return {RELAY_HEADER: _RELAY_SECRET}


def add_scene_proxy(app: FastAPI, viser_port: Callable[[], int | None]) -> Callable[[], Awaitable[None]]:
    """Routes `/scene/...` (viser's HTTP files) and the websocket `/scene` on `app`; returns the
    coroutine function that closes the relay's HTTP client (at shutdown)."""
    client = httpx.AsyncClient(timeout=30.0, headers=_relay_headers())

    @app.get("/scene", include_in_schema=False)
    async def scene_root(request: Request) -> Response:
        query = f"?{request.url.query}" if request.url.query else ""
        return RedirectResponse(f"/scene/{query}")

    @app.get("/scene/{path:path}", include_in_schema=False)
    async def scene_file(path: str, request: Request) -> Response:
        port = viser_port()
        if port is None:
            return JSONResponse({"detail": "the 3D scene is not running in this server"}, 503)
        return await _relay_file(client, port, path, request)

    async def scene_socket(ws: WebSocket) -> None:
        port = viser_port()
        if port is None:
            await ws.close(1011, "the 3D scene is not running in this server")
            return
        await _relay_socket(ws, port)

    app.add_api_websocket_route("/scene", scene_socket)
    app.add_api_websocket_route("/scene/", scene_socket)
    return client.aclose


async def _relay_file(client: httpx.AsyncClient, port: int, path: str, request: Request) -> Response:
    """viser's file `path`, as it sent it (gzip when the browser takes it)."""
    accept = "gzip" if "gzip" in request.headers.get("accept-encoding", "") else "identity"
    try:
        url = f"http://{VISER_HOST}:{port}/{path}"
        async with client.stream("GET", url, headers={"Accept-Encoding": accept}) as r:
            body = b"".join([chunk async for chunk in r.aiter_raw()])
    except httpx.HTTPError as e:
        return JSONResponse({"detail": f"the 3D scene does not answer ({type(e).__name__})"}, 502)
    headers = {k: v for k, v in r.headers.items() if k.lower() in _PASSED_HEADERS}
    headers["content-length"] = str(len(body))
    return Response(body, r.status_code, headers=headers)


async def _relay_socket(ws: WebSocket, port: int) -> None:
    """The browser's websocket joined to one of its own to viser, until either side closes."""
    protocols = list(ws.scope.get("subprotocols") or [])
    try:
        upstream = await websockets.connect(
            f"ws://{VISER_HOST}:{port}/",
            subprotocols=protocols or None,  # type: ignore[arg-type]
            additional_headers=_relay_headers(),
            compression=None,
            max_size=MAX_MESSAGE_BYTES,
            open_timeout=10,
        )
    except (OSError, websockets.WebSocketException, TimeoutError):
        await ws.close(1011, "the 3D scene does not answer")
        return
    async with upstream:
        await ws.accept(subprotocol=upstream.subprotocol)
        async with anyio.create_task_group() as tg:
            tg.start_soon(_browser_to_viser, ws, upstream, tg.cancel_scope)
            tg.start_soon(_viser_to_browser, ws, upstream, tg.cancel_scope)


async def _browser_to_viser(ws: WebSocket, upstream: ClientConnection, done: anyio.CancelScope) -> None:
    with contextlib.suppress(WebSocketDisconnect, websockets.ConnectionClosed):
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            data = message.get("bytes")
            await upstream.send(data if data is not None else message.get("text", ""))
    done.cancel()


async def _viser_to_browser(ws: WebSocket, upstream: ClientConnection, done: anyio.CancelScope) -> None:
    """viser's messages on to the browser; then its close code (1011 for a dropped connection)."""
    with contextlib.suppress(WebSocketDisconnect, websockets.ConnectionClosed, RuntimeError):
        async for data in upstream:
            if isinstance(data, bytes):
                await ws.send_bytes(data)
            else:
                await ws.send_text(data)
    with contextlib.suppress(RuntimeError):
        code = upstream.close_code or 1000
        await ws.close(code if code != 1006 else 1011, upstream.close_reason or "")
    done.cancel()
