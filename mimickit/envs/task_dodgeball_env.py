"""TaskDodgeballEnv (`task_dodgeball`): SMP style while dodging balls thrown at the character, as the reference's.

Each env has `num_projectiles` free balls (`data/assets/objects/dodgeball.xml`, radius 0.1 m), resting at
(10 + i, 10, 0.1) until launched. A ball is launched when the env time reaches its trigger time (U[proj_
trigger_time_min, max] s after the reset or its previous launch): aimed at `proj_target_body` (plus
Gaussian noise of std proj_aim_noise_scale) where that body will be if it keeps its velocity, from
proj_dist ~ U[min, max] m away in a uniform xy direction at height U[proj_h_min, max], with horizontal
speed U[proj_speed_min, max]: it reaches the aim point's xy after proj_dist / speed seconds, at the aim
point's height (`ballistic_launch`).

Task obs (6 per ball): its position relative to the root and its velocity, in the heading frame. Task reward
(`dodge_reward`): 0.9·(1 − exp(−0.3·d)), d the distance from the root to the nearest ball, + 0.1·exp(−|v_xy|²)
of the root's velocity. A ball hits (`dodgeball_hits`) when it is within hit_dist of any body and either its
xy contact force exceeds hit_force_threshold or its velocity differs from the free flight's (previous
velocity + g·dt) by more than hit_delta_v_threshold; with early termination a hit ends the episode (FAIL).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from mimickit.engines.engine import ObjType
from mimickit.envs.base_env import DoneFlags
from mimickit.envs.env_config import TaskDodgeballEnvConfig
from mimickit.envs.smp_env import SMPEnv
from mimickit.envs.viewable import ShowsTaskTarget
from mimickit.util import torch_util as tu
from mimickit.util.errors import MimicKitError

PROJ_FILE = "data/assets/objects/dodgeball.xml"
PROJ_RADIUS = 0.1  # m, the ball's in PROJ_FILE
PROJ_COLOR = (0.9725, 0.42, 0.1137)  # the reference's


class TaskDodgeballEnv(SMPEnv, ShowsTaskTarget):
    config: TaskDodgeballEnvConfig  # type: ignore[assignment]

    # ----------------------------------------------------------- construction
    def _build_env(self, env_id: int, config: TaskDodgeballEnvConfig) -> None:  # type: ignore[override]
        super()._build_env(env_id, config)
        asset = str(self.data_paths.resolve(PROJ_FILE))
        self._proj_ids = [
            self._engine.create_obj(
                env_id=env_id,
                obj_type=ObjType.rigid,
                asset_file=asset,
                name=f"projectile{i}",
                start_pos=inactive_pos(i),
                color=PROJ_COLOR,
            )
            for i in range(config.num_projectiles)
        ]

    def _build_sim_tensors(self, config: TaskDodgeballEnvConfig) -> None:  # type: ignore[override]
        super()._build_sim_tensors(config)
        n, p, dev = self.num_envs, len(self._proj_ids), self.device
        self._proj_trigger_times = torch.zeros(n, p, device=dev)
        self._prev_proj_vel = torch.zeros(n, p, 3, device=dev)
        self._proj_hits = torch.zeros(n, p, dtype=torch.bool, device=dev)
        self._proj_target_body_id = self._char_model.get_body_id(config.proj_target_body)
        self._proj_h_min = max(config.proj_h_min, PROJ_RADIUS)
        if self._proj_h_min > config.proj_h_max:
            raise MimicKitError(f"proj_h_max {config.proj_h_max} is below the ball's radius {PROJ_RADIUS} m")
        self._gravity_z = float(self._engine.get_gravity()[2])
        self._inactive_pos = torch.tensor(
            np.stack([inactive_pos(i) for i in range(p)]), dtype=torch.float32, device=dev
        )

    # ---------------------------------------------------------------- public
    def get_proj_ids(self) -> list[int]:
        """The engine object ids of the balls, in projectile order."""
        return list(self._proj_ids)

    def get_proj_states(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The balls' positions and velocities, each [N, P, 3] (world frame)."""
        e = self._engine
        pos = torch.stack([e.get_root_pos(i) for i in self._proj_ids], dim=1)
        vel = torch.stack([e.get_root_vel(i) for i in self._proj_ids], dim=1)
        return pos, vel

    def get_proj_hits(self) -> torch.Tensor:
        """Which balls hit the character in the last step [N, P] (bool)."""
        return self._proj_hits

    def get_proj_trigger_times(self) -> torch.Tensor:
        """The env time [N, P] (s) at which each ball is next launched."""
        return self._proj_trigger_times

    def task_target(self, env_id: int = 0) -> dict[str, float | bool | str]:
        """The nearest ball: its distance from the target body (m) and speed (m/s), the time to the next
        launch (s), and whether a ball hit in the last step."""
        pos, vel = self.get_proj_states()
        target = self._engine.get_body_pos(self._char_id)[env_id, self._proj_target_body_id]
        dist = (pos[env_id] - target).norm(dim=-1)
        i = int(dist.argmin())
        wait = self._proj_trigger_times[env_id] - self.get_env_time()[env_id]
        return {
            "kind": "dodgeball",
            "distance_m": round(float(dist[i]), 3),
            "speed_mps": round(float(vel[env_id, i].norm()), 3),
            "next_launch_s": round(float(wait.min()), 3),
            "hit": bool(self._proj_hits[env_id].any()),
        }

    # ---------------------------------------------------------------- launches
    def launch_projectiles(self, env_ids: torch.Tensor, proj_idx: torch.Tensor) -> None:
        """Throw ball proj_idx[k] of env env_ids[k] now (both [n]) and draw its next trigger time."""
        n, cfg, dev = len(env_ids), self.config, self.device
        if n == 0:
            return
        char = self._char_id
        target = self._engine.get_body_pos(char)[env_ids, self._proj_target_body_id]
        target = target + cfg.proj_aim_noise_scale * torch.randn_like(target)
        target_vel = self._engine.get_body_vel(char)[env_ids, self._proj_target_body_id]
        speed = uniform(cfg.proj_speed_min, cfg.proj_speed_max, n, dev)
        dist = uniform(cfg.proj_dist_min, cfg.proj_dist_max, n, dev)
        height = uniform(self._proj_h_min, cfg.proj_h_max, n, dev)
        angle = uniform(0.0, 2 * math.pi, n, dev)
        pos, vel = ballistic_launch(target, target_vel, speed, dist, height, angle, self._gravity_z)
        identity = tu.quat_identity((n,), dev)
        for i, obj in enumerate(self._proj_ids):
            mask = proj_idx == i
            if bool(mask.any()):
                ids = env_ids[mask]
                self._engine.set_root_state(ids, obj, pos[mask], identity[mask], vel[mask], 0.0)
                self._prev_proj_vel[ids, i] = vel[mask]
        wait = uniform(cfg.proj_trigger_time_min, cfg.proj_trigger_time_max, n, dev)
        self._proj_trigger_times[env_ids, proj_idx] = self.get_env_time(env_ids) + wait

    def _reset_projectiles(self, env_ids: torch.Tensor) -> None:
        """Balls back to rest off to the side; their first launch U[trigger_time_min, max] s from now."""
        n, cfg = len(env_ids), self.config
        identity = tu.quat_identity((n,), self.device)
        for i, obj in enumerate(self._proj_ids):
            self._engine.set_root_state(env_ids, obj, self._inactive_pos[i].expand(n, 3), identity, 0.0, 0.0)
        self._prev_proj_vel[env_ids] = 0.0
        self._proj_hits[env_ids] = False
        wait = uniform(cfg.proj_trigger_time_min, cfg.proj_trigger_time_max, (n, len(self._proj_ids)), self.device)
        self._proj_trigger_times[env_ids] = self.get_env_time(env_ids).unsqueeze(-1) + wait

    # ---------------------------------------------------------------- per step
    def _apply_action(self, action: torch.Tensor) -> None:
        self._prev_proj_vel[:] = self.get_proj_states()[1]  # the free-flight check compares against it
        super()._apply_action(action)

    def _reset_envs(self, env_ids: torch.Tensor) -> None:
        super()._reset_envs(env_ids)
        self._reset_projectiles(env_ids)

    def _update_misc(self) -> None:
        super()._update_misc()
        due = torch.nonzero(self.get_env_time().unsqueeze(-1) >= self._proj_trigger_times)
        self.launch_projectiles(due[:, 0], due[:, 1])

    def _compute_obs(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        obs = super()._compute_obs(env_ids)
        s = self._char_state(env_ids)
        pos, vel = self.get_proj_states()
        if env_ids is not None:
            pos, vel = pos[env_ids], vel[env_ids]
        return torch.cat([obs, dodgeball_obs(s["root_pos"], s["root_rot"], pos, vel)], dim=-1)

    def _compute_task_reward(self, env_ids: torch.Tensor | None = None) -> torch.Tensor:
        s = self._char_state(env_ids)
        pos = self.get_proj_states()[0]
        return dodge_reward(s["root_pos"], s["root_vel"], pos if env_ids is None else pos[env_ids])

    def _update_done(self) -> None:
        super()._update_done()
        pos, vel = self.get_proj_states()
        force = torch.stack([self._engine.get_contact_forces(i) for i in self._proj_ids], dim=1)  # [N, P, B, 3]
        force_xy = force[..., :2].norm(dim=-1).amax(dim=-1)
        cfg = self.config
        self._proj_hits[:] = dodgeball_hits(
            self._engine.get_body_pos(self._char_id), pos, vel, self._prev_proj_vel, force_xy,
            cfg.hit_dist, cfg.hit_force_threshold, cfg.hit_delta_v_threshold, self._gravity_z,
            self._engine.get_timestep(),
        )  # fmt: skip
        if cfg.enable_early_termination:
            self._done_buf.masked_fill_(self._proj_hits.any(dim=-1), int(DoneFlags.FAIL))


def inactive_pos(proj_idx: int) -> np.ndarray:
    """Where ball proj_idx rests between launches: (10 + i, 10) on the ground."""
    return np.array([10.0 + proj_idx, 10.0, PROJ_RADIUS])


def uniform(lo: float, hi: float, shape: int | tuple[int, ...], device: torch.device) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(shape, device=device)


def ballistic_launch(
    target_pos: torch.Tensor,
    target_vel: torch.Tensor,
    speed: torch.Tensor,
    dist: torch.Tensor,
    height: torch.Tensor,
    angle: torch.Tensor,
    gravity_z: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Launch position and velocity [n, 3] of a ball that, after T = dist / speed seconds of free flight,
    is at the target's predicted xy (target_pos + target_vel·T) and target_pos's height.

    target_pos, target_vel [n, 3]; speed (horizontal, m/s), dist (xy, m), height (launch z, m), angle
    (direction from the predicted target to the launch point, rad) [n]; gravity_z (m/s², negative).
    """
    t = dist / speed
    pred = target_pos + target_vel * t.unsqueeze(-1)
    offset = dist.unsqueeze(-1) * torch.stack([torch.cos(angle), torch.sin(angle)], dim=-1)
    pos = torch.cat([pred[:, :2] + offset, height.unsqueeze(-1)], dim=-1)
    vel_z = (target_pos[:, 2] - height) / t - 0.5 * gravity_z * t
    vel = torch.cat([-offset / dist.unsqueeze(-1) * speed.unsqueeze(-1), vel_z.unsqueeze(-1)], dim=-1)
    return pos, vel


def dodgeball_obs(
    root_pos: torch.Tensor, root_rot: torch.Tensor, proj_pos: torch.Tensor, proj_vel: torch.Tensor
) -> torch.Tensor:
    """Each ball's position relative to the root and velocity, in the root's heading frame: root_pos [n, 3],
    root_rot [n, 4], proj_pos / proj_vel [n, P, 3] → [n, 6P]."""
    heading_inv = tu.calc_heading_quat_inv(root_rot).unsqueeze(-2).expand(*proj_pos.shape[:-1], 4)
    local_pos = tu.quat_rotate(heading_inv, proj_pos - root_pos.unsqueeze(-2))
    local_vel = tu.quat_rotate(heading_inv, proj_vel)
    return torch.cat([local_pos, local_vel], dim=-1).flatten(-2)


def dodge_reward(root_pos: torch.Tensor, root_vel: torch.Tensor, proj_pos: torch.Tensor) -> torch.Tensor:
    """0.9·(1 − exp(−0.3·d)) + 0.1·exp(−|root_vel_xy|²) [n], d the distance from the root to the nearest
    ball (the reference's weights and scales): root_pos, root_vel [n, 3], proj_pos [n, P, 3]."""
    dist = (proj_pos - root_pos.unsqueeze(-2)).norm(dim=-1).amin(dim=-1)
    still = torch.exp(-(root_vel[:, :2] ** 2).sum(-1))
    return 0.9 * (1.0 - torch.exp(-0.3 * dist)) + 0.1 * still


def dodgeball_hits(
    body_pos: torch.Tensor,
    proj_pos: torch.Tensor,
    proj_vel: torch.Tensor,
    prev_proj_vel: torch.Tensor,
    proj_force_xy: torch.Tensor,
    hit_dist: float,
    hit_force_threshold: float,
    hit_delta_v_threshold: float,
    gravity_z: float,
    dt: float,
) -> torch.Tensor:
    """Which balls hit the character [n, P] (the reference's rule): within hit_dist of any body [n, J, 3],
    and an xy contact force [n, P] above hit_force_threshold or a velocity change beyond free flight's
    (|v − (v_prev + g·dt)| over the control step) above hit_delta_v_threshold."""
    near = ((proj_pos.unsqueeze(-2) - body_pos.unsqueeze(-3)).norm(dim=-1) < hit_dist).any(dim=-1)
    expected = prev_proj_vel.clone()
    expected[..., 2] += gravity_z * dt
    delta_v = (proj_vel - expected).norm(dim=-1)
    return near & ((proj_force_xy > hit_force_threshold) | (delta_v > hit_delta_v_threshold))
