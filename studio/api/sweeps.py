"""Sweep endpoints: one arg file × lists of values → one run per combination, one group in the run list.

`values` maps a MimicKit argument (`rand_seed`, `motion_file`, `num_envs`, `max_samples` or any other
`--key` a run takes, e.g. `devices`) to its list of values; `dataset` adds one value of `motion_file`
per clip of a dataset yaml. Every run is queued as a launch is (a Ray job each with the Ray executor,
the local queue otherwise), with the shared overrides and resources of the body.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

from fastapi import APIRouter, Request
from pydantic import Field, ValidationError

from mimickit.anim.motion_lib import DatasetConfig
from mimickit.run_args import RUN_ARGS
from mimickit.util.config import load_config, nearest_name
from mimickit.util.errors import MimicKitError
from studio.api import studio_of
from studio.api.bodies import OneLineErrors, validation_line
from studio.api.runs import LaunchRun, resolve_motion_file, run_config, run_json
from studio.runs import RunError
from studio.settings import Settings

router = APIRouter(prefix="/sweeps", tags=["sweeps"], route_class=OneLineErrors)
MAX_RUNS = 256
# LaunchRun's fields, checked as a launch's
TYPED_KEYS = ("rand_seed", "motion_file", "num_envs", "max_samples", "max_hours")
STUDIO_KEYS = {"arg_file", "out_dir", "mode", "model_file", "data_dir", "json"}  # set by the studio, not swept
SweepValue = str | int | float | bool


class LaunchSweep(LaunchRun):
    values: dict[str, list[SweepValue]] = Field(
        default_factory=dict, description="--key (without dashes): its values; one run per combination"
    )
    dataset: str | None = Field(None, description="a dataset yaml: one run per clip, as motion_file")


def sweep_keys(values: dict[str, list[Any]]) -> None:
    """RunError 400 for a key no run takes (naming the nearest) or an empty list of values."""
    known = [k for k in RUN_ARGS if k not in STUDIO_KEYS]
    for key, vals in values.items():
        if key not in known:
            near = nearest_name(key, known)
            raise RunError(f"values: unknown argument {key!r}" + (f"; did you mean {near!r}?" if near else ""), 400)
        if not vals:
            raise RunError(f"values.{key}: give at least one value", 400)


def dataset_clips(path: str, settings: Settings) -> list[str]:
    """The clip files a dataset yaml lists (each once, in order), as it names them."""
    try:
        dataset = load_config(DatasetConfig, resolve_motion_file(path, settings))
    except MimicKitError as e:
        raise RunError(f"dataset: {e}", 400) from None
    return list(dict.fromkeys(entry.file for entry in dataset.motions))


def combinations(values: dict[str, list[Any]]) -> list[dict[str, Any]]:
    keys = list(values)
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(values[k] for k in keys))]


def run_name(base: str, combo: dict[str, Any]) -> str:
    parts = [f"{k}={Path(str(v)).stem if k == 'motion_file' else v}" for k, v in combo.items()]
    return " ".join([base, *parts])[:200]


@router.post("", status_code=201)
def launch_sweep(body: LaunchSweep, request: Request) -> dict[str, Any]:
    """Queue one run per combination of `values` (and of `dataset`'s clips), all in one new sweep."""
    studio = studio_of(request)
    values = dict(body.values)
    if body.dataset:
        values["motion_file"] = [*values.get("motion_file", []), *dataset_clips(body.dataset, studio.settings)]
    sweep_keys(values)
    combos = combinations(values)
    if len(combos) > MAX_RUNS:
        raise RunError(f"the sweep makes {len(combos)} runs; at most {MAX_RUNS} at once", 400)
    shared = body.model_dump(exclude={"values", "dataset", "name"}, exclude_none=True)
    configs = []
    for combo in combos:  # every run's config checked before any is queued
        typed = {k: v for k, v in combo.items() if k in TYPED_KEYS}
        try:
            config = run_config(LaunchRun(**{**shared, **typed}), studio.settings)
        except ValidationError as e:
            raise RunError(f"values: {validation_line(e.errors())}", 400) from None
        extra = {k: str(v).lower() if isinstance(v, bool) else str(v) for k, v in combo.items() if k not in typed}
        configs.append({**config, "args": extra} if extra else config)
    name = body.name or f"sweep {Path(configs[0]['arg_file']).stem}"
    spec = {"arg_file": configs[0]["arg_file"], "values": values, **shared}
    sweep_id = studio.registry.create_sweep(name, spec)
    runs = [studio.runs.submit(run_name(name, c), cfg, sweep_id) for c, cfg in zip(combos, configs, strict=True)]
    return {"id": sweep_id, "name": name, "spec": spec, "runs": [run_json(r) for r in runs]}


@router.get("")
def list_sweeps(request: Request) -> list[dict[str, Any]]:
    """Every sweep: its id, name, spec and the ids of its runs."""
    return studio_of(request).registry.sweeps()


@router.get("/{sweep_id}")
def get_sweep(sweep_id: int, request: Request) -> dict[str, Any]:
    """One sweep with its runs as `GET /api/runs/{id}` gives them."""
    studio = studio_of(request)
    sweep = next((s for s in studio.registry.sweeps() if s["id"] == sweep_id), None)
    if sweep is None:
        raise RunError(f"no sweep {sweep_id}", 404)
    return {**sweep, "runs": [run_json(studio.runs.get(i)) for i in sweep["run_ids"]]}
