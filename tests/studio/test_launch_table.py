"""The one table of launch fields (studio/runs/launch_fields.py) and what is derived from it: the request
body's model and its checks, the trainer's argv (the same argv for the same launch as before the
table), the sweep keys, and the fields the page builds its launch form from. In-process, no server;
test_launch_fields.py has every field reaching the real trainer, test_page_browser.py the form."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from mimickit.runner.args import RUN_ARGS
from studio.api.bodies import validation_line
from studio.api.runs import LaunchRun, ResumeRun, run_config
from studio.api.sweeps import STUDIO_KEYS
from studio.runs.launch_fields import LAUNCH_FIELDS, SWEEP_FIELDS
from studio.runs.manager import train_command
from studio.settings import Settings

# The form's element ids, as the browser tests and the page's other code find them.
FORM_IDS = [
    "arg-file", "run-name", "num-envs", "max-samples", "max-hours", "motion-file", "rand-seed", "save-int-models"
]  # fmt: skip


def test_the_table_is_consistent_with_the_trainer() -> None:
    names = [f.name for f in LAUNCH_FIELDS]
    assert list(LaunchRun.model_fields) == names  # the body's keys, in the table's order
    assert list(ResumeRun.model_fields) == ["max_samples", "max_hours"]
    for f in LAUNCH_FIELDS:
        assert f.flag is None or f.flag in RUN_ARGS, f"{f.name}: --{f.flag} is no trainer argument"
        assert not f.sweepable or f.flag, f"{f.name}: a swept value must reach the trainer"
        assert (f.flag in STUDIO_KEYS) == (f.flag is not None and not f.sweepable)
    ids = [f.element_id for f in LAUNCH_FIELDS]
    assert len(set(ids)) == len(ids) and set(FORM_IDS) <= set(ids)
    assert set(SWEEP_FIELDS) == {"num_envs", "max_samples", "max_hours", "motion_file", "rand_seed"}
    assert "save_int_models" in STUDIO_KEYS  # one value for all of a sweep's runs, set beside its values


def test_the_same_argv_for_the_same_launch() -> None:
    """Every trainer field, the studio's own keys and a sweep's further keys: the order the trainer got
    before the table (the arg file, the run folder, the fields, the data folder, the checkpoint, the rest);
    the name and the resources are not the trainer's."""
    config = {
        "arg_file": "/a/x.txt",
        "motion_file": "/d/clip.pkl",
        "num_envs": 4,
        "max_samples": 256,
        "max_hours": 1e-09,
        "rand_seed": 7,
        "save_int_models": True,
        "num_cpus": 1,
        "num_gpus": 0.5,
        "model_file": "/r/1/model.pt",
        "args": {"devices": ["cpu", "cpu"], "logger": "tb"},
    }
    argv = train_command(["mimickit", "train"], config, "/r/1", "/data")
    assert argv == [
        "mimickit", "train", "--arg_file", "/a/x.txt", "--out_dir", "/r/1", "--num_envs", "4",
        "--max_samples", "256", "--max_hours", "1e-09", "--motion_file", "/d/clip.pkl", "--rand_seed", "7",
        "--save_int_models", "true", "--data_dir", "/data", "--model_file", "/r/1/model.pt",
        "--devices", "cpu", "cpu", "--logger", "tb",
    ]  # fmt: skip
    assert train_command(["t"], {"arg_file": "a.txt"}, "/r/2") == ["t", "--arg_file", "a.txt", "--out_dir", "/r/2"]


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ({"num_envs": True}, "num_envs: Input should be a valid integer"),
        ({"num_envs": 4.0}, "num_envs: Input should be a valid integer"),
        ({"num_envs": 65_537}, "num_envs: Input should be less than or equal to 65536"),
        ({"max_samples": 0}, "max_samples: Input should be greater than 0"),
        ({"max_hours": float("inf")}, "max_hours: Input should be a finite number"),
        ({"max_hours": "1"}, "max_hours: Input should be a valid number"),
        ({"rand_seed": -1}, "rand_seed: Input should be greater than or equal to 0"),
        ({"num_gpus": 65}, "num_gpus: Input should be less than or equal to 64"),
        ({"name": "a\nb"}, "name: String should match pattern"),
        ({"save_int_models": "true"}, "save_int_models: Input should be a valid boolean"),
        ({"save_int_models": 1}, "save_int_models: Input should be a valid boolean"),
        ({"num_env": 4}, "unknown key 'num_env'; did you mean 'num_envs'?"),
    ],
)
def test_the_body_checks_each_field_by_the_table(body: dict, needle: str) -> None:
    with pytest.raises(ValidationError) as e:
        LaunchRun(arg_file="args/x.txt", **body)
    line = validation_line(e.value.errors())  # the one line a request gets
    assert needle in line, line


def test_a_launch_with_every_field_validates() -> None:
    body = LaunchRun(arg_file="a.txt", name="n", num_envs=4, max_samples=8, max_hours=0.5, rand_seed=0, num_cpus=2)
    assert (body.num_envs, body.max_hours, body.motion_file, body.num_gpus) == (4, 0.5, None, None)
    with pytest.raises(ValidationError, match="arg_file"):
        LaunchRun()


def test_a_checkbox_field_reaches_the_trainer_only_when_ticked(tmp_path: Path) -> None:
    """`save_int_models`: true is `--save_int_models true`; false (an unticked box) is as not given, so the
    registry's record and the argv are those of a launch without it."""
    settings = Settings(runs_dir=tmp_path / "runs").resolved()
    arg_file = settings.runs_dir / "args" / "x.txt"  # the runs folder's args: inside the allowed folders
    arg_file.parent.mkdir(parents=True)
    arg_file.write_text("--num_envs 2\n")
    ticked = run_config(LaunchRun(arg_file=str(arg_file), save_int_models=True), settings)
    assert ticked == {"arg_file": str(arg_file), "save_int_models": True}
    assert train_command(["t"], ticked, "/r/1")[-2:] == ["--save_int_models", "true"]
    for body in (LaunchRun(arg_file=str(arg_file), save_int_models=False), LaunchRun(arg_file=str(arg_file))):
        assert run_config(body, settings) == {"arg_file": str(arg_file)}


def test_the_fields_as_the_page_gets_them() -> None:
    fields = {f.name: f.to_json() for f in LAUNCH_FIELDS}
    envs = fields["num_envs"]
    assert (envs["type"], envs["min"], envs["max"], envs["flag"], envs["sweepable"]) == (
        "integer",
        1,
        65536,
        "--num_envs",
        True,
    )
    widget = {"kind": "number", "id": "num-envs", "label": "envs", "placeholder": "default", "row": "budget"}
    assert envs["widget"] == {**widget, "step": "1"}
    hours = fields["max_hours"]
    assert (hours["type"], hours["min"], hours["widget"]["step"]) == ("number", 0, "any")
    assert "--max_hours" in hours["help"] and fields["num_cpus"]["flag"] is None
    assert fields["arg_file"]["required"] and fields["arg_file"]["widget"]["kind"] == "select"
    assert fields["name"]["widget"]["id"] == "run-name" and not fields["name"]["sweepable"]
    keep = fields["save_int_models"]
    assert (keep["type"], keep["flag"], keep["default"]) == ("boolean", "--save_int_models", None)
    assert keep["sweepable"] is False
    widget = keep["widget"]
    assert (widget["kind"], widget["id"], widget["step"]) == ("checkbox", "save-int-models", None)
