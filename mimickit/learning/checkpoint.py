"""Checkpoint files (`model.pt`): read untrusted ones safely, check that they fit, write them atomically.

A checkpoint is the agent's `state_dict()` (reference key names: `_obs_norm.*`, `_a_norm.*`,
`_model.*`; every value a tensor), plus one extra key `_train_state` holding what a resumed run needs
(next iteration, global sample count, wall time, last test result, optimiser states). A reference
checkpoint has no `_train_state` and loads as a fresh start.

A checkpoint may come from anywhere, so it is treated as hostile: it is read only with
`torch.load(weights_only=True)` (no code runs, no arbitrary objects are built), its archive may not
expand past `MAX_CHECKPOINT_BYTES`, and every value is type-checked before the agent sees it. Each
mistake is one `MimicKitError` line naming the file and the key.

Writes go through `atomic_write_bytes` (a reader sees the old file or the new one, never half), a
full disk or a read-only folder is one line, and the `.model.pt.XXXXXXXX` temp files a killed writer
leaves behind are removed the next time a run starts or saves in that folder.
"""

from __future__ import annotations

import io
import math
import os
import pickle
import re
import warnings
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import torch

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import atomic_write_bytes

TRAIN_STATE_KEY = "_train_state"
TRAIN_STATE_FORMAT = 1
MAX_CHECKPOINT_BYTES = int(os.environ.get("MIMICKIT_MAX_CHECKPOINT_BYTES", 2 << 30))
"""Largest checkpoint (file, or expanded archive) read; a policy of this project is a few MB."""

# atomic_write_bytes names its temp file `.{name}.` + mkstemp's 8 random characters.
_TEMP_RE = re.compile(r"^\.(?P<name>.+\.pt)\.[a-z0-9_]{8}$")
_MSG_CHARS = 200

# torch warns (several lines) about a file's pickle protocol before it refuses or reads it; our one-line error
# or the checks below say what matters. Filtered once, here: `warnings.catch_warnings` around each load would
# swap the process-wide filters under the studio's request threads.
warnings.filterwarnings("ignore", message=r"Detected pickle protocol", category=UserWarning)


# ---------------------------------------------------------------- reading


def read_checkpoint(path: str | Path, map_location: torch.device | str = "cpu") -> dict[str, Any]:
    """The checkpoint's state dict, every model value a tensor and `_train_state` (if present)
    type-checked by `check_train_state`; one `MimicKitError` for anything else."""
    path = Path(path)
    if not path.is_file():
        raise MimicKitError(f"model file not found: {path}")
    _check_size(path)
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        detail = _weights_only_detail(e)
        if "global" in detail.lower():  # a class or function reference: code a full unpickler would run
            msg = f"{path}: refused: it refers to code, not only tensors and plain data ({detail})"
            raise MimicKitError(msg) from None
        raise MimicKitError(f"{path}: not a readable checkpoint ({detail})") from None
    except Exception as e:  # noqa: BLE001 - any unreadable file is the same user error
        raise MimicKitError(f"{path}: not a readable checkpoint ({_describe(e)})") from None
    if not isinstance(state, dict):
        raise MimicKitError(f"{path}: not a checkpoint (expected a state dict, got {type(state).__name__})")
    for key, val in state.items():
        if not isinstance(key, str):
            raise MimicKitError(f"{path}: not a checkpoint (key {_short(repr(key))} is not a string)")
        if key == TRAIN_STATE_KEY:
            continue
        if not isinstance(val, torch.Tensor):
            raise MimicKitError(f"{path}: '{_short(key)}' is not a tensor (got {type(val).__name__})")
        if val.layout != torch.strided or val.is_quantized:  # a network's weights are plain dense tensors
            raise MimicKitError(f"{path}: '{_short(key)}' is not a dense tensor ({val.layout})")
    if TRAIN_STATE_KEY in state:
        state[TRAIN_STATE_KEY] = check_train_state(state[TRAIN_STATE_KEY], path)
    return state


def split_train_state(state: Mapping[str, Any]) -> tuple[dict[str, torch.Tensor], dict[str, Any] | None]:
    """(the model's tensors, `_train_state` or None)."""
    model = {k: v for k, v in state.items() if k != TRAIN_STATE_KEY}
    return model, state.get(TRAIN_STATE_KEY)


