"""Recipe study (issue 35): several training recipes, each for the same wall time, tested at fixed marks.

Each recipe is a name and its `mimickit train` arguments; `agent.KEY=VALUE` tokens among them change the
recipe's agent yaml (dotted keys reach nested ones: `agent.model.action_std=0.1`), written to the recipe's
folder and passed as `--agent_config`. The recipes train one after the other (never concurrently), at
`nice 19`. At every mark (every `--every_min` minutes of the run's recorded wall time, metrics.jsonl's
`wall_time`) the deterministic test (`mimickit test --num_envs 32 --test_episodes 64 --rand_seed 0 --json`)
scores the checkpoint of that moment.

Testing pauses training: each mark is one trainer segment (`--max_hours MARK`, resumed from the
segment before with `--model_file`), its `model.pt` copied to `marks/`, then tested while no trainer
runs. So the test neither steals CPU from the trainer nor moves its clock (the recorded wall time counts
only the trainer's own `train_model` time; a segment's start-up and the test between segments are
outside it). A segment ends at the first iteration past its mark, after the trainer's own output test
(`test_episodes` of the agent yaml), so a mark's checkpoint is a few seconds past it: the table gives
its recorded wall time. Beside each row: the 1-minute load average sampled every 10 s during the
segment (mean and max), and the trainer's CPU share (its CPU seconds over the segment's wall seconds,
in cores).

Output under `--out_dir`: one folder per recipe (`recipe.json`, `train/` the run folder, `marks/`
the checkpoints, their load and test records), `table.csv`, `table.md` and `plot.png` (e_pos, DoF
velocity error and episode length against recorded wall hours, the recipes side by side). `--resume`
continues where a run stopped (a mark already tested is kept; a recipe's training resumes from its
`train/model.pt`); with every mark done it only rebuilds the table and the plot.

    # the smoke run (2 recipes x 2 minutes, marks every minute, 4 envs, 8 test episodes)
    python benchmarks/recipe_study.py --out_dir /tmp/recipe_study/smoke --minutes 2 --every_min 1 \\
        --test_envs 4 --test_episodes 8 --data_dir ../shared/data \\
        --recipe "base=--arg_file args/deepmimic_humanoid_walk_ppo_args.txt --num_envs 4" \\
        --recipe "epochs2=--arg_file args/deepmimic_humanoid_walk_ppo_args.txt --num_envs 4 agent.actor_epochs=2"
    # the first baseline (docs/benchmarks.md): the default walk recipe, 45 minutes, marks every 15
    python benchmarks/recipe_study.py --out_dir /tmp/recipe_study/walk --minutes 45 --every_min 15 \\
        --data_dir ../shared/data --recipe "default=--arg_file args/deepmimic_humanoid_walk_ppo_args.txt"
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

ROOT = Path(__file__).resolve().parents[1]
MIMICKIT = ["nice", "-n", "19", sys.executable, "-m", "mimickit.cli"]
HARNESS_KEYS = ("out_dir", "model_file", "max_hours", "max_samples", "mode")  # the harness sets these
LOAD_SAMPLE_S = 10.0
MAX_MARKS = 1000
COLUMNS = [
    "recipe", "mark_h", "wall_h", "samples", "iteration", "e_pos_m", "dof_vel_err", "episode_length",
    "full_episodes", "episodes", "load1_mean", "load1_max", "trainer_cpu", "cores",
]  # fmt: skip


class StudyError(Exception):
    """Bad input or a failed step: one line for the user."""


def short(text: str, limit: int = 160) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


@dataclass(frozen=True)
class Recipe:
    name: str
    train_args: list[str]
    """`mimickit train` arguments (without the `agent.KEY=VALUE` tokens)."""
    agent_set: dict[str, str] = field(default_factory=dict)
    """Agent yaml overrides: dotted key -> yaml value text."""


def parse_recipe(text: str) -> Recipe:
    """`NAME=ARGS`: a folder-safe name, then `mimickit train` arguments and `agent.KEY=VALUE` tokens."""
    name, sep, rest = text.partition("=")
    name = name.strip()
    if not sep or not name or not all(c.isalnum() or c in "_-." for c in name) or name.startswith("."):
        raise StudyError(f"--recipe {short(text)!r}: expected NAME=ARGS with a name of letters, digits, _ - .")
    try:
        tokens = shlex.split(rest)
    except ValueError as e:
        raise StudyError(f"--recipe {name}: {e}") from None
    args, agent_set = [], {}
    for tok in tokens:
        if tok.startswith("agent."):
            key, eq, value = tok[len("agent.") :].partition("=")
            if not eq or not key:
                raise StudyError(f"--recipe {name}: {short(tok)!r}: expected agent.KEY=VALUE")
            agent_set[key] = value
        else:
            args.append(tok)
    for key in HARNESS_KEYS:
        if f"--{key}" in args:
            raise StudyError(f"--recipe {name}: --{key} is set by the harness; leave it out")
    if "--arg_file" not in args and "--agent_config" not in args:
        raise StudyError(f"--recipe {name}: give --arg_file (or the configs) of the recipe")
    return Recipe(name, args, agent_set)


def mark_hours(minutes: float, every_min: float) -> list[float]:
    """The wall-time marks in hours: every `every_min` minutes, and the budget's end (`minutes`)."""
    if not (0 < minutes < math.inf and 0 < every_min < math.inf):
        raise StudyError(f"--minutes and --every_min must be finite and > 0 (got {minutes:g} and {every_min:g})")
    count = int(minutes / every_min + 1e-9)
    if count > MAX_MARKS:
        raise StudyError(f"{count} marks ({minutes:g} min every {every_min:g} min): at most {MAX_MARKS}")
    marks = [round(every_min * i, 6) for i in range(1, count + 1)]
    if not marks or marks[-1] < minutes - 1e-6:
        marks.append(round(minutes, 6))
    return [m / 60.0 for m in marks]


