"""The arguments `mimickit train|test` (and `python mimickit/run.py`) know, and their checks.

`RUN_ARGS` is the one table of argument names and what each does. `check_run_args` runs before
anything starts (no env, no process, no file written): an unknown key is one error naming it, where it
was given (the command line or the arg file) and the nearest known name; a value of the wrong kind or
out of range is one error naming the key and the value. `visualize` and `video` are accepted (the
reference's arg files carry them) and ignored by training: the studio and `mimickit video` show runs.
"""

from __future__ import annotations

import math
import os
import re
import tempfile
from pathlib import Path

from mimickit.util.arg_parser import COMMAND_LINE, FALSE_VALUES, TRUE_VALUES, ArgParser
from mimickit.util.config import nearest_name
from mimickit.util.errors import MimicKitError, shorten

RUN_ARGS: dict[str, str] = {
    "arg_file": "a file of --key value lines, or .json: an object of them or a run's args.json (the command line wins)",
    "mode": "train or test",
    "num_envs": "envs per process (an integer >= 1)",
    "engine_config": "engine yaml (physics backend and rates)",
    "env_config": "env yaml (character, clip or dataset, rewards)",
    "agent_config": "agent yaml (PPO, AWR, AMP, ADD, ASE)",
    "out_dir": "run folder for log.txt, metrics.jsonl, model.pt (train mode)",
    "model_file": "checkpoint to start from (train) or to evaluate (test)",
    "max_samples": "stop training after this many env steps (an integer >= 1)",
    "max_hours": "stop training once the run's recorded wall time, resumes included, reaches this many hours (> 0)",
    "test_episodes": "episodes to evaluate in test mode (an integer >= 1)",
    "logger": "txt, tb (TensorBoard) or wandb",
    "rand_seed": "random seed (an integer >= 0; -1 or absent: draw one and record it)",
    "devices": "one device per process: cpu, cuda or cuda:N",
    "master_port": "TCP port of the multi-process rendezvous (0: pick a free one)",
    "save_int_models": "also keep int_models/model_{iteration}.pt (true/false)",
    "visualize": "accepted for the reference's arg files; training does not draw (true/false)",
    "video": "accepted for the reference's arg files; see `mimickit video` (true/false)",
    "data_dir": "a MimicKit data folder, searched first for data/... paths",
    "json": "test mode: print the result as one JSON object (true/false)",
    "motion_file": "a .pkl clip or a dataset .yaml that replaces the env config's motion_file",
}

MODES = ("train", "test")
LOGGERS = ("txt", "tb", "wandb")
MAX_NUM_ENVS = 65_536
MAX_SEED = 2**62
_BOOL_ARGS = ("save_int_models", "visualize", "video", "json")
MULTI_VALUE_ARGS = ("devices",)
"""Arguments that take several values (`--devices cpu cpu`)."""
_DEVICE_RE = re.compile(r"^(cpu|cuda)(:(\d+))?$")


def check_run_args(args: ArgParser, probe_out_dir: bool = True) -> None:
    """Raise one `MimicKitError` for the first unknown key or bad value of a run's arguments
    (`probe_out_dir` False: --out_dir is not probed, as for a torchrun rank other than 0)."""
    for key in args.all_keys():
        if key not in RUN_ARGS:
            near = nearest_name(key, RUN_ARGS)
            hint = f" (did you mean --{near}?)" if near else f" (known: {', '.join(RUN_ARGS)})"
            raise MimicKitError(f"unknown argument --{shorten(key, 80)}{_where(args, key)}{hint}")
        n = len(args.parse_strings(key))
        if n > 1 and key not in MULTI_VALUE_ARGS:
            raise MimicKitError(f"--{key}{_where(args, key)} takes one value, got {n}")
    mode = args.parse_string("mode", "train")
    _check_choice(args, "mode", MODES)
    _check_choice(args, "logger", LOGGERS)
    _check_int(args, "num_envs", 1, MAX_NUM_ENVS)
    _check_int(args, "max_samples", 1)
    _check_positive(args, "max_hours")
    _check_int(args, "test_episodes", 1)
    _check_int(args, "rand_seed", -1, MAX_SEED)
    _check_int(args, "master_port", 0, 65_535)
    for key in _BOOL_ARGS:
        _check_bool(args, key)
    _check_devices(args)
    _check_existing(args, "data_dir", is_dir=True)
    _check_existing(args, "model_file", is_dir=False)
    _check_model_file(args)
    if mode == "train" and probe_out_dir:
        check_writable_dir(Path(args.parse_string("out_dir", "output/")), f"--out_dir{_where(args, 'out_dir')}")


