"""The house's layers, read from the source with `ast`: every import counts, those under `if TYPE_CHECKING:`
and inside functions included, since each one ties two files together whether or not it runs at import.

(a) No file of `mimickit/` or of `studio/` is in an import circle, directly or through other files.
(b) `mimickit/` (the library) imports neither `studio/` nor the web stack.
(c) Inside `mimickit/` and inside `studio/`, every import goes down or sideways in the package's layers
    (`MIMICKIT_LAYERS`, `STUDIO_LAYERS`), never up.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest

from mimickit.util.paths import PROJECT_ROOT

PACKAGES = ("mimickit", "studio")
WEB_PACKAGES = ("studio", "fastapi", "starlette", "uvicorn", "viser", "mjviser")
"""Top-level packages the library must not import: the studio and what serves or draws it."""

MIMICKIT_LAYERS: tuple[tuple[str, ...], ...] = (
    ("mimickit/__init__.py", "mimickit/util/"),  # the version, and helpers that know no domain
    ("mimickit/anim/",),  # characters and motion clips
    ("mimickit/engines/",),  # physics
    ("mimickit/envs/",),  # tasks on an engine
    ("mimickit/learning/",),  # agents, models, the training loop
    ("mimickit/runner/",),  # what a run reads and records: arguments, inputs, policy loading, torchrun
    ("mimickit/run.py", "mimickit/tools/"),  # the train/test entry (MimicKit's run.py) and the other commands
    ("mimickit/cli.py",),  # the `mimickit` command
)
"""Bottom to top: a file may import files of its own layer or of layers below it. A file's layer is that of
the longest entry that names it or a folder above it."""

STUDIO_LAYERS: tuple[tuple[str, ...], ...] = (
    # Helpers that know no studio service: settings, path confinement, disk checks, guarded parsing, children.
    (
        "studio/__init__.py",
        "studio/settings.py",
        "studio/security.py",
        "studio/disk.py",
        "studio/parsing.py",
        "studio/child.py",
        "studio/die_with_parent.py",
    ),  # fmt: skip
    ("studio/runs/",),  # runs: the manager, registry, executors, metrics, checkpoints
    ("studio/scene/", "studio/live_state.py"),  # the 3D scene and its players; what the stream pushes
    ("studio/library.py",),  # the files on disk (a character's default pose is drawn by the scene's code)
    ("studio/jobs/",),  # evals and videos: children like runs, on one queue
    ("studio/services.py",),  # `Studio`: every service
    ("studio/api/",),  # the HTTP routes
    ("studio/app.py",),  # the FastAPI app
    ("studio/cli.py",),  # the `mimickit-studio` command
)
LAYERS = {"mimickit": MIMICKIT_LAYERS, "studio": STUDIO_LAYERS}


@cache
def module_files(package: str) -> dict[str, Path]:
    """Every module of `package` by its dotted name (a package by its own name, for its `__init__.py`)."""
    found = {}
    for path in sorted((PROJECT_ROOT / package).rglob("*.py")):
        parts = path.relative_to(PROJECT_ROOT).with_suffix("").parts
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imported_names(path: Path, module: str) -> Iterator[tuple[str, int]]:
    """(dotted name, line) for everything `path` imports, anywhere in the file: for `from a import b` both
    `a` and `a.b` (b may be a module or a name in a), relative imports made absolute."""
    is_package = path.name == "__init__.py"
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                here = module.split(".") if is_package else module.split(".")[:-1]
                here = here[: len(here) - (node.level - 1)]
                base = ".".join([*here, *([node.module] if node.module else [])])
            yield base, node.lineno
            for alias in node.names:
                yield f"{base}.{alias.name}", node.lineno


@cache
def package_imports(package: str) -> dict[str, list[tuple[str, int]]]:
    """module → what it imports (`imported_names`), each file read once."""
    return {module: list(imported_names(path, module)) for module, path in module_files(package).items()}


@cache
def import_graph(package: str) -> dict[str, dict[str, int]]:
    """module → {module of the same package it imports: the first line that does}."""
    graph: dict[str, dict[str, int]] = {}
    for module, names in package_imports(package).items():
        edges = graph.setdefault(module, {})
        for name, line in names:
            if name in module_files(package) and name != module:
                edges.setdefault(name, line)
    return graph


def circles(graph: dict[str, dict[str, int]]) -> list[list[str]]:
    """The strongly connected groups of more than one module (Tarjan), each sorted: every module of a group
    reaches every other through imports."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def describe(group: list[str], graph: dict[str, dict[str, int]]) -> str:
    ties = [f"{a} -> {b} (line {graph[a][b]})" for a in group for b in group if b in graph[a]]
    return "circle of " + ", ".join(group) + ": " + "; ".join(ties)


def layer_of(path: Path) -> int:
    rel = path.relative_to(PROJECT_ROOT).as_posix()
    best, level = "", -1
    for i, entries in enumerate(LAYERS[rel.split("/")[0]]):
        for entry in entries:
            names_it = rel == entry or (entry.endswith("/") and rel.startswith(entry))
            if names_it and len(entry) > len(best):
                best, level = entry, i
    return level


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_circles(package: str) -> None:
    graph = import_graph(package)
    assert [describe(g, graph) for g in circles(graph)] == []


def test_circles_are_found() -> None:
    """The search itself: a loop through three modules, a self-contained pair, and a tree with none."""
    graph = {"a": {"b": 1}, "b": {"c": 1}, "c": {"a": 1}, "d": {"e": 1}, "e": {"d": 1}, "f": {"a": 1}, "g": {}}
    assert sorted(circles(graph)) == [["a", "b", "c"], ["d", "e"]]
    assert circles({"a": {"b": 1}, "b": {"c": 1}, "c": {}}) == []


def test_every_kind_of_import_is_read(tmp_path: Path) -> None:
    """Imports under TYPE_CHECKING, inside functions and relative ones are all edges."""
    path = tmp_path / "mod.py"
    path.write_text(
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n    from pkg.a import A\n"
        "def f():\n    import pkg.b\n    from . import c\n    from ..d import D\n"
    )
    names = {name for name, _ in imported_names(path, "pkg.sub.mod")}
    assert {"pkg.a", "pkg.b", "pkg.sub.c", "pkg.d", "pkg.d.D"} <= names


def test_mimickit_imports_no_studio_or_web_stack() -> None:
    files = module_files("mimickit")
    bad = [
        f"{files[module].relative_to(PROJECT_ROOT)}:{line} imports {name}"
        for module, names in package_imports("mimickit").items()
        for name, line in names
        if name.split(".")[0] in WEB_PACKAGES
    ]
    assert bad == []


@pytest.mark.parametrize("package", PACKAGES)
def test_every_file_has_a_layer(package: str) -> None:
    unplaced = [str(p.relative_to(PROJECT_ROOT)) for p in module_files(package).values() if layer_of(p) < 0]
    assert unplaced == [], f"add them to {package.upper()}_LAYERS"


@pytest.mark.parametrize("package", PACKAGES)
def test_imports_go_down_the_layers(package: str) -> None:
    files = module_files(package)
    upward = [
        f"{files[a].relative_to(PROJECT_ROOT)}:{line} imports {b}, of a higher layer ({layer_of(files[b])})"
        for a, edges in import_graph(package).items()
        for b, line in edges.items()
        if layer_of(files[b]) > layer_of(files[a])
    ]
    assert upward == []
