"""The studio's services (`studio.services.Studio`): one object holds every handle, its scene commands
raise the model's own error when there is no scene (the API maps it to 503), it closes its job queues,
and the routers do not import the app that includes them."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import studio.api
from studio.app import create_studio
from studio.services import SceneOff
from studio.settings import Settings


def test_a_scene_command_without_a_scene_is_scene_off(tmp_path: Path) -> None:
    studio = create_studio(Settings(runs_dir=tmp_path / "runs", start_viser=False))
    try:
        assert studio.active() is None and studio.viser_port is None
        with pytest.raises(SceneOff, match="the 3D scene is not running in this server"):
            studio.command(lambda target: None)
    finally:
        studio.close()
    with pytest.raises(Exception, match="stopping"):  # the queues closed with it
        studio.evals.submit(tmp_path / "model.pt", configs={"env_config": tmp_path / "env.yaml"})


def test_the_routers_do_not_import_the_app() -> None:
    """The app includes the routers; a router that imported it back would make a circle."""
    for path in sorted(Path(studio.api.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names += [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            assert not [n for n in names if n == "studio.app" or n.startswith("studio.app.")], path.name
