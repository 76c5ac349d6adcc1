"""Request bodies and their errors, shared by every router: unknown keys are refused by name, and a
request that does not validate gets a 422 with one line naming the field, not pydantic's list."""

from __future__ import annotations

from collections.abc import Callable, Coroutine, Sequence
from typing import Any

from fastapi import Request, Response
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import APIRoute
from pydantic import BaseModel, model_validator

from mimickit.util.config import nearest_name


class OneLineErrors(APIRoute):
    """A request these routes cannot validate gets a 422 with one line naming the field, not pydantic's list."""

    def get_route_handler(self) -> Callable[[Request], Coroutine[Any, Any, Response]]:
        handler = super().get_route_handler()

        async def route(request: Request) -> Response:
            try:
                return await handler(request)
            except RequestValidationError as e:
                return JSONResponse({"detail": validation_line(e.errors())}, status_code=422)

        return route


def validation_line(errors: Sequence[Any]) -> str:
    """`field: message` of the first problem (and how many more there are)."""
    if not errors:
        return "invalid request"
    first = errors[0]
    loc = [str(p) for p in first.get("loc", ()) if p != "body"]
    msg = str(first.get("msg", "invalid value")).removeprefix("Value error, ")
    line = f"{'.'.join(loc)}: {msg}" if loc else msg
    return line + (f" (and {len(errors) - 1} more)" if len(errors) > 1 else "")


class StrictBody(BaseModel):
    """A request body whose unknown keys are refused by name (with the nearest known one)."""

    @model_validator(mode="before")
    @classmethod
    def _known_keys(cls, data: Any) -> Any:
        if isinstance(data, dict):
            known = list(cls.model_fields)
            for key in data:
                if key not in known:
                    near = nearest_name(str(key)[:100], known)
                    hint = f"; did you mean {near!r}?" if near else f"; known keys: {', '.join(known)}"
                    shown = key if len(key) <= 60 else key[:60] + "..."  # never echo unbounded input
                    raise ValueError(f"unknown key {shown!r}{hint}")
        return data
