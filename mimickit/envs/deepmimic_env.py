"""DeepMimicEnv: track a reference clip (the reference's `deepmimic`).

Reference-state initialisation from the MotionLib, observations with target frames ahead, the
five-term imitation reward (`deepmimic_rewards`), early termination on ground contact of non-contact
bodies and on pose deviation. `info["reward_terms"]` holds each unweighted term [N] of the last step's
reward and `info["tracking"]` the tracking errors [N]. A reset leaves both as the last step's (like the
reward buffer, they describe the step that ended the episode until the env steps again), except that in
TEST mode it updates and records the tracking errors of its envs, as the reference does. A reset observes
the state it set (the reference frame, held by its `ResetBatch`) without reading the engine back, and
takes that frame from a pool evaluated ahead during the physics (see "reset pool"). A step reads the
character's state from the engine once, for its observations, info, reward and done flags alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import torch

from mimickit.anim.motion import LoopMode
from mimickit.anim.motion_lib import MotionLib
from mimickit.engines.engine import ObjType
from mimickit.envs.base_env import DoneFlags, EnvMode
from mimickit.envs.char_env import CharEnv
from mimickit.envs.char_obs import compute_phase_obs, compute_tar_pose_obs, join_tar_obs
from mimickit.envs.deepmimic_rewards import (
    TERM_NAMES,
    TRACKING_NAMES,
    Deltas,
    body_pos_errors,
    compute_reward_errors,
    reward_terms,
    stacked_tracking_errors,
    state_deltas,
)
from mimickit.envs.env_config import DeepMimicEnvConfig
from mimickit.envs.viewable import TracksReference
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

REF_CHAR_COLOR = (0.3, 0.5, 0.1)
CONTACT_FORCE_THRESHOLD = 0.1  # N: any larger ground force on a non-contact body ends the episode
ClipGroup = tuple[torch.Tensor, torch.Tensor, torch.Tensor]  # motion ids [n], times [n], steps [s] (× dt)


@dataclass(frozen=True)
class ResetBatch:
    """The envs one `reset()` resets (the ids its hooks receive) and the character state it set for them:
    the reference frame with its FK bodies (the `_char_state` keys but `dof_pos`). The reset's observations
    and info read it rather than the engine, which would recompute the same (to float rounding) with a
    kinematics pass that the next step does anyway."""

    env_ids: torch.Tensor
    char_state: dict[str, torch.Tensor]


class DeepMimicEnv(CharEnv, TracksReference):
    config: DeepMimicEnvConfig

    # ----------------------------------------------------------- construction
    def _build_envs(self, config: DeepMimicEnvConfig, num_envs: int) -> None:
        self._enable_ref_char = self._visualize and config.visualize_ref_char
        super()._build_envs(config, num_envs)
        self._motion_lib = MotionLib(config.motion_file, self._char_model, self.device, data_paths=self.data_paths)

    def _build_env(self, env_id: int, config: DeepMimicEnvConfig) -> None:
        super()._build_env(env_id, config)
        if self._enable_ref_char:
            self._ref_char_id = self._engine.create_obj(
                env_id=env_id,
                obj_type=ObjType.articulated,
                asset_file=str(self._char_file),
                name="reference",
                is_visual=True,
                enable_self_collisions=False,
                disable_motors=True,
                color=REF_CHAR_COLOR,
            )

    def _build_sim_tensors(self, config: DeepMimicEnvConfig) -> None:
        super()._build_sim_tensors(config)
        n, dev, char = self.num_envs, self.device, self._char_model
        self._track_root = config.enable_tar_obs and config.global_obs
        self._motion_ids = torch.zeros(n, dtype=torch.long, device=dev)
        self._motion_time_offsets = torch.zeros(n, device=dev)
        joint_err_w = config.joint_err_w or [1.0] * (char.get_num_joints() - 1)
        if len(joint_err_w) != char.get_num_joints() - 1:
            raise MimicKitError(
                f"joint_err_w has {len(joint_err_w)} values; {self._char_file} has {char.get_num_joints() - 1} joints"
            )
        self._joint_err_w = torch.tensor(joint_err_w, dtype=torch.float32, device=dev)
        self._dof_joint_ids = torch.as_tensor(char.dof_joint_ids(), device=dev)
        self._dof_err_w = self._joint_err_w[self._dof_joint_ids]
        contact = {char.get_body_id(b) for b in config.contact_bodies}
        non_contact = [b for b in range(char.get_num_joints()) if b not in contact]
        self._non_contact_ids = torch.tensor(non_contact, dtype=torch.long, device=dev)
        self._reward_weights = {t: getattr(config, f"reward_{t}_w") for t in TERM_NAMES}
        self._reward_scales = {t: getattr(config, f"reward_{t}_scale") for t in TERM_NAMES}
        self._neg_reward_scales = torch.tensor([[-self._reward_scales[t]] for t in TERM_NAMES], device=dev)
        self._info_rows: dict[str, tuple[torch.Tensor, dict]] = {}  # `_store_rows`' buffers [K, N], their dicts
        steps = config.tar_obs_steps if config.enable_tar_obs else []
        self._ref_steps = torch.tensor([0, *steps], dtype=torch.float32, device=dev)
        self._all_env_ids = torch.arange(n, device=dev)
        self._clip_end_cache: torch.Tensor | None = None  # `_clip_end` of the current motion ids
        self._frames: dict[str, torch.Tensor] = {}
        self._tar_pose_obs: torch.Tensor | None = None  # valid from `_advance_clock` until the frames change
        self._step_state: dict[str, torch.Tensor] | None = None  # the character's state, within one step
        self._reset_batch: ResetBatch | None = None  # the reset in progress
        self._in_call = False  # a step or reset runs (the only time `_step_state` is kept)
        self._init_frames()
        self._build_reset_pool()
        self._ref_char_offset = torch.tensor(config.ref_char_offset, dtype=torch.float32, device=dev)

    # ---------------------------------------------------------------- public
    @property
    def motion_lib(self) -> MotionLib:
        return self._motion_lib

    @property
    def reward_weights(self) -> dict[str, float]:
        return dict(self._reward_weights)

    @property
    def tracks_pose(self) -> bool:
        return True

    @property
    def ref_char_offset(self) -> tuple[float, float, float]:
        x, y, z = (float(v) for v in self._ref_char_offset.tolist())
        return x, y, z

    def get_ref_char_id(self) -> int | None:
        return self._ref_char_id if self._enable_ref_char else None

    def get_motion_ids(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        """The MotionLib clip each env tracks [N] (or of `env_ids`)."""
        return self._motion_ids.clone() if env_ids is None else self._motion_ids.index_select(0, env_ids)

    def get_motion_time(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        t = self._time_buf + self._motion_time_offsets
        return t if env_ids is None else t.index_select(0, env_ids)

    def start_next_resets_at(self, motion_ids: torch.Tensor, times: torch.Tensor) -> None:
        """The next resets start from these clip states (motion ids [n], times [n]), before any sampled
        one: a viewer starts two envs from one state (the studio's A/B rollout). Times are clamped to
        each clip's length."""
        ids = motion_ids.to(device=self.device, dtype=torch.long).reshape(-1)
        if len(ids) and (int(ids.min()) < 0 or int(ids.max()) >= self._motion_lib.num_motions()):
            n = self._motion_lib.num_motions()
            raise MimicKitError(f"motion ids {ids.tolist()} outside this env's {n} clips")
        length = self._motion_lib.get_motion_length(ids)
        t = torch.minimum(times.to(self.device, torch.float32).reshape(-1), length)
        frames = self._pack(self._eval_clip([(ids, t, self._ref_steps)])[0])
        self._pool_ids = torch.cat([ids, self._pool_ids])
        self._pool_times = torch.cat([t, self._pool_times])
        self._pool_frames = torch.cat([frames, self._pool_frames])

    def get_ref_state(self) -> dict[str, torch.Tensor]:
        """The reference at the current motion time: root_pos [N,3], root_rot [N,4], joint_rot [N,J-1,4],
        dof_pos [N,D], body_pos [N,J,3], body_rot [N,J,4], velocities."""
        return dict(self._ref, dof_pos=self._char_model.rot_to_dof(self._ref["joint_rot"]))

    def get_ref_frames(self) -> dict[str, torch.Tensor]:
        """The reference frames the env holds: {key: [N, S, ...]}, column 0 at the motion time, then the
        target steps ahead (read only)."""
        return dict(self._frames)

    def eval_ref_frames(self, env_ids: torch.Tensor) -> dict[str, torch.Tensor]:
        """The same frames of `env_ids` evaluated afresh from the clip at their motion times."""
        return self._eval_frames(env_ids, self.get_motion_time(env_ids), self._ref_steps)

    def get_reset_pool(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The reset states evaluated ahead, in the order resets take them: motion ids [p], times [p]."""
        return self._pool_ids.clone(), self._pool_times.clone()

    def set_mode(self, mode: EnvMode) -> None:
        super().set_mode(mode)
        self._tracking_sum: dict[str, float] = {}
        self._tracking_count = 0
        self._episode_ends = torch.zeros(len(DoneFlags), dtype=torch.long, device=self.device)

    # The state read once per step (`_step_state`) and a reset's `ResetBatch` hold only while that call
    # runs: between calls the engine may be set from outside (a viewer, a test), so reads go to it
    # (`_in_call`: a read between calls, e.g. get_char_state(), must not fill the cache either).
    def reset(self, env_ids: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, Any]]:
        self._in_call = True
        try:
            return super().reset(env_ids)
        finally:
            self._reset_batch = self._step_state = None
            self._in_call = False

    def step(self, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, dict[str, Any]]:
        self._in_call = True
        try:
            out = super().step(action)
        finally:
            self._step_state = None
            self._in_call = False
        if self._mode == EnvMode.TEST:  # why each test episode ended, beside its tracking errors
            self._episode_ends += torch.bincount(out[2].long(), minlength=len(DoneFlags))
        return out

    def episode_end_summary(self) -> dict[str, int]:
        """Episodes that ended since the env entered TEST mode, by DoneFlags: {"fail", "succ", "time"}."""
        ends = getattr(self, "_episode_ends", None)
        counts = [0] * len(DoneFlags) if ends is None else ends.tolist()
        return {f.name.lower(): counts[f] for f in DoneFlags if f != DoneFlags.NULL}

    def record_diagnostics(self) -> dict[str, float]:
        return self.tracking_summary() if self.config.log_tracking_error else {}

    def tracking_summary(self) -> dict[str, float]:
        """Mean tracking errors over every env-step recorded since the env entered TEST mode."""
        if not getattr(self, "_tracking_count", 0):
            return {}
        return {k: v / self._tracking_count for k, v in self._tracking_sum.items()}

    # ------------------------------------------------------------- reference
    # The clip is evaluated at the motion time and at the target steps ahead: frames [N, S, ...] with
    # column 0 "now". `_ref` and `_tar` are views into these buffers. A control step advances every
    # env by one column, so when the steps are 0, 1, ..., S-1 the buffers shift and only the newest
    # column needs the MotionLib and FK: a quarter of the work for the humanoid's [1, 2, 3]. The
    # reference's dof_pos is not kept: only resets (and get_ref_state) need it, for the envs they touch.
    def _eval_clip(self, groups: list[ClipGroup]) -> list[dict[str, torch.Tensor]]:
        """The clip for each group (motion ids [n], times [n], steps [s]) at times + steps × dt, all groups
        with one MotionLib call and one FK (per-call costs dominate at these sizes): {key: [n, s, ...]} each."""
        dt = self._engine.get_timestep()
        ids = [m if len(st) == 1 else m.repeat_interleave(len(st)) for m, _, st in groups]
        times = [(t.unsqueeze(-1) + dt * st).flatten() for _, t, st in groups]
        ids, times = (ids[0], times[0]) if len(groups) == 1 else (torch.cat(ids), torch.cat(times))
        f = self._motion_lib.calc_motion_frame(ids, times)
        body_pos, body_rot = self._char_model.forward_kinematics(f.root_pos, f.root_rot, f.joint_rot)
        values = {
            "root_pos": f.root_pos, "root_rot": f.root_rot, "root_vel": f.root_vel, "root_ang_vel": f.root_ang_vel,
            "joint_rot": f.joint_rot, "dof_vel": f.dof_vel,
            "body_pos": body_pos, "body_rot": body_rot,
        }  # fmt: skip
        out, row = [], 0
        for m, _, st in groups:
            n, s = len(m), len(st)
            out.append({k: v[row : row + n * s].view(n, s, *v.shape[1:]) for k, v in values.items()})
            row += n * s
        return out

    def _eval_frames(self, env_ids: torch.Tensor, times: torch.Tensor, steps: torch.Tensor) -> dict[str, torch.Tensor]:
        """The clip of envs `env_ids` at `times` [n] + steps × dt: {key: [n, len(steps), ...]}."""
        return self._eval_clip([(self._motion_ids.index_select(0, env_ids), times, steps)])[0]

    def _init_frames(self) -> None:
        """Every column of every env at its motion time, into newly laid-out buffers (the first build; then
        steps advance the columns and resets copy in their pooled frames)."""
        frames = self._eval_frames(self._all_env_ids, self._motion_time_offsets, self._ref_steps)
        self._alloc_frames(frames)
        self._packed_frames.copy_(self._pack(frames))

    def _alloc_frames(self, like: dict[str, torch.Tensor]) -> None:
        """One buffer [N, S, F] holds every key side by side (`_frames[k]` are views into it), so that the
        per-step shift is one copy instead of one per key."""
        n, s = self.num_envs, len(self._ref_steps)
        sizes = {k: v[0, 0].numel() for k, v in like.items()}
        self._packed_frames = torch.zeros(n, s, sum(sizes.values()), device=self.device)
        self._frames, offset = {}, 0
        for k, v in like.items():
            self._frames[k] = self._packed_frames[..., offset : offset + sizes[k]].view(n, s, *v.shape[2:])
            offset += sizes[k]
        self._ref = {k: v[:, 0] for k, v in self._frames.items()}
        self._tar = {k: self._frames[k][:, 1:] for k in ("root_pos", "root_rot", "joint_rot", "body_pos")}
        self._can_shift = bool(torch.equal(self._ref_steps, torch.arange(s, dtype=self._ref_steps.dtype)))

    def _pack(self, frames: dict[str, torch.Tensor]) -> torch.Tensor:
        """Frames {key: [n, S, ...]} in the layout of `_packed_frames`: [n, S, F]."""
        n, s = next(iter(frames.values())).shape[:2]
        return torch.cat([frames[k].reshape(n, s, -1) for k in self._frames], dim=-1)

    def _advance_ref(self, extra: ClipGroup | None = None) -> None:
        """All envs moved one control step on: shift the columns and evaluate only the newest. `extra`, a
        group of reset samples for the pool, is evaluated in the same call."""
        self._tar_pose_obs = None
        shift = self._can_shift and len(self._ref_steps) > 1
        steps = self._ref_steps[-1:] if shift else self._ref_steps
        groups = [(self._motion_ids, self.get_motion_time(), steps)] + ([extra] if extra is not None else [])
        frames = self._eval_clip(groups)
        if extra is not None:
            self._add_to_pool(extra, frames[1])
        if not shift:
            for k, buf in self._frames.items():
                buf.copy_(frames[0][k])
            return
        packed = self._packed_frames
        packed[:, :-1] = packed[:, 1:].clone()
        for k, buf in self._frames.items():
            buf[:, -1:] = frames[0][k]

    # ------------------------------------------------------------ reset pool
    # A reset state is the clip at a sampled (motion, time): it does not depend on the simulation. So the
    # frames of the next resets are evaluated ahead, during the physics (`_advance_clock`) and in the same
    # MotionLib/FK call as the newest reference column, and a reset takes them from this pool (it samples
    # and evaluates afresh only what the pool lacks). The pool holds about twice the recent resets per step.
    def _build_reset_pool(self) -> None:
        dev = self.device
        self._pool_ids = torch.zeros(0, dtype=torch.long, device=dev)
        self._pool_times = torch.zeros(0, device=dev)
        self._pool_frames = self._packed_frames.new_zeros(0, *self._packed_frames.shape[1:])
        self._reset_rate, self._resets_since_clock = 0.0, 0

    def _sample_reset_states(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        lib = self._motion_lib
        ids = lib.sample_motions(n).to(self.device)
        times = lib.sample_time(ids) if self.config.rand_reset else torch.zeros(n, device=self.device)
        return ids, times

    def _pool_request(self) -> ClipGroup | None:
        """New samples for the pool this step (motion ids, times, steps), or None when it holds enough."""
        self._reset_rate = 0.9 * self._reset_rate + 0.1 * self._resets_since_clock
        self._resets_since_clock = 0
        need = min(self.num_envs, math.ceil(2.0 * self._reset_rate) + 2) - len(self._pool_ids)
        return (*self._sample_reset_states(need), self._ref_steps) if need > 0 else None

    def _add_to_pool(self, group: ClipGroup, frames: dict[str, torch.Tensor]) -> None:
        self._pool_ids = torch.cat([self._pool_ids, group[0]])
        self._pool_times = torch.cat([self._pool_times, group[1]])
        self._pool_frames = torch.cat([self._pool_frames, self._pack(frames)])

    def _draw_reset_states(self, n: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """n reset states: motion ids [n], times [n], packed frames [n, S, F]; from the pool first."""
        self._resets_since_clock += n
        take = min(n, len(self._pool_ids))
        ids, times, frames = self._pool_ids[:take], self._pool_times[:take], self._pool_frames[:take]
        self._pool_ids, self._pool_times, self._pool_frames = (
            self._pool_ids[take:], self._pool_times[take:], self._pool_frames[take:]
        )  # fmt: skip
        if take == n:
            return ids, times, frames
        new_ids, new_times = self._sample_reset_states(n - take)
        new_frames = self._pack(self._eval_clip([(new_ids, new_times, self._ref_steps)])[0])
        if take == 0:
            return new_ids, new_times, new_frames
        return torch.cat([ids, new_ids]), torch.cat([times, new_times]), torch.cat([frames, new_frames])

    def _ref_each_step(self) -> bool:
        """Whether the reference is evaluated at every step (it is read by the reward or observations)."""
        return True

    def _pose_ref_char(self, env_ids: torch.Tensor) -> None:
        e, c = self._engine, self._ref_char_id
        ref = {k: self._ref[k].index_select(0, env_ids) for k in ("root_pos", "root_rot", "joint_rot")}
        e.set_root_state(env_ids, c, ref["root_pos"] + self._ref_char_offset, ref["root_rot"], 0.0, 0.0)
        e.set_joint_rot(env_ids, c, ref["joint_rot"])
        e.set_dof_vel(env_ids, c, 0.0)

    # ---------------------------------------------------------------- resets
    def _reset_char(self, env_ids: torch.Tensor) -> None:
        ids, times, frames = self._draw_reset_states(len(env_ids))
        self._motion_ids.index_copy_(0, env_ids, ids)
        self._clip_end_cache = None
        self._motion_time_offsets.index_copy_(0, env_ids, times)
        self._packed_frames.index_copy_(0, env_ids, frames)
        self._tar_pose_obs = None
        e, c = self._engine, self._char_id
        ref = {k: v.index_select(0, env_ids) for k, v in self._ref.items()}
        e.set_root_state(env_ids, c, ref["root_pos"], ref["root_rot"], ref["root_vel"], ref["root_ang_vel"])
        e.set_joint_rot(env_ids, c, ref["joint_rot"])
        e.set_dof_vel(env_ids, c, ref["dof_vel"])
        self._step_state = None
        self._reset_batch = ResetBatch(env_ids, ref)
        if self._enable_ref_char:
            self._pose_ref_char(env_ids)

    # ---------------------------------------------------------- per step
    def _step_physics(self) -> None:
        """The engine's step, and meanwhile on this thread the clock and what depends on it alone: the
        reference clip at the new time, its target features, the next resets' frames. None of that reads
        or writes the engine, so it overlaps the physics (`Engine.stepping`)."""
        self._step_state = None
        with self._engine.stepping():
            self._update_time()
            self._advance_clock()

    def _char_state(self, env_ids: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """All envs: read from the engine once per step (or reset). The envs of the reset in progress:
        the state it set (`ResetBatch`). Other subsets: read from the engine."""
        if env_ids is None:
            if not self._in_call:
                return self._read_char_state(None)
            if self._step_state is None:
                self._step_state = self._read_char_state(None)
            return dict(self._step_state)
        batch = self._reset_batch
        if batch is not None and env_ids is batch.env_ids:
            return dict(batch.char_state)
        return super()._char_state(env_ids)

    def _advance_clock(self) -> None:
        pool_samples = self._pool_request()
        if self._ref_each_step():
            self._advance_ref(pool_samples)
            if self.config.enable_tar_obs:  # the clip alone decides them: computed while the physics runs
                self._tar_pose_obs = self._tar_pose(self._tar)
        elif pool_samples is not None:
            self._add_to_pool(pool_samples, self._eval_clip([pool_samples])[0])

    def _update_misc(self) -> None:
        super()._update_misc()
        if self._enable_ref_char:  # the engine may be written only now, after its step
            self._pose_ref_char(self._all_env_ids)

    def _compute_obs(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        obs = [super()._compute_obs(env_ids)]
        if self.config.enable_phase_obs:
            ids = self._motion_ids if env_ids is None else self._motion_ids.index_select(0, env_ids)
            phase = self._motion_lib.calc_motion_phase(ids, self.get_motion_time(env_ids))
            obs.append(compute_phase_obs(phase, self.config.num_phase_encoding))
        if self.config.enable_tar_obs:
            obs.append(self._compute_tar_obs(env_ids))
        return torch.cat(obs, dim=-1)

    def _compute_tar_obs(self, env_ids: torch.Tensor | None) -> torch.Tensor:
        """Target frames from the frame buffers at the current motion time (all envs: the buffers
        themselves, no copy, and the pose features `_advance_clock` computed during the physics)."""
        tar = self._tar if env_ids is None else {k: v.index_select(0, env_ids) for k, v in self._tar.items()}
        ref_pos = self._char_state(env_ids)["root_pos"] if self.config.global_obs else tar["root_pos"][:, 0]
        ref_rot = tar["root_rot"][:, 0]
        pose = self._tar_pose_obs if env_ids is None and self._tar_pose_obs is not None else self._tar_pose(tar)
        cfg = self.config
        return join_tar_obs(ref_pos, ref_rot, tar["root_pos"], pose, cfg.global_obs, cfg.root_height_obs)

    def _tar_pose(self, tar: dict[str, torch.Tensor]) -> torch.Tensor:
        return compute_tar_pose_obs(
            tar["root_rot"][:, 0], tar["root_pos"], tar["root_rot"], tar["joint_rot"],
            tar["body_pos"].index_select(2, self._key_body_ids), self.config.global_obs,
        )  # fmt: skip

    def _sim_state(self, env_ids: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        s = self._char_state(env_ids)
        s["key_pos"] = s["body_pos"].index_select(1, self._key_body_ids)
        return s

    def _update_info(self, env_ids: torch.Tensor | None = None) -> None:
        if env_ids is not None:  # a reset: its reward terms stay the last step's (module doc)
            self._update_tracking(env_ids)
            return
        sim, ref = self._char_state(), self._ref  # a step: its reward terms and tracking errors
        d = state_deltas(sim, ref)
        self._store_rows("reward_terms", TERM_NAMES, self._reward_terms(sim, ref, d), None)
        self._last_sim = sim  # the state pose termination reads
        self._update_tracking(None, sim, ref, d)

    def score_state(self) -> dict[str, dict[str, torch.Tensor]]:
        """Every env's reward terms and tracking errors for its current state against its reference, as a
        step computes them after its physics; nothing is stored. A way to check a pose, e.g. a reset's."""
        sim, ref = self._char_state(), self._ref
        d = state_deltas(sim, ref)
        terms, tracking = self._reward_terms(sim, ref, d), stacked_tracking_errors(sim, ref, d, self._dof_joint_ids)
        return {
            "reward_terms": dict(zip(TERM_NAMES, terms.unbind(0), strict=True)),
            "tracking": dict(zip(TRACKING_NAMES, tracking.unbind(0), strict=True)),
        }

    def body_pos_errors(self) -> torch.Tensor:
        """Each env's per-body position errors [N, J] (metres) of its current state against its reference,
        read now (`deepmimic_rewards.body_pos_errors`: the root's global error, the other bodies'
        root-relative ones; the mean over J is the paper's position error)."""
        return body_pos_errors(self.get_char_state(), self._ref)

    def _reward_terms(self, sim: dict[str, torch.Tensor], ref: dict[str, torch.Tensor], d: Deltas) -> torch.Tensor:
        """The unweighted terms [5, N] in TERM_NAMES order."""
        errors = compute_reward_errors(
            sim, ref, d, self._key_body_ids, self._joint_err_w, self._dof_err_w, self._track_root,
            self.config.root_height_obs,
        )  # fmt: skip
        return reward_terms(errors, self._neg_reward_scales)

    def _ref_state(self, env_ids: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        ref = self._ref if env_ids is None else {k: v.index_select(0, env_ids) for k, v in self._ref.items()}
        return dict(ref, key_pos=ref["body_pos"].index_select(1, self._key_body_ids))

    def _update_tracking(
        self,
        env_ids: torch.Tensor | None,
        sim: dict[str, torch.Tensor] | None = None,
        ref: dict[str, torch.Tensor] | None = None,
        d: Deltas | None = None,
    ) -> None:
        """Tracking errors of the given envs (all when None) into `info["tracking"]`, from their sim and
        reference states (read here unless given); TEST mode also records them, which `mimickit test`
        reports whatever the yaml says. A reset in training leaves its envs' values as the last step's:
        the agents read info after a step, and the reference records tracking at reset only in TEST mode
        (kept, so the means compare with its logs)."""
        if env_ids is not None and self._mode != EnvMode.TEST:
            return
        if sim is None or ref is None:
            sim, ref = self._sim_state(env_ids), self._ref_state(env_ids)
        tracking = stacked_tracking_errors(sim, ref, d or state_deltas(sim, ref), self._dof_joint_ids)
        self._store_rows("tracking", TRACKING_NAMES, tracking, env_ids)
        if self._mode == EnvMode.TEST:
            self._record_tracking(dict(zip(TRACKING_NAMES, tracking.unbind(0), strict=True)))

    def _store_info(self, key: str, values: dict[str, torch.Tensor], env_ids: torch.Tensor | None) -> None:
        """Write per-env values [n] into the persistent info buffers [N] (only the rows of env_ids)."""
        if key not in self._info:
            self._info[key] = {k: torch.zeros(self.num_envs, device=self.device) for k in values}
        buf = self._info[key]
        for k, v in values.items():
            if env_ids is None:
                buf[k][:] = v
            else:
                buf[k].index_copy_(0, env_ids, v)

    def _store_rows(self, key: str, names: tuple[str, ...], values: torch.Tensor, env_ids: torch.Tensor | None) -> None:
        """Write stacked per-env values [K, n] (K = len(names)) into `info[key]`: {name: [N]}, the rows of
        one [K, N] buffer, so that a step stores them with one copy (only the columns of env_ids)."""
        buf, rows = self._info_rows.get(key, (None, None))
        if buf is None or self._info.get(key) is not rows:  # new, or dropped by a subclass to be rebuilt
            buf = torch.zeros(len(names), self.num_envs, device=self.device)
            rows = self._info[key] = dict(zip(names, buf, strict=True))
            self._info_rows[key] = (buf, rows)
        if env_ids is None:
            buf.copy_(values)
        else:
            buf.index_copy_(1, env_ids, values)

    def _record_tracking(self, tracking: dict[str, torch.Tensor]) -> None:
        if not hasattr(self, "_tracking_sum"):
            self._tracking_sum, self._tracking_count = {}, 0
        for k, v in tracking.items():
            self._tracking_sum[k] = self._tracking_sum.get(k, 0.0) + float(v.sum())
        self._tracking_count += len(next(iter(tracking.values())))

    def _update_reward(self) -> None:
        terms = self._info["reward_terms"]
        self._reward_buf[:] = sum(self._reward_weights[k] * terms[k] for k in TERM_NAMES)

    def _update_done(self) -> None:
        super()._update_done()
        done = self._done_buf
        done.masked_fill_(self.get_motion_time() >= self._clip_end(), int(DoneFlags.SUCC))
        if self.config.enable_early_termination:
            done.masked_fill_(self._fallen() | self._pose_failed(), int(DoneFlags.FAIL))

    def _clip_end(self) -> torch.Tensor:
        """Per env the motion time at which its clip ends the episode [N]: the clip's length, or +inf for
        a wrapping clip. Cached until a reset changes the motion ids (one comparison per step instead of
        two table lookups)."""
        if self._clip_end_cache is None:
            lib, ids = self._motion_lib, self._motion_ids
            wrap = lib.get_motion_loop_mode(ids) == LoopMode.WRAP
            self._clip_end_cache = lib.get_motion_length(ids).masked_fill(wrap, math.inf)
        return self._clip_end_cache

    def _fallen(self) -> torch.Tensor:
        if not self.config.contact_bodies:
            return torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        forces = self._engine.get_ground_contact_forces(self._char_id).index_select(1, self._non_contact_ids)
        return (forces.abs() > CONTACT_FORCE_THRESHOLD).any(dim=(1, 2))

    def _pose_failed(self) -> torch.Tensor:
        if not self.config.pose_termination:
            return torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        d2 = self.config.pose_termination_dist**2
        sim_pos, ref_pos = self._last_sim["body_pos"], self._ref["body_pos"]
        if self.config.global_obs and self._track_root:  # the root's own distance is body 0's below
            diff = sim_pos - ref_pos
            return (diff * diff).sum(-1).max(-1).values > d2
        sim_rel = sim_pos[:, 1:] - sim_pos[:, :1]
        ref_rel = ref_pos[:, 1:] - ref_pos[:, :1]
        if not self.config.global_obs:
            sim_rel = tu.quat_rotate_inverse(self._last_sim["root_rot"].unsqueeze(1), sim_rel)
            ref_rel = tu.quat_rotate_inverse(self._ref["root_rot"].unsqueeze(1), ref_rel)
        diff = sim_rel - ref_rel
        return (diff * diff).sum(-1).max(-1).values > d2

    def info_snapshot(self) -> dict[str, Any]:
        return self._info
