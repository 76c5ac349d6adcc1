"""The `mimickit` command: `motion info|convert|validate`, `plot`, `video`, and the training entry points.

Every user mistake (bad clip, bad config, missing file) ends as one line on stderr and exit code 2.
`train` also ends with 1 (an error after the run started: state failed) or 3 (diverged); 0 is finished
or stopped (`mimickit.learning.run_folder.ExitCode`).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths
from mimickit.util.warn import one_line_warnings

DEFAULT_BENCH_AGENT = "data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml"


def _motion_info(args: argparse.Namespace) -> int:
    from mimickit.tools.motion_report import format_info, motion_info

    char = _char_model(args.char)
    infos = [motion_info(p, char) for p in args.paths]
    if args.json:
        print(json.dumps(infos, indent=1))
    else:
        print("\n".join(format_info(i) for i in infos))
    return 0


def _char_model(path: str | None):  # -> KinCharModel | None
    """The character named by --char; imported only then, so a clip check alone starts without torch."""
    if not path:
        return None
    from mimickit.anim.mjcf_char_model import load_char_model

    return load_char_model(path)


def _motion_validate(args: argparse.Namespace) -> int:
    from mimickit.tools.motion_report import validate_motion

    char = _char_model(args.char)
    bad = 0
    for p in args.paths:
        problems, notes = validate_motion(p, char)
        for line in notes:
            print(f"warning: {line}", file=sys.stderr)
        if problems:
            bad += 1
            for line in problems:
                print(line, file=sys.stderr)
        else:
            print(f"{p}: ok")
    if bad:
        print(f"{bad} of {len(args.paths)} file(s) invalid", file=sys.stderr)
    return 1 if bad else 0


def _motion_convert(args: argparse.Namespace) -> int:
    from mimickit.anim.motion import save_motion
    from mimickit.tools.motion_convert import ConvertOptions, convert_motion

    if not args.out.endswith(".pkl"):
        raise MimicKitError(f"output must be a .pkl file, got {args.out}")
    opts = ConvertOptions(
        fmt=args.format,
        char=args.char,
        fps=args.fps,
        loop=args.loop,
        start_frame=args.start_frame,
        end_frame=args.end_frame,
        z_correction=args.z_correction,
        up=args.up,
        input_fps=args.input_fps,
        root_rot_order=args.root_rot_order,
        data_paths=DataPaths(args.data_dir),
    )
    result = convert_motion(args.input, opts)
    motion = result.motion
    save_motion(args.out, motion)
    line = (
        f"wrote {args.out}: {motion.num_frames} frames at {motion.fps:g} fps ({motion.duration:.3f} s),"
        f" loop {motion.loop_mode.name.lower()}"
    )
    if motion.fps != result.input_fps:
        line += f"; resampled from {result.input_fps:g} fps"
    print(f"{line} [{result.fmt}]")
    return 0


def _bench(args: argparse.Namespace) -> int:
    from mimickit.tools.bench import format_bench, run_bench
    from mimickit.util.malloc_tuning import tune_malloc

    tune_malloc()  # as `mimickit train` runs (util/malloc_tuning)
    paths = DataPaths(args.data_dir)
    if args.train:
        if args.steps is not None or args.raw is not None:
            raise MimicKitError("--steps and --raw time the env alone: --train times one iteration per round")
        from mimickit.tools.train_bench import format_train_bench, run_train_bench

        results = [
            run_train_bench(
                args.engine_config, args.env_config, args.agent_config, n, rounds=args.rounds, data_paths=paths
            )
            for n in args.num_envs
        ]
        fmt = format_train_bench
    else:
        if args.agent_config != DEFAULT_BENCH_AGENT:
            raise MimicKitError("--agent_config is read only with --train")
        results = [
            run_bench(
                args.engine_config,
                args.env_config,
                n,
                args.steps or 100,
                rounds=args.rounds,
                raw_mode=args.raw or "free",
                data_paths=paths,
            )
            for n in args.num_envs
        ]
        fmt = format_bench
    if args.json:
        print(json.dumps(results[0] if len(results) == 1 else results))
    else:
        print("\n".join(fmt(r) for r in results))
    return 0


def _sim2sim(args: argparse.Namespace) -> int:
    from mimickit.tools.sim2sim import format_report, run_sim2sim

    report = run_sim2sim(
        args.arg_file, args.model_file, args.motion_file, tuple(args.engines), args.seconds, DataPaths(args.data_dir)
    )
    print(json.dumps(report) if args.json else format_report(report))
    return 0


def _checkpoint_export(args: argparse.Namespace) -> int:
    from mimickit.tools.export_checkpoint import export_checkpoint

    sizes = export_checkpoint(args.src, args.dst, reference=args.reference)
    print(f"{args.dst}: {sizes['exported_bytes'] / 1e6:.1f} MB (from {sizes['source_bytes'] / 1e6:.1f} MB)")
    return 0


def _plot(args: argparse.Namespace) -> int:
    from mimickit.tools.plot_log import plot_logs

    w, h = plot_logs(args.logs, args.out, x=args.x, columns=args.y)
    print(f"wrote {args.out} ({w}x{h} px, {len(args.logs)} run(s))")
    return 0


def _video(args: argparse.Namespace) -> int:
    from mimickit.tools.video import VideoOptions, motion_video, policy_video

    if bool(args.motion) == bool(args.model_file) or bool(args.motion) != bool(args.char):
        raise MimicKitError("give either --model_file M --arg_file A, or --motion PATH --char MJCF")
    if args.model_file and not args.arg_file:
        raise MimicKitError("--model_file needs --arg_file (the env, agent and engine configs of the model)")
    frame_png = Path(args.frame_png) if args.frame_png else None
    size = {k: v for k in ("width", "height") if (v := getattr(args, k)) is not None}  # else VideoOptions'
    opts = VideoOptions(args.seconds, frame_png=frame_png, data_paths=DataPaths(args.data_dir), **size)
    if args.motion:
        info = motion_video(args.motion, args.char, args.out, opts)
    else:
        info = policy_video(args.model_file, args.arg_file, args.out, opts, seed=args.rand_seed)
    print(
        f"wrote {info.path}: {info.frames} frames at {info.fps:g} fps, {info.width}x{info.height} ({info.gl_backend})"
    )
    return 0


def _train_prior(args: argparse.Namespace) -> int:
    from mimickit.tools.train_prior import train_prior

    train_prior(
        args.config,
        args.out_dir,
        DataPaths(args.data_dir),
        max_iterations=args.max_iterations,
        device=args.device,
        seed=args.seed,
    )
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="mimickit", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("train", help="train an agent (MimicKit arguments: --arg_file, --num_envs, --out_dir, ...)")
    sub.add_parser("test", help="test a checkpoint (MimicKit arguments: --arg_file, --model_file, --json, ...)")
    _add_motion_parser(sub)
    _add_checkpoint_parser(sub)
    _add_bench_parser(sub)
    _add_sim2sim_parser(sub)
    _add_plot_parser(sub)
    _add_video_parser(sub)
    _add_train_prior_parser(sub)

    from mimickit.tools.evaluate import add_eval_parser
    from mimickit.tools.onnx_export import add_export_parser

    add_eval_parser(sub)
    add_export_parser(sub)
    return parser


# One function per subcommand, in the order `mimickit --help` lists them; `sub` is build_parser's subparsers.
def _add_motion_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit motion info|validate|convert`."""
    motion = sub.add_parser("motion", help="inspect, validate and convert motion clips")
    msub = motion.add_subparsers(dest="motion_command", required=True)

    info = msub.add_parser("info", help="fps, loop mode, frames, duration, NaN and limit report of clips")
    info.add_argument("paths", nargs="+", help=".pkl clips")
    info.add_argument("--char", help="MJCF character: also check frame width and joint limits")
    info.add_argument("--json", action="store_true", help="print one JSON list, one object per clip")
    info.set_defaults(func=_motion_info)

    val = msub.add_parser("validate", help="exit non-zero and list the problems of each bad clip")
    val.add_argument("paths", nargs="+")
    val.add_argument("--char", help="MJCF character the clips must fit")
    val.set_defaults(func=_motion_validate)

    conv = msub.add_parser(
        "convert", help="convert a DeepMimic .txt, an AMASS/SMPL .npz or a GMR robot motion into a MimicKit .pkl"
    )
    conv.add_argument("input", help="DeepMimic humanoid3d .txt, AMASS .npz, or GMR .pkl/.npz")
    conv.add_argument("out", help="output .pkl")
    conv.add_argument(
        "--format", default="auto", choices=["auto", "deepmimic", "amass", "gmr"], help="default: from the file"
    )
    conv.add_argument("--char", help="MJCF character (amass: default data/assets/smpl/smpl.xml; gmr: checks DoFs)")
    conv.add_argument("--fps", type=float, help="resample to this frame rate (same duration; slerp for rotations)")
    conv.add_argument("--loop", choices=["wrap", "clamp"], help="loop mode (default: the file's, else wrap)")
    conv.add_argument("--start_frame", type=int, default=0, help="first input frame kept")
    conv.add_argument("--end_frame", type=int, default=-1, help="input frame to stop before (-1: the end)")
    conv.add_argument(
        "--z_correction", default="calibrate", choices=["none", "calibrate", "full"],
        help="amass: lowest body 2.5 cm above ground over the first 30 frames (calibrate) or all (full)",
    )  # fmt: skip
    conv.add_argument("--up", default="z", choices=["z", "y"], help="amass: up axis of the input world (AMASS: z)")
    conv.add_argument("--input_fps", type=float, help="amass: frame rate when the file stores none")
    conv.add_argument("--root_rot_order", default="xyzw", choices=["xyzw", "wxyz"], help="gmr: root_rot order")
    conv.add_argument("--data_dir", help="a MimicKit data folder for data/... paths (the SMPL character)")
    conv.set_defaults(func=_motion_convert)


