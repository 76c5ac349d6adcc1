"""What the registry tests (agents, envs, engines) derive from a registry instead of pinning names by hand,
so a new entry is checked without editing a test: the shipped yamls that use each name, the docs that
mention it, and the module each class lives in."""

from __future__ import annotations

import contextlib
from collections.abc import Iterable
from pathlib import Path

from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from mimickit.util.registry import Registry

DOC_PAGES = [PROJECT_ROOT / "README.md", *sorted((PROJECT_ROOT / "docs").glob("*.md"))]


def shipped_yamls(folder: str, key: str) -> dict[str, Path]:
    """The first yaml in data/<folder>/ of each value of its `key` (e.g. "envs", "env_name")."""
    found: dict[str, Path] = {}
    for path in sorted((PROJECT_DATA_DIR / folder).glob("*.yaml")):
        found.setdefault(load_yaml(path)[key], path)
    return found


def undocumented(names: Iterable[str]) -> list[str]:
    """The names that no page of the README or docs/ writes as code (`name`)."""
    text = "\n".join(p.read_text() for p in DOC_PAGES)
    return [name for name in names if f"`{name}`" not in text]


def class_modules(registry: Registry) -> dict[str, str]:
    """The module of each registered class that imports here (an optional extra that is not installed
    is left out: nothing can import it then)."""
    modules: dict[str, str] = {}
    for name in registry.names:
        with contextlib.suppress(MimicKitError):
            modules[name] = registry.resolve(name).__module__
    return modules


def supported_list(registry: Registry) -> str:
    """How an unknown-name error lists the registered names."""
    return f"supported {registry.role}s: {', '.join(registry.names)}"
