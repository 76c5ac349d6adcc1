"""StaticObjectsEnv (`static_objects`): DeepMimic with objects fixed in the world, as the reference's (the
vault, double-kong and climbing clips jump onto or over boxes).

Each env gets every object of the config's `objects` list: an MJCF asset (looked up like every asset) at
`pos`, turned by `rot` (xyzw), its root welded to the world (`fix_root`), dark grey, colliding with the
character. The observation, reward and termination are DeepMimic's: the reference gives the policy no
observation of the objects (they stand where the clip needs them). Early termination counts the floor's
contacts only (`get_ground_contact_forces`), as the reference on Newton: a hand on the box does not end an
episode (its Isaac Gym approximation also counts any contact of a body below `ground_contact_height`).
"""

from __future__ import annotations

import numpy as np

from mimickit.engines.engine import ObjType
from mimickit.envs.deepmimic_env import DeepMimicEnv
from mimickit.envs.env_config import StaticObjectsEnvConfig

OBJECT_COLOR = np.array([0.3, 0.3, 0.3])  # the reference's


class StaticObjectsEnv(DeepMimicEnv):
    config: StaticObjectsEnvConfig  # type: ignore[assignment]

    def _build_env(self, env_id: int, config: StaticObjectsEnvConfig) -> None:  # type: ignore[override]
        super()._build_env(env_id, config)
        self._object_ids = [
            self._engine.create_obj(
                env_id=env_id,
                obj_type=ObjType.rigid,
                asset_file=str(self.data_paths.resolve(obj.file)),
                name=f"static_object{i}",
                fix_root=True,
                start_pos=np.asarray(obj.pos, dtype=np.float64),
                start_rot=np.asarray(obj.rot, dtype=np.float64),
                color=OBJECT_COLOR,
            )
            for i, obj in enumerate(config.objects)
        ]

    def get_object_ids(self) -> list[int]:
        """The engine object ids of the static objects, in the config's order."""
        return list(self._object_ids)
