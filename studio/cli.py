"""`mimickit-studio serve`: one process, the REST API + dashboard (uvicorn) and the 3D scene (viser,
on an internal loopback port, relayed under the dashboard's `/scene/`).

It prints one URL: the dashboard's (with the token, when one is needed).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import shlex
import socket
import sys
import urllib.error
import urllib.request
from pathlib import Path

import uvicorn

from mimickit.runner.args import MULTI_VALUE_ARGS
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths
from mimickit.util.warn import one_line_warnings
from studio.runs.executors.base import EXECUTORS
from studio.security import new_token
from studio.settings import DEFAULT_TRAINER, DEMO_CLIP, Settings, parse_trainer

SERVER_WORK_DIR = "studio"  # under --runs-dir: the server's working directory


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mimickit-studio", description="a web studio for MimicKit clips and runs")
    sub = parser.add_subparsers(dest="command", required=True)
    serve = sub.add_parser("serve", help="start the studio server and print its URL")
    _add_serve_options(serve)
    _add_serve_limits(serve)
    add_sweep_parser(sub)
    _add_replay_parser(sub)
    return parser


def _add_serve_options(serve: argparse.ArgumentParser) -> None:
    """Where `serve` listens, whom it lets in, what it reads and shows first."""
    serve.add_argument("--host", default="127.0.0.1", help="address to bind; anything but loopback needs a token")
    serve.add_argument("--port", type=int, default=8000, help="dashboard/API port (0: a free one)")
    serve.add_argument(
        "--viser-port", type=int, default=0, help="the 3D scene's internal port on 127.0.0.1 (0: a free one)"
    )
    serve.add_argument("--data-dir", type=Path, help="a MimicKit data folder (motions/, assets/, datasets/, ...)")
    serve.add_argument("--runs-dir", type=Path, help="where runs, uploads and the registry live")
    serve.add_argument("--token", help="access token for /api and /scene (generated and printed if needed and absent)")
    serve.add_argument(
        "--allowed-hosts",
        default="",
        help="comma-separated Host header names accepted besides the bound host's (e.g. a reverse proxy's "
        "name; '*': any). Other names are refused (DNS rebinding)",
    )
    serve.add_argument(
        "--clip", default=str(DEMO_CLIP), help="the clip playing when the page opens ('none': an empty scene)"
    )
    serve.add_argument("--char", help="the MJCF character for --clip (default: guessed from its frame width)")


def _add_serve_limits(serve: argparse.ArgumentParser) -> None:
    """What `serve` runs and how much of it: runs at once, queues, time limits, the trainer, the executor."""
    serve.add_argument("--max-concurrent-runs", type=int, default=1, help="runs trained at once; the rest queue")
    serve.add_argument(
        "--max-queued-runs",
        type=int,
        default=Settings.max_queued_runs,
        help="training runs that may wait in the queue at once",
    )
    serve.add_argument(
        "--max-queued-jobs",
        type=int,
        default=Settings.max_queued_jobs,
        help="eval (and video) jobs that may wait at once",
    )
    serve.add_argument(
        "--eval-time-limit", type=float, default=Settings.eval_time_limit_s, help="seconds an eval job may run"
    )
    serve.add_argument(
        "--video-time-limit", type=float, default=Settings.video_time_limit_s, help="seconds a video job may run"
    )
    serve.add_argument(
        "--trainer",
        default=shlex.join(DEFAULT_TRAINER),
        help="the command a run starts, before its --arg_file ... arguments (default: mimickit train)",
    )
    serve.add_argument(
        "--executor",
        choices=EXECUTORS,
        default="local",
        help="what runs the trainers: local subprocesses (the default) or jobs on a Ray cluster",
    )
    serve.add_argument(
        "--ray-address",
        default="http://127.0.0.1:8265",
        help="the Ray cluster's dashboard address (Job Submission API), for --executor ray",
    )


def _add_replay_parser(sub: argparse._SubParsersAction) -> None:
    replay = sub.add_parser(
        "export-replay", help="write a clip or a policy rollout as one HTML file that plays offline in a browser"
    )
    replay.add_argument("--motion", help="a clip (.pkl) to replay")
    replay.add_argument("--char", help="the MJCF character of --motion (default: guessed from its frame width)")
    replay.add_argument("--model_file", help="a checkpoint (.pt): replay its deterministic policy in MuJoCo")
    replay.add_argument("--env_config", help="env yaml of --model_file (default: the one beside it)")
    replay.add_argument("--agent_config", help="agent yaml of --model_file (default: the one beside it)")
    replay.add_argument("--engine_config", help="engine yaml of --model_file (default: the one beside it)")
    replay.add_argument("--seconds", type=float, default=10.0, help="length of the policy rollout")
    replay.add_argument("--no-follow", action="store_true", help="a fixed world; by default it moves with the root")
    replay.add_argument("--data-dir", type=Path, help="a MimicKit data folder for data/... paths")
    replay.add_argument("--out", required=True, help="F.html (standalone page) or F.viser (viser recording)")


def add_sweep_parser(sub: argparse._SubParsersAction) -> None:
    sweep = sub.add_parser(
        "sweep", help="queue one run per combination of values on a running studio (POST /api/sweeps)"
    )
    sweep.add_argument("arg_file", help="the runs' arg file: args/x.txt, data/args/x.txt or an absolute path")
    sweep.add_argument(
        "--values",
        action="append",
        default=[],
        metavar="KEY=V1,V2,...",
        help="a MimicKit argument and its values (repeat for a grid), e.g. rand_seed=0,1,2",
    )
    sweep.add_argument("--dataset", help="a dataset yaml: one run per clip, as motion_file")
    sweep.add_argument("--name", help="the sweep's name (its runs are named after it and their values)")
    sweep.add_argument("--num_envs", type=int)
    sweep.add_argument("--max_samples", type=int)
    sweep.add_argument("--max_hours", type=float, help="each run's wall-time budget (the trainer's --max_hours)")
    sweep.add_argument(
        "--save_int_models",
        action="store_const",
        const=True,
        help="every run also keeps int_models/model_{iteration}.pt (the trainer's --save_int_models true)",
    )
    sweep.add_argument("--num-cpus", type=float, help="CPUs each run reserves on a Ray cluster (default 1)")
    sweep.add_argument("--num-gpus", type=float, help="GPUs each run reserves on a Ray cluster")
    sweep.add_argument("--url", default="http://127.0.0.1:8000/", help="the studio's address")
    sweep.add_argument("--token", help="the studio's access token (off loopback)")


def sweep_body(args: argparse.Namespace) -> dict[str, object]:
    """The POST /api/sweeps body of `mimickit-studio sweep ...`."""
    values: dict[str, list[str | int | float | list[str]]] = {}
    for item in args.values:
        key, sep, text = item.partition("=")
        if not sep or not key.strip() or not text.strip():
            raise MimicKitError(f"--values {item!r}: write KEY=V1,V2,... (e.g. rand_seed=0,1,2)")
        key = key.strip().removeprefix("--")
        several = key in MULTI_VALUE_ARGS  # "devices=cpu cpu": one value of two argv items, sent as a list
        values.setdefault(key, []).extend(v.split() if several else _typed(v.strip()) for v in text.split(","))
    body = {"arg_file": args.arg_file, "values": values, "dataset": args.dataset, "name": args.name}
    body |= {"num_envs": args.num_envs, "max_samples": args.max_samples, "max_hours": args.max_hours}
    body |= {"save_int_models": args.save_int_models}
    body |= {"num_cpus": args.num_cpus, "num_gpus": args.num_gpus}
    return {k: v for k, v in body.items() if v is not None}


def _typed(text: str) -> str | int | float:
    """A number stays a number (as the page sends it): the studio takes no string for an integer field."""
    for kind in (int, float):
        try:
            number = kind(text)
        except ValueError:
            continue
        if math.isfinite(number):
            return number
    return text


def sweep(args: argparse.Namespace) -> int:
    headers = {"Content-Type": "application/json", "X-Studio-Request": "1"}
    if args.token:
        headers["Authorization"] = f"Bearer {args.token}"
    url = args.url.rstrip("/") + "/api/sweeps"
    request = urllib.request.Request(url, json.dumps(sweep_body(args)).encode(), headers, method="POST")
    try:
        with urllib.request.urlopen(request, timeout=60) as response:
            result = json.load(response)
    except urllib.error.HTTPError as e:
        detail = json.loads(e.read() or b"{}").get("detail", e.reason)
        raise MimicKitError(f"the studio refused the sweep ({e.code}): {detail}") from None
    except (urllib.error.URLError, OSError) as e:
        raise MimicKitError(f"cannot reach the studio at {args.url}: {getattr(e, 'reason', e)}") from None
    print(f"sweep {result['id']} ({result['name']}): {len(result['runs'])} runs queued")
    for run in result["runs"]:
        print(f"  run {run['id']}: {run['name']} -> {run['out_dir']}")
    return 0


def export_replay(args: argparse.Namespace) -> int:
    with one_line_warnings():  # e.g. a clip's NaN columns, warned of by the character guess and the replay: once
        return _export_replay(args)


def _export_replay(args: argparse.Namespace) -> int:
    from studio.scene import replay  # imports viser, torch, mujoco: only when asked

    if bool(args.motion) == bool(args.model_file):
        raise MimicKitError("give either --motion CLIP [--char MJCF] or --model_file CHECKPOINT")
    paths = DataPaths(args.data_dir)
    replay.check_output(args.out)
    if args.motion:
        clip = paths.resolve(args.motion)
        char = paths.resolve(args.char) if args.char else _guess_char(clip, paths)
        info = replay.export_clip_replay(clip, char, args.out, follow=not args.no_follow)
    else:
        from studio.scene.rollout import source_for_checkpoint

        configs = {k: paths.resolve(v) if (v := getattr(args, k)) else None for k in CONFIG_ARGS}
        source = source_for_checkpoint(paths.resolve(args.model_file), **configs)
        source.data_dir = source.data_dir or args.data_dir
        info = replay.export_policy_replay(source, args.out, seconds=args.seconds)
    print(f"wrote {info.path}: {info.kind}, {info.frames} poses at {info.fps:g} Hz ({info.duration:.2f} s), "
          f"{info.bytes / 1e6:.2f} MB")  # fmt: skip
    return 0


CONFIG_ARGS = ("env_config", "agent_config", "engine_config")


def _guess_char(clip: Path, paths: DataPaths) -> Path:
    """The character whose DoF count fits the clip (as the studio's library guesses it)."""
    from mimickit.anim.motion import load_motion
    from studio.library import Library

    library = Library(Settings(data_dir=paths.data_dir).resolved())
    shown = library.character_for_width(load_motion(clip).frame_dim, clip)
    if shown is None:
        raise MimicKitError(f"{clip}: no character in the data folders fits it; name one with --char")
    return paths.resolve(shown)


def serve(args: argparse.Namespace) -> int:
    from studio.app import create_app  # imports viser, torch, mujoco: only when serving

    settings = Settings(
        host=args.host,
        port=args.port,
        viser_port=args.viser_port,
        data_dir=args.data_dir,
        token=args.token,
        allowed_hosts=[h.strip() for h in args.allowed_hosts.split(",") if h.strip()],
        max_concurrent_runs=max(1, args.max_concurrent_runs),
        trainer=parse_trainer(args.trainer),
        executor=args.executor,
        ray_address=args.ray_address,
    )
    if args.runs_dir:
        settings.runs_dir = args.runs_dir
    for flag, value in (("--max-queued-jobs", args.max_queued_jobs), ("--eval-time-limit", args.eval_time_limit),
                        ("--video-time-limit", args.video_time_limit),
                        ("--max-queued-runs", args.max_queued_runs)):  # fmt: skip
        if not value > 0:
            raise MimicKitError(f"{flag} must be positive, got {value:g}")
    settings.max_queued_jobs, settings.max_queued_runs = args.max_queued_jobs, args.max_queued_runs
    settings.eval_time_limit_s, settings.video_time_limit_s = args.eval_time_limit, args.video_time_limit
    if args.clip.lower() == "none":
        settings.startup_clip = None
    elif Path(args.clip).resolve() != DEMO_CLIP.resolve() or args.char:
        settings.startup_clip, settings.startup_char = Path(args.clip), args.char and Path(args.char)
    if settings.data_dir is not None and not Path(settings.data_dir).is_dir():
        raise MimicKitError(f"--data-dir {settings.data_dir} is not a folder")
    if settings.token is not None and not re.fullmatch(r"[A-Za-z0-9._~-]+", settings.token):
        # It travels in URLs and in the scene's cookie: nothing there may need escaping.
        raise MimicKitError("--token may hold only letters, digits and . _ ~ - (e.g. one from `openssl rand -hex 16`)")
    if settings.needs_token and not settings.token:
        settings.token = new_token()
    enter_work_dir(settings)
    # Bind first, so that --port 0 gets a real port to print and no other process can take it.
    family = socket.AF_INET6 if ":" in settings.host else socket.AF_INET
    # proto=IPPROTO_TCP matters: asyncio sets TCP_NODELAY only on sockets that say so, and without it
    # every keep-alive response waits ~40 ms for a delayed ACK (Nagle).
    sock = socket.socket(family, socket.SOCK_STREAM, socket.IPPROTO_TCP)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((settings.host, settings.port))
    except OSError as e:
        raise MimicKitError(f"cannot listen on {settings.host}:{settings.port} ({e.strerror})") from None
    sock.listen(2048)  # connections made right after the URL is printed wait in the backlog, not refused
    settings.port = sock.getsockname()[1]
    app = create_app(settings)
    # 0.0.0.0 / :: mean "every interface": show a name other machines can use instead.
    shown_host = socket.gethostname() if settings.host in ("0.0.0.0", "::") else settings.host
    shown_host = f"[{shown_host}]" if ":" in shown_host else shown_host
    url = f"http://{shown_host}:{settings.port}/"
    print(f"MimicKit Studio: {url}{'?token=' + settings.token if settings.needs_token else ''}", flush=True)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=2))
    server.run(sockets=[sock])
    return 0


def enter_work_dir(settings: Settings) -> Path:
    """Make `<runs-dir>/studio/` the server's working directory, after every path is made absolute.

    Rollouts, clip kinematics and the like run MuJoCo inside the server process, and MuJoCo writes its
    warnings to `MUJOCO_LOG.TXT` in the working directory: that must not be the folder the user
    started the server from (e.g. a checkout). Trainers and jobs get their own folders anyway."""
    settings.resolved()
    work_dir = settings.runs_dir / SERVER_WORK_DIR
    work_dir.mkdir(parents=True, exist_ok=True)
    os.chdir(work_dir)
    return work_dir


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    commands = {"serve": serve, "export-replay": export_replay, "sweep": sweep}
    try:
        return commands[args.command](args)
    except MimicKitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