def nonfinite_tensors(state: Mapping[str, Any]) -> list[str]:
    """Dotted names of the floating-point tensors holding NaN or ±inf, in the state dict and nested
    inside it (optimiser states in `_train_state` included), in file order. Empty for a sound checkpoint."""
    found: list[str] = []
    _collect_nonfinite(state, "", found)
    return found


def check_train_state(ts: Any, source: str | Path) -> dict[str, Any]:
    """`_train_state` with every field of the right type (missing ones at their fresh-start value);
    fields this version does not know are kept as they are (a later version may add some)."""
    where = f"{source}: {TRAIN_STATE_KEY}"
    if not isinstance(ts, dict):
        raise MimicKitError(f"{where} must be a mapping, got {type(ts).__name__}")
    fmt = _int_field(ts, "format", TRAIN_STATE_FORMAT, where)
    if fmt > TRAIN_STATE_FORMAT:
        raise MimicKitError(f"{where}.format is {fmt}: written by a newer version (this reads {TRAIN_STATE_FORMAT})")
    out = dict(ts)
    out["format"] = fmt
    name = ts.get("agent_name", "")
    if not isinstance(name, str):
        raise MimicKitError(f"{where}.agent_name must be a string, got {type(name).__name__}")
    out["iteration"] = _int_field(ts, "iteration", 0, where)
    out["samples"] = _int_field(ts, "samples", 0, where)
    out["wall_time_hours"] = _float_field(ts, "wall_time_hours", 0.0, where, minimum=0.0)
    test = ts.get("test", {})
    if not isinstance(test, dict):
        raise MimicKitError(f"{where}.test must be a mapping, got {type(test).__name__}")
    out["test"] = {
        "mean_return": _float_field(test, "mean_return", 0.0, f"{where}.test"),
        "mean_ep_len": _float_field(test, "mean_ep_len", 0.0, f"{where}.test", minimum=0.0),
        "num_eps": _int_field(test, "num_eps", 0, f"{where}.test"),
        "num_fail": _int_field(test, "num_fail", 0, f"{where}.test"),  # absent before 2026-12-04
    }
    out["optimizers"] = _check_optimizers(ts.get("optimizers", {}), where)
    return out


def check_fits(path: str | Path, own: Mapping[str, torch.Tensor], state: Mapping[str, Any]) -> None:
    """One MimicKitError listing what of `state` does not fit `own` (missing/unexpected keys, shapes)."""
    problems: list[str] = []
    for key, val in own.items():
        if key not in state:
            continue
        theirs = state[key]
        if not isinstance(theirs, torch.Tensor):
            problems.append(f"'{key}' is not a tensor in the checkpoint")
        elif tuple(theirs.shape) != tuple(val.shape):
            problems.append(
                f"{_what_differs(key)}: '{key}' has shape {list(theirs.shape)} in the checkpoint"
                f" but {list(val.shape)} here"
            )
        elif theirs.is_floating_point() != val.is_floating_point():
            problems.append(f"'{key}' is {theirs.dtype} in the checkpoint but {val.dtype} here")
    missing = [k for k in own if k not in state]
    unexpected = [k for k in state if k not in own and k != TRAIN_STATE_KEY]
    hint = "(a different agent or model config?)"
    if missing:
        problems.append(f"keys missing from the checkpoint: {_some(missing)} {hint}")
    if unexpected:
        problems.append(f"unexpected keys in the checkpoint: {_some(unexpected)} {hint}")
    if problems:
        raise MimicKitError(f"{path} does not fit this agent and environment: " + "; ".join(problems))


def check_finite(path: str | Path, state: Mapping[str, Any]) -> None:
    """Refuse a checkpoint whose model tensors hold NaN or inf (a diverged run's weights)."""
    model, _ = split_train_state(state)
    bad = nonfinite_tensors(model)
    if bad:
        raise MimicKitError(
            f"{path}: non-finite weights (NaN or inf) in {_some(bad)}: the run that wrote it diverged;"
            " use an earlier checkpoint"
        )


