"""The `static_objects` env (MimicKit's StaticObjectsEnv, the vault configs): DeepMimic with objects welded to
the world where the config puts them, colliding with the character, and no observation of them (the
reference's observation is DeepMimic's)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from mimickit.envs.env_builder import build_env, load_env_configs
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_ROOT, DataPaths

ENGINE = PROJECT_ROOT / "data/engines/mujoco_engine.yaml"
VAULT = PROJECT_ROOT / "data/envs/vault_humanoid_env.yaml"
BOX_TOP_Z = 0.2 + 0.3  # vault_humanoid_env.yaml puts vault_box.xml (half-height 0.3) at z 0.2


def make(env_file: Path, test_data: Path, num_envs: int = 2):
    return build_env(env_file, ENGINE, num_envs, data_paths=DataPaths(data_dir=test_data))


def test_the_boxes_stand_where_the_config_puts_them_and_stay(test_data: Path) -> None:
    env = make(PROJECT_ROOT / "data/envs/vault_g1_env.yaml", test_data)
    env.reset()
    ids = env.get_object_ids()
    for _ in range(15):
        env.step(torch.zeros(2, env.get_action_space().shape[0]))
    pos = torch.stack([env.engine.get_root_pos(i) for i in ids], dim=1)  # [envs, objects, 3]
    want = torch.tensor([[-6.53, 0.06, 0.14], [-7.62, 0.06, 0.14]])
    torch.testing.assert_close(pos, want.expand(2, 2, 3), atol=1e-5, rtol=0)
    env.engine.close()


def test_the_character_stands_on_the_box_and_sees_no_object(test_data: Path, tmp_path: Path) -> None:
    """Env 0's character dropped over the box stays on it; env 1's, beside it, reaches the floor (no
    termination: a teleport far from the reference would reset the env)."""
    f = tmp_path / "env.yaml"
    f.write_text(
        VAULT.read_text()
        .replace("enable_early_termination: True", "enable_early_termination: False")
        .replace("pose_termination: True", "pose_termination: False")
    )
    torch.manual_seed(0)  # the reset's reference pose: from 1 start in 8 (seed 3) the dropped figure tips off the box
    env = make(f, test_data)
    plain = make(PROJECT_ROOT / "data/envs/deepmimic_humanoid_env.yaml", test_data)
    obs, _ = env.reset()
    assert obs.shape[1] == plain.reset()[0].shape[1]  # DeepMimic's observation, no object in it
    plain.engine.close()
    e, char = env.engine, env.get_char_id()
    e.set_root_pos(torch.tensor([0, 1]), char, torch.tensor([[2.2, 0.5, BOX_TOP_Z + 1.0], [0.0, -2.0, 1.0]]))
    e.set_root_vel(torch.tensor([0, 1]), char, 0.0)
    feet = [env.char_model.get_body_id(b) for b in ("right_foot", "left_foot")]
    for _ in range(20):
        env.step(torch.zeros(2, env.get_action_space().shape[0]))
    low = e.get_body_pos(char)[:, feet, 2].min(dim=1).values
    # The feet (ankle bodies, a foot's height above what they stand on): env 0's above the box top.
    assert low[0] > BOX_TOP_Z and low[1] < 0.2, low
    env.engine.close()


@pytest.mark.parametrize(
    ("objects", "needle"),
    [
        ("[]", "objects"),
        ('[{"pos": [0, 0], "file": "data/assets/objects/vault_box.xml"}]', "pos"),
        ('[{"pos": [0, 0, 0], "file": "x.xml", "colour": 1}]', "colour"),
        ('[{"pos": [0, 0, 0], "rot": [0, 0, 0, 2], "file": "data/assets/objects/vault_box.xml"}]', "unit quaternion"),
    ],
)
def test_a_bad_objects_list_is_one_line_naming_it(tmp_path: Path, objects: str, needle: str) -> None:
    line = '    objects: [{"pos": [2.2, 0.5, 0.2], "file": "data/assets/objects/vault_box.xml"}]'
    text = VAULT.read_text().replace(line, f"    objects: {objects}")
    f = tmp_path / "env.yaml"
    f.write_text(text)
    with pytest.raises(MimicKitError) as e:
        load_env_configs(f, ENGINE)
    assert str(f) in str(e.value) and needle in str(e.value) and "\n" not in str(e.value)


def test_a_missing_object_file_is_one_line(tmp_path: Path, test_data: Path) -> None:
    f = tmp_path / "env.yaml"
    f.write_text(VAULT.read_text().replace("data/assets/objects/vault_box.xml", "data/assets/objects/nope.xml"))
    with pytest.raises(MimicKitError) as e:
        make(f, test_data)
    assert "nope.xml" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.integration
@pytest.mark.parametrize("arg_file", ["vault_humanoid_args.txt", "vault_g1_args.txt"])
def test_the_vault_arg_files_train_two_iterations(arg_file: str, test_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "mimickit.cli", "train", "--arg_file", f"args/{arg_file}"]
    cmd += ["--data_dir", str(test_data), "--num_envs", "4", "--max_samples", "256", "--out_dir", str(out)]
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=PROJECT_ROOT, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    rows = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert [row["samples"] for row in rows] == [128, 256]
    assert 'env_name: "static_objects"' in (out / "env_config.yaml").read_text()
