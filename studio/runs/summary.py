"""What a run's folder says about it, for the run list: the clip or dataset and character it trains,
env count, budgets (samples, hours) and seed (args.json's effective values; the env_config.yaml as trained when a
trainer recorded no clip), samples, elapsed training time, samples/s and the last test return
(metrics.jsonl), and its end state with the line that says why (state.json). The folder is the truth;
the registry only knows what was asked.

A run list is polled every few seconds for every run: a summary is cached until one of its files
changes (mtime and size), and metrics.jsonl is read from its tail only.
"""

from __future__ import annotations

import math
import threading
from pathlib import Path
from typing import Any

from mimickit.learning.run_folder import RunFolder, is_event_row
from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from studio.runs.metrics import last_rows

NO_BUDGET = 2**62  # a max_samples at least this large is the trainer's "no limit"

_cache: dict[str, tuple[tuple, dict[str, Any]]] = {}
_NO_FILES = (None, None, None, None)  # the stamps of a folder with none of the watched files
_empty: dict[str, Any] | None = None
_lock = threading.Lock()


def run_summary(out_dir: str | Path) -> dict[str, Any]:
    folder = RunFolder(out_dir)
    watched = (folder.args_file, folder.config_file("env"), folder.metrics_file, folder.state_file)
    key = tuple(_stamp(p) for p in watched)
    if key == _NO_FILES:
        return empty_summary(out_dir)
    with _lock:
        hit = _cache.get(str(folder.path))
    if hit and hit[0] == key:
        return hit[1]
    summary = _summarize(folder)
    with _lock:
        _cache[str(folder.path)] = (key, summary)
    return summary


def empty_summary(out_dir: str | Path) -> dict[str, Any]:
    """The summary of a run folder that has none of its files yet (a queued run's): the same for every
    such folder, so it is made once and shared, without reading anything."""
    global _empty
    if _empty is None:
        _empty = _summarize(RunFolder(out_dir))
    return _empty


def _summarize(folder: RunFolder) -> dict[str, Any]:
    return {**_from_env_config(folder), **_from_args(folder), **_from_metrics(folder), **_from_state(folder)}


def seed_of(out_dir: str | Path) -> int | None:
    """The seed the run's trainer started with, as its args.json records it (a resumed run's first start)."""
    return _from_args(RunFolder(out_dir))["seed"]


def _stamp(path: Path) -> tuple[float, int] | None:
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size


def _from_args(folder: RunFolder) -> dict[str, Any]:
    record = folder.read_args() or {}
    values = record.get("effective") if isinstance(record.get("effective"), dict) else {}
    budget = _int(values.get("max_samples"))
    starts = record.get("previous_starts")
    starts = [r for r in starts if isinstance(r, dict)] if isinstance(starts, list) else []
    seeds = [_int(r.get("seed")) for r in [*starts, record]]  # a resume draws its own seed unless given one
    out = {
        "seed": seeds[0],  # the first start's: what "again with this seed" repeats
        "seeds": seeds,
        "resumes": len(starts),  # each resume keeps the start before it
        "num_envs": _int(values.get("num_envs")),
        "max_samples": budget if budget is not None and budget < NO_BUDGET else None,
        "max_hours": values.get("max_hours") if _finite(values.get("max_hours")) else None,
    }
    for key in ("motion_file", "char_file"):  # as the trainer resolved them
        if values.get(key):
            out[key] = str(values[key])
    if values.get("motion_file"):
        out["dataset"] = str(values["motion_file"]).endswith((".yaml", ".yml"))
    return out


def _from_env_config(folder: RunFolder) -> dict[str, Any]:
    try:  # the bounded loader: a run folder's yaml is read as hostile as any other
        config = load_yaml(folder.config_file("env"))
    except MimicKitError:
        config = None
    env = config.get("env") if isinstance(config, dict) else None
    env = env if isinstance(env, dict) else {}
    motion = env.get("motion_file")
    return {
        "motion_file": str(motion) if motion else None,
        "dataset": bool(motion) and str(motion).endswith((".yaml", ".yml")),
        "char_file": str(env["char_file"]) if env.get("char_file") else None,
    }


def _from_metrics(folder: RunFolder) -> dict[str, Any]:
    rows = last_rows(folder.metrics_file)
    iterations = [r for r in rows if not is_event_row(r)]
    last = iterations[-1] if iterations else {}
    tested = [r for r in iterations if _finite(r.get("test_return"))]
    fail_frac = tested[-1].get("test_fail_frac") if tested else None
    hours = last.get("wall_time")
    return {
        "samples": _int(last.get("samples")),
        "iteration": _int(last.get("iteration")),
        "elapsed_s": hours * 3600.0 if _finite(hours) else None,  # the trainer's wall_time is in hours
        "samples_per_s": last.get("time.samples_per_s") if _finite(last.get("time.samples_per_s")) else None,
        "test_return": tested[-1]["test_return"] if tested else None,
        # The share of the last test's episodes that fell: a clip that does not loop ends episodes early
        # without a fall, so the return and length alone can read as one. None from trainers before it.
        "test_fail_frac": fail_frac if _finite(fail_frac) else None,
    }


def _from_state(folder: RunFolder) -> dict[str, Any]:
    state = folder.read_state()
    if state is None:
        return {"end_state": None, "end_reason": None, "state_updated_at": None}
    return {"end_state": state.state.value, "end_reason": state.reason or None, "state_updated_at": state.updated_at}


def _int(value: Any) -> int | None:
    if isinstance(value, list) and len(value) == 1:
        value = value[0]
    try:
        return int(value)
    except (TypeError, ValueError):
        return None


def _finite(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
