"""`mimickit eval`: a checkpoint's deterministic policy on each clip of a dataset, one row per clip.

Each clip gets an env of its own (the arg file's configs with `motion_file` replaced by that one clip,
as `mimickit test --motion_file` does), the checkpoint loaded into a fresh agent, and the test episodes
of `mimickit test` (`runner.policy.test_result`: the agent's `test_model`, the env's tracking errors and how the
episodes ended). Every clip starts from the same seed, so a row does not depend on the clips before it.

A row: `clip` (the path as the dataset writes it), `weight`, `episodes` (every finished one counts, so
it can exceed the number asked for), `mean_ep_len` (control steps), `full_length_frac` (episodes that
ran to the time limit or to the end of a non-looping clip, i.e. did not fail), `mean_return`,
`pos_err_m` (the reference code's root-relative body position error), `paper_pos_err_m` and
`paper_dof_vel_err` (the paper's Table 1 errors, `deepmimic_rewards.paper_errors`); the errors are
means over every test env-step. `mean` is the episode-weighted mean of the rows.
"""

from __future__ import annotations

import argparse
import json
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths

DEFAULT_EPISODES = 8
MAX_DEFAULT_ENVS = 16
"""`--num_envs` by default is `--episodes`, at most this many (more envs than cores buy little)."""
DEVICE = "cpu"
MEAN_KEYS = ("mean_ep_len", "full_length_frac", "mean_return", "pos_err_m", "paper_pos_err_m", "paper_dof_vel_err")
_TABLE = (  # (key, header, format)
    ("weight", "weight", "{:g}"),
    ("episodes", "episodes", "{:d}"),
    ("mean_ep_len", "mean_ep_len", "{:.1f}"),
    ("full_length_frac", "full_length", "{:.0%}"),
    ("pos_err_m", "pos_err_m", "{:.4f}"),
    ("paper_pos_err_m", "paper_pos_err_m", "{:.4f}"),
    ("paper_dof_vel_err", "paper_dof_vel_err", "{:.4f}"),
)


@dataclass(frozen=True)
class EvalOptions:
    motion_file: str | None = None
    """A clip or a dataset yaml; None: the env config's own `motion_file` (or the arg file's)."""
    episodes: int = DEFAULT_EPISODES
    num_envs: int | None = None
    rand_seed: int = 0
    data_dir: str | None = None


@dataclass(frozen=True)
class EvalClip:
    name: str
    """As the dataset (or `--motion_file`, or the env config) writes it."""
    path: Path
    weight: float


def evaluate(arg_file: str, model_file: str, opts: EvalOptions) -> dict[str, Any]:
    """{"rows": one per clip, "mean": their episode-weighted mean}; one MimicKitError for bad input
    (arguments, configs, a clip, a dataset or a checkpoint), before any clip runs where it can be found."""
    from mimickit.runner.args import check_run_args
    from mimickit.runner.inputs import resolve_inputs

    for name, value in (("--episodes", opts.episodes), ("--num_envs", opts.num_envs or 1)):
        if value < 1:
            raise MimicKitError(f"{name} must be at least 1, got {value}")
    paths = DataPaths(opts.data_dir)
    num_envs = opts.num_envs or min(opts.episodes, MAX_DEFAULT_ENVS)
    args = _run_args(arg_file, model_file, opts, num_envs, paths)
    check_run_args(args, probe_out_dir=False)  # the arg file's keys, the counts, --model_file
    inputs = resolve_inputs(args, paths)
    given = args.parse_string("motion_file", "") or None  # --motion_file, or the arg file's
    clips = dataset_clips(inputs.motion_file or _env_motion_file(inputs), given=given, data_paths=paths)
    _check_clips(clips)
    rows = [_eval_clip(inputs, model_file, clip, num_envs, opts) for clip in clips]
    return {"rows": rows, "mean": weighted_mean(rows)}


def _run_args(arg_file: str, model_file: str, opts: EvalOptions, num_envs: int, data_paths: DataPaths):  # -> ArgParser
    from mimickit.util.arg_parser import ArgParser

    argv = ["--arg_file", arg_file, "--mode", "test", "--model_file", model_file]
    argv += ["--num_envs", str(num_envs), "--test_episodes", str(opts.episodes), "--rand_seed", str(opts.rand_seed)]
    if opts.motion_file is not None:
        argv += ["--motion_file", opts.motion_file]
    args = ArgParser(data_paths)
    args.load_args(argv)
    return args


def _env_motion_file(inputs: Any) -> str:
    from mimickit.envs.env_builder import load_env_configs

    env_cfg, _ = load_env_configs(inputs.env_file, inputs.engine_file)
    motion = getattr(env_cfg, "motion_file", None)
    if not motion:
        raise MimicKitError(f"env {env_cfg.env_name!r} ({inputs.env_file}) has no reference motion to evaluate on")
    return motion


