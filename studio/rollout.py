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
the live end's).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from mimickit.run_folder import AGENT_CONFIG_FILE, ENGINE_CONFIG_FILE, ENV_CONFIG_FILE, RunFolder
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import DataPaths
from mimickit.util.warn import collect_warnings
from studio.checkpoints import configs_beside
from studio.playable import Playable, command
from studio.scene import BODY_ERROR_SCALE_M, BODY_ERROR_STOPS, SUPPORT_WINDOW_S, StudioScene
from studio.scene_thread import SceneThread

HISTORY_S = 60.0  # seconds of recorded steps kept for scrubbing back
RELOAD_POLL_S = 1.0  # how often the checkpoint's mtime is checked
MAX_STEP_FRAMES = 300  # one `step` command simulates at most this many steps
MIN_SPEED, MAX_SPEED = 0.05, 4.0


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

    def to_json(self) -> dict[str, Any]:
        return {
            "checkpoint": str(self.checkpoint),
            "env_config": str(self.env_config),
            "agent_config": str(self.agent_config),
            "engine_config": str(self.engine_config) if self.engine_config else None,
            "data_dir": str(self.data_dir) if self.data_dir else None,
            "run_id": self.run_id,
            "run_name": self.run_name,
        }


def source_for_checkpoint(
    checkpoint: Path,
    *,
    env_config: Path | None = None,
    agent_config: Path | None = None,
    engine_config: Path | None = None,
    data_dir: Path | None = None,
    run_id: int | None = None,
    run_name: str | None = None,
) -> RolloutSource:
    """The configs a trainer copied beside `checkpoint` (its folder, or the parent of `int_models/`),
    unless given; MimicKitError when there are none."""
    beside = configs_beside(checkpoint)
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
    return RolloutSource(checkpoint, env, agent, engine, data_dir, run_id, run_name)


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


@dataclass
class EpisodeSummary:
    episode: int
    steps: int
    ret: float
    done: int

    def to_json(self) -> dict[str, Any]:
        return {"episode": self.episode, "steps": self.steps, "return": self.ret, "done": self.done}


