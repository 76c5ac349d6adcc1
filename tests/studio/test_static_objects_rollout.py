"""A vault run (the `static_objects` env) rolled out in the studio: the box is part of the model the 3D view
draws (mjviser draws every body of the rollout's MuJoCo model but the ghost's and the per-body error meshes),
welded where the config puts it, opaque, and the character collides with it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from mimickit.util.paths import PROJECT_ROOT
from studio.scene.rollout import Rollout, source_for_checkpoint

pytestmark = pytest.mark.integration


def test_a_vault_rollout_draws_its_box(tmp_path: Path, test_data: Path) -> None:
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", "args/vault_humanoid_args.txt"]
    cmd += ["--data_dir", str(test_data), "--num_envs", "2", "--max_samples", "64", "--out_dir", str(run)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=PROJECT_ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    r = Rollout(source_for_checkpoint(run / "model.pt", fallback_data_dir=test_data), history_s=1.0)
    try:
        box = [b for b in range(r.model.nbody) if (mujoco.mj_id2name(r.model, mujoco.mjtObj.mjOBJ_BODY, b) or "")
               .endswith("static_object0/box")]  # fmt: skip
        assert len(box) == 1 and box[0] not in r.ghost_bodies and box[0] not in r.char_bodies
        geoms = np.flatnonzero(r.model.geom_bodyid == box[0])
        assert len(geoms) == 1 and r.model.geom_rgba[geoms[0], 3] == 1.0 and r.model.geom_contype[geoms[0]] != 0
        for _ in range(5):
            frame = r.step()
        xpos, _ = r.pose(frame)
        np.testing.assert_allclose(xpos[box[0]], [2.2, 0.5, 0.2], atol=1e-6)  # vault_humanoid_env.yaml
    finally:
        r.close()