def _add_checkpoint_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit checkpoint export`."""
    ckpt = sub.add_parser("checkpoint", help="work with agent checkpoints (.pt)")
    csub = ckpt.add_subparsers(dest="checkpoint_command", required=True)
    exp = csub.add_parser("export", help="drop the optimiser states (for shipping a trained model)")
    exp.add_argument("src", help="a model.pt written by mimickit train")
    exp.add_argument("dst", help="where to write the exported checkpoint")
    exp.add_argument("--reference", action="store_true", help="drop _train_state too (MimicKit's strict loader)")
    exp.set_defaults(func=_checkpoint_export)


def _add_bench_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit bench`."""
    bench = sub.add_parser("bench", help="env steps/s with random actions vs raw MuJoCo rollout on the same model")
    bench.add_argument("--engine_config", default="data/engines/mujoco_engine.yaml")
    bench.add_argument("--env_config", default="data/envs/deepmimic_humanoid_env.yaml")
    bench.add_argument("--num_envs", type=int, nargs="+", default=[256], help="one or more env counts")
    bench.add_argument("--steps", type=int, help="control steps measured per env count (default 100)")
    bench.add_argument(
        "--rounds", type=int, default=5, help="env and raw measurements alternate this many times (noisy machines)"
    )
    bench.add_argument(
        "--raw",
        choices=["free", "replay"],
        help="raw baseline: rollout on its own copies of the states with zero controls (free), or re-running each "
        "timed env step from the same state, warm start and controls (replay); default free",
    )
    bench.add_argument(
        "--train",
        action="store_true",
        help="alternate env-only rounds (random actions) with full training iterations of --agent_config: "
        "train_ratio and where training's time goes (--steps and --raw do not apply)",
    )
    bench.add_argument("--agent_config", default=DEFAULT_BENCH_AGENT, help="the agent --train times")
    bench.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    bench.add_argument("--json", action="store_true", help="print JSON (one object, or a list for several counts)")
    bench.set_defaults(func=_bench)


def _add_sim2sim_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit sim2sim`."""
    s2s = sub.add_parser("sim2sim", help="one policy or clip from one initial state in two engines: divergence")
    s2s.add_argument("--arg_file", required=True, help="arg file naming the env (with a clip), agent and engine")
    src = s2s.add_mutually_exclusive_group(required=True)
    src.add_argument("--model_file", help="checkpoint (.pt): run its deterministic policy")
    src.add_argument("--motion_file", help="clip (.pkl): PD-track it (targets = the clip's DoF positions)")
    s2s.add_argument("--engines", nargs=2, default=["mujoco", "newton"], choices=["mujoco", "newton"])
    s2s.add_argument("--seconds", type=float, default=5.0, help="longest horizon (each run stops when it terminates)")
    s2s.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    s2s.add_argument("--json", action="store_true", help="print the report (per-step series and summary) as JSON")
    s2s.set_defaults(func=_sim2sim)