def load_optimizer_states(path: str | Path, optimizers: Mapping[str, Any], saved: Mapping[str, Any]) -> None:
    """Restore each named optimiser (anything with `load_state_dict`) from `saved` (checked by
    `check_train_state`); a state that does not fit this optimiser is one line."""
    for name, opt in optimizers.items():
        if name not in saved:
            continue
        try:
            opt.load_state_dict(saved[name])
        except (ValueError, KeyError, TypeError, RuntimeError, IndexError) as e:
            raise MimicKitError(
                f"{path}: {TRAIN_STATE_KEY}.optimizers.{name} does not fit this agent ({_describe(e)})"
            ) from None


# ---------------------------------------------------------------- writing


def make_train_state(
    agent_name: str,
    next_iter: int,
    samples: int,
    wall_time_hours: float,
    test: Mapping[str, float | int],
    optimizers: Mapping[str, Any],
) -> dict[str, Any]:
    """The `_train_state` record; `test` has `mean_return`, `mean_ep_len`, `num_eps`, `num_fail`; `optimizers`
    maps names to objects with `state_dict()`."""
    return {
        "format": TRAIN_STATE_FORMAT,
        "agent_name": agent_name,
        "iteration": int(next_iter),
        "samples": int(samples),
        "wall_time_hours": float(wall_time_hours),
        "test": dict(test),
        "optimizers": {name: opt.state_dict() for name, opt in optimizers.items()},
    }


def write_checkpoint(path: str | Path, state: Mapping[str, Any]) -> None:
    """Serialise `state` and write it atomically; stale temp files of this name go first. A full disk,
    a read-only folder or any other OS error is one `MimicKitError`, and no partial file is left."""
    path = Path(path)
    buf = io.BytesIO()
    torch.save(dict(state), buf)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temp_files(path.parent, only=path.name)
        atomic_write_bytes(path, buf.getvalue())
    except OSError as e:
        raise MimicKitError(f"cannot write checkpoint {path}: {e.strerror or _describe(e)}") from None


def remove_stale_temp_files(folder: str | Path, only: str | None = None) -> list[Path]:
    """Delete the `.NAME.pt.XXXXXXXX` temp files an interrupted checkpoint write left in `folder`
    (only those of file `only` when given); returns what was removed. Unremovable ones are left."""
    folder = Path(folder)
    removed: list[Path] = []
    try:
        entries = list(folder.iterdir())
    except OSError:
        return removed
    for p in entries:
        m = _TEMP_RE.match(p.name)
        if m is None or (only is not None and m.group("name") != only) or not p.is_file():
            continue
        try:
            p.unlink()
        except OSError:
            continue
        removed.append(p)
    return removed


# ---------------------------------------------------------------- helpers


def _check_size(path: Path) -> None:
    size = path.stat().st_size
    if size == 0:
        raise MimicKitError(f"{path}: empty file, not a checkpoint")
    if size > MAX_CHECKPOINT_BYTES:
        raise MimicKitError(f"{path}: {size} bytes, over the {MAX_CHECKPOINT_BYTES}-byte checkpoint limit")
    if not zipfile.is_zipfile(path):
        return
    try:
        with zipfile.ZipFile(path) as zf:
            expanded = sum(info.file_size for info in zf.infolist())
    except (zipfile.BadZipFile, OSError, ValueError) as e:
        raise MimicKitError(f"{path}: not a readable checkpoint (broken zip archive: {_describe(e)})") from None
    if expanded > MAX_CHECKPOINT_BYTES:
        raise MimicKitError(
            f"{path}: its archive expands to {expanded} bytes, over the {MAX_CHECKPOINT_BYTES}-byte checkpoint limit"
        )


_ADVICE = ("Weights only load failed", "(1)", "(2)", "Please file an issue", "Check the doc")


def _weights_only_detail(e: Exception) -> str:
    """torch's weights_only message is a paragraph of advice around the one line that says what failed
    (after "WeightsUnpickler error:", on that line or the next)."""
    for line in str(e).splitlines():
        line = line.split("WeightsUnpickler error:")[-1].strip()
        if line and not line.startswith(_ADVICE):
            return _short(line.split(" Please use")[0])
    return _describe(e)


def _collect_nonfinite(obj: Any, prefix: str, found: list[str]) -> None:
    if isinstance(obj, torch.Tensor):
        if (obj.is_floating_point() or obj.is_complex()) and not bool(torch.isfinite(obj).all()):
            found.append(prefix)
    elif isinstance(obj, Mapping):
        for k, v in obj.items():
            _collect_nonfinite(v, f"{prefix}.{k}" if prefix else str(k), found)
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            _collect_nonfinite(v, f"{prefix}.{i}" if prefix else str(i), found)


