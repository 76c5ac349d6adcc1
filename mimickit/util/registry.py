"""One table per role (agent, env, engine): a yaml's name → its config class and the class it builds.

The config loaders look a name up here (an unknown one is one error line that lists the known names and
the nearest), and the builders get the class from the same entry. The class is named by its import path
and imported only when asked for, so building a DeepMimic env imports neither the other envs nor the
agents, and the optional Newton engine is imported only when a config names it.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Generic, TypeVar

from mimickit.util.config import nearest_name
from mimickit.util.errors import MimicKitError

C = TypeVar("C")
K = TypeVar("K")


@dataclass(frozen=True)
class Entry(Generic[C]):
    """What one name stands for."""

    config: type[C]
    """The pydantic class its yaml is validated against."""
    cls: str
    """Import path of the class it builds, "package.module:ClassName"."""
    missing: str = ""
    """What to tell the user when the class's module cannot be imported (an optional extra), or ""."""


class Registry(Generic[C, K]):
    """Names of one role, in the order given (the order error messages list them in)."""

    def __init__(
        self, role: str, base: str, entries: Mapping[str, Entry[C]], not_ported: Mapping[str, str] | None = None
    ) -> None:
        self.role = role
        self._base = base
        """Import path of the class every registered class derives from (checked when one is imported)."""
        self._entries = dict(entries)
        self._not_ported = dict(not_ported or {})
        """Names of the reference that this port does not have, each with why (said in the error)."""

    def __contains__(self, name: object) -> bool:
        return isinstance(name, str) and name in self._entries

    def __iter__(self) -> Iterator[str]:
        return iter(self._entries)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self._entries)

    def config_class(self, name: str) -> type[C]:
        """The config class registered for `name` (a KeyError for an unknown name: check `in` first)."""
        return self._entries[name].config

    def unknown(self, name: object) -> str:
        """The error text for a name that is not registered: why, the known names and the nearest."""
        why = self._not_ported.get(name, "") if isinstance(name, str) else ""
        near = nearest_name(name, self._entries) if isinstance(name, str) else None
        return (
            f"{self.role} {name!r} is not supported{f' ({why})' if why else ''}; "
            f"supported {self.role}s: {', '.join(self._entries)}" + (f" (did you mean {near!r}?)" if near else "")
        )

    def resolve(self, name: str, source: str = "") -> type[K]:
        """The class registered for `name`, imported now. A module that cannot be imported because an
        optional extra is missing is one `MimicKitError` (naming `source`) that says how to install it."""
        entry = self._entries[name]
        try:
            cls = _import(entry.cls)
        except ImportError as exc:
            if not entry.missing:
                raise
            where = f"{source}: " if source else ""
            raise MimicKitError(f"{where}{entry.missing}; import failed: {exc}") from exc
        base = _import(self._base)
        if not (isinstance(cls, type) and issubclass(cls, base)):  # a wrong table entry, not user input
            raise TypeError(f"{self.role} {name!r}: {entry.cls} is not a {self._base}")
        return cls


def _import(path: str) -> type:
    module_name, _, attr = path.partition(":")
    return getattr(importlib.import_module(module_name), attr)
