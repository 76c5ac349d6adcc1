"""Run endpoints: launch, list, inspect, stop, resume (with a new budget), again with a run's seed,
delete, tags and notes, the launch form's fields, and a run's metrics rows (live, they are
`GET /api/stream`'s) or its whole metrics.jsonl as CSV.

Paths take the CLI's forms: `args/x.txt` (the project's args folder, then each data folder's and the
runs folder's), `data/...` (each data folder in turn), or absolute inside the allowed folders.
"""

from __future__ import annotations

import json
import time
import unicodedata
from pathlib import Path, PurePosixPath
from typing import Annotated, Any

import anyio.to_thread
from fastapi import APIRouter, Query, Response
from fastapi.responses import StreamingResponse
from pydantic import Field, create_model, field_validator

from mimickit.learning.run_folder import RunFolder
from studio.api import StudioDep
from studio.api.bodies import OneLineErrors, StrictBody
from studio.runs.launch_fields import BY_NAME, LAUNCH_FIELDS
from studio.runs.manager import RunError
from studio.runs.metrics import MAX_CSV_COLUMNS, MetricsCsv, read_rows
from studio.security import PathError, confine, shown_path
from studio.settings import Settings

router = APIRouter(prefix="/runs", tags=["runs"], route_class=OneLineErrors)
MOTION_SUFFIXES = (".pkl", ".yaml", ".yml")
CONFIG_SUFFIXES = (".yaml", ".yml")
MAX_STOP_IDS = 10_000
MAX_TAGS, MAX_TAG_CHARS, MAX_NOTES_CHARS = 16, 32, 2000


def field_spec(name: str, description: str | None = None) -> tuple[Any, Any]:
    """The pydantic (annotation, Field) of launch field `name` (`description`: another help text)."""
    f = BY_NAME[name]
    limits = dict(f.limits)
    if f.type is not str:  # strict, as the trainer's checks: `true` is not 1, `4.0` not 4, "true" not true
        limits["strict"] = True
    if f.type is float:
        limits["allow_inf_nan"] = False
    default = ... if f.required else f.default
    annotation = f.type if f.required else f.type | None
    return annotation, Field(default, description=description or f.help, **limits)


LaunchRun = create_model(
    "LaunchRun",
    __base__=StrictBody,
    __doc__="A launch: the fields of `studio.runs.launch_fields.LAUNCH_FIELDS`.",
    **{f.name: field_spec(f.name) for f in LAUNCH_FIELDS},
)
ResumeRun = create_model(
    "ResumeRun",
    __base__=StrictBody,
    max_samples=field_spec("max_samples", "the new budget: total samples, more than trained"),
    max_hours=field_spec("max_hours", "the new wall-time budget: hours in all"),
)


class StopRuns(StrictBody):
    ids: list[Annotated[int, Field(ge=0, strict=True)]] | None = Field(
        None, max_length=MAX_STOP_IDS, description="the runs to stop"
    )
    sweep_id: int | None = Field(None, ge=0, strict=True, description="stop every run of this sweep")


class RunLabels(StrictBody):
    tags: list[Annotated[str, Field(strict=True)]] | None = Field(
        None, max_length=MAX_TAGS, description=f"the run's tags (replacing its tags): up to {MAX_TAGS} labels"
    )
    notes: str | None = Field(None, strict=True, max_length=MAX_NOTES_CHARS, description="free text about the run")

    @field_validator("tags")
    @classmethod
    def _tags(cls, tags: list[str] | None) -> list[str] | None:
        """Short labels the run list shows as chips and the page edits comma-separated: no commas, no
        control characters, no padding, each once."""
        for tag in tags or []:
            shown = tag if len(tag) <= 40 else tag[:40] + "..."
            if not 1 <= len(tag) <= MAX_TAG_CHARS or tag != tag.strip():
                raise ValueError(f"{shown!r}: a tag is 1 to {MAX_TAG_CHARS} characters, no space at either end")
            if "," in tag or _has_control(tag):
                raise ValueError(f"{shown!r}: a tag has no commas and no control characters")
        if tags is not None and len(set(tags)) != len(tags):
            raise ValueError("each tag once")
        return tags

    @field_validator("notes")
    @classmethod
    def _notes(cls, notes: str | None) -> str | None:
        if notes is not None and _has_control(notes.replace("\n", "").replace("\t", "")):
            raise ValueError("notes have no control characters (but line breaks and tabs)")
        return notes


def _has_control(text: str) -> bool:
    """Control, format (bidirectional overrides) and unassigned characters: what could hide or reorder
    the text a list shows."""
    return any(unicodedata.category(c) in ("Cc", "Cf", "Cn", "Cs") for c in text)