def check_writable_dir(folder: Path, what: str) -> None:
    """Make sure files can be written in `folder` (created if missing): a probe file is written,
    synced and removed, and folders made for the probe are removed again. One line if not."""
    missing: list[Path] = []
    p = folder.absolute()
    while not p.exists() and p != p.parent:
        missing.append(p)
        p = p.parent
    if p.exists() and not p.is_dir():
        raise MimicKitError(f"{what} {folder}: {p} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write_probe.", dir=folder)
        try:
            os.write(fd, b"\0" * 4096)
            os.fsync(fd)
        finally:
            os.close(fd)
            os.unlink(probe)
    except OSError as e:
        raise MimicKitError(f"{what} {folder}: cannot write there ({e.strerror or e})") from None
    finally:
        for d in missing:  # deepest first; the run creates them itself once it starts
            try:
                d.rmdir()
            except OSError:
                break


def _where(args: ArgParser, key: str) -> str:
    src = args.source(key)
    return "" if src in (COMMAND_LINE, "set") else f" in {src}"


def _check_choice(args: ArgParser, key: str, choices: tuple[str, ...]) -> None:
    if not args.has_key(key):
        return
    val = args.parse_string(key, "")
    if val not in choices:
        raise MimicKitError(f"--{key}{_where(args, key)} must be {' or '.join(choices)}, got {shorten(val, 80)!r}")


def _check_int(args: ArgParser, key: str, lo: int, hi: int | None = None) -> None:
    if not args.has_key(key):
        return
    if not args.parse_string(key, ""):
        raise MimicKitError(f"--{key}{_where(args, key)} needs a value ({RUN_ARGS[key]})")
    val = args.parse_int(key)
    if val < lo or (hi is not None and val > hi):
        bound = f"between {lo} and {hi}" if hi is not None else f">= {lo}"
        raise MimicKitError(f"--{key}{_where(args, key)} must be an integer {bound}, got {shorten(str(val), 80)}")


def _check_positive(args: ArgParser, key: str) -> None:
    if not args.has_key(key):
        return
    if not args.parse_string(key, ""):
        raise MimicKitError(f"--{key}{_where(args, key)} needs a value ({RUN_ARGS[key]})")
    val = args.parse_float(key)
    if not math.isfinite(val) or val <= 0:
        raise MimicKitError(f"--{key}{_where(args, key)} must be a number > 0, got {shorten(str(val), 80)}")


def _check_bool(args: ArgParser, key: str) -> None:
    val = args.parse_string(key, "")
    if val and val not in TRUE_VALUES and val not in FALSE_VALUES:
        raise MimicKitError(f"--{key}{_where(args, key)} must be true or false, got {shorten(val, 80)!r}")


def _check_devices(args: ArgParser) -> None:
    import torch

    for dev in args.parse_strings("devices"):
        m = _DEVICE_RE.match(dev)
        if m is None:
            raise MimicKitError(
                f"--devices{_where(args, 'devices')}: unknown device {shorten(dev, 80)!r} (cpu, cuda or cuda:N)"
            )
        if m.group(1) != "cuda":
            continue
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        index = int(m.group(3) or 0)
        if count == 0:
            raise MimicKitError(f"--devices {dev}: CUDA is not available here (torch sees no GPU); use cpu")
        if index >= count:
            raise MimicKitError(f"--devices {dev}: there are {count} CUDA device(s), cuda:0 to cuda:{count - 1}")


def _check_existing(args: ArgParser, key: str, is_dir: bool) -> None:
    val = args.parse_string(key, "")
    if not args.has_key(key) or not val:
        return
    p = Path(val).expanduser()
    ok = p.is_dir() if is_dir else p.is_file()
    if not ok:
        kind = "folder" if is_dir else "file"
        raise MimicKitError(f"--{key}{_where(args, key)}: {kind} not found: {shorten(val, 80)}")


def _check_model_file(args: ArgParser) -> None:
    """A checkpoint that is unreadable, holds code or non-tensors, or has NaN weights is refused here,
    before an env is built; whether it fits the agent is checked when the agent loads it."""
    from mimickit.learning import checkpoint

    model_file = args.parse_string("model_file", "")
    if model_file:
        checkpoint.check_finite(model_file, checkpoint.read_checkpoint(model_file))
