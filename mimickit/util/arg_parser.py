"""MimicKit's command-line parser: `--key v1 v2 ...` tokens, optional `--arg_file`.

The reference's rules, so its arg files read the same: a token starting with `--` (3+ chars) starts a key whose
values are the following tokens; `#` tokens are comments; keys given on the command line win over the
same keys in the arg file; booleans are true for `true, True, 1, T, t`.

The parser remembers where each key came from (`source`: the command line or the arg file's path),
so an error about a value can say where to fix it. An arg file must be UTF-8 text (a binary one is
one error line naming it). Which keys a run knows and what values they take: `mimickit.runner.args`.
"""

from __future__ import annotations

from mimickit.util.config import read_text_file
from mimickit.util.errors import MimicKitError, shorten
from mimickit.util.paths import PROJECT_DATA, DataPaths

_TRUE = {"true", "True", "1", "T", "t"}
FALSE_VALUES = frozenset({"false", "False", "0", "F", "f"})
TRUE_VALUES = frozenset(_TRUE)
COMMAND_LINE = "the command line"
MAX_ARG_FILE_BYTES = 1 << 20


class ArgParser:
    def __init__(self, data_paths: DataPaths = PROJECT_DATA) -> None:
        self._data_paths = data_paths  # where an arg file named `args/...` or `data/...` is found
        self._table: dict[str, list[str]] = {}
        self._sources: dict[str, str] = {}

    def load_args(self, argv: list[str]) -> None:
        for key, vals in _parse_tokens(argv).items():
            if key not in self._table:
                self._table[key] = vals
                self._sources[key] = COMMAND_LINE
        arg_file = self.parse_string("arg_file", "")
        if arg_file:
            self.load_file(arg_file)

    def load_file(self, path: str) -> None:
        p = self._data_paths.resolve(path)  # `args/x.txt` also names the project's own, from any folder
        if not p.is_file():
            raise MimicKitError(f"arg file not found: {path}")
        tokens: list[str] = []
        for line in read_text_file(p, "arg file", MAX_ARG_FILE_BYTES).splitlines():
            if line.strip().startswith("#"):
                continue
            tokens += line.split()
        try:
            parsed = _parse_tokens(tokens)
        except MimicKitError as e:
            raise MimicKitError(f"{path}: {e}") from None
        if "arg_file" in parsed:  # the reference would ignore it silently; one arg file per run
            raise MimicKitError(f"{path}: an arg file cannot name another --arg_file")
        for key, vals in parsed.items():
            if key not in self._table:
                self._table[key] = vals
                self._sources[key] = str(path)

    def has_key(self, key: str) -> bool:
        return key in self._table

    def all_keys(self) -> list[str]:
        return list(self._table)

    def source(self, key: str) -> str:
        """Where `key` was given: `COMMAND_LINE`, an arg file's path, or "set" (by `set`)."""
        return self._sources.get(key, "set")

    def set(self, key: str, *values: str) -> None:
        self._table[key] = list(values)
        self._sources[key] = "set"

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
            if "e" not in val.lower():
                return int(val)
            f = float(val)  # 1e6 is an integer written in scientific notation; 1.5e0 is not
            if not f.is_integer():
                raise ValueError(val)
            return int(f)
        except (ValueError, OverflowError):
            raise MimicKitError(f"--{key}: expected an integer, got {shorten(val, 80)!r}") from None

    def parse_float(self, key: str, default: float = 0.0) -> float:
        val = self.parse_string(key, "")
        if val == "":
            return default
        try:
            return float(val)
        except ValueError:
            raise MimicKitError(f"--{key}: expected a number, got {shorten(val, 80)!r}") from None

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
            raise MimicKitError(f"argument {shorten(tok, 80)!r} comes before any --key")
        else:
            table[key].append(tok)
    return table


def _is_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True