class Rollout:
    """The policy of `source.checkpoint` in one env (see the module docstring). Not thread-safe."""

    def __init__(self, source: RolloutSource, history_s: float = HISTORY_S) -> None:
        from mimickit.envs.env_builder import build_env  # torch/mujoco-heavy: only when asked
        from mimickit.learning.agent_builder import build_agent

        self.source = source
        paths = DataPaths(source.data_dir)  # the run's data folder: each rollout its own
        with collect_warnings():  # dropped, as before; not `catch_warnings`, which swaps every thread's filters
            self.env = build_env(source.env_config, source.engine_config, 1, "cpu", visualize=True, data_paths=paths)
            try:
                self.agent = build_agent(source.agent_config, self.env, "cpu", verbose=False, data_paths=paths)
                self.agent.load(source.checkpoint)  # MimicKitError (one line) when it does not fit
            except BaseException:
                self.close()
                raise
        self.agent.eval()
        engine = self.env.engine
        view = engine.mujoco_view(0)  # every engine draws through a MuJoCo model of its scene
        self.model: mujoco.MjModel = view.model
        self._scratch = mujoco.MjData(self.model)  # for drawing recorded frames
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
        # Per-body tracking error against the reference the ghost shows (DeepMimic-style envs).
        tracks = ghost_id is not None and hasattr(self.env, "body_pos_errors")
        self.body_names: list[str] = self.env.char_model.get_body_names() if tracks else []
        self.reward_weights: dict[str, float] = dict(getattr(self.env, "reward_weights", {}) or {})
        self.history: deque[Frame] = deque(maxlen=max(2, round(history_s / self.dt)))
        st = source.checkpoint.stat()
        self.checkpoint_mtime_ns, self.checkpoint_mtime = st.st_mtime_ns, st.st_mtime
        self.reloads = 0
        self.error: str | None = None
        self.steps = 0
        self.episode = -1
        self.episodes: deque[EpisodeSummary] = deque(maxlen=100)
        self.reset()

    @property
    def control_freq(self) -> float:
        return 1.0 / self.dt

    def reset(self) -> None:
        """A new episode (the env's own reset: reference-state init from the clip)."""
        with torch.no_grad():
            self._obs, _ = self.env.reset()
        self.episode += 1
        self.episode_step = 0
        self.episode_return = 0.0
        self._record(None, None, 0)

    def step(self) -> Frame:
        """One control step of the deterministic policy; an episode that ends is reset at once."""
        with torch.no_grad():
            action = self.agent.compute_action(self._obs, deterministic=True)
            obs, reward, done, info = self.env.step(action)
        terms = {k: float(v.reshape(-1)[0]) for k, v in (info.get("reward_terms") or {}).items()}
        r = float(reward.reshape(-1)[0])
        d = int(done.reshape(-1)[0])
        self.steps += 1
        self.episode_step += 1
        self.episode_return += r
        frame = self._record(r, terms, d)
        if d:
            self.episodes.append(EpisodeSummary(self.episode, self.episode_step, self.episode_return, d))
            self.reset()
        else:
            self._obs = obs
        return frame

    def reload_if_newer(self) -> bool:
        """Load the checkpoint again when its file changed; True when new weights were loaded. A file
        that no longer fits keeps the old weights and sets `error`."""
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
        self.reset()
        return True

    def pose(self, frame: Frame) -> tuple[np.ndarray, np.ndarray]:
        """World xpos [nbody, 3] and xmat [nbody, 9] of a recorded frame."""
        d = self._scratch
        d.qpos[:] = frame.qpos
        mujoco.mj_kinematics(self.model, d)
        return d.xpos.copy(), d.xmat.copy()

    def close(self) -> None:
        close = getattr(getattr(getattr(self, "env", None), "engine", None), "close", None)
        if close:
            close()

    def _record(self, reward: float | None, terms: dict[str, float] | None, done: int) -> Frame:
        qpos = self.env.engine.mujoco_view(0).data.qpos.copy()  # the character and the ghost of this step
        frame = Frame(self.steps, self.episode, self.episode_step, qpos, reward, terms, self.episode_return, done)
        if self.body_names:
            frame.body_error = self.env.body_pos_errors()[0].cpu().numpy().astype(np.float64)
        self.history.append(frame)
        return frame

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
            "mean_m": round(float(frame.body_error.mean()), 5),  # = the paper's position error
            "scale_m": BODY_ERROR_SCALE_M,
            "stops": [list(c) for c in BODY_ERROR_STOPS],
            "measure": "position error per body vs the reference: root-relative, the root's own global",
        }


@dataclass
class RolloutState:
    playing: bool = False
    speed: float = 1.0
    follow: bool = True
    view: int | None = None  # index into the history being shown; None: the live end
    updates: int = 0  # scene updates sent
    height: float = 0.0  # how far the ground is lowered when following (see RolloutPlayer._height)
    root_pos: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])


