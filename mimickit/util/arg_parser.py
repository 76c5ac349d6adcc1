"""MimicKit's command-line parser: `--key v1 v2 ...` tokens, optional `--arg_file`.

Semantics of the reference (spec §1.2): a token starting with `--` (3+ chars) starts a key whose
values are the following tokens; `#` tokens are comments; keys given on the command line win over the
same keys in the arg file; booleans are true for `true, True, 1, T, t`.
"""

from __future__ import annotations

from pathlib import Path

from mimickit.util.errors import MimicKitError

_TRUE = {"true", "True", "1", "T", "t"}


class ArgParser:
    def __init__(self) -> None:
        self._table: dict[str, list[str]] = {}

    def load_args(self, argv: list[str]) -> None:
        self._table.update({k: v for k, v in _parse_tokens(argv).items() if k not in self._table})
        arg_file = self.parse_string("arg_file", "")
        if arg_file:
            self.load_file(arg_file)

    def load_file(self, path: str) -> None:
        p = Path(path)
        if not p.is_file():
            raise MimicKitError(f"arg file not found: {path}")
        tokens: list[str] = []
        for line in p.read_text().splitlines():
            if line.strip().startswith("#"):
                continue
            tokens += line.split()
        for key, vals in _parse_tokens(tokens).items():
            self._table.setdefault(key, vals)

    def has_key(self, key: str) -> bool:
        return key in self._table

    def all_keys(self) -> list[str]:
        return list(self._table)

    def set(self, key: str, *values: str) -> None:
        self._table[key] = list(values)

    def parse_string(self, key: str, default: str = "") -> str:
        vals = self._table.get(key)
        if not vals:
            return default
        return vals[0]

    def parse_strings(self, key: str, default: list[str] | None = None) -> list[str]:
        return list(self._table.get(key, default or []))

    def parse_int(self, key: str, default: int = 0) -> int:
        val = self.parse_string(key, "")
        if val == "":
            return default
        try:
            return int(float(val)) if "e" in val.lower() else int(val)
        except ValueError:
            raise MimicKitError(f"--{key}: expected an integer, got {val!r}") from None

    def parse_float(self, key: str, default: float = 0.0) -> float:
        val = self.parse_string(key, "")
        if val == "":
            return default
        try:
            return float(val)
        except ValueError:
            raise MimicKitError(f"--{key}: expected a number, got {val!r}") from None

    def parse_bool(self, key: str, default: bool = False) -> bool:
        val = self.parse_string(key, "")
        if val == "":
            return default
        return val in _TRUE


def _parse_tokens(tokens: list[str]) -> dict[str, list[str]]:
    table: dict[str, list[str]] = {}
    key = None
    for tok in tokens:
        if tok.startswith("#"):
            continue
        if tok.startswith("--") and len(tok) >= 3 and not _is_number(tok):
            key = tok[2:]
            table.setdefault(key, [])
        elif key is None:
            raise MimicKitError(f"argument {tok!r} comes before any --key")
        else:
            table[key].append(tok)
    return table


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True
