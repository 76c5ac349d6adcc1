"""docs/studio.md's REST API table and the app's routes are the same list: every route the app serves
under /api (its OpenAPI schema, generated from the routers) has a row, and every row names a route
that exists. A row may name several paths: `POST /api/scene/play`, `/pause` (a sibling of the last)."""

from __future__ import annotations

import re
from pathlib import Path

from studio.app import create_app
from studio.settings import Settings

DOC = Path(__file__).resolve().parents[2] / "docs" / "studio.md"
ROUTE = re.compile(r"(GET|POST|PUT|PATCH|DELETE) (/\S+)")
CELL_SPLIT = re.compile(r"(?<!\\)\|")  # a table cell may hold an escaped `\|`


def normal(path: str) -> str:
    """A path without its query, optional parts and parameter names: `/api/runs/{}`."""
    path = re.sub(r"\[.*$", "", path.split("?")[0])
    return re.sub(r"\{[^}]*\}", "{}", path)


def documented_routes(text: str) -> set[tuple[str, str]]:
    section = text[text.index("\n## REST API") :]
    section = section[: section.index("\n## ", 5)]
    found: set[tuple[str, str]] = set()
    for line in section.splitlines():
        if not line.startswith("| `"):
            continue
        method = last = None
        for token in re.findall(r"`([^`]*)`", CELL_SPLIT.split(line)[1]):
            if m := ROUTE.match(token):
                method, path = m[1], normal(m[2])
            elif token.startswith("/") and last is not None:
                path = last.rsplit("/", 1)[0] + normal(token)
            else:
                continue
            found.add((method, path))
            last = path
    return found


def test_every_route_has_a_row_and_every_row_a_route(tmp_path: Path) -> None:
    app = create_app(Settings(runs_dir=tmp_path, start_viser=False, startup_clip=None))
    served = {
        (method.upper(), normal(path))
        for path, ops in app.openapi()["paths"].items()
        if path.startswith("/api")
        for method in ops
    }
    documented = documented_routes(DOC.read_text())
    assert served - documented == set(), "routes without a row in docs/studio.md's REST API table"
    assert documented - served == set(), "rows of docs/studio.md's REST API table that name no route"


def test_the_reader_reads_siblings_and_escaped_pipes() -> None:
    text = (
        "\n## REST API\n\n| method and path | what |\n|---|---|\n"
        "| `POST /api/scene/play`, `/pause` | playback |\n"
        "| `GET /api/checkpoints/inspect?path=P[&a=B\\|&c=D]` | x |\n"
        "| `GET /api/runs/{run_id}/log` | y |\n\n## Next\n"
    )
    assert documented_routes(text) == {
        ("POST", "/api/scene/play"),
        ("POST", "/api/scene/pause"),
        ("GET", "/api/checkpoints/inspect"),
        ("GET", "/api/runs/{}/log"),
    }
