"""MimicKit's command-line parser: `--key v1 v2 ...` tokens, optional `--arg_file`.

The reference's rules, so its arg files read the same: a token starting with `--` (3+ chars) starts a key whose
values are the following tokens; `#` tokens are comments; keys given on the command line win over the
same keys in the arg file; booleans are true for `true, True, 1, T, t`.

The parser remembers where each key came from (`source`: the command line or the arg file's path),
so an error about a value can say where to fix it. An arg file must be UTF-8 text (a binary one is
one error line naming it). Which keys a run knows and what values they take: `mimickit.runner.args`.

An arg file ending in `.json` holds a JSON object instead: either the arguments themselves
(`{"num_envs": 8, "devices": ["cpu", "cpu"]}`: a string, number or boolean, or a list of them, per key),
or a training run's `args.json` (`mimickit.runner.record`, recognised by its `format` and `args` keys),
which gives the arguments the run was started with (`args`), made fit to test or repeat it:
- its configs are the run folder's copies as trained (`engine_config.yaml`, `env_config.yaml` with the
  run's `--motion_file` applied, `agent_config.yaml`), so `--motion_file` is not repeated, and
  `data_dir` is the folder the run resolved at its start;
- `mode`, `arg_file` (already merged into `args`), `out_dir` (a test writes no run folder, and a new
  training must not write into the recorded one unasked) and `model_file` (the checkpoint the run
  started from) are left out; with `--mode test` the run's own `model.pt` is the model_file, and
  test_episodes, unless recorded, is the count the run tested with (its agent config's, `effective`),
  where the reference's default would test without end;
- the rest stays as recorded (num_envs, max_samples, max_hours, devices, logger, rand_seed if it was
  given...); the record's other keys (argv, effective values, the seed drawn, versions, resume markers,
  earlier starts) are not arguments and are ignored.
As with text files, the command line wins over every key the file gives.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from mimickit.util.config import read_text_file
from mimickit.util.errors import MimicKitError, shorten
from mimickit.util.paths import PROJECT_DATA, DataPaths

_TRUE = {"true", "True", "1", "T", "t"}
FALSE_VALUES = frozenset({"false", "False", "0", "F", "f"})
TRUE_VALUES = frozenset(_TRUE)
COMMAND_LINE = "the command line"
MAX_ARG_FILE_BYTES = 1 << 20
RUN_RECORD_FORMAT = 1
"""The `format` of args.json this parser reads (`run_folder.ARGS_FORMAT`)."""
RUN_RECORD_CONFIGS = {
    "engine_config": "engine_config.yaml",
    "env_config": "env_config.yaml",
    "agent_config": "agent_config.yaml",
}
RUN_RECORD_MODEL = "model.pt"
"""The files beside a run's args.json, as `mimickit.learning.run_folder` names them (a layer above this
one, so spelt again here; tests/test_arg_files.py checks that the two agree)."""
RUN_RECORD_DROPPED = ("arg_file", "mode", "out_dir", "model_file")
"""Keys of a run's recorded arguments that a test or a new run does not take over (module doc)."""


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
        text = read_text_file(p, "arg file", MAX_ARG_FILE_BYTES)
        if p.suffix.lower() == ".json":
            parsed = json_arg_table(text, p, path, self.parse_string("mode", "train"), set(self._table))
        else:
            parsed = _text_arg_table(text, path)
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

    def _where(self, key: str) -> str:
        """ " in FILE" for a key an arg file gave (so a bad value says where to fix it); "" otherwise."""
        src = self.source(key)
        return "" if src in (COMMAND_LINE, "set") else f" in {src}"

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
            raise MimicKitError(f"--{key}{self._where(key)}: expected an integer, got {shorten(val, 80)!r}") from None

    def parse_float(self, key: str, default: float = 0.0) -> float:
        val = self.parse_string(key, "")
        if val == "":
            return default
        try:
            return float(val)
        except ValueError:
            raise MimicKitError(f"--{key}{self._where(key)}: expected a number, got {shorten(val, 80)!r}") from None

    def parse_bool(self, key: str, default: bool = False) -> bool:
        val = self.parse_string(key, "")
        if val == "":
            return default
        return val in _TRUE


