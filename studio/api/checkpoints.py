"""Checkpoint endpoints: list the checkpoint files of the runs and data folders, and inspect one
(agent type, network shapes, normaliser statistics, sizes, training state, and whether it fits an env
config or a character)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

from fastapi import APIRouter, HTTPException, Query, Request

from mimickit.learning.run_folder import ENGINE_CONFIG_FILE, ENV_CONFIG_FILE, INT_MODELS_DIR, MODEL_FILE
from mimickit.util.errors import MimicKitError
from studio.api import studio_of
from studio.api.bodies import OneLineErrors
from studio.runs.checkpoint_history import RunHistory, int_model_index, run_history
from studio.runs.checkpoints import check_fit_char, check_fit_env, configs_beside, inspect_checkpoint, job_file
from studio.runs.registry import Run
from studio.scene.rollout import run_data_dir, source_for_checkpoint
from studio.security import confine, display_path

router = APIRouter(prefix="/checkpoints", tags=["checkpoints"], route_class=OneLineErrors)
MAX_LISTED = 500


@router.get("")
def list_checkpoints(request: Request) -> list[dict[str, Any]]:
    """`.pt` files in the runs folder (each run's `model.pt`, `int_models/`) and in the data folders'
    `models/`, grouped: one group per run folder (the newest first), its checkpoints by iteration, the
    newest first (`model.pt`, `latest`, before an intermediate one of the same iteration), then the data
    folders' by mtime. `iteration` and `samples` are the training the weights have seen, as their
    `_train_state` and a rollout's label count it (`int_models/model_N.pt`: N + 1 iterations), from the
    file's name and the run's metrics.jsonl and state.json (no checkpoint is loaded); null when unknown."""
    studio = studio_of(request)
    s = studio.settings
    runs_by_dir = {str(Path(r.out_dir).resolve()): r for r in studio.registry.list() if r.out_dir}
    found: list[tuple[Path, Path | None]] = []  # (checkpoint, its run folder or None)
    if s.runs_dir.is_dir():
        found += [(f, f.parent) for f in s.runs_dir.glob("*/*.pt")]
        found += [(f, f.parent.parent) for f in s.runs_dir.glob(f"*/{INT_MODELS_DIR}/*.pt")]
    for d in s.data_dirs:
        if (d / "models").is_dir():
            found += [(f, None) for f in (d / "models").glob("**/*.pt")]
    per_run: dict[Path, dict[str, Any]] = {}  # what a run folder's checkpoints share: read once per request
    out = []
    for f, run_dir in found:
        try:
            st = f.stat()
        except OSError:
            continue
        if run_dir is None:
            entry = {"group": DATA_GROUP, "run_id": None, "run_name": None, "has_configs": bool(configs_beside(f))}
            entry |= {"needs_data": _needs_data(f, s.data_dir), "iteration": None, "samples": None, "latest": False}
        else:
            if run_dir not in per_run:
                per_run[run_dir] = _run_shared(f, run_dir, runs_by_dir.get(str(run_dir.resolve())), s.data_dir)
            shared = per_run[run_dir]
            entry = {k: v for k, v in shared.items() if k != "history"} | _place(f, run_dir, shared["history"])
        out.append({"path": display_path(f, s.data_dirs), "size_bytes": st.st_size, "mtime": st.st_mtime, **entry})
    return _grouped(out)[:MAX_LISTED]


DATA_GROUP = "data folders: models/"  # a "/" in it: no run folder's name can take it


def _run_shared(f: Path, run_dir: Path, run: Run | None, data_dir: Path | None) -> dict[str, Any]:
    """What every checkpoint of one run folder shares: its group ("#id name", or the folder's name for a
    folder the registry does not know), its configs (beside model.pt, the parent of int_models/), history."""
    return {
        "group": f"#{run.id} {run.name}" if run else run_dir.name,
        "run_id": run.id if run else None,
        "run_name": run.name if run else None,
        "has_configs": bool(configs_beside(f)),
        "needs_data": _needs_data(f, data_dir),
        "history": run_history(run_dir),
    }


def _place(f: Path, run_dir: Path, history: RunHistory) -> dict[str, Any]:
    """The checkpoint's iteration and samples; `latest`: it is the run's model.pt."""
    if f.parent == run_dir:
        latest = f.name == MODEL_FILE
        iteration, samples = history.model if latest else (None, None)
        return {"iteration": iteration, "samples": samples, "latest": latest}
    index = int_model_index(f)
    iteration, samples = history.int_model(index) if index is not None else (None, None)
    return {"iteration": iteration, "samples": samples, "latest": False}


def _grouped(entries: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Runs' groups first, the group with the newest file first; in a group the highest iteration first
    (unknown ones on top: a model.pt before its first metrics row), then the newest file."""
    newest: dict[str, float] = {}
    for c in entries:
        newest[c["group"]] = max(newest.get(c["group"], 0.0), c["mtime"])

    def order(c: dict[str, Any]) -> tuple[bool, float, str, float, bool, float]:
        it = c["iteration"]
        return (c["group"] == DATA_GROUP, -newest[c["group"]], c["group"], -(it if it is not None else math.inf),
                not c.get("latest", False), -c["mtime"])  # fmt: skip

    return sorted(entries, key=order)


def _needs_data(checkpoint: Path, data_dir: Path | None) -> str | None:
    """The clip its configs play when the data folders lack it (a rollout or eval of it would fail)."""
    try:
        return source_for_checkpoint(checkpoint, fallback_data_dir=data_dir).missing_clip()
    except MimicKitError:
        return None  # no configs beside it: the pick of an arg file decides


YAML = (".yaml", ".yml")


def _input(given: str | None, what: str, suffixes: tuple[str, ...], roots: list[Path]) -> Path | None:
    """A config or character to check the fit against: a file of its kind inside the folders (a folder
    or the registry is one 400 line, not a fit that failed)."""
    return job_file(confine(given, roots), given, what, suffixes) if given else None


@router.get("/inspect")
def inspect(
    request: Request,
    path: str = Query(..., description="a checkpoint inside the data or runs folders"),
    env_config: str | None = Query(None, description="check that it fits this env config (builds one env)"),
    engine_config: str | None = Query(None, description="engine yaml for that check (default: the run's)"),
    char: str | None = Query(None, description="check that it fits this character's DoFs (the action size)"),
) -> dict[str, Any]:
    """Agent type (from `_train_state`, else the key names), network layer shapes, normaliser
    statistics (count, mean |μ|, mean σ, per-dimension min/max), observation and action sizes,
    samples per iteration; `fit` with one message when `env_config` or `char` is given."""
    studio = studio_of(request)
    s = studio.settings
    ckpt = confine(path, [*s.data_dirs, s.runs_dir])
    t0 = time.perf_counter()
    info = inspect_checkpoint(ckpt)
    info["display_path"] = display_path(ckpt, s.data_dirs)
    fit = None
    target = env_config or char
    env_file = _input(env_config, "env_config", YAML, s.readable_roots)
    char_file = _input(char, "char", (".xml",), s.readable_roots) if not env_config else None
    engine = _input(engine_config, "engine_config", YAML, s.readable_roots)
    try:
        if env_file is not None:
            beside = configs_beside(ckpt)
            if engine is None and ENGINE_CONFIG_FILE in beside:
                engine = Path(beside[ENGINE_CONFIG_FILE])
            data_dir = (run_data_dir(Path(beside[ENV_CONFIG_FILE]).parent) if beside else None) or s.data_dir
            fit = check_fit_env(ckpt, env_file, engine, data_dir, env_config)
        elif char_file is not None:
            fit = check_fit_char(ckpt, char_file, char)
    except MimicKitError as e:
        fit = {"target": target, "fits": False, "message": f"cannot build {target}: {e}"}
    except Exception as e:  # noqa: BLE001 - a broken config: one line, not a traceback
        first = (str(e).strip().splitlines() or [""])[0]
        raise HTTPException(400, f"cannot check {target}: {e.__class__.__name__}: {first}") from None
    info["fit"] = fit
    info["inspect_ms"] = round((time.perf_counter() - t0) * 1000, 1)
    return info
