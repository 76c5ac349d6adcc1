"""Live rollouts: a checkpoint's deterministic policy driving one env at real time, on either engine.

`Rollout` is the simulation: the env built from a run's copied configs (`env_config.yaml`,
`engine_config.yaml`, `agent_config.yaml` in its out_dir; `data_dir` from its `args.json`) with one env
and `visualize=True`, so that the DeepMimic env adds its reference character (the "ghost", visual
only) to the scene and poses it from the clip every step. It is drawn through the engine's
`mujoco_view`: a MuJoCo model of the scene (the MuJoCo engine's own, a MuJoCo copy for Newton) and the
env's MjData, the character's and the ghost's bodies found by the env's object ids. Each step is
recorded in a ring buffer (qpos, reward, each unweighted reward term), the last `HISTORY_S` seconds;
an episode that ends is reset at once; a newer checkpoint file (polled mtime) is loaded and starts a
new episode.

`RolloutPlayer` runs a `Rollout` on the studio's scene thread at the env's control rate (× speed) and draws it
in the studio's scene. Its commands mirror the clip player's (play, pause, step, seek, configure), so
the REST scene commands and the keys drive whichever is loaded: the timeline is the recorded history;
seeking or stepping back shows a recorded frame (the simulation waits); play goes on from the frame
shown, through the recorded history to the live end, then simulating; step at the live end simulates
one more step. The state's reward, terms and episode figures are those of the frame shown (`latest`:
the live end's). An A/B rollout gives the player a `studio.scene.rollout_pair.RolloutPair`: B steps with A
(frame i of both histories is one moment), is drawn in a lane behind A, and its figures of the same
frame are the state's `b` and the history rows' `b`.

A rollout of several envs (`num_envs` up to MAX_ENVS) steps them in one batched env with one policy call;
env 0 is the one recorded in full and shown by the label, plots and pushes; each other env restarts on
its own when its episode ends, its qpos and fall mark are kept in the frame and its figures in `tallies`;
the player draws them on a grid or overlaid (`layout`).
"""

from __future__ import annotations

import functools
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import mujoco
import numpy as np
import torch

from mimickit.envs.base_env import DoneFlags
from mimickit.envs.viewable import ShowsTaskTarget, TracksReference
from mimickit.learning.run_folder import AGENT_CONFIG_FILE, ENGINE_CONFIG_FILE, ENV_CONFIG_FILE, RunFolder
from mimickit.runner.inputs import RunInputs
from mimickit.runner.policy import load_policy
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths
from mimickit.util.warn import collect_warnings
from studio.runs.checkpoints import MOTION_FILE, configs_beside
from studio.scene.playable import Playable, command
from studio.scene.thread import SceneThread
from studio.scene.view import (
    BODY_ERROR_SCALE_M,
    BODY_ERROR_STOPS,
    PAIR_LANE,
    SUPPORT_WINDOW_S,
    StudioScene,
    error_colour,
)

HISTORY_S = 60.0  # seconds of recorded steps kept for scrubbing back
RATE_WINDOW = 60  # frames the real-time factor is measured over (2 s at 30 Hz)
RELOAD_POLL_S = 1.0  # how often the checkpoint's mtime is checked
MAX_STEP_FRAMES = 300  # one `step` command simulates at most this many steps
MIN_SPEED, MAX_SPEED = 0.05, 4.0
PUBLISHED_ROWS = 600  # history rows published with each state (`Playable.feed`): 20 s at 30 Hz
# A push (`Rollout.push`): a fixed bound, not one scaled by the character's mass, so that one number means
# the same on every character; 5000 N for 0.1 s is an impulse that throws the 45 kg humanoid, and a
# longer or stronger push only flings it out of view.
MAX_PUSH_N = 5000.0
MAX_PUSH_S = 2.0  # the longest push, seconds (rounded to whole control steps by the engine)
# A drag on a body in the 3D view pulls it like a spring (MuJoCo's viewer perturbation): this many N per
# metre of pull per kg of the character (a 1 m pull: 540 N on the 45 kg humanoid), each update a push of
# DRAG_PUSH_S, so the pull acts while the drag lasts (viser sends ~20 updates/s) and ends soon after it.
DRAG_N_PER_M_KG = 12.0
DRAG_PUSH_S = 0.1
MAX_ENVS = 16  # envs of one rollout: the scene thread draws all of them at the control rate on a laptop CPU
LAYOUTS = ("grid", "overlay")  # how a rollout's envs are drawn (RolloutPlayer)
FALL_MARK_S = 1.0  # how long an env's figure stays marked after a fall


@dataclass
class RolloutSource:
    """What a rollout is built from."""

    checkpoint: Path
    env_config: Path
    agent_config: Path
    engine_config: Path | None = None
    data_dir: Path | None = None
    run_id: int | None = None
    run_name: str | None = None
    motion_file: Path | None = None  # replaces the env config's clip (a shipped model's `--motion_file`)

    def inputs(self) -> RunInputs:
        """As `mimickit test` would resolve them; `data/...` names are found in the run's data folder."""
        return RunInputs(
            env_file=str(self.env_config),
            engine_file=str(self.engine_config) if self.engine_config else None,
            agent_file=str(self.agent_config),
            motion_file=str(self.motion_file) if self.motion_file else None,
            data_paths=DataPaths(self.data_dir),
        )

    def missing_clip(self) -> str | None:
        """The clip or dataset the env plays, as its config names it, when the data folders lack it
        (MimicKit's clips are not shipped: a model trained on one needs the studio's `--data-dir`)."""
        if self.motion_file is not None:
            return None  # an arg file's `--motion_file`: found when the source was read
        return _missing_clip(self.env_config, self.engine_config, self.data_dir, _mtime(self.env_config))

    def to_json(self) -> dict[str, Any]:
        return {
            "checkpoint": str(self.checkpoint),
            "env_config": str(self.env_config),
            "agent_config": str(self.agent_config),
            "engine_config": str(self.engine_config) if self.engine_config else None,
            "motion_file": str(self.motion_file) if self.motion_file else None,
            "data_dir": str(self.data_dir) if self.data_dir else None,
            "run_id": self.run_id,
            "run_name": self.run_name,
        }


def _mtime(path: Path) -> int:
    try:
        return path.stat().st_mtime_ns
    except OSError:
        return 0