def _add_plot_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit plot`."""
    plot = sub.add_parser("plot", help="learning curves of runs (log.txt, metrics.jsonl or run folders) to a PNG")
    plot.add_argument("logs", nargs="+", metavar="LOG", help="log.txt / metrics.jsonl files or run folders")
    plot.add_argument("--out", required=True, help="PNG to write")
    plot.add_argument("--x", default="samples", choices=["samples", "iteration", "wall_time"])
    plot.add_argument("--y", nargs="+", metavar="COL", help="columns, one subplot each (default: returns, lengths)")
    plot.set_defaults(func=_plot)


def _add_video_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit video`."""
    video = sub.add_parser("video", help="render a policy (with its reference as a ghost) or a clip to an MP4")
    video.add_argument("--model_file", help="checkpoint (.pt) of a policy; needs --arg_file")
    video.add_argument("--arg_file", help="arg file naming the env, agent and engine configs of the model")
    video.add_argument(
        "--motion", help="a clip (.pkl) to play kinematically (of a dataset .yaml: its first clip); needs --char"
    )
    video.add_argument("--char", help="MJCF character of the clip")
    video.add_argument("--out", required=True, help="MP4 to write")
    video.add_argument("--seconds", type=float, default=5.0)
    video.add_argument("--width", type=int, help="pixels, even (default 640, as the studio's Export MP4)")
    video.add_argument("--height", type=int, help="pixels, even (default 480)")
    video.add_argument("--frame_png", help="also save the last frame as a PNG")
    video.add_argument("--rand_seed", type=int, default=0, help="seed of the policy episode (start time in the clip)")
    video.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    video.set_defaults(func=_video)


def _add_train_prior_parser(sub: argparse._SubParsersAction) -> None:
    """`mimickit train-prior`."""
    prior = sub.add_parser("train-prior", help="train an SMP motion prior (TinyMDM) on clips; needs the smp extra")
    prior.add_argument("--config", required=True, help="prior yaml, e.g. data/priors/tinymdm_single_clip.yaml")
    prior.add_argument("--out_dir", required=True, help="folder for model.pt, diffusion_config.yaml, env_config.yaml")
    prior.add_argument("--data_dir", help="a MimicKit data folder for data/... paths")
    prior.add_argument("--max_iterations", type=int, help="stop after this many iterations (at most the config's)")
    prior.add_argument("--device", help="torch device, replacing the config's (e.g. cpu, cuda:0)")
    prior.add_argument("--seed", type=int, help="torch seed (default: not seeded)")
    prior.set_defaults(func=_train_prior)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in ("train", "test"):
        return _train_or_test(argv[0], argv[1:])
    return run_cli(build_parser(), argv)


def _train_or_test(mode: str, rest: list[str]) -> int:
    """`mimickit train|test` take MimicKit's `--key value` arguments (see `python mimickit/run.py`)."""
    from mimickit import run

    if "-h" in rest or "--help" in rest:
        print(f"usage: mimickit {mode} --arg_file FILE [--key value ...]\n")
        print(run.__doc__)
        return 0
    return run.main(["--mode", mode, *rest])


def run_cli(parser: argparse.ArgumentParser, argv: list[str] | None) -> int:
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        with one_line_warnings():
            return func(args)
    except MimicKitError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