def _text_arg_table(text: str, path: str) -> dict[str, list[str]]:
    tokens: list[str] = []
    for line in text.splitlines():
        if line.strip().startswith("#"):
            continue
        tokens += line.split()
    try:
        return _parse_tokens(tokens)
    except MimicKitError as e:
        raise MimicKitError(f"{path}: {e}") from None


def json_arg_table(text: str, p: Path, path: str, mode: str, given: set[str]) -> dict[str, list[str]]:
    """The arguments of a `.json` arg file (module doc): a plain object of them, or a run's args.json
    made fit for `mode`. `p` is the file, `path` how it was named (for messages), `given` the keys
    the command line gave already."""
    try:
        data = json.loads(text)
    except RecursionError:
        raise MimicKitError(f"{path}: JSON nested too deeply to be an arg file") from None
    except ValueError as e:  # a syntax error, or an integer past Python's digit limit
        raise MimicKitError(f"{path}: not valid JSON ({shorten(str(e), 120)})") from None
    if not isinstance(data, dict):
        raise MimicKitError(f"{path}: a JSON arg file holds an object of arguments, got {_json_kind(data)}")
    if "format" in data and "args" in data:
        return _run_record_table(data, p.parent, path, mode, given)
    return _json_values(data, path)


def _run_record_table(
    record: dict[str, Any], folder: Path, path: str, mode: str, given: set[str]
) -> dict[str, list[str]]:
    """A run's args.json (`record`, in run folder `folder`) as the arguments to test or repeat the run."""
    if record["format"] != RUN_RECORD_FORMAT:
        got = shorten(json.dumps(record["format"]), 40)
        raise MimicKitError(f"{path}: a run record of format {got}; this mimickit reads format {RUN_RECORD_FORMAT}")
    if not isinstance(record["args"], dict):
        raise MimicKitError(f"{path}: `args` must be an object of arguments, got {_json_kind(record['args'])}")
    table = {k: v for k, v in _json_values(record["args"], path).items() if k not in RUN_RECORD_DROPPED}
    for key, name in RUN_RECORD_CONFIGS.items():
        if (folder / name).is_file():  # the configs as trained; edits to the originals since do not apply
            table[key] = [str(folder / name)]
    if (folder / RUN_RECORD_CONFIGS["env_config"]).is_file():
        table.pop("motion_file", None)  # already in the copied env config, resolved when the run started
    effective = record.get("effective") if isinstance(record.get("effective"), dict) else {}
    data_dir = effective.get("data_dir")
    if isinstance(data_dir, str) and data_dir:  # as resolved at the start: the run's cwd may not be ours
        table["data_dir"] = [data_dir]
    if mode == "test" and "model_file" not in given:
        if not (folder / RUN_RECORD_MODEL).is_file():
            raise MimicKitError(f"{path}: the run folder has no {RUN_RECORD_MODEL} to test; give --model_file")
        table["model_file"] = [str(folder / RUN_RECORD_MODEL)]
    if mode == "test":
        episodes = effective.get("test_episodes")
        if "test_episodes" not in table and type(episodes) is int and episodes > 0:
            table["test_episodes"] = [str(episodes)]
    return table


def _json_values(obj: dict[str, Any], path: str) -> dict[str, list[str]]:
    """{key: value or [values]} as the parser's {key: [tokens]}; one line for a value of another type."""
    table: dict[str, list[str]] = {}
    for key, value in obj.items():
        values = value if isinstance(value, list) else [value]
        tokens = [_json_token(v) for v in values]
        if None in tokens:
            bad = next(v for v, t in zip(values, tokens, strict=True) if t is None)
            raise MimicKitError(
                f"{path}: --{shorten(key, 80)}: expected a string, number or boolean (or a list of them), "
                f"got {_json_kind(bad)}"
            )
        table[key] = [t for t in tokens if t is not None]
    return table


def _json_token(value: Any) -> str | None:
    """A JSON scalar as the token a text arg file would hold; None for anything else."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):  # 8.0 is the integer 8 (json has one number type); nan and inf stay words
        return str(int(value)) if math.isfinite(value) and value.is_integer() else repr(value)
    return value if isinstance(value, str) else None


def _json_kind(value: Any) -> str:
    kinds = {dict: "an object", list: "a list", str: "a string", bool: "a boolean", type(None): "null"}
    return kinds.get(type(value), "a number")


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
