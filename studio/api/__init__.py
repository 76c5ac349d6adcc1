"""REST routers of the studio, one module per panel: library, scene, runs."""

from __future__ import annotations

from typing import TYPE_CHECKING

from fastapi import HTTPException, Request

if TYPE_CHECKING:
    from studio.app import Studio


def studio_of(request: Request) -> Studio:
    return request.app.state.studio


def need(value: object, what: str) -> None:
    """503 when a part of the studio is switched off (e.g. the 3D scene in API-only tests)."""
    if value is None:
        raise HTTPException(503, f"{what} is not running in this server")