def resolve_arg_file(path: str, settings: Settings) -> Path:
    """An arg file as the CLI names it: `args/x.txt` is looked up in each args folder (the project's
    first), anything else is a path of `confine` inside the arg and data folders."""
    parts = PurePosixPath(path.replace("\\", "/")).parts
    if len(parts) > 1 and parts[0] == "args":
        try:
            return confine(str(PurePosixPath(*parts[1:])), settings.arg_dirs)
        except PathError as e:
            if e.status != 404:
                raise
            raise PathError(f"arg file not found: {shown_path(path)}", 404) from None
    return confine(path, [*settings.arg_dirs, *settings.readable_roots])


@router.get("", response_model=list[dict[str, Any]])
async def list_runs(studio: StudioDep) -> Response:
    """Every run as `GET /api/runs/{id}` gives it. Encoded with `json.dumps` directly: FastAPI's generic
    encoder walked thousands of runs' nested values several times slower."""
    runs = studio.run_list
    rows = runs.fresh()
    if rows is None:
        rows = await anyio.to_thread.run_sync(runs.read)
    return Response(json.dumps(rows, allow_nan=False, separators=(",", ":")), media_type="application/json")


def resolve_motion_file(path: str, settings: Settings) -> Path:
    """A clip (.pkl) or dataset (.yaml) inside the readable folders, or PathError 400 naming it."""
    motion = confine(path, settings.readable_roots)
    if motion.suffix not in MOTION_SUFFIXES or not motion.is_file():
        raise PathError(f"motion_file must be a clip (.pkl) or a dataset (.yaml) file: {shown_path(path)}", 400)
    return motion


def resolve_config_file(key: str, path: str, settings: Settings) -> Path:
    """An engine, env or agent yaml (`key`: which) inside the readable folders, or PathError naming it."""
    config = confine(path, settings.readable_roots)
    if config.suffix not in CONFIG_SUFFIXES or not config.is_file():
        raise PathError(f"{key} must be a yaml file: {shown_path(path)}", 400)
    return config


def _arg_file(path: str, settings: Settings) -> Path:
    """An arg file (a .txt file) as `resolve_arg_file` finds it: a folder or the registry is not one."""
    arg_file = resolve_arg_file(path, settings)
    if arg_file.suffix != ".txt" or not arg_file.is_file():
        raise PathError(f"arg_file must be an arg file (a .txt file): {shown_path(path)}", 400)
    return arg_file


RESOLVERS = {"arg": _arg_file, "motion": resolve_motion_file}
"""A launch field's `path` kind: how its file is found and confined."""


def run_config(body: Any, settings: Settings) -> dict[str, Any]:
    """What the registry keeps of a launch (`body`: a `LaunchRun`): every field given but the name, the
    arg file and clip resolved (a bool only when true), and the resources (1 CPU by default with Ray, so
    that Ray, not the studio, decides how many run at once)."""
    config: dict[str, Any] = {}
    for f in LAUNCH_FIELDS:
        value = getattr(body, f.name)
        if value is None or f.name == "name" or (value == "" and not f.required):  # "": as not given
            continue
        if value is False:  # an unticked box is as not given: the argv and the registry's record stay as before
            continue
        config[f.name] = str(RESOLVERS[f.path](value, settings)) if f.path else value
    if settings.executor == "ray":
        config.setdefault("num_cpus", 1)
    return config


@router.post("", status_code=201)
def launch(body: LaunchRun, studio: StudioDep) -> dict[str, Any]:
    """Queue a training run (`mimickit train --arg_file ... --out_dir <runs-dir>/<id>-<name>`); it
    starts when fewer than `--max-concurrent-runs` runs are going (local executor) or when the Ray
    cluster has its `num_cpus`/`num_gpus` free (Ray executor)."""
    config = run_config(body, studio.settings)
    name = body.name or f"{Path(config['arg_file']).stem}-{time.strftime('%Y%m%d-%H%M%S')}"
    return studio.run_list.row(studio.runs.submit(name, config))


@router.get("/fields")
def launch_fields() -> list[dict[str, Any]]:
    """The launch's fields, in the form's order: type and bounds, help, the trainer's `--key` each
    becomes, whether a sweep may vary it, and its input (the page builds the launch form from these)."""
    return [f.to_json() for f in LAUNCH_FIELDS]


@router.get("/{run_id}")
def get_run(run_id: int, studio: StudioDep) -> dict[str, Any]:
    return studio.run_list.row(studio.runs.get(run_id))


@router.patch("/{run_id}")
def set_labels(run_id: int, body: RunLabels, studio: StudioDep) -> dict[str, Any]:
    """Set the run's `tags` (the list replaces the run's) and/or `notes`, kept in the registry; the run
    list (and the stream's `runs` events) carry them."""
    if body.tags is None and body.notes is None:
        raise RunError("give `tags` (a list of strings), `notes` (a string) or both", 422)
    return studio.run_list.row(studio.runs.label(run_id, tags=body.tags, notes=body.notes))