def _int_field(d: dict[str, Any], key: str, default: int, where: str) -> int:
    val = d.get(key, default)
    if isinstance(val, bool) or not isinstance(val, int) or val < 0:
        raise MimicKitError(f"{where}.{key} must be an integer >= 0, got {_short(repr(val))}")
    return val


def _float_field(d: dict[str, Any], key: str, default: float, where: str, minimum: float | None = None) -> float:
    val = d.get(key, default)
    if isinstance(val, bool) or not isinstance(val, (int, float)) or not math.isfinite(val):
        raise MimicKitError(f"{where}.{key} must be a finite number, got {_short(repr(val))}")
    if minimum is not None and val < minimum:
        raise MimicKitError(f"{where}.{key} must be >= {minimum}, got {val!r}")
    return float(val)


def _check_optimizers(opts: Any, where: str) -> dict[str, Any]:
    if not isinstance(opts, dict):
        raise MimicKitError(f"{where}.optimizers must be a mapping, got {type(opts).__name__}")
    for name, st in opts.items():
        if not isinstance(name, str) or not isinstance(st, dict) or not isinstance(st.get("optimizer"), dict):
            raise MimicKitError(
                f"{where}.optimizers.{_short(str(name))} must be a mapping with an 'optimizer' state dict"
            )
        _int_field(st, "steps", 0, f"{where}.optimizers.{name}")
        _check_torch_optimizer_state(st["optimizer"], f"{where}.optimizers.{name}.optimizer")
    return opts


def _check_torch_optimizer_state(opt: dict[str, Any], where: str) -> None:
    """torch's Optimizer.state_dict layout: `state` {param index: {name: tensor | number}} and
    `param_groups` [{..., "params": [index, ...]}]; torch itself would accept other shapes and fail
    (with a traceback) at the first step."""
    state, groups = opt.get("state"), opt.get("param_groups")
    if not isinstance(state, dict) or not isinstance(groups, list):
        raise MimicKitError(f"{where} must hold a 'state' mapping and a 'param_groups' list")
    for idx, entry in state.items():
        if not isinstance(entry, dict) or not all(
            isinstance(v, (torch.Tensor, int, float)) and not isinstance(v, bool) for v in entry.values()
        ):
            raise MimicKitError(f"{where}.state.{_short(str(idx))} must map names to tensors or numbers")
    for i, group in enumerate(groups):
        params = group.get("params") if isinstance(group, dict) else None
        if not isinstance(params, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in params):
            raise MimicKitError(f"{where}.param_groups.{i} must be a mapping with a 'params' list of indices")
        for key, val in group.items():
            if key != "params" and not _is_hyperparameter(val):
                raise MimicKitError(f"{where}.param_groups.{i}.{_short(str(key))}: not a number ({type(val).__name__})")


def _is_hyperparameter(val: Any) -> bool:
    """A number (finite), a flag, None, or a short tuple/list of numbers (Adam's betas)."""
    if val is None or isinstance(val, bool):
        return True
    if isinstance(val, (int, float)):
        return math.isfinite(val)
    if isinstance(val, (list, tuple)) and len(val) <= 8:
        return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in val)
    if isinstance(val, torch.Tensor):
        return val.numel() == 1 and bool(torch.isfinite(val).all())
    return False


def _what_differs(key: str) -> str:
    if key.startswith("_obs_norm."):
        return "observation size differs (a different env config or character?)"
    if key.startswith("_a_norm."):
        return "action size differs (a different character?)"
    return "network shape differs (a different agent config, env or character?)"


def _some(keys: list[str], n: int = 4) -> str:
    shown = ", ".join(f"'{_short(k)}'" for k in keys[:n])
    return shown + (f" and {len(keys) - n} more" if len(keys) > n else "")


def _describe(e: BaseException) -> str:
    text = str(e).strip()
    first = text.splitlines()[0] if text else ""
    return _short(f"{e.__class__.__name__}: {first}" if first else e.__class__.__name__)


def _short(text: str, limit: int = _MSG_CHARS) -> str:
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} characters)"
