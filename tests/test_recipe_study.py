"""benchmarks/recipe_study.py's pure parts (marks, recipes, arguments, the table) and its one-line
refusals; no training (the end-to-end smoke run is the command in the script's docstring)."""

from __future__ import annotations

import csv
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "recipe_study.py"
_spec = importlib.util.spec_from_file_location("recipe_study", SCRIPT)
study = importlib.util.module_from_spec(_spec)
sys.modules["recipe_study"] = study  # its dataclasses look their module up
_spec.loader.exec_module(study)

WALK = "--arg_file args/deepmimic_humanoid_walk_ppo_args.txt"


def row(recipe: str, mark_h: float, wall_h: float, e_pos: float | None = 0.05) -> dict:
    return {
        "recipe": recipe, "mark_h": mark_h, "wall_h": wall_h, "samples": 8192, "iteration": 1,
        "e_pos_m": e_pos, "dof_vel_err": 1.5, "episode_length": 120.5, "full_episodes": 3, "episodes": 64,
        "load1_mean": 3.2, "load1_max": 4.0, "trainer_cpu": 1.1, "cores": 2,
    }  # fmt: skip


def test_marks_every_interval_and_the_budget_end() -> None:
    assert study.mark_hours(45, 15) == [0.25, 0.5, 0.75]
    assert study.mark_hours(50, 15) == [0.25, 0.5, 0.75, 50 / 60]  # the end of the budget is a mark too
    assert study.mark_hours(2, 1) == [1 / 60, 2 / 60]
    assert study.mark_hours(0.5, 1) == [0.5 / 60]
    assert [study.mark_name(h) for h in study.mark_hours(2, 1)] == ["mark_000060s", "mark_000120s"]


@pytest.mark.parametrize(("minutes", "every"), [(0, 10), (60, 0), (-1, 10), (float("nan"), 10), (60, float("inf"))])
def test_marks_refuse_a_budget_not_finite_and_above_zero(minutes: float, every: float) -> None:
    with pytest.raises(study.StudyError, match="must be finite and > 0"):
        study.mark_hours(minutes, every)


def test_marks_refuse_too_many() -> None:
    with pytest.raises(study.StudyError, match="2000 marks .* at most 1000"):
        study.mark_hours(2000, 1)


def test_recipe_splits_train_arguments_from_agent_overrides() -> None:
    r = study.parse_recipe(f"few_epochs={WALK} --num_envs 512 agent.actor_epochs=2 agent.model.action_std=0.1")
    assert r.name == "few_epochs"
    assert r.train_args == ["--arg_file", "args/deepmimic_humanoid_walk_ppo_args.txt", "--num_envs", "512"]
    assert r.agent_set == {"actor_epochs": "2", "model.action_std": "0.1"}


@pytest.mark.parametrize(
    ("text", "says"),
    [
        (WALK, "expected NAME=ARGS"),
        (f"a/b={WALK}", "expected NAME=ARGS"),
        ("x=--num_envs 4", "give --arg_file"),
        (f"x={WALK} --max_hours 2", "--max_hours is set by the harness"),
        (f"x={WALK} agent.actor_epochs", "expected agent.KEY=VALUE"),
    ],
)
def test_recipe_refusals_are_one_line(text: str, says: str) -> None:
    with pytest.raises(study.StudyError, match=says):
        study.parse_recipe(text)


def test_with_args_replaces_a_key_and_puts_it_first() -> None:
    tokens = ["--arg_file", "a.txt", "--num_envs", "512", "--data_dir", "d"]
    out = study.with_args(tokens, num_envs="32", rand_seed="0")
    # first on the command line: the trainer keeps a key's first value
    assert out == ["--num_envs", "32", "--rand_seed", "0", "--arg_file", "a.txt", "--data_dir", "d"]


def test_agent_override_writes_the_changed_yaml(tmp_path: Path) -> None:
    import yaml

    recipe = study.parse_recipe(f"r={WALK} agent.actor_epochs=2 agent.model.action_std=0.1")
    args = study.agent_yaml(recipe, None, tmp_path / "agent.yaml")
    assert args[:2] == ["--agent_config", str(tmp_path / "agent.yaml")]
    written = yaml.safe_load((tmp_path / "agent.yaml").read_text())
    assert written["actor_epochs"] == 2 and written["model"]["action_std"] == 0.1
    assert written["critic_epochs"] == 2  # the rest is the arg file's agent yaml
    bad = study.parse_recipe(f"r={WALK} agent.nosuch.key=1")
    with pytest.raises(study.StudyError, match="no section 'nosuch'"):
        study.agent_yaml(bad, None, tmp_path / "bad.yaml")
    bad = study.parse_recipe(f"r={WALK} agent.actor_epochs=[")
    with pytest.raises(study.StudyError, match=r"agent.actor_epochs='\[': not a yaml value"):
        study.agent_yaml(bad, None, tmp_path / "bad.yaml")
    bad = study.parse_recipe("r=--agent_config /nonexistent/agent.yaml agent.actor_epochs=2")
    with pytest.raises(study.StudyError, match="r: cannot read /nonexistent/agent.yaml"):
        study.agent_yaml(bad, None, tmp_path / "bad.yaml")


