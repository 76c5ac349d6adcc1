"""The engine registry (`ENGINES`): every name validates its config class from the shipped engine yaml
and resolves its engine class, Newton only where its optional extra is installed (elsewhere one error
line saying how to install it); an unknown name is one error line naming the nearest. What is checked is
derived from the registry (tests/util/registry_checks.py): a new engine is checked without editing this."""

from __future__ import annotations

import importlib.util

import mujoco  # noqa: F401  (imported at collection: its GLFW probe starts a process, allowed only then)
import pytest

from mimickit.engines.engine import ENGINES, Engine, parse_engine_config
from mimickit.engines.engine_builder import build_engine
from mimickit.util.config import load_yaml
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR
from tests.util.registry_checks import shipped_yamls, supported_list, undocumented

HAS_NEWTON = importlib.util.find_spec("newton") is not None


def test_every_engine_has_its_shipped_yaml_and_is_documented():
    """Each registered name has data/engines/<name>_engine.yaml, each shipped engine yaml names a registered
    engine, and the docs mention every one."""
    for name in ENGINES.names:
        assert load_yaml(PROJECT_DATA_DIR / "engines" / f"{name}_engine.yaml")["engine_name"] == name
    assert set(shipped_yamls("engines", "engine_name")) <= set(ENGINES.names)
    assert not undocumented(ENGINES.names)


@pytest.mark.parametrize("name", ENGINES.names)
def test_every_engine_validates_its_config_class_and_resolves_its_class(name):
    path = PROJECT_DATA_DIR / "engines" / f"{name}_engine.yaml"
    config = parse_engine_config(load_yaml(path), path)
    assert type(config) is ENGINES.config_class(name) and config.engine_name == name
    if name == "newton" and not HAS_NEWTON:
        with pytest.raises(MimicKitError) as e:
            ENGINES.resolve(name, str(path))
        assert str(e.value).startswith(f"{path}: the Newton engine needs the optional extra: pip install .[newton]")
        assert "\n" not in str(e.value)
        return
    cls = ENGINES.resolve(name)
    assert issubclass(cls, Engine) and cls is not Engine


def test_the_builder_builds_the_registered_class():
    path = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
    engine = build_engine(load_yaml(path), 1, "cpu", source=path)
    assert type(engine) is ENGINES.resolve("mujoco")


@pytest.mark.parametrize(
    "name, needle",
    [
        ("mujoko", f"engine 'mujoko' is not supported; {supported_list(ENGINES)} (did you mean 'mujoco'?)"),
        ("isaac_lab", "engine 'isaac_lab' is not supported (Isaac Gym / Isaac Lab are not part of this port)"),
        ("physx", f"engine 'physx' is not supported; {supported_list(ENGINES)} (got 'physx')"),
    ],
)
def test_an_unknown_engine_name_is_one_line_naming_the_nearest(name, needle):
    with pytest.raises(MimicKitError) as e:
        build_engine({"engine_name": name, "env_spacing": 1.0}, 1, "cpu", source="my_engine.yaml")
    msg = str(e.value)
    assert msg.startswith("my_engine.yaml: key 'engine_name': ") and needle in msg and "\n" not in msg
