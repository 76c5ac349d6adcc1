"""The one table of a launch's fields: each field's type and bounds, help text, the trainer's argument it
becomes, whether a sweep may vary it, and its input in the page's launch form.

Everything else is derived from `LAUNCH_FIELDS`: the request body `POST /api/runs` validates
(`studio.api.runs.LaunchRun`), what the registry keeps of a launch (`run_config`), the trainer's argv
(`studio.runs.manager.train_args`), the keys a sweep types and checks as a launch's (`studio.api.sweeps`),
and the launch form the page builds from `GET /api/runs/fields` (web/runs.js). A new launch field is one
line here (plus its test); a field with a `flag` must be one of the trainer's arguments (`RUN_ARGS`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from mimickit.runner.args import MAX_NUM_ENVS, MAX_SEED

NO_CONTROL_CHARS = r"^[^\x00-\x1f\x7f]*$"
JSON_TYPES = {int: "integer", float: "number", str: "string", bool: "boolean"}


@dataclass(frozen=True)
class Widget:
    """The field's input in the launch form: `kind` number, text, select (a select's options are the
    library's, filled by the page) or checkbox (a bool: ticked sends true, unticked leaves it out); fields
    of the same `row` sit side by side."""

    kind: str
    label: str
    placeholder: str = ""
    row: str | None = None
    element_id: str | None = None  # the input's id; default: the name with dashes


@dataclass(frozen=True)
class LaunchField:
    """One field of a launch. `limits`: pydantic's Field constraints (numbers are also strict and
    finite: `true` is not 1, `4.0` not 4; a bool is strict too: `"true"` and 1 are not true; false is as
    not given, so the trainer gets `--flag true` only for true); `flag`: the trainer's `--key` it becomes
    (None: the studio's own, e.g. a run's name or the resources Ray reserves); `path`: a file the studio resolves and
    confines first (`arg` or `motion`); `sweepable`: a sweep's `values` may vary it, each value checked
    as this field's."""

    name: str
    type: type
    help: str
    widget: Widget
    required: bool = False
    default: Any = None
    limits: dict[str, Any] = field(default_factory=dict)
    flag: str | None = None
    sweepable: bool = False
    path: str | None = None

    @property
    def element_id(self) -> str:
        return self.widget.element_id or self.name.replace("_", "-")

    def to_json(self) -> dict[str, Any]:
        """The field as `GET /api/runs/fields` gives it to the page."""
        low = self.limits.get("ge", self.limits.get("gt"))
        if low is not None and self.type is int and "gt" in self.limits:
            low += 1  # the smallest integer above the bound
        return {
            "name": self.name,
            "type": JSON_TYPES[self.type],
            "required": self.required,
            "default": self.default,
            "help": self.help,
            "flag": f"--{self.flag}" if self.flag else None,
            "sweepable": self.sweepable,
            "min": low,
            "max": self.limits.get("le"),
            "widget": {
                "kind": self.widget.kind,
                "id": self.element_id,
                "label": self.widget.label,
                "placeholder": self.widget.placeholder,
                "row": self.widget.row,
                "step": {int: "1", float: "any"}.get(self.type),
            },
        }


F, W = LaunchField, Widget
# fmt: off
LAUNCH_FIELDS: tuple[LaunchField, ...] = (
    F("arg_file", str, "a MimicKit arg file: `args/x.txt`, `data/args/x.txt` or an absolute path",
      W("select", "arg file"), required=True, flag="arg_file", path="arg"),
    F("name", str, "the run's name, no control characters (default: the arg file's and the time)",
      W("text", "name", "(from the arg file)", element_id="run-name"),
      limits={"max_length": 200, "pattern": NO_CONTROL_CHARS}),
    F("num_envs", int, "envs per process (default: the arg file's)", W("number", "envs", "default", "budget"),
      limits={"gt": 0, "le": MAX_NUM_ENVS}, flag="num_envs", sweepable=True),
    F("max_samples", int, "stop training after this many env steps (default: the arg file's)",
      W("number", "max samples", "default", "budget"), limits={"gt": 0}, flag="max_samples", sweepable=True),
    F("max_hours", float, "a wall-time budget: training ends once the run has trained this many hours (--max_hours)",
      W("number", "max hours", "no limit", "budget"), limits={"gt": 0}, flag="max_hours", sweepable=True),
    F("motion_file", str, "a clip (.pkl) or dataset (.yaml) replacing the env config's",
      W("select", "clip or dataset", "(from the arg file)"), flag="motion_file", sweepable=True, path="motion"),
    F("rand_seed", int, "the seed (default: the trainer picks one)", W("number", "seed", "(the trainer picks one)"),
      limits={"ge": 0, "le": MAX_SEED}, flag="rand_seed", sweepable=True),
    # Not sweepable: keeping the intermediate checkpoints is one choice for all of a launch's runs (a
    # sweep's body sets it for every run), not a setting whose effect a sweep would compare.
    F("save_int_models", bool, "also keep int_models/model_{iteration}.pt at every output iteration "
      "(--save_int_models true): the Checkpoints box lists them per run to roll out or A/B",
      W("checkbox", "keep every output's checkpoint"), flag="save_int_models"),
    F("num_cpus", float, "CPUs the run reserves (the Ray executor; default 1)", W("number", "CPUs", "Ray: 1", "ray"),
      limits={"ge": 0, "le": 1024}),
    F("num_gpus", float, "GPUs the run reserves (the Ray executor; default 0)", W("number", "GPUs", "Ray: 0", "ray"),
      limits={"ge": 0, "le": 64}),
)
# fmt: on
BY_NAME = {f.name: f for f in LAUNCH_FIELDS}
TRAINER_FIELDS = tuple(f for f in LAUNCH_FIELDS if f.flag)
"""The fields that become the trainer's arguments, in the order of its argv."""
SWEEP_FIELDS = {f.flag: f for f in TRAINER_FIELDS if f.sweepable}
"""A sweep's typed keys (a trainer argument) and the field each value is checked as."""
NOT_SWEPT = frozenset(f.flag for f in TRAINER_FIELDS if not f.sweepable)
"""Trainer arguments a launch sets once for all its runs (the arg file): never a sweep's values."""