def test_mark_row_reads_the_test_json_and_the_checkpoint() -> None:
    test = {
        "episodes": 64, "mean_episode_length": 250.0, "episode_ends": {"time": 40, "succ": 2, "fail": 22},
        "tracking": {"paper_pos_err_m": 0.031, "paper_dof_vel_err": 1.2},
    }  # fmt: skip
    state = {"wall_time_hours": 0.2512, "samples": 100, "iteration": 3}
    load = {"load1_mean": 2.5, "load1_max": 3.0, "trainer_cpu": 1.4, "cores": 2, "segment_s": 900}
    r = study.mark_row("base", 0.25, state, load, test)
    assert (r["e_pos_m"], r["dof_vel_err"], r["episode_length"], r["full_episodes"]) == (0.031, 1.2, 250.0, 42)
    assert (r["wall_h"], r["samples"], r["load1_mean"], r["trainer_cpu"]) == (0.2512, 100, 2.5, 1.4)
    assert study.mark_row("b", 0.25, state, {}, {"episodes": 1})["e_pos_m"] is None  # a run resumed mid-way


def test_table_orders_by_mark_then_recipe_and_plots_each_recipe(tmp_path: Path) -> None:
    rows = [row("b", 0.5, 0.51), row("a", 0.5, 0.52), row("b", 0.25, 0.26), row("a", 0.25, 0.27, None)]
    lines = study.markdown(rows).splitlines()
    assert lines[0].startswith("| recipe | mark_h | wall_h |")
    assert [line.split(" | ")[0:2] for line in lines[2:]] == [["| a", "0.250"], ["| b", "0.250"], ["| a", "0.500"],
                                                               ["| b", "0.500"]]  # fmt: skip
    assert "| – |" in lines[2]  # a missing figure is a dash
    study.write_csv(rows, tmp_path / "t.csv")
    with open(tmp_path / "t.csv") as f:
        read = list(csv.DictReader(f))
    assert [(r["recipe"], r["mark_h"]) for r in read] == [("a", "0.25"), ("b", "0.25"), ("a", "0.5"), ("b", "0.5")]
    assert study.series(rows, "e_pos_m") == {"b": ([0.26, 0.51], [0.05, 0.05]), "a": ([0.52], [0.05])}
    study.plot(rows, tmp_path / "p.png")
    assert (tmp_path / "p.png").read_bytes()[:4] == b"\x89PNG"


def run_script(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, timeout=120)


@pytest.mark.integration
def test_cli_bad_recipe_is_one_error_line(tmp_path: Path) -> None:
    r = run_script("--out_dir", str(tmp_path / "o"), "--recipe", f"a={WALK} --out_dir x")
    assert r.returncode == 1
    assert r.stderr.strip() == "error: --recipe a: --out_dir is set by the harness; leave it out"
    r = run_script("--out_dir", str(tmp_path / "o"), "--recipe", f"a={WALK}", "--recipe", f"a={WALK}")
    assert r.stderr.strip() == "error: --recipe names repeat: a, a"


@pytest.mark.integration
def test_cli_refuses_an_existing_folder_without_resume_and_other_args_with_it(tmp_path: Path) -> None:
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "recipe.json").write_text(
        '{"name": "a", "train_args": ["--arg_file", "other.txt"], "agent_set": {}}'
    )
    r = run_script("--out_dir", str(tmp_path), "--recipe", f"a={WALK}")
    assert r.returncode == 1 and "exists: give --resume" in r.stderr and r.stderr.count("\n") == 1
    r = run_script("--out_dir", str(tmp_path), "--recipe", f"a={WALK}", "--resume")
    assert r.returncode == 1 and "recorded with other arguments" in r.stderr and r.stderr.count("\n") == 1


@pytest.mark.integration
def test_cli_a_refused_training_is_its_last_line(tmp_path: Path) -> None:
    r = run_script("--out_dir", str(tmp_path), "--minutes", "1", "--recipe", f"a={WALK} --num_envs 0")
    assert r.returncode == 1 and r.stderr.count("\n") == 1
    assert r.stderr.startswith("error: train exited with 2 (error: --num_envs must be an integer between 1 and")
    assert str(tmp_path / "a" / "train" / "console.log") in r.stderr