def mark_name(hours: float) -> str:
    return f"mark_{round(hours * 3600):06d}s"


def with_args(tokens: list[str], **values: str) -> list[str]:
    """`tokens` with each `--key` of `values` removed (with its values) and set to the given value,
    first: the trainer's parser keeps the first value of a key, and the command line wins over the arg file."""
    out: list[str] = []
    skipping = False
    for tok in tokens:
        if tok.startswith("--") and len(tok) > 2:
            skipping = tok[2:] in values
        if not skipping:
            out.append(tok)
    return [tok for key, value in values.items() for tok in (f"--{key}", value)] + out


def set_dotted(config: dict[str, Any], key: str, value_text: str) -> None:
    """config[a][b]... = the yaml value of `value_text` for `key` "a.b..."; a missing parent is an error."""
    *parents, last = key.split(".")
    node = config
    for part in parents:
        node = node.get(part) if isinstance(node, dict) else None
        if not isinstance(node, dict):
            raise StudyError(f"agent.{short(key)}: the agent yaml has no section {part!r}")
    try:
        node[last] = yaml.safe_load(value_text)
    except yaml.YAMLError:
        raise StudyError(f"agent.{short(key)}={short(value_text)!r}: not a yaml value") from None


def agent_yaml(recipe: Recipe, data_dir: str | None, out: Path) -> list[str]:
    """The recipe's train arguments, with `--agent_config` pointing at its changed yaml (written to `out`)."""
    if not recipe.agent_set:
        return recipe.train_args
    from mimickit.util.arg_parser import ArgParser
    from mimickit.util.errors import MimicKitError
    from mimickit.util.paths import DataPaths

    paths = DataPaths(Path(data_dir) if data_dir else None)
    parser = ArgParser(paths)
    try:
        parser.load_args(recipe.train_args)
    except MimicKitError as e:
        raise StudyError(f"--recipe {recipe.name}: {e}") from None
    base = parser.parse_string("agent_config")
    if not base:
        raise StudyError(f"--recipe {recipe.name}: no --agent_config to change (agent.KEY=VALUE)")
    try:
        config = yaml.safe_load(paths.resolve(base).read_text())
    except (OSError, yaml.YAMLError) as e:
        raise StudyError(f"--recipe {recipe.name}: cannot read {short(base)}: {short(str(e))}") from None
    if not isinstance(config, dict):
        raise StudyError(f"--recipe {recipe.name}: {short(base)} is not a yaml mapping")
    for key, value in recipe.agent_set.items():
        set_dotted(config, key, value)
    out.write_text(f"# {base} with {json.dumps(recipe.agent_set)}\n" + yaml.safe_dump(config, sort_keys=False))
    return with_args(recipe.train_args, agent_config=str(out))


# ------------------------------------------------------------------ one recipe


def checkpoint_state(model: Path) -> dict[str, Any]:
    """The checkpoint's train state: iteration, samples, wall_time_hours (recorded)."""
    from mimickit.learning.checkpoint import TRAIN_STATE_KEY, read_checkpoint

    return read_checkpoint(model)[TRAIN_STATE_KEY]