@functools.lru_cache(maxsize=256)
def _missing_clip(env: Path, engine: Path | None, data_dir: Path | None, _mtime_ns: int) -> str | None:
    """`RolloutSource.missing_clip`, once per config file version (the checkpoint list asks for each)."""
    from mimickit.envs.env_builder import load_env_configs  # every env's module: loaded when first asked

    try:
        env_cfg, _ = load_env_configs(env, engine)
    except (MimicKitError, OSError):
        return None  # a broken config: building the rollout says what is wrong
    motion = getattr(env_cfg, "motion_file", None)
    return motion if motion and not DataPaths(data_dir).resolve(motion).is_file() else None


def source_for_checkpoint(
    checkpoint: Path,
    *,
    env_config: Path | None = None,
    agent_config: Path | None = None,
    engine_config: Path | None = None,
    data_dir: Path | None = None,
    run_id: int | None = None,
    run_name: str | None = None,
    fallback_data_dir: Path | None = None,
) -> RolloutSource:
    """The configs a trainer copied beside `checkpoint` (its folder, or the parent of `int_models/`) or
    its arg file names, unless given (the arg file's `--motion_file` goes with its env config only);
    MimicKitError when there are none. Its data folder: `data_dir`, else the run's, else
    `fallback_data_dir` (the studio's `--data-dir`)."""
    beside = configs_beside(checkpoint)
    motion = Path(beside[MOTION_FILE]) if env_config is None and MOTION_FILE in beside else None
    env = env_config or (Path(beside[ENV_CONFIG_FILE]) if ENV_CONFIG_FILE in beside else None)
    agent = agent_config or (Path(beside[AGENT_CONFIG_FILE]) if AGENT_CONFIG_FILE in beside else None)
    engine = engine_config or (Path(beside[ENGINE_CONFIG_FILE]) if ENGINE_CONFIG_FILE in beside else None)
    if env is None or agent is None:
        missing = " and ".join(n for n, v in (("env_config", env), ("agent_config", agent)) if v is None)
        raise MimicKitError(
            f"{checkpoint}: no {missing} beside it (a run folder has env_config.yaml and agent_config.yaml);"
            f" name the {missing} to roll it out"
        )
    if data_dir is None and beside:
        data_dir = run_data_dir(Path(beside[ENV_CONFIG_FILE]).parent)
    data_dir = data_dir or fallback_data_dir
    return RolloutSource(checkpoint, env, agent, engine, data_dir, run_id, run_name, motion)


def run_data_dir(run_dir: Path) -> Path | None:
    """`--data_dir` of the run, from the args.json the trainer wrote: its effective value (resolved
    against the trainer's working folder), or the top-level list of older run folders."""
    record = RunFolder(run_dir).read_args()
    if record is None:
        return None
    effective = record.get("effective")
    value = effective.get("data_dir") if isinstance(effective, dict) else record.get("data_dir")
    if isinstance(value, list):
        value = value[0] if value else None
    return Path(value) if isinstance(value, str) and value else None


@dataclass(slots=True)
class Frame:
    """One recorded step. `reward`/`terms` are None for the pose an episode starts from."""

    step: int  # simulation steps since the rollout was built
    episode: int
    episode_step: int
    qpos: np.ndarray
    reward: float | None
    terms: dict[str, float] | None
    episode_return: float
    done: int = 0  # DoneFlags of the step that ended an episode (1 fail, 2 success, 3 time)
    low_z: float | None = None  # lowest body origin of the followed figure (see RolloutPlayer._height)
    body_error: np.ndarray | None = None  # [J] metres, each body's tracking error (Rollout.body_names)
    waiting: bool = False  # an ended episode's last pose, held while an A/B partner still runs
    push: tuple[PushMark, ...] = ()  # the pushes that acted on the character during this step
    others: np.ndarray | None = None  # [N-1, nq] float32 qpos of envs 1.. of a rollout of several (None: one env)
    marked: np.ndarray | None = None  # [N] bool: each env fell within FALL_MARK_S before this step
    tallies: np.ndarray | None = None  # [N, 5] each env's `EnvTally.row` after this step (scrubbing back shows them)
    fall_after_push_s: float | None = None  # a fall (done 1) ending an episode, seconds after its last push
    task: dict[str, float | bool | str] | None = None  # a task env's target at this step (ShowsTaskTarget)


@dataclass(frozen=True, slots=True)
class PushMark:
    """One push acting during a recorded step (`Rollout.push`): what the history, the plot and the arrow show."""

    body: str  # the character's body name
    view_body: int  # its MuJoCo body id in `Rollout.model` (where the arrow points)
    force: tuple[float, float, float]  # N, world frame
    duration_s: float  # the whole push, in whole control steps
    start: bool  # the push's first step

    def to_json(self) -> dict[str, Any]:
        return {"body": self.body, "force": list(self.force), "duration_s": self.duration_s}


@dataclass
class EnvTally:
    """One env's figures in a rollout of several: what its finished episodes did and where its current
    one is (env 0's are those of `Rollout.episodes` and the label)."""

    episodes: int = 0  # finished episodes (a user's reset does not finish one)
    falls: int = 0  # of them, ended by failure (DoneFlags.FAIL)
    episode_step: int = 0
    episode_return: float = 0.0
    return_sum: float = 0.0  # of the finished episodes
    last_fall_step: int | None = None  # `Rollout.steps` when it last fell

    def end(self, done: int, steps: int) -> None:
        self.episodes += 1
        self.return_sum += self.episode_return
        if done == DoneFlags.FAIL:
            self.falls += 1
            self.last_fall_step = steps
        self.episode_step, self.episode_return = 0, 0.0

    def row(self) -> tuple[int, int, int, float, float]:
        """The figures as of now, as a frame records them (`Frame.tallies`)."""
        return self.episodes, self.falls, self.episode_step, self.episode_return, self.return_sum

    @staticmethod
    def row_json(env: int, row: Any) -> dict[str, Any]:
        """One env's figures for the scene state from a `row` (live or a recorded frame's)."""
        episodes, falls, episode_step, episode_return, return_sum = row
        return {
            "env": env,
            "episodes": int(episodes),
            "falls": int(falls),
            "episode_step": int(episode_step),
            "episode_return": round(float(episode_return), 4),
            "mean_return": round(float(return_sum) / episodes, 4) if episodes else None,
        }


