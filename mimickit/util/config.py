"""YAML configs loaded into typed, validated pydantic models.

A wrong key, a wrong type or a missing required field is one `MimicKitError` that names the file and
the key (an unknown key also names the nearest known one). Numbers written as `1e-4` (a string to
PyYAML) are coerced to numbers by pydantic's lax mode; NaN and infinity are refused unless a field
allows them.

A yaml file may come from anywhere, so it is read as hostile input: at most `MAX_YAML_BYTES`, UTF-8
text only, no duplicate keys, and aliases may not expand the document past `MAX_YAML_NODES` nodes
(a 1 KB "billion laughs" file expands to 10^9), checked on the parsed node graph before anything is
built from it. An error echoes at most `MAX_ECHO_CHARS` characters of the offending input.
"""

from __future__ import annotations

import difflib
import reprlib
import typing
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from mimickit.util.errors import MimicKitError

T = TypeVar("T", bound="ConfigModel")

MAX_YAML_BYTES = 8 << 20
"""Largest yaml file read (the biggest shipped config is a few KB)."""
MAX_YAML_NODES = 200_000
"""Most nodes a document may hold once its aliases are expanded (each use of an alias counts its
anchor's whole subtree)."""
MAX_ECHO_CHARS = 200
"""Most characters of user input an error message repeats."""
_MAX_ERRORS = 5  # problems listed in one validation message

_SafeLoader: type[yaml.SafeLoader] = getattr(yaml, "CSafeLoader", yaml.SafeLoader)  # type: ignore[assignment]


class ConfigModel(BaseModel):
    """Base of every config: unknown keys are errors, fields are validated on assignment too, and a
    float field takes no NaN/inf unless it says so (`Field(allow_inf_nan=True)`)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, protected_namespaces=(), allow_inf_nan=False)


class _BoundedLoader(_SafeLoader):  # type: ignore[misc, valid-type]
    """PyYAML's safe loader that refuses alias bombs, recursive aliases and duplicate keys."""

    def construct_document(self, node: yaml.Node) -> Any:
        _check_expanded_size(node)
        return super().construct_document(node)

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: set[Any] = set()
        for key_node, _ in node.value:
            if isinstance(key_node, yaml.ScalarNode):
                key = key_node.value
                if key in seen:
                    line = key_node.start_mark.line + 1
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {_echo(key)} (line {line})", key_node.start_mark
                    )
                seen.add(key)
        return super().construct_mapping(node, deep=deep)


def load_yaml_text(text: str, source: str | Path = "<yaml text>") -> Any:
    """Parse one yaml document from `text` with the bounded loader; any problem is one
    `MimicKitError` naming `source`."""
    try:
        return yaml.load(text, Loader=_BoundedLoader)  # noqa: S506 - a SafeLoader subclass
    except _YamlTooBig as e:
        raise MimicKitError(f"{source}: {e}") from None
    except yaml.YAMLError as e:
        raise MimicKitError(f"{source}: not valid YAML ({e.__class__.__name__}: {_yaml_problem(e)})") from None
    except (ValueError, OverflowError, RecursionError, TypeError) as e:  # e.g. an int of 10^5 digits
        raise MimicKitError(f"{source}: not valid YAML ({e.__class__.__name__}: {_echo_line(str(e))})") from None


