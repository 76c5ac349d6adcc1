"""The env registry (`ENVS`): every name loads its config class from a yaml and resolves its env class
(the builder builds from the same entry, importing only that env's module); an unknown name is one error
line naming the nearest. What is checked is derived from the registries (tests/util/registry_checks.py): a
new env is checked without editing this."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import mujoco  # noqa: F401  (imported at collection: its GLFW probe starts a process, allowed only then)
import pytest
import yaml

from mimickit.engines.engine import ENGINES
from mimickit.envs.env_builder import ENVS, build_env_from_configs, load_env_configs
from mimickit.envs.env_config import CharEnvConfig
from mimickit.envs.sim_env import SimEnv
from mimickit.learning.agent_builder import AGENTS
from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from tests.util.config_errors import load_error
from tests.util.registry_checks import class_modules, shipped_yamls, supported_list, undocumented

ENGINE = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
DEEPMIMIC = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"


def shipped_env_yamls() -> dict[str, Path]:
    """The first shipped env yaml of each env_name."""
    return shipped_yamls("envs", "env_name")


def char_env_yaml(tmp_path: Path) -> Path:
    """A plain `char` env yaml (no shipped one): the DeepMimic humanoid's fields that CharEnvConfig has."""
    fields = load_yaml(DEEPMIMIC)["env"]
    path = tmp_path / "char_env.yaml"
    path.write_text(
        yaml.safe_dump({"env_name": "char", "env": {k: fields[k] for k in CharEnvConfig.model_fields if k in fields}})
    )
    return path


def test_every_env_is_shipped_or_the_base_of_one_and_documented():
    """Each shipped env yaml names a registered env; each registered env has a shipped yaml or is the base
    class of one that has (as `char` is of `deepmimic`); the docs mention every one."""
    shipped = shipped_env_yamls()
    assert set(shipped) <= set(ENVS.names)
    for name in set(ENVS.names) - set(shipped):
        cls = ENVS.resolve(name)
        assert any(issubclass(ENVS.resolve(s), cls) for s in shipped), f"{name}: no shipped yaml uses it"
    assert not undocumented(ENVS.names)


@pytest.mark.parametrize("name", ENVS.names)
def test_every_env_loads_its_config_class_and_resolves_its_class(tmp_path, name):
    path = shipped_env_yamls().get(name) or char_env_yaml(tmp_path)
    env_cfg, _ = load_env_configs(path, ENGINE)
    assert type(env_cfg) is ENVS.config_class(name) and env_cfg.env_name == name
    cls = ENVS.resolve(name)
    assert issubclass(cls, SimEnv) and cls is not SimEnv


def test_the_builder_builds_the_registered_class(tmp_path):
    env_cfg, engine_cfg = load_env_configs(char_env_yaml(tmp_path), ENGINE)
    env = build_env_from_configs(env_cfg, engine_cfg, 1)
    assert type(env) is ENVS.resolve("char")


def test_an_unknown_env_name_is_one_line_naming_the_nearest(tmp_path):
    f = tmp_path / "env.yaml"
    f.write_text(DEEPMIMIC.read_text().replace('env_name: "deepmimic"', 'env_name: "deepmimc"'))
    with pytest.raises(MimicKitError) as e:
        load_env_configs(f, ENGINE)
    near = "(did you mean 'deepmimic'?)"
    assert str(e.value) == f"{f}: key 'env_name': env 'deepmimc' is not supported; {supported_list(ENVS)} {near}"


@pytest.mark.parametrize(
    "text, needle",
    [
        ("episode_length: 1.0\n", "missing required key 'env_name'"),
        ("env_name: [amp]\n", "env ['amp'] is not supported; supported envs: char,"),
        ("env_name: 7\n", "env 7 is not supported"),
    ],
)
def test_odd_env_names_are_one_line(tmp_path, text, needle):
    f, msg = load_error(tmp_path, text, lambda f: load_env_configs(f, ENGINE), "env.yaml")
    assert msg.startswith(f"{f}: ") and needle in msg and "\n" not in msg


def test_a_config_built_in_code_with_an_unknown_name_is_refused_by_the_builder(tmp_path):
    env_cfg, engine_cfg = load_env_configs(char_env_yaml(tmp_path), ENGINE)
    bad = env_cfg.model_copy(update={"env_name": "chr"})
    with pytest.raises(MimicKitError, match="env 'chr' is not supported.*did you mean 'char'"):
        build_env_from_configs(bad, engine_cfg, 1)


LAZY_CHECK = f"""
import json, sys
from mimickit.envs.env_builder import build_env
env = build_env({str(DEEPMIMIC)!r}, {str(ENGINE)!r}, 1)
print(json.dumps([type(env).__name__, sorted(sys.modules)]))
"""


@pytest.mark.integration
def test_building_a_deepmimic_env_imports_no_other_env_agent_or_engine():
    """No module of another registered env (its own and its base classes' aside), of any agent, of an
    engine other than MuJoCo, nor Newton's package."""
    out = subprocess.run(
        [sys.executable, "-c", LAZY_CHECK], cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    name, modules = json.loads(out.stdout.strip().splitlines()[-1])
    assert name == ENVS.resolve("deepmimic").__name__
    own = {c.__module__ for c in ENVS.resolve("deepmimic").__mro__}
    others = {*class_modules(ENVS).values(), *class_modules(AGENTS).values(), *class_modules(ENGINES).values()}
    others -= own | {ENGINES.resolve("mujoco").__module__}
    assert others  # the check below checks something
    assert sorted(others & set(modules)) == [] and not [m for m in modules if m.split(".")[0] == "newton"]


def test_load_env_configs_replaces_the_clip_or_refuses_an_env_without_one() -> None:
    """`--motion_file` replaces an env's clip; an env that plays no clip refuses it in one line."""
    env_cfg, _ = load_env_configs(PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml", ENGINE, "other.pkl")
    assert env_cfg.motion_file == "other.pkl"
    dof_test = PROJECT_DATA_DIR / "envs" / "dof_test_humanoid_env.yaml"
    with pytest.raises(MimicKitError, match=r"--motion_file: env 'char_dof_test' \(.*dof_test_humanoid_env.yaml\)"):
        load_env_configs(dof_test, ENGINE, "other.pkl")
