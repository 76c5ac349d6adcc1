"""Sweep endpoints: one arg file × lists of values → one run per combination, one group in the run list.

`values` maps a MimicKit argument (`rand_seed`, `motion_file`, `num_envs`, `max_samples` or any other
`--key` a run takes, e.g. `devices`) to its list of values; each value is one argv item of the trainer
(a list of strings is several: `"devices": [["cpu", "cpu"]]`), and a config yaml's path is confined as
any path of a request; a value of a launch field a sweep may vary (`launch_fields.SWEEP_FIELDS`) is
checked as that field of a launch is. `dataset` adds one value of `motion_file` per clip of a dataset yaml. Every run
is queued as a launch is (a Ray job each with the Ray executor, the local queue otherwise), with the
shared overrides and resources of the body.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

from fastapi import APIRouter
from pydantic import Field, ValidationError, model_validator

from mimickit.anim.motion_lib import DatasetConfig
from mimickit.runner.args import RUN_ARGS
from mimickit.util.config import load_config, nearest_name
from mimickit.util.errors import MimicKitError, shorten
from studio.api import StudioDep
from studio.api.bodies import OneLineErrors, validation_line
from studio.api.runs import LaunchRun, resolve_config_file, resolve_motion_file, run_config
from studio.runs.launch_fields import NOT_SWEPT, SWEEP_FIELDS
from studio.runs.manager import RunError
from studio.settings import Settings

router = APIRouter(prefix="/sweeps", tags=["sweeps"], route_class=OneLineErrors)
MAX_RUNS = 256
# set by the studio, or once for all of a sweep's runs (the arg file): never a sweep's values
STUDIO_KEYS = {"out_dir", "mode", "model_file", "data_dir", "json", *NOT_SWEPT}
CONFIG_KEYS = ("engine_config", "env_config", "agent_config")  # files: confined as every path of a request
SweepValue = str | int | float | bool | list[str]  # a list: several values of one argument (`devices`)


class LaunchSweep(LaunchRun):
    values: dict[str, list[SweepValue]] = Field(
        default_factory=dict, description="--key (without dashes): its values; one run per combination"
    )
    dataset: str | None = Field(None, description="a dataset yaml: one run per clip, as motion_file")

    @model_validator(mode="before")
    @classmethod
    def _known_values(cls, data: Any) -> Any:
        """Keys first, before pydantic could quote one in an error: a key no run takes is one line (400)
        with at most 60 characters of it. A RunError is not pydantic's to collect: it reaches the app's
        handler as it is."""
        if isinstance(data, dict) and isinstance(data.get("values"), dict):
            sweep_keys(data["values"])
        return data


def sweep_keys(values: dict[Any, Any]) -> None:
    """RunError 400 for a key no run takes (naming the nearest), a launch field a sweep does not vary, or an
    empty list of values."""
    known = [k for k in RUN_ARGS if k not in STUDIO_KEYS]
    for key, vals in values.items():
        if key in NOT_SWEPT:  # a launch field set once per launch (the arg file, save_int_models): say where it goes
            raise RunError(f"values: {key} is one value for all of a sweep's runs: give it beside values", 400)
        if key not in known:
            near = nearest_name(str(key)[:100], known)
            hint = f"; did you mean {near!r}?" if near else ""
            raise RunError(f"values: unknown argument {shorten(str(key), 60)!r}{hint}", 400)
        if isinstance(vals, list) and not vals:
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
    parts = [f"{k}={_value_name(k, v)}" for k, v in combo.items()]
    return " ".join([base, *parts])[:200]


def _value_name(key: str, value: Any) -> str:
    if isinstance(value, list):
        return ",".join(map(str, value))
    return Path(str(value)).stem if key == "motion_file" else str(value)


def run_args(combo: dict[str, Any], settings: Settings) -> dict[str, str | list[str]]:
    """The untyped values of one combination as the trainer's argv items (each value one item, a list
    several); a config yaml's path confined and resolved."""
    args: dict[str, str | list[str]] = {}
    for key, value in combo.items():
        if key in SWEEP_FIELDS:
            continue
        if key in CONFIG_KEYS:
            if not isinstance(value, str):
                raise RunError(f"values.{key}: give a yaml file's path, got {shorten(repr(value), 60)}", 400)
            value = str(resolve_config_file(key, value, settings))
        if value == []:
            raise RunError(f"values.{key}: an empty list is no value; give at least one item", 400)
        args[key] = [str(v) for v in value] if isinstance(value, list) else _item(value)
    return args


def _item(value: SweepValue) -> str:
    return str(value).lower() if isinstance(value, bool) else str(value)


@router.post("", status_code=201)
def launch_sweep(body: LaunchSweep, studio: StudioDep) -> dict[str, Any]:
    """Queue one run per combination of `values` (and of `dataset`'s clips), all in one new sweep. Its
    size is counted before anything is built, and every run's arguments are checked as the trainer
    checks them before any is queued: a bad value is one line and no run."""
    values = dict(body.values)
    if body.dataset:
        values["motion_file"] = [*values.get("motion_file", []), *dataset_clips(body.dataset, studio.settings)]
    count = math.prod(len(v) for v in values.values())
    if count > MAX_RUNS:
        raise RunError(f"the sweep makes {count} runs; at most {MAX_RUNS} at once", 400)
    combos = combinations(values)
    shared = body.model_dump(exclude={"values", "dataset", "name"}, exclude_none=True)
    configs = []
    for combo in combos:
        typed = {SWEEP_FIELDS[k].name: v for k, v in combo.items() if k in SWEEP_FIELDS}
        try:
            config = run_config(LaunchRun(**{**shared, **typed}), studio.settings)
        except ValidationError as e:
            raise RunError(f"values: {validation_line(e.errors())}", 400) from None
        extra = run_args(combo, studio.settings)
        configs.append({**config, "args": extra} if extra else config)
    name = body.name or f"sweep {Path(configs[0]['arg_file']).stem}"
    spec = {"arg_file": configs[0]["arg_file"], "values": values, **shared}
    try:
        runs = studio.runs.submit_many(
            [(run_name(name, c), cfg) for c, cfg in zip(combos, configs, strict=True)], sweep=(name, spec)
        )
    except RunError as e:
        raise RunError(f"values: {e}" if e.status == 400 else str(e), e.status) from None
    return {"id": runs[0].sweep_id, "name": name, "spec": spec, "runs": [studio.run_list.row(r) for r in runs]}


@router.get("")
def list_sweeps(studio: StudioDep) -> list[dict[str, Any]]:
    """Every sweep: its id, name, spec and the ids of its runs."""
    return studio.registry.sweeps()


@router.get("/{sweep_id}")
def get_sweep(sweep_id: int, studio: StudioDep) -> dict[str, Any]:
    """One sweep with its runs as `GET /api/runs/{id}` gives them."""
    sweep = studio.registry.sweep(sweep_id)
    if sweep is None:
        raise RunError(f"no sweep {sweep_id}", 404)
    return {**sweep, "runs": [studio.run_list.row(studio.runs.get(i)) for i in sweep["run_ids"]]}