def read_text_file(path: str | Path, what: str = "file", max_bytes: int = MAX_YAML_BYTES) -> str:
    """The UTF-8 text of a small regular file; a missing, huge, binary or non-UTF-8 file is one line."""
    p = Path(path)
    if not p.is_file():
        if p.exists():  # a folder, a FIFO, /dev/zero: reading would fail or never end
            raise MimicKitError(f"{p}: not a regular file, so not a {what}")
        raise MimicKitError(f"{what} not found: {p}")
    try:
        size = p.stat().st_size
        if size > max_bytes:
            raise MimicKitError(f"{p}: {size} bytes, over the {max_bytes}-byte limit for a {what}")
        data = p.read_bytes()
    except OSError as e:
        raise MimicKitError(f"{p}: cannot read it ({e.strerror or e})") from None
    if b"\x00" in data:
        raise MimicKitError(f"{p}: a binary file, not a text {what}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise MimicKitError(f"{p}: not UTF-8 text (byte 0x{data[e.start]:02x} at offset {e.start})") from None


def load_yaml(path: str | Path) -> dict[str, Any]:
    """A yaml file's top-level mapping (`{}` for an empty file)."""
    p = Path(path)
    data = load_yaml_text(read_text_file(p, "config file"), p)
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise MimicKitError(f"{p}: expected a mapping of keys at the top level, got {type(data).__name__}")
    return data


def parse_config(model: type[T], data: dict[str, Any], source: str | Path) -> T:
    """Validate `data` against `model`; errors name `source` and the offending key."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise MimicKitError(f"{source}: {format_validation_error(e, model)}") from None


def load_config(model: type[T], path: str | Path) -> T:
    return parse_config(model, load_yaml(path), path)


def format_validation_error(e: ValidationError, model: type[BaseModel] | None = None) -> str:
    """One line for all of `e`'s errors; echoed input is cut to `MAX_ECHO_CHARS`, and an unknown key
    names the nearest field of `model` when given."""
    parts = []
    errors = e.errors()
    for err in errors[:_MAX_ERRORS]:
        loc = tuple(err["loc"])
        key = _echo_line(".".join(str(x) for x in loc) or "(top level)")
        if err["type"] == "extra_forbidden":
            hint = _nearest_field(model, loc) if model is not None else ""
            parts.append(f"unknown key '{key}'{hint}")
        elif err["type"] == "missing":
            parts.append(f"missing required key '{key}'")
        else:
            parts.append(f"key '{key}': {_echo_line(err['msg'])} (got {_echo(err.get('input'))})")
    if len(errors) > _MAX_ERRORS:
        parts.append(f"and {len(errors) - _MAX_ERRORS} more problems")
    return "; ".join(parts)


def unknown_key(key: object, known: typing.Iterable[str], where: str = "") -> str:
    """`unknown key 'k'{where} (did you mean 'n'?)`, the key cut to `MAX_ECHO_CHARS` and the hint
    the nearest of `known`, when one is close."""
    near = nearest_name(key, known) if isinstance(key, str) else None
    return f"unknown key {_echo(key)}{where}" + (f" (did you mean '{near}'?)" if near else "")


def nearest_name(name: str, known: typing.Iterable[str]) -> str | None:
    """The known name closest to `name` (difflib), or None when nothing is close."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return close[0] if close else None


# ---------------------------------------------------------------- helpers


class _YamlTooBig(yaml.YAMLError):
    pass


def _check_expanded_size(root: yaml.Node) -> None:
    """Count the document's nodes as if every alias were copied out, without building anything: a
    node's expanded size is computed once (aliases share the node object) by an iterative post-order
    walk; a node met again on the current path is a recursive alias."""
    sizes: dict[int, int] = {}
    on_path: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        nid = id(node)
        if children_done:
            on_path.discard(nid)
            total = 1 + sum(sizes[id(c)] for c in _children(node))
            if total > MAX_YAML_NODES:
                raise _YamlTooBig(
                    f"its aliases expand to more than {MAX_YAML_NODES} nodes (an alias bomb?); write the values out"
                )
            sizes[nid] = total
            continue
        if nid in sizes:
            continue
        if nid in on_path:
            raise _YamlTooBig("an alias refers to a node that contains it (a recursive alias)")
        on_path.add(nid)
        stack.append((node, True))
        stack.extend((c, False) for c in _children(node) if id(c) not in sizes)


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def _nearest_field(model: type[BaseModel], loc: tuple[Any, ...]) -> str:
    """' (did you mean 'x'?)' for the unknown key at `loc`, looked up in the (nested) model."""
    current: Any = model
    for part in loc[:-1]:
        if isinstance(part, int):  # an item of a list: `current` is already the item's model
            continue
        field = getattr(current, "model_fields", {}).get(part) if isinstance(part, str) else None
        if field is None:
            return ""
        current = _model_of(field.annotation)
        if current is None:
            return ""
    fields = getattr(current, "model_fields", None)
    if not fields or not isinstance(loc[-1], str):
        return ""
    near = nearest_name(loc[-1], fields)
    return f" (did you mean '{near}'?)" if near else ""


def _model_of(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):  # Optional[Model], Model | None
        if isinstance(arg, type) and issubclass(arg, BaseModel):
            return arg
    return None


_repr = reprlib.Repr()
_repr.maxlevel, _repr.maxlist, _repr.maxdict, _repr.maxstring, _repr.maxother = 3, 8, 8, 80, 80
_repr.maxlong = 40


def _echo(value: Any) -> str:
    """A bounded repr: reprlib stops after a few items per level, so a huge value costs nothing."""
    return _echo_line(_repr.repr(value))


def _echo_line(text: str) -> str:
    text = " ".join(text.split())
    return text if len(text) <= MAX_ECHO_CHARS else text[:MAX_ECHO_CHARS] + f"... ({len(text)} characters)"


def _yaml_problem(e: yaml.YAMLError) -> str:
    """The problem and its line/column, without the echoed source line PyYAML appends."""
    problem = getattr(e, "problem", None)
    mark = getattr(e, "problem_mark", None)
    if problem:
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        return _echo_line(f"{problem}{where}")
    text = str(e).strip()
    return _echo_line(text.splitlines()[0] if text else "")
