"""Train or test an agent: `python mimickit/run.py --arg_file args/...txt`, as in MimicKit.

`mimickit train ...` and `mimickit test ...` call the same code with `--mode` set. Arguments follow the
reference (spec §1.2): arg_file, mode, num_envs, engine_config, env_config, agent_config, out_dir,
model_file, max_samples, test_episodes, logger (txt|tb|wandb), rand_seed, devices, save_int_models,
visualize, video; plus data_dir (a MimicKit data folder for `data/...` paths) and json (test mode: print
one JSON object). SIGTERM or Ctrl-C during training saves a checkpoint and exits 0.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the package importable, as the reference does
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch

from mimickit.util.arg_parser import ArgParser
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import resolve_data_path, set_data_dir


def default_devices() -> list[str]:
    return ["cuda:0"] if torch.cuda.is_available() else ["cpu"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def seed_everything(args: ArgParser, rank: int) -> int:
    seed = args.parse_int("rand_seed", -1)
    if seed < 0:
        seed = int(np.uint64(time.time() * 256) % np.uint64(2**31))
    seed += 41 * rank
    random.seed(seed)
    np.random.seed(seed % 2**32)
    torch.manual_seed(seed)
    return seed


def run(rank: int, world: int, device: str, port: int, argv: list[str]) -> dict[str, Any] | None:
    """One process of a (possibly multi-process) run."""
    from mimickit.envs.env_builder import build_env
    from mimickit.learning import mp_util
    from mimickit.learning.agent_builder import build_agent

    args = ArgParser()
    args.load_args(argv)
    set_data_dir(args.parse_string("data_dir", "") or None)
    mode = args.parse_string("mode", "train")
    if mode not in ("train", "test"):
        raise MimicKitError(f"--mode must be train or test, got {mode!r}")
    mp_util.init(rank, world, device, port)
    seed_everything(args, rank)
    torch.set_num_threads(max(1, (os.cpu_count() or 1) // world))

    env_file = _config_path(args, "env_config", required=True)
    engine_file = _config_path(args, "engine_config")
    agent_file = _config_path(args, "agent_config")
    num_envs = args.parse_int("num_envs", 1)
    env = build_env(env_file, engine_file, num_envs, device, visualize=False)
    agent = build_agent(agent_file, env, device)
    model_file = args.parse_string("model_file", "")
    if model_file:
        agent.load(model_file)

    if mode == "test":
        episodes = args.parse_int("test_episodes", np.iinfo(np.int64).max)
        result: dict[str, Any] = agent.test_model(episodes).to_dict()
        summary = getattr(env, "tracking_summary", dict)()
        result["tracking"] = test_tracking(summary)
        return result

    out_dir = Path(args.parse_string("out_dir", "output/"))
    if mp_util.is_root_proc():
        out_dir.mkdir(parents=True, exist_ok=True)
        _copy_configs(out_dir, env_file, engine_file, agent_file)
        (out_dir / "args.json").write_text(json.dumps({k: args.parse_strings(k) for k in args.all_keys()}, indent=1))
    _install_stop_handlers(agent)
    agent.train_model(
        max_samples=args.parse_int("max_samples", np.iinfo(np.int64).max),
        out_dir=str(out_dir),
        save_int_models=args.parse_bool("save_int_models", False),
        logger_type=args.parse_string("logger", "txt"),
    )
    return None


def test_tracking(summary: dict[str, float]) -> dict[str, float]:
    """The env's tracking errors over the test steps, averaged over processes, plus the two of the ADD
    paper's Table 1: `pos_err_m` (mean over bodies of the root-relative body position error, metres) and
    `dof_vel_err` (mean |Δ dof velocity|, rad/s). Empty for envs without a reference motion."""
    from mimickit.learning import mp_util

    tracking = {k: float(mp_util.reduce_mean(v)) for k, v in sorted(summary.items())}
    if "body_pos_err" in tracking:
        tracking["pos_err_m"] = tracking["body_pos_err"]
    return tracking


def _config_path(args: ArgParser, key: str, required: bool = False) -> str | None:
    value = args.parse_string(key, "")
    if not value:
        if required:
            raise MimicKitError(f"--{key} is required")
        return None
    path = resolve_data_path(value)
    if not path.is_file():
        raise MimicKitError(f"--{key}: file not found: {value}")
    return str(path)


def _copy_configs(out_dir: Path, env_file: str, engine_file: str | None, agent_file: str | None) -> None:
    for src, name in (
        (engine_file, "engine_config.yaml"),
        (env_file, "env_config.yaml"),
        (agent_file, "agent_config.yaml"),
    ):
        if src:
            shutil.copyfile(src, out_dir / name)


def _install_stop_handlers(agent: Any) -> None:
    def stop(signum: int, _frame: Any) -> None:
        agent.request_stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)


def _worker(rank: int, world: int, devices: list[str], port: int, argv: list[str]) -> None:
    run(rank, world, devices[rank], port, argv)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = ArgParser()
        args.load_args(argv)
        devices = args.parse_strings("devices") or default_devices()
        world = len(devices)
        port = args.parse_int("master_port", 0) or free_port()
        if world > 1:
            import torch.multiprocessing as mp

            ctx = mp.get_context("spawn")
            procs = [ctx.Process(target=_worker, args=(r, world, devices, port, argv)) for r in range(1, world)]
            for p in procs:
                p.start()
        result = run(0, world, devices[0], port, argv)
        if world > 1:
            for p in procs:
                p.join()
                if p.exitcode != 0:
                    raise MimicKitError(f"worker process exited with code {p.exitcode}")
    except MimicKitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if result is not None:
        if args.has_key("json") and args.parse_bool("json", True):
            print(json.dumps(result))
        else:
            print(f"Mean Return: {result['mean_return']:.4f}")
            print(f"Mean Episode Length: {result['mean_episode_length']:.2f}")
            print(f"Episodes: {result['episodes']}")
            for k, v in result.get("tracking", {}).items():
                print(f"Tracking {k}: {v:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
