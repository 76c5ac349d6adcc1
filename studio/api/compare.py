"""Comparing runs: what each run's folder says about how it was started (`args.json`, the three config
yamls as trained, `state.json`) and the keys on which two or more runs differ.

The curves themselves come from `GET /api/runs/{id}/metrics?follow=false`; this adds what the rows do
not carry: where a run diverged (its `state.json`), and the settings to tell two runs apart.
"""

from __future__ import annotations

from typing import Any

import yaml
from fastapi import APIRouter, Query, Request
from fastapi.responses import StreamingResponse

from mimickit.learning.run_folder import AGENT_CONFIG_FILE, ENGINE_CONFIG_FILE, ENV_CONFIG_FILE, EndState, RunFolder
from studio.api import studio_of
from studio.api.bodies import OneLineErrors
from studio.api.runs import csv_response
from studio.runs.manager import RunError
from studio.runs.metrics import MetricsCsv

router = APIRouter(prefix="/compare", tags=["compare"], route_class=OneLineErrors)
MAX_RUNS = 12
MAX_ID_DIGITS = 30
CONFIG_FILES = {"engine": ENGINE_CONFIG_FILE, "env": ENV_CONFIG_FILE, "agent": AGENT_CONFIG_FILE}
# args.json fields that differ between any two runs and say nothing about how they train.
NOT_SETTINGS = {"argv", "start_time", "start_time_utc", "previous_starts", "format", "effective.out_dir"}


@router.get("")
def compare(request: Request, runs: str = Query(description="run ids, comma-separated: `3,5`")) -> dict[str, Any]:
    """Each run's settings (flattened `args.json` and config keys), where it diverged, and `diff`: the keys
    whose values are not the same in every run (a key one run lacks shows as null there)."""
    ids = _parse_ids(runs)
    studio = studio_of(request)
    entries = [_run_entry(studio.runs.get(i)) for i in ids]
    keys = sorted({k for e in entries for k in e["settings"]})
    diff = []
    for key in keys:
        values = [e["settings"].get(key) for e in entries]
        if any(v != values[0] for v in values[1:]):
            diff.append({"key": key, "values": values})
    return {"runs": [{k: v for k, v in e.items() if k != "settings"} for e in entries], "diff": diff}


@router.get("/metrics.csv", response_class=StreamingResponse)
def compare_csv(request: Request, runs: str = Query(description="run ids, comma-separated")) -> StreamingResponse:
    """The runs' `metrics.jsonl` files as one CSV (streamed): a `run` column (the id), then the union of
    their keys, each run's rows in turn, in the order the ids are given."""
    ids = _parse_ids(runs)
    studio = studio_of(request)
    folders = [(str(i), RunFolder(studio.runs.get(i).out_dir).metrics_file) for i in ids]
    return csv_response(MetricsCsv(folders), f"runs-{'-'.join(map(str, ids))}-metrics.csv")


def _parse_ids(text: str) -> list[int]:
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if not parts or not all(p.isdigit() for p in parts):
        shown = text if len(text) <= 100 else text[:100] + "..."
        raise RunError(f"runs={shown!r}: expected run ids separated by commas, e.g. 3,5", 422)
    for p in parts:
        if len(p) > MAX_ID_DIGITS:  # past any id (and past what int() reads): no such run
            raise RunError(f"no run {p[:MAX_ID_DIGITS]}...", 404)
    ids = list(dict.fromkeys(int(p) for p in parts))
    if len(ids) > MAX_RUNS:
        raise RunError(f"runs: at most {MAX_RUNS} runs at once, got {len(ids)}", 422)
    return ids


def _run_entry(run: Any) -> dict[str, Any]:
    folder = RunFolder(run.out_dir) if run.out_dir else None
    settings: dict[str, Any] = _flatten(run.config, "launch.")  # what the user asked: arg file, overrides
    diverged = None
    if folder is not None:
        record = folder.read_args() or {}
        settings.update(_flatten({k: v for k, v in record.items() if k not in NOT_SETTINGS}))
        for role, name in CONFIG_FILES.items():
            settings.update(_flatten(_read_yaml(folder.file(name)), f"{role}_config."))
        state = folder.read_state()
        if state is not None and state.state == EndState.DIVERGED:
            diverged = {"iteration": state.iteration, "samples": state.samples, "reason": state.reason}
    settings = {k: v for k, v in settings.items() if k not in NOT_SETTINGS}
    return {"id": run.id, "name": run.name, "status": run.status.value, "diverged": diverged, "settings": settings}


def _read_yaml(path: Any) -> dict[str, Any]:
    """A config as the run trained it; an unreadable one is one `(unreadable: ...)` value, not an error,
    so one damaged folder does not hide the comparison of the others."""
    try:
        data = yaml.safe_load(path.read_text()) if path.is_file() else None
    except (OSError, yaml.YAMLError) as e:
        return {"(unreadable)": f"{path.name}: {type(e).__name__}"}
    return data if isinstance(data, dict) else {}


def _flatten(obj: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested mappings as dotted keys; lists stay values (a one-item list of an arg, as args.json keeps
    them, becomes its item)."""
    out: dict[str, Any] = {}
    for k, v in obj.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, f"{key}."))
        else:
            out[key] = v[0] if isinstance(v, list) and len(v) == 1 else v
    return out
