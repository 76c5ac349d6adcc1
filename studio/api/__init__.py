"""REST routers of the studio, one module per panel: library, scene, runs, evals, videos, the stream.
A handler reaches the studio's services as a parameter `studio: StudioDep`."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, HTTPException, Request

from studio.services import Studio


def studio_of(request: Request) -> Studio:
    return request.app.state.studio


StudioDep = Annotated[Studio, Depends(studio_of)]


def need(value: object, what: str) -> None:
    """503 when a part of the studio is switched off (e.g. the 3D scene in API-only tests)."""
    if value is None:
        raise HTTPException(503, f"{what} is not running in this server")
