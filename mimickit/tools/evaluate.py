"""`mimickit eval`: a checkpoint's deterministic policy on each clip of a dataset, one row per clip.

Each clip gets an env of its own (the arg file's configs with `motion_file` replaced by that one clip,
as `mimickit test --motion_file` does) and the checkpoint loaded into a fresh agent. Every clip starts
from the same seed, so a row does not depend on the clips before it.

Which episodes count: exactly `--episodes` per clip. `mimickit test` keeps the reference's rule (every
episode that ends while the slowest env finishes counts, so "2 episodes" can come back as 3); here the
count is fixed in advance, per env: with n envs (at most `--episodes`), env i counts its first
`episodes // n` episodes, plus one more for the first `episodes % n` envs, and whatever it runs after
that is ignored. So the default (`--num_envs` = `--episodes`) counts each env's first episode. The
quota does not depend on how the episodes go: taking the first N episodes to end instead would favour
short ones, i.e. falls and starts just before a clip's end.

A row: `clip` (the path as the dataset writes it), `weight`, `episodes` (the number asked for),
`mean_ep_len` (control steps), `mean_return`, `failed` (counted episodes that ended in a failure: a fall
or a pose termination), `full_length_frac`, the errors, `steps` and `available_steps` (their sums over
the counted episodes).

`full_length_frac` is time-weighted: the counted episodes' control steps / the steps they had
available. An episode's available steps run from its start (reference-state init starts it at a random
time of the clip) to its time limit or, for a clip that does not loop, to the clip's end, whichever
comes first; a failed episode loses the rest of them (rounded up to whole steps). An episode that
starts 0.1 s before a non-looping clip's end has 3 steps available at 30 Hz: it weighs 3 steps, not
one episode. 100% means no counted episode failed.

The errors are means over the counted episodes' control steps (each step's state after its physics;
the reset state, a copy of the reference, is not counted): `pos_err_m` (the reference code's
root-relative body position error), `paper_pos_err_m` and `paper_dof_vel_err` (the paper's Table 1
errors, `deepmimic_rewards.paper_errors`).

`mean` pools the rows, as one row of every counted episode would be: `mean_ep_len` and `mean_return`
weighted by episodes, `full_length_frac` by available steps, the errors by steps.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA, DataPaths

if TYPE_CHECKING:
    import torch  # the tensors of a rollout; imported when one runs

DEFAULT_EPISODES = 8
MAX_DEFAULT_ENVS = 16
"""`--num_envs` by default is `--episodes`, at most this many (more envs than cores buy little)."""
DEVICE = "cpu"
ERROR_KEYS = {
    "pos_err_m": "body_pos_err",
    "paper_pos_err_m": "paper_pos_err_m",
    "paper_dof_vel_err": "paper_dof_vel_err",
}
"""A row's error columns and the env's `info["tracking"]` entries they average."""
MEAN_WEIGHTS = {
    "mean_ep_len": "episodes",
    "mean_return": "episodes",
    "full_length_frac": "available_steps",
    **dict.fromkeys(ERROR_KEYS, "steps"),
}
"""How the mean row pools each column: weighted by the rows' episodes, available steps or steps."""
MEAN_KEYS = tuple(MEAN_WEIGHTS)
SUM_KEYS = ("episodes", "failed", "steps", "available_steps")
FULL_HELP = (
    "full_time: time-weighted full length, the counted episodes' steps / the steps they had available (to "
    "the time limit or a non-looping clip's end, whichever is first); a failure loses the rest of its episode"
)
_TABLE = (  # (key, header, format)
    ("weight", "weight", "{:g}"),
    ("episodes", "episodes", "{:d}"),
    ("failed", "failed", "{:d}"),
    ("mean_ep_len", "mean_ep_len", "{:.1f}"),
    ("full_length_frac", "full_time", "{:.0%}"),
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
    num_envs = min(opts.num_envs or MAX_DEFAULT_ENVS, opts.episodes)  # an env past the quota would count none
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
    from mimickit.runner.policy import load_policy
    from mimickit.runner.seeding import seed_everything
    from mimickit.util.arg_parser import ArgParser

    seed_everything(ArgParser(), 0, opts.rand_seed)
    env, agent = load_policy(replace(inputs, motion_file=str(clip.path)), model_file, num_envs, DEVICE)
    try:
        if not callable(getattr(env, "get_motion_time", None)):
            raise MimicKitError(f"{clip.name}: the env tracks no reference motion (it needs a DeepMimic-family env)")
        totals = count_episodes(agent, env, opts.episodes)
    finally:
        env.engine.close()
    return clip_row(clip, totals)


@dataclass
class EpisodeTotals:
    """Sums over the counted episodes of one clip."""

    episodes: int = 0
    failed: int = 0
    steps: int = 0
    available_steps: int = 0
    returns: float = 0.0
    errors: dict[str, float] = field(default_factory=dict)
    """Per `info["tracking"]` entry, the sum over the counted episodes' steps."""


def episode_quota(episodes: int, num_envs: int) -> list[int]:
    """How many of its first episodes each env counts: `episodes` in all, spread as evenly as they go,
    the first envs taking one more (decided before any step, so outcomes cannot bias the choice)."""
    return [episodes // num_envs + (i < episodes % num_envs) for i in range(num_envs)]


def count_episodes(agent: Any, env: Any, episodes: int) -> EpisodeTotals:
    """Step the deterministic policy (`agent.test_steps`) until every env has ended the episodes its
    quota counts (`episode_quota`); sum those episodes' returns, lengths, available steps and tracking
    errors per step. Later episodes of an env run on (the envs step together) but are not counted."""
    import torch

    from mimickit.envs.base_env import DoneFlags

    n = env.get_num_envs()
    quota = torch.tensor(episode_quota(episodes, n))
    counted = torch.zeros(n, dtype=torch.long)
    ret, length = torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.long)
    names: list[str] = []
    err = torch.zeros(0, n, dtype=torch.float64)
    totals = EpisodeTotals()
    with contextlib.closing(agent.test_steps()) as steps:
        for reward, done, info in steps:
            tracking = info.get("tracking") or {}
            if not names:
                names, err = sorted(tracking), torch.zeros(len(tracking), n, dtype=torch.float64)
            ret += reward.cpu().double()
            length += 1
            if names:
                err += torch.stack([tracking[k].detach().cpu().double() for k in names])
            done = done.cpu()
            ended = done != DoneFlags.NULL
            take = (ended & (counted < quota)).nonzero().flatten()
            if len(take):
                _add_episodes(totals, env, take, done, ret, length, dict(zip(names, err, strict=True)))
            counted += ended.long()
            ret[ended], length[ended], err[:, ended] = 0.0, 0, 0.0
            if bool((counted >= quota).all()):
                break
    return totals


def _add_episodes(
    totals: EpisodeTotals,
    env: Any,
    ids: torch.Tensor,
    done: torch.Tensor,
    ret: torch.Tensor,
    length: torch.Tensor,
    errors: dict[str, torch.Tensor],
) -> None:
    """Add the episodes of envs `ids` that just ended (tensors [N]: done flags, returns, lengths, and
    per tracking entry the error sums) to `totals`."""
    from mimickit.envs.base_env import DoneFlags

    failed = done[ids] == DoneFlags.FAIL
    lengths = length[ids]
    available = lengths.clone()  # an episode that did not fail ran all it had
    if bool(failed.any()):
        fail_ids = ids[failed]
        available[failed] = lengths[failed] + steps_left(env, fail_ids)
    totals.episodes += len(ids)
    totals.failed += int(failed.sum())
    totals.steps += int(lengths.sum())
    totals.available_steps += int(available.sum())
    totals.returns += float(ret[ids].sum())
    for k, v in errors.items():
        totals.errors[k] = totals.errors.get(k, 0.0) + float(v[ids].sum())


def steps_left(env: Any, ids: torch.Tensor) -> torch.Tensor:
    """Control steps envs `ids` had left when they failed, before their episode would have ended by
    itself: at the time limit (`episode_length`) or, for a clip that does not loop, at the clip's end
    (the env's own two ends, `SimEnv._update_done` and `DeepMimicEnv._update_done`)."""
    import torch

    from mimickit.anim.motion import LoopMode

    dev = env.get_motion_time().device
    ids_dev = ids.to(dev)
    dt = env.engine.get_timestep()
    left = env.config.episode_length - env.get_env_time(ids_dev)
    motion_ids = env.get_motion_ids(ids_dev)
    lib = env.motion_lib
    clip_left = lib.get_motion_length(motion_ids) - env.get_motion_time(ids_dev)
    wrap = lib.get_motion_loop_mode(motion_ids) == LoopMode.WRAP
    left = torch.where(wrap, left, torch.minimum(left, clip_left))
    # An end comes at the first step whose time reaches it; 1e-3 of a step absorbs float32 rounding.
    return torch.ceil(left / dt - 1e-3).clamp(min=0).long().cpu()


def clip_row(clip: EvalClip, totals: EpisodeTotals) -> dict[str, Any]:
    """A row from one clip's `EpisodeTotals`."""
    if not all(key in totals.errors for key in ERROR_KEYS.values()) or not totals.episodes:
        raise MimicKitError(f"{clip.name}: the env reports no tracking errors (it needs a DeepMimic-family env)")
    return {
        "clip": clip.name,
        "weight": clip.weight,
        "episodes": totals.episodes,
        "failed": totals.failed,
        "mean_ep_len": totals.steps / totals.episodes,
        "full_length_frac": totals.steps / totals.available_steps if totals.available_steps else 0.0,
        "mean_return": totals.returns / totals.episodes,
        **{key: totals.errors[name] / totals.steps for key, name in ERROR_KEYS.items()},
        "steps": totals.steps,
        "available_steps": totals.available_steps,
    }


def weighted_mean(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """The rows pooled (`MEAN_WEIGHTS`: each column weighted by the rows' episodes, available steps or
    steps), with the clip count and the totals of `SUM_KEYS`."""
    mean: dict[str, Any] = {"clips": len(rows), **{k: sum(r[k] for r in rows) for k in SUM_KEYS}}
    for key, weight in MEAN_WEIGHTS.items():
        total = mean[weight]
        mean[key] = sum(r[key] * r[weight] for r in rows) / total if total else 0.0
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
        "eval",
        help="a checkpoint's policy on each clip of a dataset: one row of episode and error figures per clip",
        description="Columns: episodes (exactly --episodes: each of the n envs counts its first episodes // n "
        "episodes, the first episodes % n envs one more), failed (falls and pose terminations), mean_ep_len "
        f"(control steps), {FULL_HELP}; errors: means over the counted episodes' steps. The mean row pools the "
        "rows (episodes, available steps or steps as weights).",
    )
    p.add_argument("--arg_file", required=True, help="arg file naming the env, agent and engine configs of the model")
    p.add_argument("--model_file", required=True, help="checkpoint (.pt)")
    p.add_argument("--motion_file", help="a clip (.pkl) or a dataset (.yaml); default: the env config's motion_file")
    p.add_argument("--episodes", type=int, default=DEFAULT_EPISODES, help="test episodes counted per clip (exactly)")
    envs_help = f"envs per clip (at most --episodes; default --episodes, at most {MAX_DEFAULT_ENVS})"
    p.add_argument("--num_envs", type=int, help=envs_help)
    p.add_argument("--rand_seed", type=int, default=0, help="seed of every clip's episodes (start times)")
    p.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    p.add_argument("--json", action="store_true", help='print {"rows": [...], "mean": {...}}')
    p.set_defaults(func=eval_command)


def eval_command(args: argparse.Namespace) -> int:
    opts = EvalOptions(args.motion_file, args.episodes, args.num_envs, args.rand_seed, args.data_dir)
    report = evaluate(args.arg_file, args.model_file, opts)
    print(json.dumps(report) if args.json else format_table(report))
    return 0
