"""A MuJoCo copy of another engine's scene, posed from that engine's state: the `mujoco_view` of an engine
whose own MuJoCo model cannot be drawn as it is.

Newton's SolverMuJoCo compiles a MuJoCo model of one world (`solver.mj_model`), but it leaves out every
geom that does not collide (`skip_visual_only_geoms`): the reference character, visual only, has bodies
and no geoms there, so a viewer would draw no ghost. The mirror is the MuJoCo engine's own scene of the same
objects (the same MJCF build, colours and body order), one env of it, posed on each call from the source
engine's public getters (root state and DoF coordinates of every object, in the `Engine` conventions both
engines share) and copied into one MjData per env asked for.
"""

from __future__ import annotations

from typing import Any

import mujoco

from mimickit.engines.engine import ControlMode, Engine, EngineConfig, MujocoView
from mimickit.engines.mujoco_engine import MujocoEngine


class MujocoMirror:
    """Env `i` of `source` as a MuJoCo model and data (see the module docstring)."""

    def __init__(self, source: Engine, objects: list[dict[str, Any]]) -> None:
        """`objects`: the `create_obj` keyword arguments of each object of an env (all but env_id; the start
        pose only matters for a fixed root, which the source's getters then keep in place)."""
        self._source = source
        # Kinematics only: no actuators (control mode none) and no worker threads.
        config = EngineConfig.model_validate(
            {**source.config.model_dump(), "engine_name": "mujoco", "control_mode": ControlMode.none, "num_threads": 1}
        )
        self._engine = MujocoEngine(config, 1, "cpu")
        self._engine.create_env()
        for kwargs in objects:
            self._engine.create_obj(0, **kwargs)
        self._engine.initialize_sim()
        self._datas: dict[int, mujoco.MjData] = {}

    def view(self, env_id: int) -> MujocoView:
        """The mirror posed as env `env_id` of the source now, in that env's own MjData."""
        self._pose(env_id)
        mirror = self._engine.mujoco_view(0)
        data = self._datas.get(env_id)
        if data is None:
            data = self._datas[env_id] = mujoco.MjData(mirror.model)
        mujoco.mj_copyData(data, mirror.model, mirror.data)
        return MujocoView(mirror.model, data, mirror.objects)

    def _pose(self, env_id: int) -> None:
        """Every object's root state and DoFs of env `env_id` of the source into the mirror's one env (the
        MuJoCo engine's setters take the rows on any device)."""
        src, dst, i = self._source, self._engine, slice(env_id, env_id + 1)
        for o in range(src.get_objs_per_env()):
            root = (src.get_root_pos(o), src.get_root_rot(o), src.get_root_vel(o), src.get_root_ang_vel(o))
            dst.set_root_state(None, o, *(t[i] for t in root))
            if src.get_obj_num_dofs(o):
                dst.set_dof_pos(None, o, src.get_dof_pos(o)[i])
                dst.set_dof_vel(None, o, src.get_dof_vel(o)[i])