def train_segment(args: list[str], run_dir: Path, hours: float) -> dict[str, float]:
    """Train (or resume) the run in `run_dir` until its recorded wall time reaches `hours`, at nice 19;
    the load and the trainer's CPU share over the segment."""
    model = run_dir / "model.pt"
    resume = {"model_file": str(model)} if model.is_file() else {}
    cmd = [*MIMICKIT, "train", *with_args(args, out_dir=str(run_dir), max_hours=f"{hours:.6f}", **resume)]
    print("$", shlex.join(cmd), flush=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start, loads = time.monotonic(), []
    with open(run_dir / "console.log", "a") as log:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT)
        try:
            while proc.poll() is None:
                loads.append(os.getloadavg()[0])
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(timeout=LOAD_SAMPLE_S)
        finally:
            if proc.poll() is None:  # the harness was stopped: the trainer saves model.pt and exits
                proc.send_signal(signal.SIGTERM)
                proc.wait()
    elapsed = time.monotonic() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        last = last_line(run_dir / "console.log")
        raise StudyError(f"train exited with {proc.returncode} ({short(last)}); see {run_dir / 'console.log'}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {
        "segment_s": round(elapsed, 1),
        "load1_mean": round(sum(loads) / len(loads), 2),
        "load1_max": round(max(loads), 2),
        "trainer_cpu": round(cpu / elapsed, 2),
        "cores": os.cpu_count() or 0,
    }


def last_line(path: Path) -> str:
    """The last non-empty line of a log that may be long (its last 4 KiB are read)."""
    with open(path, "rb") as f:
        f.seek(max(0, f.seek(0, os.SEEK_END) - 4096))
        lines = f.read().decode(errors="replace").strip().splitlines()
    return lines[-1] if lines else "(no output)"


def run_test(args: list[str], model: Path, envs: int, episodes: int) -> dict[str, Any]:
    """The deterministic test of `model` (a fresh process, seed 0): `mimickit test --json`'s object."""
    test_args = with_args(args, num_envs=str(envs), test_episodes=str(episodes), rand_seed="0", model_file=str(model))
    cmd = [*MIMICKIT, "test", *test_args, "--json"]
    print("$", shlex.join(cmd), flush=True)
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["(no output)"])[-1]
        raise StudyError(f"test of {model} failed: {short(last)}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def mark_row(recipe: str, hours: float, state: dict[str, Any], load: dict[str, Any], test: dict[str, Any]) -> dict:
    """One table row: the checkpoint of a mark, its test and the load while it trained."""
    tracking = test.get("tracking") or {}
    ends = test.get("episode_ends") or {}
    return {
        "recipe": recipe,
        "mark_h": round(hours, 4),
        "wall_h": round(state["wall_time_hours"], 4),
        "samples": state["samples"],
        "iteration": state["iteration"],
        "e_pos_m": tracking.get("paper_pos_err_m"),
        "dof_vel_err": tracking.get("paper_dof_vel_err"),
        "episode_length": test.get("mean_episode_length"),
        "full_episodes": ends.get("time", 0) + ends.get("succ", 0),
        "episodes": test.get("episodes"),
        **{k: load.get(k) for k in ("load1_mean", "load1_max", "trainer_cpu", "cores")},
    }


def run_recipe(recipe: Recipe, folder: Path, marks: list[float], opts: argparse.Namespace) -> list[dict]:
    """Train `recipe` mark by mark in `folder` and test each mark's checkpoint; its table rows."""
    (folder / "marks").mkdir(parents=True, exist_ok=True)
    args = agent_yaml(recipe, opts.data_dir, folder / "agent_config.yaml")
    if opts.data_dir and "--data_dir" not in args:
        args = [*args, "--data_dir", opts.data_dir]
    run_dir, rows = folder / "train", []
    for hours in marks:
        name = folder / "marks" / mark_name(hours)
        row_file, model, load_file = name.with_suffix(".json"), name.with_suffix(".pt"), name.with_suffix(".load.json")
        if not row_file.is_file():
            if not model.is_file():
                done = (
                    checkpoint_state(run_dir / "model.pt")["wall_time_hours"]
                    if (run_dir / "model.pt").is_file()
                    else 0.0
                )
                if done < hours:  # else the trainer already passed this mark (stopped before its copy)
                    load_file.write_text(json.dumps(train_segment(args, run_dir, hours)))
                shutil.copyfile(run_dir / "model.pt", model)
            load = json.loads(load_file.read_text()) if load_file.is_file() else {}
            test = run_test(args, model, opts.test_envs, opts.test_episodes)
            row_file.write_text(json.dumps(mark_row(recipe.name, hours, checkpoint_state(model), load, test)))
        rows.append(json.loads(row_file.read_text()))
        print(markdown([rows[-1]]).splitlines()[-1], flush=True)
    return rows


def open_recipe_folder(recipe: Recipe, folder: Path, resume: bool) -> None:
    """A fresh folder for the recipe, or (--resume) its own folder: the same recipe as recorded."""
    record = folder / "recipe.json"
    if record.is_file():
        if not resume:
            raise StudyError(f"{folder} exists: give --resume to continue it, or another --out_dir")
        if json.loads(record.read_text()) != asdict(recipe):
            raise StudyError(
                f"{record}: recorded with other arguments than --recipe {recipe.name}; use another --out_dir"
            )
        return
    folder.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps(asdict(recipe), indent=1) + "\n")


