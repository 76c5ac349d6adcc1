"""Train or test an agent: `python mimickit/run.py --arg_file args/...txt`, as in MimicKit.

`mimickit train ...` and `mimickit test ...` call the same code with `--mode` set. Arguments are the
reference's `run.py` ones: arg_file, mode, num_envs, engine_config, env_config, agent_config, out_dir,
model_file, max_samples, test_episodes, logger (txt|tb|wandb), rand_seed, devices, save_int_models,
visualize, video; plus data_dir (a MimicKit data folder for `data/...` paths), motion_file (a clip or
dataset yaml that replaces the env config's `motion_file`), max_hours (a wall-time budget: training ends,
as at max_samples, once the recorded wall time reaches it) and json (test mode: print one JSON object).

A training run's folder (`--out_dir`, see `mimickit.learning.run_folder`) records the run: args.json (argv,
effective values, the seed used, versions), the configs as trained, state.json (running, then
finished / stopped / diverged / failed with the line that says why). Without `--rand_seed` a seed is
drawn and recorded; `--rand_seed <seed>` repeats a CPU run's metrics rows exactly (same num_envs).
`--model_file RUN/model.pt --out_dir RUN --max_samples LARGER` (or `--max_hours LARGER`) continues a run
with a new budget. `--arg_file RUN/args.json` takes a run's recorded arguments and its configs as trained
(test mode: its model.pt; never its out_dir; see `mimickit.util.arg_parser`).
SIGTERM or Ctrl-C during training saves a checkpoint and exits 0 (state stopped).
Several processes: `--devices cpu cpu` spawns one per device; under torchrun (`torchrun --nproc-per-node 2
-m mimickit.cli train ...`, see `mimickit.runner.torchrun_env`) every process is already started and joins the
group through env://; rank 0 draws the seed and broadcasts it, and writes the run folder, as with
`--devices`. args.json's `launch` says which (`spawn` or `torchrun`, world size, nodes).
Exit codes: 0 finished or stopped, 1 failed after the run started, 2 refused before anything started
(one `error:` line), 3 diverged (a non-finite loss, gradient, weight, observation or action).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import signal
import socket
import sys
import time
import traceback
from pathlib import Path
from typing import Any

if __package__ in (None, ""):  # run as a script: make the package importable, as the reference does
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
import torch
import yaml

from mimickit.learning.run_folder import STATE_FILE, EndState, ExitCode, RunFolder
from mimickit.runner.args import check_run_args
from mimickit.runner.inputs import RunInputs, build_run_env, resolve_inputs
from mimickit.runner.policy import test_result
from mimickit.runner.seeding import draw_seed, seed_everything
from mimickit.runner.torchrun_env import TorchrunEnv, check_master_port, node_devices, read_torchrun_env
from mimickit.util.arg_parser import ArgParser
from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from mimickit.util.malloc_tuning import tune_malloc
from mimickit.util.paths import atomic_write_bytes
from mimickit.util.warn import one_line_warnings

NO_LIMIT = int(np.iinfo(np.int64).max)
REFUSAL_WAIT_S = 10.0
DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EROFS)
"""A full, over-quota or read-only disk: the run fails with one line, no traceback."""
"""Under torchrun, how long a refusing process other than LOCAL_RANK 0 waits to be ended (see `_print_refusal`)."""


def default_devices() -> list[str]:
    return ["cuda:0"] if torch.cuda.is_available() else ["cpu"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(
    rank: int,
    world: int,
    device: str,
    port: int | None,
    argv: list[str],
    base_seed: int | None = None,
    launch: dict[str, Any] | None = None,
) -> dict[str, Any] | int:
    """One process of a (possibly multi-process) run: the test result (test mode) or the exit code.
    `port` None: join the group through env:// (torchrun). `launch`: how the processes were started
    (`spawn_launch` / `TorchrunEnv.record`, plus this node's `devices`), recorded in args.json."""
    from mimickit.learning import mp_util

    args = ArgParser()
    args.load_args(argv)  # checked by main() (check_run_args) before any process started
    mode = args.parse_string("mode", "train")
    inputs = resolve_inputs(args)
    resume = None
    if mode == "train":
        resume = check_resume_budget(
            args.parse_string("model_file", ""), args.parse_int("max_samples", NO_LIMIT), max_hours(args)
        )
    if base_seed is None:
        base_seed = draw_seed(args)[0]
    launch = launch or spawn_launch([device] * world)
    mp_util.init(rank, world, device, port)
    result: dict[str, Any] | int = ExitCode.FAILED
    try:
        result = _run_in_group(args, argv, inputs, device, rank, base_seed, launch, resume, mode)
    finally:
        # the group is left before the interpreter exits (gloo aborts otherwise); a failed process
        # does not wait for peers that may never arrive
        mp_util.shutdown(synchronize=result != ExitCode.FAILED)
    return result


def _run_in_group(
    args: ArgParser,
    argv: list[str],
    inputs: RunInputs,
    device: str,
    rank: int,
    base_seed: int,
    launch: dict[str, Any],
    resume: dict[str, Any] | None,
    mode: str,
) -> dict[str, Any] | int:
    from mimickit.learning import mp_util
    from mimickit.learning.agent_builder import build_agent

    base_seed = mp_util.broadcast_int(base_seed)  # torchrun: each process drew its own; rank 0's counts
    seed_everything(args, rank, base_seed)
    torch.set_num_threads(max(1, (os.cpu_count() or 1) // launch["local_world_size"]))
    tune_malloc()  # this process's malloc: big tensors kept in the heap between steps (util/malloc_tuning)

    env, env_info = build_run_env(inputs, args.parse_int("num_envs", 1), device)
    agent = build_agent(inputs.agent_file, env, device)
    model_file = args.parse_string("model_file", "")
    if model_file:
        agent.load(model_file)

    if mode == "test":
        return test_result(agent, env, args.parse_int("test_episodes", NO_LIMIT))
    return _train(args, argv, inputs, env_info, agent, base_seed, launch, resume)


def max_hours(args: ArgParser) -> float | None:
    """`--max_hours` (checked > 0 by `check_run_args`); None: no wall-time budget."""
    return args.parse_float("max_hours") if args.parse_string("max_hours", "") else None


def check_resume_budget(model_file: str, max_samples: int, hours: float | None = None) -> dict[str, Any] | None:
    """Where training resumes from (`model_file`, `iteration`, `samples` of the checkpoint's train
    state; None for no checkpoint or one without a train state, i.e. a fresh start), after refusing a
    checkpoint that already reached `max_samples` or `hours` of recorded wall time (it would train nothing)."""
    if not model_file:
        return None
    from mimickit.learning import checkpoint

    _, train_state = checkpoint.split_train_state(checkpoint.read_checkpoint(model_file))
    if train_state is None:
        return None
    samples = train_state["samples"]
    if samples >= max_samples:
        raise MimicKitError(
            f"{model_file} already has {samples} samples, which reaches --max_samples {max_samples}:"
            " nothing to train (give a larger --max_samples to continue it)"
        )
    if hours is not None and train_state["wall_time_hours"] >= hours:
        raise MimicKitError(
            f"{model_file} already has {train_state['wall_time_hours']:.3f} h of training, which reaches --max_hours"
            f" {hours:g}: nothing to train (give a larger --max_hours to continue it)"
        )
    return {"model_file": str(Path(model_file).resolve()), "iteration": train_state["iteration"], "samples": samples}


def _train(
    args: ArgParser,
    argv: list[str],
    inputs: RunInputs,
    env_info: dict[str, Any],
    agent: Any,
    seed: int,
    launch: dict[str, Any],
    resume: dict[str, Any] | None,
) -> int:
    from mimickit.learning import mp_util

    max_samples = args.parse_int("max_samples", NO_LIMIT)
    folder = RunFolder(Path(args.parse_string("out_dir", "output/")).resolve())
    root = mp_util.is_root_proc()
    if root:
        effective = _effective_values(args, inputs, env_info, agent, folder, max_samples, launch)
        try:
            _start_run_folder(folder, args, argv, inputs, effective, seed, resume, launch)
        except OSError as e:  # the --out_dir probe passed, then the disk filled up: still one line
            raise MimicKitError(_failure_line(e, folder)) from None
    signals = _install_stop_handlers(agent)
    try:
        summary = agent.train_model(
            max_samples=max_samples,
            out_dir=str(folder.path),
            save_int_models=args.parse_bool("save_int_models", False),
            logger_type=args.parse_string("logger", "txt"),
            max_hours=max_hours(args),
        )
    except Exception as e:  # noqa: BLE001 - any error ends the run as failed, with its one line
        line = _failure_line(e, folder)
        if not isinstance(e, MimicKitError) and _disk_error(e) is None:
            _quietly(traceback.print_exc)
        if root:
            line += _record_state(folder, EndState.FAILED, line, agent.get_iteration(), agent.get_sample_count())
        _quietly(print, f"error: {line}", file=sys.stderr, flush=True)
        return ExitCode.FAILED
    state, reason, code = _end_state(summary, max_samples, max_hours(args), signals, folder.model_file.is_file())
    if root:
        note = _record_state(folder, state, reason, summary.iterations, summary.samples)
        if note:
            _quietly(print, f"warning: {note.strip(' ()')}", file=sys.stderr, flush=True)
        if state != EndState.DIVERGED:  # the divergence line is already on the terminal
            _quietly(print, f"{state.value}: {reason}", flush=True)
    return code


def _record_state(folder: RunFolder, state: EndState, reason: str, iteration: int, samples: int) -> str:
    """Write state.json; "" when written, else a note for the terminal line saying it is not."""
    try:
        folder.write_state(state, reason, iteration=iteration, samples=samples)
    except OSError as e:
        return f" ({STATE_FILE} not written: {e.strerror or e})"
    return ""


def _disk_error(e: BaseException) -> OSError | None:
    """The full, over-quota or read-only disk behind `e` (itself, or what it was raised from), if any."""
    seen: list[BaseException] = []
    cur: BaseException | None = e
    while cur is not None and cur not in seen:
        if isinstance(cur, OSError) and cur.errno in DISK_ERRNOS:
            return cur
        seen.append(cur)
        cur = cur.__cause__ or cur.__context__
    return None


def _failure_line(e: BaseException, folder: RunFolder) -> str:
    """The one line of an error that ended the run: a full or read-only disk says which file (or
    which folder, when the OS did not say) and why."""
    disk = _disk_error(e)
    if disk is None or isinstance(e, MimicKitError):
        return _one_line(e)
    name = disk.filename or f"into the run folder {folder.path} or the trainer's output"
    return f"cannot write {name}: {disk.strerror}"


def _quietly(fn: Any, *args: Any, **kwargs: Any) -> None:
    """Print to a terminal that may itself be a file on the full disk (the studio's console.log)."""
    with contextlib.suppress(OSError):
        fn(*args, **kwargs)


def _end_state(
    summary: Any, max_samples: int, hours: float | None, signals: list[str], saved: bool
) -> tuple[EndState, str, int]:
    done = f"iteration {summary.iterations}, {summary.samples} samples"
    if summary.diverged:
        return EndState.DIVERGED, summary.diverged, ExitCode.DIVERGED
    if summary.stopped:
        by = signals[0] if signals else "a stop request"
        saved_note = "; model.pt saved" if saved else " (before the first iteration: no model.pt)"
        return EndState.STOPPED, f"stopped by {by} at {done}{saved_note}", ExitCode.OK
    if summary.out_of_time:
        return EndState.FINISHED, f"reached max_hours {hours:g} of recorded wall time at {done}", ExitCode.OK
    return EndState.FINISHED, f"reached max_samples {max_samples} at {done}", ExitCode.OK


def _effective_values(
    args: ArgParser,
    inputs: RunInputs,
    env_info: dict[str, Any],
    agent: Any,
    folder: RunFolder,
    max_samples: int,
    launch: dict[str, Any],
) -> dict[str, Any]:
    """Every value the run uses, whether given, from the arg file, from a config or a default."""
    cfg = agent.config
    model_file = args.parse_string("model_file", "")
    data_dir = args.parse_string("data_dir", "")
    return {
        "mode": "train",
        "num_envs": agent.get_num_envs(),
        "max_samples": max_samples if max_samples < NO_LIMIT else None,
        "max_hours": max_hours(args),
        "devices": launch["devices"],
        "world_size": launch["world_size"],
        "engine_config": inputs.engine_file,
        "env_config": inputs.env_file,
        "agent_config": inputs.agent_file,
        **env_info,
        "agent_name": cfg.agent_name,
        "steps_per_iter": cfg.steps_per_iter,
        "iters_per_output": cfg.iters_per_output,
        "test_episodes": cfg.test_episodes,
        "out_dir": str(folder.path),
        "model_file": str(Path(model_file).resolve()) if model_file else None,
        "logger": args.parse_string("logger", "txt"),
        "save_int_models": args.parse_bool("save_int_models", False),
        "data_dir": str(Path(data_dir).expanduser().resolve()) if data_dir else None,
        "torch_threads": torch.get_num_threads(),
    }


def _start_run_folder(
    folder: RunFolder,
    args: ArgParser,
    argv: list[str],
    inputs: RunInputs,
    effective: dict[str, Any],
    seed: int,
    resume: dict[str, Any] | None,
    launch: dict[str, Any],
) -> None:
    """Configs as trained, args.json and state.json `running` (rank 0), before the first iteration."""
    from mimickit.runner.record import args_record

    folder.path.mkdir(parents=True, exist_ok=True)
    for role, src in (("engine", inputs.engine_file), ("env", inputs.env_file), ("agent", inputs.agent_file)):
        if src:
            text = _env_config_text(src, inputs.motion_file) if role == "env" else Path(src).read_text()
            atomic_write_bytes(folder.config_file(role), text.encode())
    table = {k: args.parse_strings(k) for k in args.all_keys()}
    source = "rand_seed" if args.parse_int("rand_seed", -1) >= 0 else "drawn"
    previous = folder.read_args() if resume is not None else None
    record = {k: v for k, v in launch.items() if k != "devices"}  # devices: under `effective`
    folder.write_args(args_record(argv, table, effective, seed, source, resume, previous, record))
    folder.write_state(EndState.RUNNING, "", iteration=resume["iteration"] if resume else 0,
                       samples=resume["samples"] if resume else 0)  # fmt: skip


def _env_config_text(env_file: str, motion_file: str | None) -> str:
    """The env config as trained: the file itself, or (with `--motion_file`) its mapping with
    `motion_file` replaced, under a comment saying so."""
    if motion_file is None:
        return Path(env_file).read_text()
    raw = load_yaml(env_file)
    fields = raw["env"] if isinstance(raw.get("env"), dict) else raw
    fields["motion_file"] = motion_file
    header = f"# {env_file} as trained: motion_file replaced by --motion_file\n"
    return header + yaml.safe_dump(raw, sort_keys=False, default_flow_style=None)


def _one_line(e: BaseException) -> str:
    text = str(e).strip()
    first = text.splitlines()[0] if text else ""
    return first if isinstance(e, MimicKitError) else f"{e.__class__.__name__}: {first}".rstrip(": ")


def _install_stop_handlers(agent: Any) -> list[str]:
    """SIGTERM / SIGINT ask the agent to stop; the returned list collects the signals' names."""
    received: list[str] = []

    def stop(signum: int, _frame: Any) -> None:
        received.append(signal.Signals(signum).name)
        agent.request_stop()

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    return received


def spawn_launch(devices: list[str]) -> dict[str, Any]:
    """args.json's `launch` for processes `main` spawned, one per `--devices` entry."""
    n = len(devices)
    return {"launcher": "spawn", "world_size": n, "local_world_size": n, "nodes": 1, "devices": list(devices)}


def _worker(rank: int, devices: list[str], port: int, argv: list[str], seed: int) -> None:
    with one_line_warnings():
        run(rank, len(devices), devices[rank], port, argv, seed, spawn_launch(devices))


def _run_spawned(args: ArgParser, argv: list[str], seed: int) -> dict[str, Any] | int:
    """Rank 0 here, ranks 1.. in spawned processes, one per `--devices` entry."""
    devices = args.parse_strings("devices") or default_devices()
    world = len(devices)
    port = args.parse_int("master_port", 0) or free_port()
    procs = []
    if world > 1:
        import torch.multiprocessing as mp

        ctx = mp.get_context("spawn")
        procs = [ctx.Process(target=_worker, args=(r, devices, port, argv, seed)) for r in range(1, world)]
        for p in procs:
            p.start()
    result = run(0, world, devices[0], port, argv, seed, spawn_launch(devices))
    for p in procs:
        p.join()
        if p.exitcode != 0:
            raise MimicKitError(f"worker process exited with code {p.exitcode}")
    return result


def _run_torchrun(args: ArgParser, argv: list[str], tenv: TorchrunEnv, seed: int) -> dict[str, Any] | int:
    """This process's rank of a torchrun launch: nothing to spawn, the group joined through env://."""
    check_master_port(args.parse_int("master_port", 0) != 0, tenv)
    cuda_count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    devices = node_devices(args.parse_strings("devices"), tenv, cuda_count)
    launch = {**tenv.record(), "devices": devices}
    return run(tenv.rank, tenv.world, devices[tenv.local_rank], None, argv, seed, launch)


def _print_refusal(e: MimicKitError, tenv: TorchrunEnv | None) -> None:
    """The `error:` line, once per node under torchrun: every process of a node ran the same checks on
    the same files, so LOCAL_RANK 0 prints it. The others wait first: torchrun ends them as soon as
    LOCAL_RANK 0 exits, and if it did not refuse (it waits in the rendezvous) they print their own."""
    if tenv is not None and tenv.local_rank != 0:
        time.sleep(REFUSAL_WAIT_S)
    print(f"error: {e}", file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    with one_line_warnings():
        return _main(list(sys.argv[1:] if argv is None else argv))


def _main(argv: list[str]) -> int:
    tenv: TorchrunEnv | None = None
    try:
        tenv = read_torchrun_env()
        args = ArgParser()
        args.load_args(argv)
        # unknown keys and bad values: one line before any process or file exists. Under torchrun only
        # rank 0 probes --out_dir (the one that writes it; concurrent probes would race on its removal).
        check_run_args(args, probe_out_dir=tenv is None or tenv.rank == 0)
        seed = draw_seed(args)[0]  # drawn once, so every process and args.json share it (torchrun: rank 0's)
        result = _run_spawned(args, argv, seed) if tenv is None else _run_torchrun(args, argv, tenv, seed)
    except MimicKitError as e:
        _print_refusal(e, tenv)
        return ExitCode.REFUSED
    if isinstance(result, int):
        return result
    if tenv is not None and tenv.rank != 0:
        return ExitCode.OK  # the test result (the same on every rank) is printed once, by rank 0
    if args.has_key("json") and args.parse_bool("json", True):
        print(json.dumps(result))
    else:
        print(f"Mean Return: {result['mean_return']:.4f}")
        print(f"Mean Episode Length: {result['mean_episode_length']:.2f}")
        print(f"Episodes: {result['episodes']}")
        if result.get("episode_ends"):  # a clip that does not loop ends episodes early as a success, not a fall
            print("Episode Ends: " + ", ".join(f"{k} {v}" for k, v in result["episode_ends"].items()))
        for k, v in result.get("tracking", {}).items():
            print(f"Tracking {k}: {v:.4f}")
    return ExitCode.OK


if __name__ == "__main__":
    sys.exit(main())
