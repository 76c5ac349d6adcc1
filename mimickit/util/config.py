"""YAML configs loaded into typed, validated pydantic models.

A wrong key, a wrong type or a missing required field is one `MimicKitError` that names the file and
the key. Numbers written as `1e-4` (a string to PyYAML) are coerced to numbers by pydantic's lax mode.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from mimickit.util.errors import MimicKitError

T = TypeVar("T", bound="ConfigModel")


class ConfigModel(BaseModel):
    """Base of every config: unknown keys are errors, fields are validated on assignment too."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, protected_namespaces=())


def load_yaml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise MimicKitError(f"config file not found: {p}")
    try:
        data = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise MimicKitError(f"{p}: not valid YAML ({e.__class__.__name__}: {_first_line(e)})") from None
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
        raise MimicKitError(f"{source}: {format_validation_error(e)}") from None


def load_config(model: type[T], path: str | Path) -> T:
    return parse_config(model, load_yaml(path), path)


def format_validation_error(e: ValidationError) -> str:
    parts = []
    for err in e.errors():
        key = ".".join(str(x) for x in err["loc"]) or "(top level)"
        if err["type"] == "extra_forbidden":
            parts.append(f"unknown key '{key}'")
        elif err["type"] == "missing":
            parts.append(f"missing required key '{key}'")
        else:
            parts.append(f"key '{key}': {err['msg']} (got {err.get('input')!r})")
    return "; ".join(parts)


def _first_line(e: Exception) -> str:
    return str(e).strip().splitlines()[0] if str(e).strip() else ""