# ------------------------------------------------------------------ table and plot


def fmt_cell(value: Any) -> str:
    if value is None:
        return "–"
    if isinstance(value, float):
        return f"{value:.3f}" if abs(value) < 100 else f"{value:.0f}"
    return str(value)


def markdown(rows: list[dict]) -> str:
    """The rows as a markdown table, ordered by mark then recipe (a mark's recipes side by side)."""
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for row in sorted(rows, key=lambda r: (r["mark_h"], r["recipe"])):
        lines.append("| " + " | ".join(fmt_cell(row.get(c)) for c in COLUMNS) + " |")
    return "\n".join(lines)


def write_csv(rows: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(sorted(rows, key=lambda r: (r["mark_h"], r["recipe"])))


def series(rows: list[dict], key: str) -> dict[str, tuple[list[float], list[float]]]:
    """recipe -> (recorded wall hours, `key`) in wall-time order, rows without `key` left out."""
    out: dict[str, tuple[list[float], list[float]]] = {}
    for row in sorted(rows, key=lambda r: r["wall_h"]):
        if row.get(key) is not None:
            xs, ys = out.setdefault(row["recipe"], ([], []))
            xs.append(row["wall_h"])
            ys.append(row[key])
    return out


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [("e_pos_m", "test e_pos (paper_pos_err_m, m)"), ("dof_vel_err", "test DoF vel error (paper_dof_vel_err)"),
              ("episode_length", "test mean episode length (steps)")]  # fmt: skip
    fig, axes = plt.subplots(1, len(panels), figsize=(13, 3.6))
    for ax, (key, title) in zip(axes, panels, strict=True):
        for recipe, (xs, ys) in series(rows, key).items():
            ax.plot(xs, ys, marker="o", label=recipe)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel("recorded wall time (h)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# ------------------------------------------------------------------ main


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--recipe", action="append", required=True, help="NAME=ARGS (repeat): train arguments")
    p.add_argument("--out_dir", type=Path, required=True, help="one folder per recipe, the table and the plot")
    p.add_argument("--minutes", type=float, default=60.0, help="recorded wall time each recipe trains")
    p.add_argument("--every_min", type=float, default=10.0, help="minutes of recorded wall time between marks")
    p.add_argument("--test_envs", type=int, default=32)
    p.add_argument("--test_episodes", type=int, default=64)
    p.add_argument("--data_dir", help="MimicKit's data folder, passed to every recipe that gives none")
    p.add_argument("--resume", action="store_true", help="continue the recipes' folders in --out_dir")
    opts = p.parse_args(argv)
    try:
        recipes = [parse_recipe(t) for t in opts.recipe]
        names = [r.name for r in recipes]
        if len(set(names)) != len(names):
            raise StudyError(f"--recipe names repeat: {short(', '.join(names))}")
        marks = mark_hours(opts.minutes, opts.every_min)
        out = opts.out_dir.resolve()
        for recipe in recipes:
            open_recipe_folder(recipe, out / recipe.name, opts.resume)
        rows = [row for recipe in recipes for row in run_recipe(recipe, out / recipe.name, marks, opts)]
    except StudyError as e:
        sys.exit(f"error: {e}")
    except KeyboardInterrupt:
        sys.exit("stopped: --resume continues it")
    (out / "table.md").write_text(markdown(rows) + "\n")
    write_csv(rows, out / "table.csv")
    plot(rows, out / "plot.png")
    print(f"\n{markdown(rows)}\n\nwrote {out / 'table.md'}, {out / 'table.csv'}, {out / 'plot.png'}")


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, signal.default_int_handler)  # a SIGTERM stops the trainer as Ctrl-C does
    main()
