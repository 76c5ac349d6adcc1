"""`mimickit-studio serve`: one process, the REST API + dashboard (uvicorn) and the 3D scene (viser).

It prints one URL: the dashboard's (with the token, when one is needed).
"""

from __future__ import annotations

import argparse
import shlex
import socket
import sys
from pathlib import Path

import uvicorn

from mimickit.util.errors import MimicKitError
from studio.security import new_token
from studio.settings import DEFAULT_TRAINER, DEMO_CLIP, Settings, parse_trainer


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mimickit-studio", description="a web studio for MimicKit clips and runs")
    sub = parser.add_subparsers(dest="command", required=True)
    serve = sub.add_parser("serve", help="start the studio server and print its URL")
    serve.add_argument("--host", default="127.0.0.1", help="address to bind; anything but loopback needs a token")
    serve.add_argument("--port", type=int, default=8000, help="dashboard/API port (0: a free one)")
    serve.add_argument("--viser-port", type=int, default=0, help="3D scene port (0: a free one)")
    serve.add_argument("--data-dir", type=Path, help="a MimicKit data folder (motions/, assets/, datasets/, ...)")
    serve.add_argument("--runs-dir", type=Path, help="where runs, uploads and the registry live")
    serve.add_argument("--token", help="access token for /api (generated and printed if needed and absent)")
    serve.add_argument(
        "--clip", default=str(DEMO_CLIP), help="the clip playing when the page opens ('none': an empty scene)"
    )
    serve.add_argument("--char", help="the MJCF character for --clip (default: guessed from its frame width)")
    serve.add_argument("--max-concurrent-runs", type=int, default=1, help="runs trained at once; the rest queue")
    serve.add_argument(
        "--trainer",
        default=shlex.join(DEFAULT_TRAINER),
        help="the command a run starts, before its --arg_file ... arguments (default: mimickit train)",
    )
    return parser


def serve(args: argparse.Namespace) -> int:
    from studio.app import create_app  # imports viser, torch, mujoco: only when serving

    settings = Settings(
        host=args.host,
        port=args.port,
        viser_port=args.viser_port,
        data_dir=args.data_dir,
        token=args.token,
        max_concurrent_runs=max(1, args.max_concurrent_runs),
        trainer=parse_trainer(args.trainer),
    )
    if args.runs_dir:
        settings.runs_dir = args.runs_dir
    if args.clip.lower() == "none":
        settings.startup_clip = None
    elif Path(args.clip).resolve() != DEMO_CLIP.resolve() or args.char:
        settings.startup_clip, settings.startup_char = Path(args.clip), args.char and Path(args.char)
    if settings.data_dir is not None and not Path(settings.data_dir).is_dir():
        raise MimicKitError(f"--data-dir {settings.data_dir} is not a folder")
    if settings.needs_token and not settings.token:
        settings.token = new_token()
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
    if settings.needs_token:
        app_port = app.state.studio.viser_port
        print(
            f"note: the 3D scene's port {app_port} has no token: whoever reaches it can watch and drive the player",
            file=sys.stderr,
        )
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=2))
    server.run(sockets=[sock])
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return serve(args)
    except MimicKitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