@dataclass
class EpisodeSummary:
    episode: int
    steps: int
    ret: float
    done: int
    fall_after_push_s: float | None = None  # a fall (done 1) after a push in the episode: seconds since it

    def to_json(self) -> dict[str, Any]:
        return {
            "episode": self.episode,
            "steps": self.steps,
            "return": self.ret,
            "done": self.done,
            "fall_after_push_s": self.fall_after_push_s,
        }


class Rollout:
    """The policy of `source.checkpoint` in one env (see the module docstring). Not thread-safe."""

    def __init__(self, source: RolloutSource, history_s: float = HISTORY_S, num_envs: int = 1) -> None:
        """`num_envs` (1..MAX_ENVS) envs of one batched env, one policy call per step; env 0 is the main
        one (history, label, plots, pushes), the others are drawn and counted (`tallies`)."""
        if not 1 <= num_envs <= MAX_ENVS:
            raise MimicKitError(f"num_envs must be 1 to {MAX_ENVS}, not {num_envs}")
        self.source = source
        self.num_envs = num_envs
        with collect_warnings():  # dropped, as before; not `catch_warnings`, which swaps every thread's filters
            # MimicKitError (one line) when the checkpoint does not fit
            self.env, self.agent = load_policy(source.inputs(), source.checkpoint, num_envs, visualize=True)
        engine = self.env.engine
        view = engine.mujoco_view(0)  # every engine draws through a MuJoCo model of its scene
        self.model: mujoco.MjModel = view.model
        self._scratch = mujoco.MjData(self.model)  # for drawing recorded frames
        # Objects welded to the world (the static_objects env's boxes) are mocap bodies: their pose is not
        # in qpos, so a recorded frame is drawn with the engine's (it never changes after the env is built).
        self._scratch.mocap_pos[:] = view.data.mocap_pos
        self._scratch.mocap_quat[:] = view.data.mocap_quat
        self.dt = float(engine.get_timestep())
        # The character's and the ghost's bodies in that model, by the env's object ids.
        self.root_body = int(view.objects[self.env.get_char_id()].body_ids[0])
        ghost_id = self.env.get_ref_char_id()
        self.ghost_bodies = view.objects[ghost_id].body_ids if ghost_id is not None else np.zeros(0, dtype=np.int64)
        self.ghost_root = int(self.ghost_bodies[0]) if len(self.ghost_bodies) else None
        # Height follow tracks the reference (it may climb; the policy may fall), else the character.
        char_bodies = np.asarray(view.objects[self.env.get_char_id()].body_ids)
        self.follow_bodies = self.ghost_bodies if len(self.ghost_bodies) else char_bodies
        self.char_bodies = char_bodies  # the character's body j -> its MuJoCo body id
        # What an env tracking clips offers (mimickit.envs.viewable): the per-body error against the
        # reference the ghost shows, its reward terms' weights, the clips it plays (resolved paths).
        tracking = self.env if isinstance(self.env, TracksReference) else None
        # Per-body error only where the reward tracks the ghost's pose (not AMP's style, nor its task envs').
        posed = tracking is not None and tracking.tracks_pose and ghost_id is not None
        self.body_names: list[str] = self.env.char_model.get_body_names() if posed else []
        self.reward_weights: dict[str, float] = tracking.reward_weights if tracking else {}
        self.motion_files: list[str] | None = list(tracking.motion_lib.motion_files) if tracking else None
        self.history: deque[Frame] = deque(maxlen=max(2, round(history_s / self.dt)))
        st = source.checkpoint.stat()
        self.checkpoint_mtime_ns, self.checkpoint_mtime = st.st_mtime_ns, st.st_mtime
        self.reloads = 0
        self.error: str | None = None
        self.steps = 0
        self.episode = -1
        self.episodes: deque[EpisodeSummary] = deque(maxlen=100)
        self.ended = 0  # the DoneFlags of an episode that ended without a reset (`step(auto_reset=False)`)
        self.push_bodies: list[str] = engine.get_obj_body_names(self.env.get_char_id())  # what `push` takes
        self._push_steps: dict[int, int] = {}  # body id -> control steps of the push given last (its start)
        self._last_push_step: int | None = None  # `steps` when the episode's last push began
        self._clip_start: tuple[torch.Tensor, torch.Tensor] | None = None  # (clip ids, times) of the episode's start
        self.tallies = [EnvTally() for _ in range(num_envs)]
        self.reset()
        self.spacing_m = self._spacing()

    @property
    def control_freq(self) -> float:
        return 1.0 / self.dt

    def reset(self, same_start: bool = False) -> None:
        """A new episode of every env (the env's own reset: reference-state init from the clip); `same_start`:
        env 0 from the clip state its last episode started from (an env tracking clips), to see one start
        with and without a push."""
        for t in self.tallies:  # cut short by hand, not finished: not counted as an episode
            t.episode_step, t.episode_return = 0, 0.0
        self._start_main(same_start, every_env=True)

    def _start_main(self, same_start: bool = False, every_env: bool = False) -> None:
        """Env 0's next episode (with `every_env`, every env's); its first frame is recorded."""
        tracking = self.env if isinstance(self.env, TracksReference) else None
        if same_start and tracking is not None and self._clip_start is not None:
            tracking.start_next_resets_at(*self._clip_start)  # taken by the first env reset: env 0
        ids = None if every_env or self.num_envs == 1 else torch.zeros(1, dtype=torch.long, device=self.env.device)
        with torch.no_grad():
            self._obs, _ = self.env.reset(ids)
        if tracking is not None:  # right after the reset the clip time is the start's
            self._clip_start = (tracking.get_motion_ids()[:1], tracking.get_motion_time()[:1].clone())
        self.episode += 1
        self.episode_step = 0
        self.episode_return = 0.0
        self.ended = 0
        self._last_push_step = None  # the env's reset placed the character anew: its pushes ended
        self._record(None, None, 0)

    def restart(self) -> None:
        """Forget the recorded steps and episodes and start again from episode 0 (an A/B pair's first
        start replaces the one each side recorded when it was built)."""
        self.history.clear()
        self.episodes.clear()
        self.episode = -1
        self.reset()

    def step(self, auto_reset: bool = True) -> Frame:
        """One control step of the deterministic policy; an episode that ends is reset at once, or with
        `auto_reset` False left ended (`ended`: its done flag) until `reset`."""
        pushes = self._acting_pushes()  # read before the step that applies them (it counts them down)
        with torch.no_grad():
            action = self.agent.compute_action(self._obs, deterministic=True)
            obs, reward, done, info = self.env.step(action)
        terms = {k: float(v.reshape(-1)[0]) for k, v in (info.get("reward_terms") or {}).items()}
        rewards = [float(x) for x in reward.reshape(-1).tolist()]
        dones = [int(x) for x in done.reshape(-1).tolist()]
        r, d = rewards[0], dones[0]
        self.steps += 1
        self.episode_step += 1
        self.episode_return += r
        for i, t in enumerate(self.tallies):
            t.episode_step += 1
            t.episode_return += rewards[i]
            if dones[i]:
                t.end(dones[i], self.steps)
        frame = self._record(r, terms, d, pushes)  # the ended envs' last poses, before they restart
        if not d:
            self._obs = obs
        if ended := [i for i in range(1, self.num_envs) if dones[i]]:  # the others restart on their own
            with torch.no_grad():
                self._obs, _ = self.env.reset(torch.tensor(ended, dtype=torch.long, device=self.env.device))
        if d:
            summary = EpisodeSummary(self.episode, self.episode_step, self.episode_return, d, frame.fall_after_push_s)
            self.episodes.append(summary)
            if auto_reset:
                self._start_main()
            else:
                self.ended = d
        return frame

    def check_push(self, body: str, force: list[float] | tuple[float, ...], duration_s: float) -> int:
        """The body id of a valid push of the character (`push`); MimicKitError (one line) otherwise."""
        if body not in self.push_bodies:
            raise MimicKitError(f"no body {body[:60]!r} on the character; its bodies: {', '.join(self.push_bodies)}")
        f = np.asarray(force, dtype=np.float64).reshape(-1)
        if f.shape != (3,) or not np.isfinite(f).all():
            raise MimicKitError("force must be 3 finite numbers [x, y, z] in newtons (world frame, z up)")
        if np.linalg.norm(f) > MAX_PUSH_N:
            raise MimicKitError(f"a force of {np.linalg.norm(f):.0f} N is more than a push's {MAX_PUSH_N:.0f} N")
        if not (np.isfinite(duration_s) and 0 < duration_s <= MAX_PUSH_S):
            raise MimicKitError(f"duration_s must be above 0 and at most {MAX_PUSH_S:g} s, not {duration_s}")
        return self.push_bodies.index(body)

    def push(
        self, body: str, force: list[float] | tuple[float, ...], duration_s: float, env_id: int = 0
    ) -> dict[str, Any]:
        """Push the character's `body` with `force` (N, world frame, at its centre of mass) over the next
        control steps (`Engine.apply_body_force`: whole steps); it acts from the next simulated step and
        ends with the episode. Bounds: MAX_PUSH_N, MAX_PUSH_S. `env_id`: another env of a rollout of
        several (only env 0's pushes are recorded in its frames and drawn as arrows)."""
        body_id = self.check_push(body, force, duration_s)
        if not 0 <= env_id < self.num_envs:
            raise MimicKitError(f"env must be 0 to {self.num_envs - 1} (the rollout's envs), not {env_id}")
        f = [float(x) for x in force]
        char = self.env.get_char_id()
        steps = self.env.engine.apply_body_force(env_id, char, body_id, f, duration_s=float(duration_s))
        if env_id == 0:
            self._push_steps[body_id] = steps
        return {"body": body, "force": f, "duration_s": steps * self.dt, "steps": steps, "env": env_id}

    def _acting_pushes(self) -> tuple[PushMark, ...]:
        """The character's pushes the next step applies, as recorded marks."""
        char = self.env.get_char_id()
        marks = []
        for f in self.env.engine.get_body_forces(0):
            if f.obj_id != char:
                continue
            total = self._push_steps.get(f.body_id, f.steps_left)
            force = (float(f.force[0]), float(f.force[1]), float(f.force[2]))
            name, view_body = self.push_bodies[f.body_id], int(self.char_bodies[f.body_id])
            marks.append(PushMark(name, view_body, force, total * self.dt, f.steps_left == total))
        return tuple(marks)

    def hold(self) -> Frame:
        """One control step of waiting after an ended episode: its last pose again, no reward (an A/B
        partner still runs; both histories keep one frame per step)."""
        self.steps += 1
        frame = replace(
            self.history[-1], step=self.steps, reward=None, terms=None, waiting=True, push=(), fall_after_push_s=None
        )
        self.history.append(frame)
        return frame

    def reload_if_newer(self, reset: bool = True) -> bool:
        """Load the checkpoint again when its file changed; True when new weights were loaded (and, with
        `reset`, a new episode started). A file that no longer fits keeps the old weights and sets `error`."""
        try:
            st = self.source.checkpoint.stat()
        except OSError:
            return False
        if st.st_mtime_ns == self.checkpoint_mtime_ns:
            return False
        # This version is tried once, fitting or not.
        self.checkpoint_mtime_ns, self.checkpoint_mtime = st.st_mtime_ns, st.st_mtime
        try:
            self.agent.load(self.source.checkpoint)
        except MimicKitError as e:
            self.error = f"kept the previous weights: {e}"
            return False
        self.agent.eval()
        self.error = None
        self.reloads += 1
        if reset:
            self.reset()
        return True

    def pose(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """World xpos [nbody, 3] and xmat [nbody, 9] of a recorded frame."""
        d = self._scratch
        d.qpos[:] = frame.qpos
        mujoco.mj_kinematics(self.model, d)
        return d.xpos.copy(), d.xmat.copy()

    def close(self) -> None:
        self.env.engine.close()  # every engine has one (mimickit.engines.engine.Engine)

    def _record(
        self, reward: float | None, terms: dict[str, float] | None, done: int, pushes: tuple[PushMark, ...] = ()
    ) -> Frame:
        qpos = self.env.engine.mujoco_view(0).data.qpos.copy()  # the character and the ghost of this step
        frame = Frame(self.steps, self.episode, self.episode_step, qpos, reward, terms, self.episode_return, done)
        frame.push = pushes
        if any(p.start for p in pushes):
            self._last_push_step = self.steps  # the step it began on: the plot's push marker
        if done == DoneFlags.FAIL and self._last_push_step is not None:  # a fall, not the time limit or clip end
            frame.fall_after_push_s = round((self.steps - self._last_push_step) * self.dt, 3)
        if self.body_names:  # only for an env that tracks a reference (see __init__)
            frame.body_error = self.env.body_pos_errors()[0].cpu().numpy().astype(np.float64)
        if isinstance(self.env, ShowsTaskTarget):  # recorded per frame: scrubbing back shows that step's
            frame.task = self.env.task_target(0)
        if self.num_envs > 1:
            self._record_others(frame)
        self.history.append(frame)
        return frame

    def _record_others(self, frame: Frame) -> None:
        """Envs 1..N-1 of `frame`: their qpos (float32: 16 envs x 60 s stay small), the fall marks and every
        env's tally."""
        engine = self.env.engine
        frame.others = np.stack([engine.mujoco_view(i).data.qpos for i in range(1, self.num_envs)]).astype(np.float32)
        window = round(FALL_MARK_S / self.dt)
        frame.marked = np.array(
            [t.last_fall_step is not None and self.steps - t.last_fall_step < window for t in self.tallies]
        )
        frame.tallies = np.array([t.row() for t in self.tallies], dtype=np.float64)

    def pose_others(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """World xpos [N-1, nbody, 3] and xmat [N-1, nbody, 9] of envs 1.. in a recorded frame (env-local:
        each env's own world, as the engine simulates it)."""
        if frame.others is None:
            return np.zeros((0, self.model.nbody, 3)), np.zeros((0, self.model.nbody, 9))
        d = self._scratch
        xpos = np.empty((len(frame.others), self.model.nbody, 3))
        xmat = np.empty((len(frame.others), self.model.nbody, 9))
        for k, q in enumerate(frame.others):
            d.qpos[:] = q
            mujoco.mj_kinematics(self.model, d)
            xpos[k], xmat[k] = d.xpos, d.xmat
        return xpos, xmat

    def _spacing(self) -> float:
        """The grid's cell (metres) from the character's size: its standing height (body origins of the
        first pose, plus the largest geom's radius at each end) and 30 % room; about 2 m for the humanoid."""
        xpos, _ = self.pose(self.history[-1])
        z = xpos[self.char_bodies, 2]
        radius = float(self.model.geom_rbound[np.isin(self.model.geom_bodyid, self.char_bodies)].max(initial=0.0))
        return round(max(1.0, 1.3 * (float(z.max() - z.min()) + 2 * radius)), 1)

    def body_error_colours(self, frame: Frame) -> dict[int, float]:
        """{MuJoCo body id of the character: its error in metres} of `frame` (empty without a reference),
        what `StudioScene.colour_bodies` takes."""
        if frame.body_error is None:
            return {}
        return {int(b): float(e) for b, e in zip(self.char_bodies, frame.body_error, strict=True)}

    def body_error_json(self, frame: Frame) -> dict[str, Any] | None:
        """The per-body tracking error of `frame` for the scene state (None without a reference)."""
        if frame.body_error is None:
            return None
        return {
            "bodies": self.body_names,
            "errors_m": [round(float(e), 5) for e in frame.body_error],
            # each body's colour in the 3D view, for the page's bars: the formula lives only in view.py
            "colours": [list(error_colour(e)) for e in frame.body_error],
            "mean_m": round(float(frame.body_error.mean()), 5),  # = the paper's position error
            "scale_m": BODY_ERROR_SCALE_M,
            "stops": [list(c) for c in BODY_ERROR_STOPS],
            "measure": "position error per body vs the reference: root-relative, the root's own global",
        }


class Lockstep(Protocol):
    """What the player drives of an A/B rollout (`studio.scene.rollout_pair.RolloutPair`, which builds on
    `Rollout`: declared here so that this module does not import it back)."""

    a: Rollout
    b: Rollout

    @property
    def sides(self) -> tuple[Rollout, Rollout]: ...

    def reset(self, same_start: bool = False) -> None: ...

    def step(self) -> None: ...

    def reload_if_newer(self) -> bool: ...

    def close(self) -> None: ...


@dataclass
class RolloutState:
    playing: bool = False
    speed: float = 1.0
    follow: bool = True
    view: int | None = None  # index into the history being shown; None: the live end
    updates: int = 0  # scene updates sent
    height: float = 0.0  # how far the ground is lowered when following (see RolloutPlayer._height)
    root_pos: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    push_body: str | None = None  # the body a click in the 3D view picked for the page's Push (None: the root)
    last_push: dict[str, Any] | None = None  # the last push given: body, force, duration_s, steps, at_step


class RolloutPlayer(Playable):
    """A `Rollout` stepped by the scene thread `owner` and drawn in `scene` (None: not drawn, for tests)."""

    def __init__(
        self,
        rollout: Rollout,
        scene: StudioScene | None,
        owner: SceneThread | None = None,
        *,
        play: bool = False,
        pair: Lockstep | None = None,
        layout: str = "grid",
    ) -> None:
        """`pair`: an A/B rollout whose A is `rollout`; B is stepped in lockstep and drawn beside it.
        `layout`: how a rollout of several envs is drawn, "grid" (each env on its cell of a square grid)
        or "overlay" (all where they are simulated, the others translucent)."""
        super().__init__(owner)
        if pair is not None and pair.a is not rollout:
            raise ValueError("the A/B pair's A must be the rollout shown")
        if layout not in LAYOUTS:
            raise MimicKitError(f"layout must be one of {', '.join(LAYOUTS)}, not {layout[:40]!r}")
        self.layout = layout
        # Each env's offset from where it is simulated (env-local: all at one origin): grid cells.
        n = rollout.num_envs
        self.cells = grid_cells(n, rollout.spacing_m) if layout == "grid" else np.zeros((n, 3))
        self._at = np.zeros((rollout.num_envs, 3))  # each env's root as drawn in the frame shown (the state)
        self.rollout = rollout
        self.pair = pair
        self.scene = scene
        self.state = RolloutState(playing=play)
        self._ground = np.inf  # the lowest `Frame.low_z` drawn so far (see _height)
        self._rows: deque[dict[str, Any]] = deque(maxlen=PUBLISHED_ROWS)  # see _published_rows
        self._played: deque[float] = deque(maxlen=RATE_WINDOW)  # when the last frames were played
        if scene is not None:
            # B's character is drawn only by its body meshes (A's also by mjviser): all of them, always.
            b = (pair.b.model, pair.b.ghost_bodies, pair.b.char_bodies) if pair is not None else None
            scene.show_rollout(*_figure(rollout), partner=b)
            if rollout.num_envs > 1:
                scene.show_crowd(rollout.model, rollout.char_bodies, self.cells, layout == "overlay", rollout.spacing_m)
            scene.on_body_click(self._clicked, self._dragged)  # a click on A's body picks it, a drag pulls it
        now = time.monotonic()
        self._next_t, self._next_poll = now, now + RELOAD_POLL_S
        self._draw()

    # -- commands (any thread: run on the scene thread) ----------------------------------------------

    @command
    def play(self) -> None:
        """Play on from the frame shown: through the recorded history first (at the control rate),
        then simulating from the live end."""
        if not self.state.playing:
            self._next_t = time.monotonic()
            self._played.clear()
        self.state.playing = True
        self._changed()

    @command
    def step(self, frames: int = 1) -> None:
        """Pause; forward through the recorded history, simulating at its live end; back for frames < 0."""
        self.state.playing = False
        hist = self.rollout.history
        if frames < 0:
            self.state.view = max(0, self._shown_index() + frames)
        else:
            for _ in range(min(frames, MAX_STEP_FRAMES)):
                i = self._shown_index()
                if i < len(hist) - 1:
                    self.state.view = i + 1
                else:
                    self._simulate()
                    self.state.view = None
            if self.state.view is not None and self.state.view >= len(hist) - 1:
                self.state.view = None
        self._draw()

    @command
    def seek(self, *, frame: int | None = None, time_s: float | None = None) -> None:
        """Show a recorded frame (pauses): `frame` indexes the history, `time_s` is rollout time."""
        hist = self.rollout.history
        if frame is None:  # the last frame at or before that step (an episode's end and the next
            step = round((time_s or 0.0) / self.rollout.dt)  # episode's start share a step number)
            frame = max([0, *(i for i, f in enumerate(hist) if f.step <= step)])
        self.state.playing = False
        i = max(0, min(int(frame), len(hist) - 1))
        self.state.view = None if i == len(hist) - 1 else i
        self._draw()

    @command
    def configure(self, *, speed: float | None = None, loop: bool | None = None, follow: bool | None = None) -> None:
        if speed is not None:
            self.state.speed = min(max(float(speed), MIN_SPEED), MAX_SPEED)
        if follow is not None:
            self.state.follow = bool(follow)
            self._draw()
        self._changed()

    @command
    def reset(self, same_start: bool = False) -> None:
        """Start a new episode now (an A/B pair: both, from one clip state); `same_start`: from the clip
        state the last one started from."""
        (self.pair or self.rollout).reset(same_start)
        self.state.view = None
        self._draw()

    @command
    def close(self) -> None:
        self.state.playing = False
        (self.pair or self.rollout).close()

    @command
    def push(self, body: str | None, force: list[float], duration_s: float, env: int = 0) -> dict[str, Any]:
        """Push `body` of the character (None: the one a click picked, else the root; of both in an A/B
        rollout: the same push, for a fair comparison) from the next simulated step (`Rollout.push`); the
        view goes to the live end, where it acts. `env`: which env of a rollout of several."""
        body = body or self.state.push_body or self.rollout.push_bodies[0]
        for r in self.sides:  # every side accepts it before any is pushed
            r.check_push(body, force, duration_s)
        given = [r.push(body, force, duration_s, env) for r in self.sides][0]
        self.state.last_push = {**given, "at_step": self.rollout.steps + 1}
        self.state.view = None
        self._draw()
        return given

    @command
    def pick(self, view_body: int) -> None:
        """A click in the 3D view on the character's body `view_body` (a MuJoCo body id of A's model)."""
        r = self.rollout
        hit = np.flatnonzero(np.asarray(r.char_bodies) == view_body)
        if len(hit):
            self.state.push_body = r.push_bodies[int(hit[0])]
            self._changed()

    @command
    def drag(self, view_body: int, pull: np.ndarray | None) -> None:
        """A drag in the 3D view on A's body `view_body` by `pull` [3] metres (world; None: released):
        picks the body and pushes it with a spring's force (DRAG_N_PER_M_KG) for DRAG_PUSH_S."""
        self.pick(view_body)
        if pull is None or view_body not in self.rollout.char_bodies:
            return
        mass = float(self.rollout.model.body_mass[self.rollout.char_bodies].sum())
        force = DRAG_N_PER_M_KG * mass * np.asarray(pull, dtype=np.float64)
        norm = float(np.linalg.norm(force))
        if norm > MAX_PUSH_N:
            force *= MAX_PUSH_N / norm
        if norm > 0:
            self.push(self.state.push_body, force.tolist(), DRAG_PUSH_S)

    def _clicked(self, view_body: int) -> None:
        """viser's callback (its thread pool): queued for the scene thread, not waited for."""
        self._from_viser(self.pick, view_body)

    def _dragged(self, view_body: int, pull: np.ndarray | None) -> None:
        self._from_viser(self.drag, view_body, pull)

    def _from_viser(self, command: Callable[..., Any], *args: Any) -> None:
        if self.owner is None:
            command(*args)
        else:
            self.owner.submit(command, *args)

    @property
    def sides(self) -> tuple[Rollout, ...]:
        """The rollouts shown: A alone, or A and B."""
        return self.pair.sides if self.pair is not None else (self.rollout,)

    def plays_from(self, folder: Path) -> bool:
        """Whether a checkpoint rolled out lies in `folder` (a run folder about to go)."""
        folder = Path(folder).resolve()
        return any(r.source.checkpoint.resolve().is_relative_to(folder) for r in self.sides)

    # -- reading ------------------------------------------------------------------------------------

    def _snapshot(self) -> dict[str, Any]:
        """The rollout's state, with the clip player's keys (frame/num_frames is the history)."""
        r, s = self.rollout, self.state
        i = self._shown_index()
        return {
            "mode": "rollout",
            "clip": None,
            "char": None,
            "num_frames": len(r.history),
            "fps": r.control_freq,
            "duration": len(r.history) * r.dt,
            "frame": i,
            "time": r.history[i].step * r.dt,
            "playing": s.playing,
            "speed": s.speed,
            "loop": True,
            "follow": s.follow,
            "updates": s.updates,
            "root_pos": list(s.root_pos),
            "contacts": {},
            "rollout": self._rollout_json(i),
        }

    def _rollout_json(self, i: int) -> dict[str, Any]:
        """The state's `rollout`: A's source and figures of the frame shown (a history frame while
        scrubbed back, as the label shows it), B's of the same frame, and the live end's (`latest`)."""
        r, s = self.rollout, self.state
        shown = r.history[i]
        live = self._last_with_terms(len(r.history) - 1)  # an episode's first frame has none
        return {
            **_side_json(r, i),  # source, reloads, error; episode, reward, terms, body error, waiting
            "control_freq": r.control_freq,
            "real_time_factor": self._real_time_factor(),
            "step": r.steps,
            "live": s.view is None,
            "latest": {  # the live end, the newest simulated step
                "step": r.history[-1].step,
                "episode": r.history[-1].episode,
                "episode_step": r.history[-1].episode_step,
                "episode_return": r.history[-1].episode_return,
                "reward": live.reward if live else None,
                "reward_terms": live.terms if live else {},
            },
            "b": _side_json(self.pair.b, i) if self.pair is not None else None,  # B at the same frame
            "figures": self.scene.figures() if self.scene is not None else [],  # A/B: both, as drawn
            "envs": self._envs_json(shown),
            "follow_height": s.height,
            "reward_weights": r.reward_weights,
            "motion_files": r.motion_files,
            "history_seconds": len(r.history) * r.dt,
            "push": {  # what the page's Push control offers and what it last did
                "bodies": r.push_bodies,
                "picked": s.push_body or r.push_bodies[0],
                "max_force_n": MAX_PUSH_N,
                "max_duration_s": MAX_PUSH_S,
                "last": s.last_push,
                "acting": [p.to_json() for p in shown.push],  # on the frame shown
            },
            "shown": {
                "step": shown.step,
                "episode": shown.episode,
                "episode_step": shown.episode_step,
                "reward": shown.reward,
                "reward_terms": shown.terms or {},
                "episode_return": shown.episode_return,
            },
        }

    def _envs_json(self, shown: Frame) -> dict[str, Any]:
        """The rollout's envs: how many, how drawn, and per env its episodes, falls, current episode step,
        mean return of finished episodes, where its root is drawn and whether its figure is marked by a
        recent fall: all as of the frame shown."""
        r = self.rollout
        marked = shown.marked if shown.marked is not None else np.zeros(r.num_envs, dtype=bool)
        rows = shown.tallies if shown.tallies is not None else [t.row() for t in r.tallies]
        return {
            "num_envs": r.num_envs,
            "layout": self.layout,
            "spacing_m": r.spacing_m,
            "drawn": self.scene.crowd() if self.scene is not None else None,  # envs 1.. as the 3D view has them
            "per_env": [
                {**EnvTally.row_json(i, row), "at": [round(float(v), 3) for v in at], "marked": bool(m)}
                for i, (row, at, m) in enumerate(zip(rows, self._at, marked, strict=True))
            ],
        }

    def _real_time_factor(self) -> float | None:
        """Rollout seconds played per wall second over the last `RATE_WINDOW` frames (None while paused):
        below the speed asked for when the machine cannot keep up."""
        t = self._played
        if not self.state.playing or len(t) < 2 or t[-1] <= t[0]:
            return None
        return round((len(t) - 1) * self.rollout.dt / (t[-1] - t[0]), 2)

    @command
    def history_qpos(self) -> list[np.ndarray]:
        """Copies of the recorded qpos (the timeline), oldest first: what a replay export draws."""
        return [f.qpos.copy() for f in self.rollout.history]

    @command
    def history_rows(self, since_step: int = -1, limit: int = 5000) -> list[dict[str, Any]]:
        """Recorded steps after `since_step` with their reward and terms (episode starts left out; an
        A/B rollout: `b`, B's reward and terms of the same step, null where a side has none), at most
        the last `limit`."""
        hist = self.rollout.history
        b_hist = self.pair.b.history if self.pair is not None else None
        picked: list[int] = []
        for i in range(len(hist) - 1, -1, -1):  # newest first: steps never go back along the history
            if hist[i].step <= since_step or len(picked) == limit:
                break
            if hist[i].terms is not None or (b_hist is not None and b_hist[i].terms is not None):
                picked.append(i)
        return [self._row(i) for i in reversed(picked)]

    def _row(self, i: int) -> dict[str, Any]:
        f = self.rollout.history[i]
        row = {
            "step": f.step,
            "time": f.step * self.rollout.dt,
            "episode": f.episode,
            "reward": f.reward,
            "terms": f.terms or {},
            "body_error": None if f.body_error is None else [round(float(e), 5) for e in f.body_error],
            "push": [p.to_json() for p in f.push if p.start] or None,  # pushes that began on this step
            "fall_after_push_s": f.fall_after_push_s,
        }
        if self.pair is not None:
            b = self.pair.b.history[i]
            row["b"] = {"reward": b.reward, "terms": b.terms or {}}
        return row

    def _published_rows(self) -> tuple[dict[str, Any], ...]:
        """The last `PUBLISHED_ROWS` history rows: those recorded since the last change are added to the
        ones published before (a row, once recorded, does not change; steps only go forward)."""
        new = self.history_rows(self._rows[-1]["step"] if self._rows else -1, PUBLISHED_ROWS)
        self._rows.extend(new)
        return tuple(self._rows)

    # -- internals ----------------------------------------------------------------------------------

    def _last_with_terms(self, i: int) -> Frame | None:
        """The frame `i` or, for an episode's first frame (no reward yet), the latest before it."""
        hist = self.rollout.history
        for j in range(i, -1, -1):
            if hist[j].terms is not None:
                return hist[j]
        return None

    def _shown_index(self) -> int:
        n = len(self.rollout.history)
        return n - 1 if self.state.view is None else min(self.state.view, n - 1)

    def _draw(self) -> None:
        r = self.rollout
        i = self._shown_index()
        frame = r.history[i]
        xpos, xmat = r.pose(frame)
        frame.low_z = float(xpos[r.follow_bodies, 2].min())
        self.state.height = self._height(i)
        root = xpos[r.root_body]
        # Following keeps the pair in view: the point halfway between the character and its ghost.
        centre = root if r.ghost_root is None else 0.5 * (root + xpos[r.ghost_root])
        partner, partner_errors = None, None
        arrows = _push_arrows(frame, xpos)
        if self.pair is not None:  # B's frame i is the same moment as A's (studio.scene.rollout_pair)
            b = self.pair.b
            b_frame = b.history[i]
            partner, partner_errors = b.pose(b_frame), b.body_error_colours(b_frame)
            arrows = np.concatenate([arrows, _push_arrows(b_frame, partner[0] + PAIR_LANE)])
        self._at[0] = root
        if r.num_envs > 1:
            self._draw_others(frame)
        if self.scene is not None:
            self.scene.draw_bodies(xpos, xmat, centre, self.state.follow, self.state.height, partner)
            self.scene.draw_push(arrows)
            self.scene.colour_bodies(r.body_error_colours(frame), BODY_ERROR_SCALE_M, partner_errors)
        self.state.root_pos = root.astype(float).tolist()
        self.state.updates += 1
        self._changed()

    def _draw_others(self, frame: Frame) -> None:
        """Envs 1.. of `frame` on their cells (before env 0's draw, whose flush sends them too)."""
        r = self.rollout
        xpos, xmat = r.pose_others(frame)
        xpos += self.cells[1:, None, :]
        self._at[1:] = xpos[:, r.root_body]
        if self.scene is not None and frame.marked is not None:
            falls = frame.tallies[:, 1] if frame.tallies is not None else [t.falls for t in r.tallies]
            self.scene.draw_crowd(xpos, xmat, frame.marked[1:], [int(f) for f in falls])

    def _simulate(self) -> None:
        """One simulated step: of the rollout, or of both sides of an A/B pair."""
        (self.pair or self.rollout).step()

    def _advance(self) -> None:
        """One frame on: the next recorded one while history is shown, else one simulated step."""
        if self.state.view is None:
            self._simulate()
            return
        self.state.view += 1
        if self.state.view >= len(self.rollout.history) - 1:
            self.state.view = None

    def _height(self, i: int) -> float:
        """How far the followed figure stands above the lowest level it has stood on: the lowest of
        its bodies over the last `SUPPORT_WINDOW_S` of the episode (a lifted foot or a jump do not
        count), above the lowest seen in the whole rollout (the ground)."""
        r, hist = self.rollout, self.rollout.history
        episode = hist[i].episode
        lows = []
        for j in range(i, max(-1, i - round(SUPPORT_WINDOW_S / r.dt) - 1), -1):
            f = hist[j]
            if f.episode != episode:
                break
            if f.low_z is None:
                f.low_z = float(r.pose(f)[0][r.follow_bodies, 2].min())
            lows.append(f.low_z)
        self._ground = min(self._ground, *lows)
        return max(0.0, min(lows) - self._ground)

    def due(self) -> float | None:
        """The next control step while playing, else the next checkpoint poll."""
        return min(self._next_t, self._next_poll) if self.state.playing else self._next_poll

    def tick(self, now: float) -> None:
        """Step at control rate × speed while playing (no bursts to catch up); poll the checkpoint."""
        if now >= self._next_poll:
            self._next_poll = now + RELOAD_POLL_S
            try:
                if (self.pair or self.rollout).reload_if_newer():
                    self.state.view = None
                    self._draw()
                elif any(r.error for r in self.sides):
                    self._changed()
            except Exception as e:  # noqa: BLE001
                self.rollout.error = f"reload failed: {e!r}"
        if not self.state.playing or now < self._next_t:
            return
        period = self.rollout.dt / self.state.speed
        try:
            self._advance()
            self._played.append(now)
            self._draw()
        except Exception as e:  # noqa: BLE001 - a simulation error pauses the rollout, reported in state
            self.state.playing = False
            self.rollout.error = f"simulation stopped: {e!r}"
            self._changed()
        self._next_t = max(self._next_t + period, now - period)


def grid_cells(n: int, spacing: float) -> np.ndarray:
    """[n, 3] places of n envs on a square grid `spacing` m apart: env 0 at the origin, the others in
    rows along -x (env 0's ghost stands at +x) and further rows behind (+y)."""
    side = int(np.ceil(np.sqrt(n)))
    i = np.arange(n)
    return np.stack([-(i % side) * spacing, (i // side) * spacing, np.zeros(n)], axis=1).astype(np.float64)


def _push_arrows(frame: Frame, xpos: np.ndarray) -> np.ndarray:
    """[P, 2, 3] arrows (tail, head) of the pushes acting in `frame`, `xpos` its bodies where they are
    drawn: each ends at its body, pointing along the force, longer for a stronger push (0.3 m to 1.3 m)."""
    arrows = []
    for p in frame.push:
        f = np.asarray(p.force)
        n = float(np.linalg.norm(f))
        if n > 0.0:
            head = xpos[p.view_body]
            arrows.append((head - f / n * (0.3 + n / MAX_PUSH_N), head))
    return np.asarray(arrows, dtype=np.float64).reshape(-1, 2, 3)


def _figure(r: Rollout) -> tuple[mujoco.MjModel, np.ndarray, np.ndarray | None]:
    """What the scene draws of `r`: its model, ghost bodies, and the bodies coloured by their error."""
    return r.model, r.ghost_bodies, r.char_bodies if r.body_names else None


def _side_json(r: Rollout, i: int) -> dict[str, Any]:
    """One side (A, or B of an A/B rollout) at history frame `i`: its source and what the label and plots
    show (`reward` None for an episode's first frame; `body_error` None without a reference; `waiting`:
    an A/B side's ended episode, held until the other ends)."""
    shown = r.history[min(i, len(r.history) - 1)]
    return {
        **r.source.to_json(),
        "checkpoint_mtime": r.checkpoint_mtime,
        # The training the weights have seen (the checkpoint's `_train_state`; 0 for a file without one).
        "iteration": r.agent.get_iteration(),
        "samples": r.agent.get_sample_count(),
        "reloads": r.reloads,
        "error": r.error,
        "episode": shown.episode,
        "episode_step": shown.episode_step,
        "episode_return": shown.episode_return,
        "reward": shown.reward,
        "reward_terms": shown.terms or {},
        "body_error": r.body_error_json(shown),
        "task": shown.task,  # a task env's target (ShowsTaskTarget), else None
        "waiting": shown.waiting,
        "episodes": [e.to_json() for e in list(r.episodes)[-10:]],
    }