def dataset_clips(motion_file: str, given: str | None = None, data_paths: DataPaths = PROJECT_DATA) -> list[EvalClip]:
    """The clips of a dataset yaml (each entry, in order, duplicates kept) or the one clip `motion_file`;
    `given` is how the user wrote a single clip's path (the name of its row); `data_paths` finds
    `data/...` names."""
    from mimickit.anim.motion_lib import DatasetConfig, load_motion_list
    from mimickit.util.config import load_config

    entries = load_motion_list(motion_file, data_paths)  # checks every entry's file exists, one line naming it
    path = data_paths.resolve(motion_file)
    if path.suffix in (".yaml", ".yml"):
        names = [e.file for e in load_config(DatasetConfig, path).motions]
    else:
        names = [given or motion_file]
    return [EvalClip(n, p, w) for n, (p, w) in zip(names, entries, strict=True)]


def _check_clips(clips: list[EvalClip]) -> None:
    """Each distinct clip parsed once in a bounded child process (the clips are untrusted files): a bad
    one is refused before anything runs, and a hostile one cannot hang or exhaust this process."""
    from mimickit.anim.motion import load_motion_guarded

    with warnings.catch_warnings():  # a clip's warnings (NaN columns) come once, when its env loads it
        warnings.simplefilter("ignore")
        for path in dict.fromkeys(c.path for c in clips):
            load_motion_guarded(path)


def _eval_clip(inputs: Any, model_file: str, clip: EvalClip, num_envs: int, opts: EvalOptions) -> dict[str, Any]:
    from mimickit.runner.policy import load_policy, test_result
    from mimickit.runner.seeding import seed_everything
    from mimickit.util.arg_parser import ArgParser

    seed_everything(ArgParser(), 0, opts.rand_seed)
    env, agent = load_policy(replace(inputs, motion_file=str(clip.path)), model_file, num_envs, DEVICE)
    try:
        result = test_result(agent, env, opts.episodes)
    finally:
        env.engine.close()
    return clip_row(clip, result)


def clip_row(clip: EvalClip, result: dict[str, Any]) -> dict[str, Any]:
    """A row from `test_result`'s dict (its `episode_ends` counts say which episodes failed)."""
    ends, tracking = result["episode_ends"], result["tracking"]
    if "paper_pos_err_m" not in tracking or not ends:
        raise MimicKitError(f"{clip.name}: the env reports no tracking errors (it needs a DeepMimic-family env)")
    ended = sum(ends.values())
    return {
        "clip": clip.name,
        "weight": clip.weight,
        "episodes": result["episodes"],
        "mean_ep_len": result["mean_episode_length"],
        "full_length_frac": (ended - ends["fail"]) / ended if ended else 0.0,
        "mean_return": result["mean_return"],
        "pos_err_m": tracking["pos_err_m"],
        "paper_pos_err_m": tracking["paper_pos_err_m"],
        "paper_dof_vel_err": tracking["paper_dof_vel_err"],
    }


def weighted_mean(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The rows' `MEAN_KEYS` weighted by their episodes, with the clip and episode totals."""
    total = sum(r["episodes"] for r in rows)
    mean: dict[str, Any] = {"clips": len(rows), "episodes": total}
    for key in MEAN_KEYS:
        mean[key] = sum(r[key] * r["episodes"] for r in rows) / total if total else 0.0
    return mean


def format_table(report: dict[str, Any]) -> str:
    """The rows and their mean as an aligned text table."""
    mean = {**report["mean"], "clip": f"mean ({report['mean']['clips']} clips)", "weight": ""}
    body = [[r["clip"], *(fmt.format(r[k]) for k, _, fmt in _TABLE)] for r in report["rows"]]
    body.append([mean["clip"], "", *(fmt.format(mean[k]) for k, _, fmt in _TABLE[1:])])
    header = ["clip", *(h for _, h, _ in _TABLE)]
    widths = [max(len(row[i]) for row in [header, *body]) for i in range(len(header))]

    def line(cells: list[str]) -> str:
        return "  ".join([cells[0].ljust(widths[0]), *(c.rjust(w) for c, w in zip(cells[1:], widths[1:], strict=True))])

    return "\n".join(line(row) for row in [header, *body])


def add_eval_parser(sub: Any) -> None:
    """`mimickit eval` in the CLI's subparsers."""
    p = sub.add_parser(
        "eval", help="a checkpoint's policy on each clip of a dataset: one row of episode and error figures per clip"
    )
    p.add_argument("--arg_file", required=True, help="arg file naming the env, agent and engine configs of the model")
    p.add_argument("--model_file", required=True, help="checkpoint (.pt)")
    p.add_argument("--motion_file", help="a clip (.pkl) or a dataset (.yaml); default: the env config's motion_file")
    p.add_argument("--episodes", type=int, default=DEFAULT_EPISODES, help="test episodes per clip (at least)")
    p.add_argument("--num_envs", type=int, help=f"envs per clip (default: --episodes, at most {MAX_DEFAULT_ENVS})")
    p.add_argument("--rand_seed", type=int, default=0, help="seed of every clip's episodes (start times)")
    p.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    p.add_argument("--json", action="store_true", help='print {"rows": [...], "mean": {...}}')
    p.set_defaults(func=eval_command)


def eval_command(args: argparse.Namespace) -> int:
    opts = EvalOptions(args.motion_file, args.episodes, args.num_envs, args.rand_seed, args.data_dir)
    report = evaluate(args.arg_file, args.model_file, opts)
    print(json.dumps(report) if args.json else format_table(report))
    return 0
