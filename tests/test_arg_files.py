"""Every shipped arg file names only arguments `mimickit` reads, and the configs it names exist and
validate (env, engine and agent yamls), so a typo in a rarely run arg file fails here, not an hour
into someone's run."""

from __future__ import annotations

from pathlib import Path

import pytest

from mimickit.envs.env_builder import load_env_configs
from mimickit.learning.agent_builder import load_agent_config
from mimickit.runner.args import RUN_ARGS, check_run_args
from mimickit.util.arg_parser import ArgParser
from mimickit.util.paths import PROJECT_DATA, PROJECT_ROOT

ARG_FILES = sorted((PROJECT_ROOT / "args").glob("*_args.txt"))


def test_every_arg_file_is_checked() -> None:
    assert len(ARG_FILES) >= 20


@pytest.mark.parametrize("arg_file", ARG_FILES, ids=lambda p: p.name)
def test_arg_file_names_known_args_and_valid_configs(arg_file: Path, tmp_path: Path, monkeypatch) -> None:
    args = ArgParser()
    args.load_file(str(arg_file))
    unknown = set(args.all_keys()) - set(RUN_ARGS)
    assert not unknown, f"{arg_file.name}: unknown arguments {sorted(unknown)}"
    monkeypatch.chdir(tmp_path)  # the out_dir probe runs in a scratch folder
    check_run_args(args)
    assert args.parse_int("num_envs", 1) >= 1
    monkeypatch.chdir(PROJECT_ROOT)

    paths = {}
    for key in ("env_config", "engine_config", "agent_config"):
        value = args.parse_string(key, "")
        if value:
            paths[key] = PROJECT_DATA.resolve(value)
            assert paths[key].is_file(), f"{arg_file.name}: --{key} {value} not found"
    assert "env_config" in paths, f"{arg_file.name}: no --env_config"
    load_env_configs(paths["env_config"], paths.get("engine_config"))
    if "agent_config" in paths:
        load_agent_config(paths["agent_config"])