@router.post("/stop")
def stop_many(body: StopRuns, studio: StudioDep) -> dict[str, list[int]]:
    """Stop many runs in one request: `ids`, or every run of `sweep_id`. Queued ones never start;
    going ones are stopped as one stop does; `ended` lists those that had ended already."""
    if (body.ids is None) == (body.sweep_id is None):
        raise RunError("give one of `ids` (a list of run ids) and `sweep_id`", 422)
    if body.sweep_id is not None:
        if studio.registry.sweep(body.sweep_id) is None:
            raise RunError(f"no sweep {body.sweep_id}", 404)
        ids = [run.id for run in studio.registry.of_sweep(body.sweep_id)]
    else:
        ids = body.ids or []
    return studio.runs.stop_many(ids)


@router.post("/{run_id}/stop")
def stop(run_id: int, studio: StudioDep) -> dict[str, Any]:
    """SIGTERM: the trainer writes its checkpoint and exits; the run becomes `stopped`."""
    return studio.run_list.row(studio.runs.stop(run_id))


@router.post("/{run_id}/resume")
def resume(run_id: int, studio: StudioDep, body: ResumeRun | None = None) -> dict[str, Any]:
    """A new process in the same run folder with `--model_file <out_dir>/model.pt`; `max_samples` sets
    a new budget (needed to continue a run that reached its budget). The trainer marks the resume with a
    `{"event": "resume"}` row in metrics.jsonl."""
    budget = {"max_samples": body.max_samples, "max_hours": body.max_hours} if body else {}
    return studio.run_list.row(studio.runs.resume(run_id, **budget))


@router.post("/{run_id}/again", status_code=201)
def again(run_id: int, studio: StudioDep) -> dict[str, Any]:
    """A new run with the same arg file and overrides, and the seed this run used (from its args.json)."""
    return studio.run_list.row(studio.runs.again(run_id))


@router.delete("/{run_id}", status_code=204)
def delete(run_id: int, studio: StudioDep) -> Response:
    """Remove the run and its folder (a running run must be stopped first); a rollout of one of its
    checkpoints is stopped and cleared."""
    out_dir = studio.runs.get(run_id).out_dir
    studio.runs.delete(run_id)
    if out_dir and studio.scene.rollout is not None and studio.scene.rollout.plays_from(Path(out_dir)):
        studio.end_rollout()
    return Response(status_code=204)


@router.get("/{run_id}/log")
def log_tail(run_id: int, studio: StudioDep, lines: int = Query(200, gt=0, le=5000)) -> dict[str, Any]:
    """The last lines of the run's console output (a running Ray job's from Ray)."""
    text = studio.runs.logs(run_id)
    return {"lines": text.splitlines()[-lines:]}


@router.get("/{run_id}/metrics", response_model=None)
def metrics(
    run_id: int,
    studio: StudioDep,
    follow: bool = Query(False, description="retired: the live rows come from `GET /api/stream?run=ID`"),
    start: int = Query(0, ge=0, description="first row index to send"),
) -> list[dict[str, Any]]:
    """The run's `metrics.jsonl` rows so far, from index `start`, as one JSON list (a non-finite value
    as null, named in the row's `nonfinite`). The live rows, as the trainer writes them, are the
    `metrics` events of `GET /api/stream?run=ID`."""
    if follow:
        raise RunError(f"this per-run event stream is retired: follow the rows with GET /api/stream?run={run_id}", 410)
    run = studio.runs.get(run_id)
    return read_rows(RunFolder(run.out_dir).metrics_file, start)


@router.get("/{run_id}/metrics.csv", response_class=StreamingResponse)
def metrics_csv(run_id: int, studio: StudioDep) -> StreamingResponse:
    """The run's whole `metrics.jsonl` as CSV (streamed): one column per key any row has, in the order
    they first appear, one line per row (a resume's marker row too); a value a row lacks is empty, a
    non-finite one `nan`/`inf`/`-inf`."""
    run = studio.runs.get(run_id)
    return csv_response(MetricsCsv([(None, RunFolder(run.out_dir).metrics_file)]), f"run-{run_id}-metrics.csv")


def csv_response(table: MetricsCsv, filename: str) -> StreamingResponse:
    """`table` as a download named `filename`, or a RunError 413 when its rows have too many keys."""
    if len(table.columns) > MAX_CSV_COLUMNS:
        raise RunError(f"the metrics have {len(table.columns)} columns, more than {MAX_CSV_COLUMNS}", 413)
    headers = {"Content-Disposition": f'attachment; filename="{filename}"'}
    return StreamingResponse(table.chunks(), media_type="text/csv; charset=utf-8", headers=headers)