class RolloutPlayer(Playable):
    """A `Rollout` stepped by the scene thread `owner` and drawn in `scene` (None: not drawn, for tests)."""

    def __init__(
        self, rollout: Rollout, scene: StudioScene | None, owner: SceneThread | None = None, *, play: bool = False
    ) -> None:
        super().__init__(owner)
        self.rollout = rollout
        self.scene = scene
        self.state = RolloutState(playing=play)
        self._ground = np.inf  # the lowest `Frame.low_z` drawn so far (see _height)
        if scene is not None:
            error_bodies = rollout.char_bodies if rollout.body_names else None  # coloured by their error
            scene.show_rollout(rollout.model, rollout.ghost_bodies, error_bodies)
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
                    self.rollout.step()
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
    def reset(self) -> None:
        """Start a new episode now."""
        self.rollout.reset()
        self.state.view = None
        self._draw()

    @command
    def close(self) -> None:
        self.state.playing = False
        self.rollout.close()

    def plays_from(self, folder: Path) -> bool:
        """Whether the checkpoint rolled out lies in `folder` (a run folder about to go)."""
        return self.rollout.source.checkpoint.resolve().is_relative_to(Path(folder).resolve())

    # -- reading ------------------------------------------------------------------------------------

    def _snapshot(self) -> dict[str, Any]:
        """The rollout's state, with the clip player's keys (frame/num_frames is the history)."""
        r, s = self.rollout, self.state
        i = self._shown_index()
        shown = r.history[i]
        latest = r.history[-1]
        live_terms = self._last_with_terms(len(r.history) - 1)  # an episode's first frame has none
        src = r.source
        return {
            "mode": "rollout",
            "clip": None,
            "char": None,
            "num_frames": len(r.history),
            "fps": r.control_freq,
            "duration": len(r.history) * r.dt,
            "frame": i,
            "time": shown.step * r.dt,
            "playing": s.playing,
            "speed": s.speed,
            "loop": True,
            "follow": s.follow,
            "updates": s.updates,
            "root_pos": list(s.root_pos),
            "contacts": {},
            "rollout": {
                **src.to_json(),
                "checkpoint_mtime": r.checkpoint_mtime,
                "reloads": r.reloads,
                "error": r.error,
                "control_freq": r.control_freq,
                "step": r.steps,
                "live": s.view is None,
                # The frame the scene shows (a history frame while scrubbed back), as the label shows it.
                "episode": shown.episode,
                "episode_step": shown.episode_step,
                "episode_return": shown.episode_return,
                "reward": shown.reward,  # None for an episode's first frame
                "reward_terms": shown.terms or {},
                "body_error": r.body_error_json(shown),  # the frame shown's, None without a reference
                "latest": {  # the live end, the newest simulated step
                    "step": latest.step,
                    "episode": latest.episode,
                    "episode_step": latest.episode_step,
                    "episode_return": latest.episode_return,
                    "reward": live_terms.reward if live_terms else None,
                    "reward_terms": live_terms.terms if live_terms else {},
                },
                "episodes": [e.to_json() for e in list(r.episodes)[-10:]],
                "follow_height": s.height,
                "reward_weights": r.reward_weights,
                "history_seconds": len(r.history) * r.dt,
                "shown": {
                    "step": shown.step,
                    "episode": shown.episode,
                    "episode_step": shown.episode_step,
                    "reward": shown.reward,
                    "reward_terms": shown.terms or {},
                    "episode_return": shown.episode_return,
                },
            },
        }

    @command
    def history_qpos(self) -> list[np.ndarray]:
        """Copies of the recorded qpos (the timeline), oldest first: what a replay export draws."""
        return [f.qpos.copy() for f in self.rollout.history]

    @command
    def history_rows(self, since_step: int = -1, limit: int = 5000) -> list[dict[str, Any]]:
        """Recorded steps after `since_step` with their reward and terms (episode starts left out)."""
        frames = [f for f in self.rollout.history if f.step > since_step and f.terms is not None]
        dt = self.rollout.dt
        return [
            {
                "step": f.step,
                "time": f.step * dt,
                "episode": f.episode,
                "reward": f.reward,
                "terms": f.terms,
                "body_error": None if f.body_error is None else [round(float(e), 5) for e in f.body_error],
            }
            for f in frames[-limit:]
        ]

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
        if self.scene is not None:
            self.scene.draw_bodies(xpos, xmat, centre, self.state.follow, self.state.height)
            self.scene.colour_bodies(r.body_error_colours(frame), BODY_ERROR_SCALE_M)
        self.state.root_pos = root.astype(float).tolist()
        self.state.updates += 1
        self._changed()

    def _advance(self) -> None:
        """One frame on: the next recorded one while history is shown, else one simulated step."""
        if self.state.view is None:
            self.rollout.step()
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
                if self.rollout.reload_if_newer():
                    self.state.view = None
                    self._draw()
                elif self.rollout.error:
                    self._changed()
            except Exception as e:  # noqa: BLE001
                self.rollout.error = f"reload failed: {e!r}"
        if not self.state.playing or now < self._next_t:
            return
        period = self.rollout.dt / self.state.speed
        try:
            self._advance()
            self._draw()
        except Exception as e:  # noqa: BLE001 - a simulation error pauses the rollout, reported in state
            self.state.playing = False
            self.rollout.error = f"simulation stopped: {e!r}"
            self._changed()
        self._next_t = max(self._next_t + period, now - period)
