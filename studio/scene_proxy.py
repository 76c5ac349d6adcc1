"""The 3D scene through the studio's own port: viser listens on 127.0.0.1 only (an internal port) and
`/scene/` relays its page (HTTP) and its websocket, so that the scene sits behind the same Host,
Origin and token checks as the API (one port, one check; see `studio.security.RequestGuard`).

viser's client is one self-contained `index.html`; it opens its websocket at the page's URL without
the query string and the trailing slash (`/scene/` -> `ws://host:port/scene`), with the subprotocol
`viser-v<version>` that viser checks. The relay copies frames both ways unchanged.
"""

from __future__ import annotations

import contextlib
from collections.abc import Awaitable, Callable

import anyio
import httpx
import websockets
from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import JSONResponse, RedirectResponse, Response
from starlette.websockets import WebSocketDisconnect

VISER_HOST = "127.0.0.1"
MAX_MESSAGE_BYTES = 64 * 1024 * 1024  # viser's own limit is 50 MB (e.g. a client's render)
_PASSED_HEADERS = ("content-type", "content-encoding", "content-length", "cache-control")


def add_scene_proxy(app: FastAPI, viser_port: Callable[[], int | None]) -> Callable[[], Awaitable[None]]:
    """Routes `/scene/...` (viser's HTTP files) and the websocket `/scene` on `app`; returns the
    coroutine function that closes the relay's HTTP client (at shutdown)."""
    client = httpx.AsyncClient(timeout=30.0)

    @app.get("/scene", include_in_schema=False)
    async def scene_root(request: Request) -> Response:
        query = f"?{request.url.query}" if request.url.query else ""
        return RedirectResponse(f"/scene/{query}")

    @app.get("/scene/{path:path}", include_in_schema=False)
    async def scene_file(path: str, request: Request) -> Response:
        port = viser_port()
        if port is None:
            return JSONResponse({"detail": "the 3D scene is not running in this server"}, 503)
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

    async def scene_socket(ws: WebSocket) -> None:
        port = viser_port()
        if port is None:
            await ws.close(1011, "the 3D scene is not running in this server")
            return
        protocols = list(ws.scope.get("subprotocols") or [])
        try:
            upstream = await websockets.connect(
                f"ws://{VISER_HOST}:{port}/",
                subprotocols=protocols or None,  # type: ignore[arg-type]
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

                async def browser_to_viser() -> None:
                    with contextlib.suppress(WebSocketDisconnect, websockets.ConnectionClosed):
                        while True:
                            message = await ws.receive()
                            if message["type"] == "websocket.disconnect":
                                break
                            data = message.get("bytes")
                            await upstream.send(data if data is not None else message.get("text", ""))
                    tg.cancel_scope.cancel()

                async def viser_to_browser() -> None:
                    with contextlib.suppress(WebSocketDisconnect, websockets.ConnectionClosed, RuntimeError):
                        async for data in upstream:
                            if isinstance(data, bytes):
                                await ws.send_bytes(data)
                            else:
                                await ws.send_text(data)
                    with contextlib.suppress(RuntimeError):
                        code = upstream.close_code or 1000
                        await ws.close(code if code != 1006 else 1011, upstream.close_reason or "")
                    tg.cancel_scope.cancel()

                tg.start_soon(browser_to_viser)
                tg.start_soon(viser_to_browser)

    app.add_api_websocket_route("/scene", scene_socket)
    app.add_api_websocket_route("/scene/", scene_socket)
    return client.aclose
