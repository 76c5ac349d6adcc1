"""Hostile yaml configs, arg files and command-line values: each is refused with one clear line that
names the file or key (`err-...`), or accepted (`ok-...`): alias bombs, binary files, numbers that
would hang the engine or allocate gigabytes, typos in argument names, unwritable output folders."""

from __future__ import annotations

import errno
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from mimickit.envs.env_builder import load_env_configs
from mimickit.learning.agent_builder import load_agent_config
from mimickit.runner.args import RUN_ARGS, check_run_args
from mimickit.util.arg_parser import ArgParser
from mimickit.util.config import MAX_ECHO_CHARS, MAX_YAML_BYTES, load_yaml, load_yaml_text
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from tests.hostile.read_only import read_only_dir

ENV_YAML = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"
AMP_ENV_YAML = PROJECT_DATA_DIR / "envs" / "amp_humanoid_env.yaml"
ENGINE_YAML = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
DEMO_MODEL = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"
AGENT_YAML = PROJECT_DATA_DIR / "agents" / "amp_humanoid_agent.yaml"
ARG_FILE = PROJECT_ROOT / "args" / "deepmimic_humanoid_ppo_args.txt"
ARG_FILES = sorted((PROJECT_ROOT / "args").glob("*_args.txt"))
DATA_YAMLS = sorted((PROJECT_DATA_DIR / "envs").glob("*.yaml")) + sorted((PROJECT_DATA_DIR / "agents").glob("*.yaml"))
MAX_LINE = MAX_ECHO_CHARS + 400  # the message's own words plus at most MAX_ECHO_CHARS of echoed input


def one_case(case_id: str) -> pytest.MarkDecorator:
    """A single case with its `err-`/`ok-` id, so the suite counts it like the parametrized ones."""
    return pytest.mark.parametrize("case", [case_id], ids=[case_id])


def bomb(levels: int, width: int, key: str = "episode_length") -> str:
    """A "billion laughs" document: `key` expands to width**levels strings."""
    lines = [f"l0: &l0 [{', '.join(['lol'] * width)}]"]
    lines += [f"l{i}: &l{i} [{', '.join([f'*l{i - 1}'] * width)}]" for i in range(1, levels)]
    return "\n".join(lines) + f"\n{key}: *l{levels - 1}\n"


def assert_one_line(e: pytest.ExceptionInfo[MimicKitError], *needles: str) -> str:
    msg = str(e.value)
    assert "\n" not in msg and len(msg) < MAX_LINE, msg[:1000]
    for n in needles:
        assert n in msg, msg
    return msg


# ---------------------------------------------------------------- yaml files


def write(tmp_path: Path, name: str, content: str | bytes) -> Path:
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return p


YAML_FILE_CASES = [
    pytest.param(bomb(9, 10), "alias bomb", id="err-yaml-billion-laughs-10e9"),
    pytest.param(bomb(7, 9), "alias bomb", id="err-yaml-bomb-9e7"),
    pytest.param(bomb(3, 100, key="key_bodies"), "alias bomb", id="err-yaml-bomb-wide"),
    pytest.param("a: &a [1, *a]\nepisode_length: *a\n", "recursive alias", id="err-yaml-recursive-alias"),
    pytest.param(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "binary file", id="err-yaml-binary-png"),
    pytest.param(b"episode_length: 10\x00\x00\x00", "binary file", id="err-yaml-nul-bytes"),
    pytest.param("env_name: caf\u00e9\n".encode("latin-1"), "not UTF-8", id="err-yaml-latin1"),
    pytest.param(b"\xff\xfe\x00e\x00n\x00v", "binary file", id="err-yaml-utf16"),
    pytest.param("a: 1\nb: 2\na: 3\n", "duplicate key 'a'", id="err-yaml-duplicate-key"),
    pytest.param("episode_length: " + "9" * 100_000 + "\n", "not valid YAML", id="err-yaml-int-100k-digits"),
    pytest.param("a: " + "[" * 100_000 + "]" * 100_000, "not valid YAML", id="err-yaml-deep-nesting"),
    pytest.param("- 1\n- 2\n", "expected a mapping", id="err-yaml-top-level-list"),
    pytest.param("a: [1, 2\nb: " + "x" * 1_000_000 + "\n", "not valid YAML", id="err-yaml-syntax-long-line"),
    pytest.param("a: !!python/object/apply:os.system ['true']\n", "not valid YAML", id="err-yaml-python-tag"),
]


@pytest.mark.parametrize("content, needle", YAML_FILE_CASES)
def test_hostile_yaml_file_is_one_line(tmp_path: Path, content: str | bytes, needle: str) -> None:
    path = write(tmp_path, "env.yaml", content)
    with pytest.raises(MimicKitError) as e:
        load_yaml(path)
    assert_one_line(e, needle, str(path))


@pytest.mark.parametrize(
    "content",
    [
        pytest.param(bomb(9, 10), id="err-yaml-text-billion-laughs"),
        pytest.param("a: &a [*a]\n", id="err-yaml-text-recursive"),
    ],
)
def test_hostile_yaml_text_is_one_line(content: str) -> None:
    with pytest.raises(MimicKitError) as e:
        load_yaml_text(content, "upload.yaml")
    assert_one_line(e, "upload.yaml")


@one_case("err-env-billion-laughs-episode-length")
def test_billion_laughs_env_config_is_refused(
    case: str, tmp_path: Path
) -> None:  # the case, through the env loader
    env = write(tmp_path, "env.yaml", "env_name: deepmimic\n" + bomb(9, 10).replace("\nl", "\n_l"))
    with pytest.raises(MimicKitError) as e:
        load_env_configs(env, ENGINE_YAML)
    assert_one_line(e, "alias bomb")


@pytest.mark.parametrize(
    "content",
    [
        pytest.param(b"x" * (MAX_YAML_BYTES + 1), id="err-yaml-over-size-limit"),
    ],
)
def test_oversized_yaml(tmp_path: Path, content: bytes) -> None:
    with pytest.raises(MimicKitError) as e:
        load_yaml(write(tmp_path, "big.yaml", content))
    assert_one_line(e, "byte limit")


@pytest.mark.parametrize(
    "path, needle",
    [
        pytest.param("/dev/zero", "not a regular file", id="err-yaml-dev-zero"),
        pytest.param("/", "not a regular file", id="err-yaml-a-folder"),
        pytest.param("/no/such/env.yaml", "not found", id="err-yaml-missing"),
    ],
)
def test_not_a_regular_file(path: str, needle: str) -> None:
    with pytest.raises(MimicKitError) as e:
        load_yaml(path)
    assert_one_line(e, needle, path)


@one_case("ok-yaml-small-aliases-and-merge")
def test_small_aliases_are_fine(case: str, tmp_path: Path) -> None:  # ok-: anchors as people use them stay accepted
    path = write(tmp_path, "a.yaml", "w: &w [1.0, 0.5]\nx: *w\ny: {<<: {k: 1}, j: 2}\n")
    assert load_yaml(path) == {"w": [1.0, 0.5], "x": [1.0, 0.5], "y": {"k": 1, "j": 2}}


# ---------------------------------------------------------------- numbers in configs


def env_yaml(tmp_path: Path, base: Path = ENV_YAML, **env: object) -> Path:
    raw = yaml.safe_load(base.read_text())
    raw["env"].update(env)
    return write(tmp_path, "env.yaml", yaml.safe_dump(raw))


def engine_yaml(tmp_path: Path, **fields: object) -> Path:
    raw = yaml.safe_load(ENGINE_YAML.read_text())
    raw.update(fields)
    return write(tmp_path, "engine.yaml", yaml.safe_dump(raw))


ENV_VALUE_CASES = [
    pytest.param({"num_phase_encoding": 100_000_000}, "num_phase_encoding", id="err-env-num-phase-encoding-1e8"),
    pytest.param({"num_phase_encoding": "1e8"}, "num_phase_encoding", id="err-env-num-phase-encoding-1e8-str"),
    pytest.param({"num_phase_encoding": -1}, "num_phase_encoding", id="err-env-num-phase-encoding-negative"),
    pytest.param({"tar_obs_steps": []}, "tar_obs_steps", id="err-env-tar-obs-steps-empty"),
    pytest.param({"tar_obs_steps": [0]}, "tar_obs_steps", id="err-env-tar-obs-steps-zero"),
    pytest.param({"tar_obs_steps": [1, 10**9]}, "tar_obs_steps", id="err-env-tar-obs-steps-huge"),
    pytest.param({"tar_obs_steps": list(range(1, 200))}, "tar_obs_steps", id="err-env-tar-obs-steps-too-many"),
    pytest.param({"episode_length": float("inf")}, "episode_length", id="err-env-episode-length-inf"),
    pytest.param({"episode_length": float("nan")}, "episode_length", id="err-env-episode-length-nan"),
    pytest.param({"episode_length": 0}, "episode_length", id="err-env-episode-length-zero"),
    pytest.param({"episode_length": -5.0}, "episode_length", id="err-env-episode-length-negative"),
    pytest.param({"episode_length": "x" * 100_000}, "episode_length", id="err-env-episode-length-100k-string"),
    pytest.param({"reward_pose_w": float("nan")}, "reward_pose_w", id="err-env-reward-weight-nan"),
    pytest.param({"episode_lenght": 10.0}, "did you mean 'episode_length'", id="err-env-typo-key"),
]


@pytest.mark.parametrize("env, needle", ENV_VALUE_CASES)
def test_env_config_values(tmp_path: Path, env: dict[str, object], needle: str) -> None:
    with pytest.raises(MimicKitError) as e:
        load_env_configs(env_yaml(tmp_path, **env), ENGINE_YAML)
    assert_one_line(e, needle, "env.yaml")


def env_yaml_beside(tmp_path: Path, **top: object) -> Path:
    """The shipped env yaml (MimicKit's layout, fields under `env:`) with `top` beside the block."""
    raw = yaml.safe_load(ENV_YAML.read_text())
    raw.update(top)
    return write(tmp_path, "beside_env.yaml", yaml.safe_dump(raw))


@pytest.mark.parametrize(
    "top, needle",
    [
        pytest.param(
            {"motion_file": "/nonexistent/x.pkl"},
            "key 'motion_file' stands beside the env: block",
            id="err-env-clip-beside-block",
        ),
        pytest.param(
            {"typo_key": 1}, "unknown key 'typo_key' beside the env: block", id="err-env-unknown-key-beside-block"
        ),
        pytest.param({"engin": {"sim_freq": 120}}, "did you mean 'engine'?", id="err-env-engine-typo-beside-block"),
        pytest.param({"episode_lenght": 5.0}, "did you mean 'episode_length'?", id="err-env-field-typo-beside-block"),
    ],
)
def test_key_beside_the_env_block(tmp_path: Path, top: dict[str, object], needle: str) -> None:
    with pytest.raises(MimicKitError) as e:
        load_env_configs(env_yaml_beside(tmp_path, **top), ENGINE_YAML)
    assert_one_line(e, needle, "env.yaml")


@pytest.mark.parametrize(
    "env, needle",
    [
        pytest.param({"num_disc_obs_steps": 1_000_000}, "num_disc_obs_steps", id="err-env-disc-obs-steps-1e6"),
        pytest.param({"num_disc_obs_steps": 0}, "num_disc_obs_steps", id="err-env-disc-obs-steps-zero"),
    ],
)
def test_amp_env_config_values(tmp_path: Path, env: dict[str, object], needle: str) -> None:
    with pytest.raises(MimicKitError) as e:
        load_env_configs(env_yaml(tmp_path, AMP_ENV_YAML, **env), ENGINE_YAML)
    assert_one_line(e, needle)


ENGINE_VALUE_CASES = [
    pytest.param({"sim_freq": 30_000_000}, "sim_freq", id="err-engine-sim-freq-3e7"),
    pytest.param({"sim_freq": 3e7}, "sim_freq", id="err-engine-sim-freq-3e7-float"),
    pytest.param({"sim_freq": 250}, "multiple of control_freq", id="err-engine-sim-freq-not-multiple"),
    pytest.param({"sim_freq": 0}, "sim_freq", id="err-engine-sim-freq-zero"),
    pytest.param({"control_freq": 0}, "control_freq", id="err-engine-control-freq-zero"),
    pytest.param({"control_freq": 480}, "multiple of control_freq", id="err-engine-control-above-sim"),
    pytest.param({"sim_freq": 10_000, "control_freq": 1}, "physics steps per control step", id="err-engine-substeps"),
    pytest.param({"solver_iterations": 10**9}, "solver_iterations", id="err-engine-solver-iterations-1e9"),
    pytest.param({"env_spacing": float("nan")}, "env_spacing", id="err-engine-env-spacing-nan"),
    pytest.param({"num_threads": -3}, "num_threads", id="err-engine-num-threads-negative"),
]


@pytest.mark.parametrize("fields, needle", ENGINE_VALUE_CASES)
def test_engine_config_values(tmp_path: Path, fields: dict[str, object], needle: str) -> None:
    with pytest.raises(MimicKitError) as e:
        load_env_configs(ENV_YAML, engine_yaml(tmp_path, **fields))
    assert_one_line(e, needle, "engine.yaml")


AGENT_VALUE_CASES = [
    pytest.param({"steps_per_iter": 10**9}, "steps_per_iter", id="err-agent-steps-per-iter-1e9"),
    pytest.param({"disc_buffer_size": 10**12}, "disc_buffer_size", id="err-agent-disc-buffer-1e12"),
    pytest.param({"actor_epochs": 10**7}, "actor_epochs", id="err-agent-actor-epochs-1e7"),
    pytest.param({"test_episodes": 10**12}, "test_episodes", id="err-agent-test-episodes-1e12"),
    pytest.param({"discount": float("nan")}, "discount", id="err-agent-discount-nan"),
    pytest.param(
        {"actor_optimizer": {"type": "Adam", "learning_rate": ".nan"}}, "learning_rate", id="err-agent-lr-nan"
    ),
    pytest.param({"model": {"actor_nett": 1}}, "did you mean 'actor_net'", id="err-agent-nested-typo"),
    pytest.param({"learnign_rate": 1}, "unknown key 'learnign_rate'", id="err-agent-typo-key"),
]


@pytest.mark.parametrize("fields, needle", AGENT_VALUE_CASES)
def test_agent_config_values(tmp_path: Path, fields: dict[str, object], needle: str) -> None:
    raw = yaml.safe_load(AGENT_YAML.read_text())
    for k, v in fields.items():
        raw[k] = {**raw[k], **v} if isinstance(v, dict) and isinstance(raw.get(k), dict) else v
    with pytest.raises(MimicKitError) as e:
        load_agent_config(write(tmp_path, "agent.yaml", yaml.safe_dump(raw)))
    assert_one_line(e, needle, "agent.yaml")


@one_case("err-env-bomb-under-limit-bounded-echo")
def test_echo_of_a_large_bad_value_is_bounded(case: str, tmp_path: Path) -> None:  # a bomb just under the node limit
    path = write(tmp_path, "env.yaml", "env_name: deepmimic\n" + bomb(5, 9).replace("\nl", "\n_l"))
    with pytest.raises(MimicKitError) as e:
        load_env_configs(path, ENGINE_YAML)
    assert_one_line(e, "env.yaml")


@pytest.mark.parametrize("path", DATA_YAMLS, ids=lambda p: f"ok-data-{p.parent.name}-{p.stem}")
def test_shipped_configs_load(path: Path) -> None:
    if path.parent.name == "envs":
        env_cfg, engine_cfg = load_env_configs(path, ENGINE_YAML)
        assert env_cfg.episode_length > 0 and engine_cfg.substeps >= 1
    else:
        assert load_agent_config(path).steps_per_iter >= 1


# ---------------------------------------------------------------- arguments


def parsed(argv: list[str]) -> ArgParser:
    args = ArgParser()
    args.load_args(argv)
    return args


ARG_CASES = [
    pytest.param(["--num_env", "8"], "did you mean --num_envs?", id="err-arg-num-env-typo"),
    pytest.param(["--motion_fle", "a.pkl"], "did you mean --motion_file?", id="err-arg-motion-file-typo"),
    pytest.param(["--zzzz", "1"], "unknown argument --zzzz", id="err-arg-unknown-far"),
    pytest.param(["--num_envs", "0"], "--num_envs must be an integer between 1", id="err-arg-num-envs-0"),
    pytest.param(["--num_envs", "-4"], "--num_envs", id="err-arg-num-envs-negative"),
    pytest.param(["--num_envs", "1.5"], "--num_envs: expected an integer", id="err-arg-num-envs-fraction"),
    pytest.param(["--num_envs", "many"], "--num_envs: expected an integer", id="err-arg-num-envs-word"),
    pytest.param(["--num_envs", "1e400"], "--num_envs: expected an integer", id="err-arg-num-envs-overflow"),
    pytest.param(["--num_envs", "1e9"], "--num_envs must be an integer between 1", id="err-arg-num-envs-1e9"),
    pytest.param(["--num_envs", "8", "16"], "--num_envs takes one value, got 2", id="err-arg-num-envs-two-values"),
    pytest.param(["--num_envs"], "--num_envs needs a value", id="err-arg-num-envs-empty"),
    pytest.param(["--devices", "toaster"], "unknown device 'toaster'", id="err-arg-devices-toaster"),
    pytest.param(["--devices", "cpu", "gpu0"], "unknown device 'gpu0'", id="err-arg-devices-second-bad"),
    pytest.param(["--devices", "cuda:x"], "unknown device 'cuda:x'", id="err-arg-devices-cuda-x"),
    pytest.param(["--devices", "cuda:999"], "cuda:999", id="err-arg-devices-cuda-999"),
    pytest.param(["--logger", "csv"], "--logger must be txt or tb or wandb", id="err-arg-logger"),
    pytest.param(["--mode", "play"], "--mode must be train or test", id="err-arg-mode"),
    pytest.param(["--rand_seed", "-7"], "--rand_seed", id="err-arg-rand-seed-negative"),
    pytest.param(["--rand_seed", "seed"], "--rand_seed: expected an integer", id="err-arg-rand-seed-word"),
    pytest.param(["--max_samples", "0"], "--max_samples", id="err-arg-max-samples-0"),
    pytest.param(["--test_episodes", "0"], "--test_episodes", id="err-arg-test-episodes-0"),
    pytest.param(["--master_port", "70000"], "--master_port", id="err-arg-master-port"),
    pytest.param(["--save_int_models", "yes"], "--save_int_models must be true or false", id="err-arg-bool-yes"),
    pytest.param(["--model_file", "/no/such/model.pt"], "file not found", id="err-arg-model-file-missing"),
    pytest.param(["--data_dir", "/no/such/dir"], "folder not found", id="err-arg-data-dir-missing"),
]


@pytest.mark.parametrize("argv, needle", ARG_CASES)
def test_bad_run_args(tmp_path: Path, argv: list[str], needle: str) -> None:
    args = parsed(["--arg_file", str(ARG_FILE), "--out_dir", str(tmp_path / "run"), *argv])
    with pytest.raises(MimicKitError) as e:
        check_run_args(args)
    assert_one_line(e, needle)


@one_case("err-argfile-num-env-typo")
def test_typo_in_arg_file_names_the_file(case: str, tmp_path: Path) -> None:  # err-: the key came from the file
    f = write(tmp_path, "my_args.txt", ARG_FILE.read_text() + "\n--num_env 8\n")
    with pytest.raises(MimicKitError) as e:
        check_run_args(parsed(["--arg_file", str(f)]))
    assert_one_line(e, "unknown argument --num_env in", "my_args.txt", "did you mean --num_envs?")


ARG_FILE_CASES = [
    pytest.param(b"\x7fELF\x02\x01\x01\x00\x00\x00", "binary file", id="err-argfile-binary-elf"),
    pytest.param("--num_envs 8 \u00e9\n".encode("latin-1"), "not UTF-8", id="err-argfile-latin1"),
    pytest.param(b"--num_envs " + b"1" * (1 << 20), "byte limit", id="err-argfile-over-size-limit"),
    pytest.param(b"num_envs 8\n", "comes before any --key", id="err-argfile-value-before-key"),
    pytest.param(b"--arg_file other.txt\n", "cannot name another --arg_file", id="err-argfile-nested-arg-file"),
]


@pytest.mark.parametrize("content, needle", ARG_FILE_CASES)
def test_hostile_arg_file(tmp_path: Path, content: bytes, needle: str) -> None:
    f = write(tmp_path, "bad_args.txt", content)
    with pytest.raises(MimicKitError) as e:
        parsed(["--arg_file", str(f)])
    assert_one_line(e, needle, "bad_args.txt")


JSON_ARG_FILE_CASES = [
    pytest.param(b'{"num_envs": 8,', "not valid JSON", id="err-jsonargs-truncated"),
    pytest.param(b"{'num_envs': 8}", "not valid JSON", id="err-jsonargs-single-quotes"),
    pytest.param(b'["--num_envs", "8"]', "holds an object of arguments, got a list", id="err-jsonargs-list"),
    pytest.param(b'"--num_envs 8"', "got a string", id="err-jsonargs-string"),
    pytest.param(b"null", "got null", id="err-jsonargs-null"),
    pytest.param(b"42", "got a number", id="err-jsonargs-number"),
    pytest.param(
        b'{"num_envs": {"n": 8}}', "--num_envs: expected a string, number or boolean", id="err-jsonargs-object"
    ),
    pytest.param(b'{"num_envs": null}', "got null", id="err-jsonargs-null-value"),
    pytest.param(b'{"devices": ["cpu", ["cpu"]]}', "--devices: expected", id="err-jsonargs-nested-list"),
    pytest.param(b"[" * 200_000 + b"]" * 200_000, "nested too deeply", id="err-jsonargs-deep-nesting"),
    pytest.param(b'{"num_envs": ' + b"9" * 5000 + b"}", "not valid JSON", id="err-jsonargs-5000-digit-number"),
    pytest.param(b'{"pad": "' + b"x" * (1 << 20) + b'"}', "byte limit", id="err-jsonargs-over-size-limit"),
    pytest.param(b'{"arg_file": "other.txt"}', "cannot name another --arg_file", id="err-jsonargs-nested-arg-file"),
    pytest.param(b'{"format": 2, "args": {}}', "a run record of format 2", id="err-jsonargs-record-format"),
    pytest.param(b'{"format": 1, "args": ["--num_envs"]}', "`args` must be an object", id="err-jsonargs-record-args"),
    pytest.param(b'{"format": 1, "args": {"num_envs": [{}]}}', "--num_envs: expected", id="err-jsonargs-record-type"),
    pytest.param(b"\xff\xfe{}", "not UTF-8", id="err-jsonargs-utf16-bom"),
]


@pytest.mark.parametrize("content, needle", JSON_ARG_FILE_CASES)
def test_hostile_json_arg_file(tmp_path: Path, content: bytes, needle: str) -> None:
    f = write(tmp_path, "bad_args.json", content)
    with pytest.raises(MimicKitError) as e:
        parsed(["--arg_file", str(f)])
    assert_one_line(e, needle, "bad_args.json")


JSON_CHECK_CASES = [
    pytest.param({"num_env": 8}, "unknown argument --num_env in", id="err-jsonargs-unknown-key"),
    pytest.param(
        {"format": 1, "args": {"nmu_envs": ["8"]}}, "unknown argument --nmu_envs in", id="err-jsonargs-record-key"
    ),
    pytest.param({"num_envs": 1.5}, "--num_envs in", id="err-jsonargs-num-envs-fraction"),
    pytest.param({"num_envs": True}, "expected an integer, got 'true'", id="err-jsonargs-num-envs-bool"),
    pytest.param({"max_hours": float("nan")}, "must be a number > 0, got nan", id="err-jsonargs-max-hours-nan"),
    pytest.param({"num_envs": [8, 16]}, "takes one value, got 2", id="err-jsonargs-two-values"),
    pytest.param({"k" * 5000: 1}, "unknown argument", id="err-jsonargs-huge-key"),
]


@pytest.mark.parametrize("obj, needle", JSON_CHECK_CASES)
def test_bad_json_arg_values_name_the_file(tmp_path: Path, obj: dict, needle: str) -> None:
    """Parsed, then refused by the run's checks in one line naming the key and the file."""
    import json

    f = write(tmp_path, "my_args.json", json.dumps({"env_config": str(ENV_YAML), **obj}))
    with pytest.raises(MimicKitError) as e:
        check_run_args(parsed(["--arg_file", str(f), "--mode", "test", "--model_file", str(DEMO_MODEL)]))
    assert_one_line(e, needle, "my_args.json")


@one_case("ok-jsonargs-plain-object")
def test_plain_json_arg_file(case: str, tmp_path: Path) -> None:  # ok-: JSON types become the text tokens
    f = write(
        tmp_path,
        "ok_args.json",
        b'{"env_config": "data/envs/deepmimic_humanoid_env.yaml", "num_envs": 8, "max_samples": 1e6, '
        b'"devices": ["cpu", "cpu"], "save_int_models": true, "max_hours": 0.5}',
    )
    args = parsed(["--arg_file", str(f), "--num_envs", "4", "--out_dir", str(tmp_path / "run")])
    check_run_args(args)
    assert args.parse_int("num_envs") == 4 and args.source("num_envs") == "the command line"  # the command line wins
    assert args.parse_int("max_samples") == 1_000_000 and args.parse_strings("devices") == ["cpu", "cpu"]
    assert args.parse_bool("save_int_models") and args.parse_float("max_hours") == 0.5
    assert args.source("devices") == str(f)


@pytest.mark.integration
@one_case("err-outdir-read-only")
def test_unwritable_out_dir(case: str, tmp_path: Path) -> None:  # err-: a read-only folder (the real thing)
    with read_only_dir(tmp_path / "ro") as ro:
        with pytest.raises(MimicKitError) as e:
            check_run_args(parsed(["--arg_file", str(ARG_FILE), "--out_dir", str(ro / "run")]))
        assert_one_line(e, "--out_dir", "cannot write there")
        assert list(ro.iterdir()) == []


@pytest.mark.parametrize(
    "make, needle",
    [
        pytest.param(lambda d: (d / "f").write_text("x") and d / "f", "is a file", id="err-outdir-is-a-file"),
        pytest.param(lambda d: (d / "f").write_text("x") and d / "f" / "run", "is a file", id="err-outdir-under-file"),
    ],
)
def test_out_dir_that_is_a_file(tmp_path: Path, make, needle: str) -> None:
    out = make(tmp_path)
    with pytest.raises(MimicKitError) as e:
        check_run_args(parsed(["--arg_file", str(ARG_FILE), "--out_dir", str(out)]))
    assert_one_line(e, "--out_dir", needle)


@one_case("err-outdir-full-disk")
def test_full_disk_out_dir(case: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """err-: a full disk, simulated at the write (the read-only test above is the real-folder one)."""

    def full(fd: int, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "write", full)
    out = tmp_path / "a" / "b"
    with pytest.raises(MimicKitError) as e:
        check_run_args(parsed(["--arg_file", str(ARG_FILE), "--out_dir", str(out)]))
    assert_one_line(e, "--out_dir", os.strerror(errno.ENOSPC))
    assert list(tmp_path.iterdir()) == []  # the folders made for the probe are gone again


OK_ARGS = [
    pytest.param(["--visualize", "true"], id="ok-arg-visualize"),
    pytest.param(["--video", "true"], id="ok-arg-video"),
    pytest.param(["--devices", "cpu", "cpu"], id="ok-arg-two-cpu-devices"),
    pytest.param(["--rand_seed", "-1"], id="ok-arg-rand-seed-draw"),
    pytest.param(["--rand_seed", "12345"], id="ok-arg-rand-seed"),
    pytest.param(["--max_samples", "1e6"], id="ok-arg-max-samples-sci"),
    pytest.param(["--mode", "test", "--json", "--test_episodes", "4"], id="ok-arg-test-json-flag"),
    pytest.param(["--logger", "tb", "--save_int_models", "T"], id="ok-arg-logger-tb"),
]


@pytest.mark.parametrize("argv", OK_ARGS)
def test_good_run_args(tmp_path: Path, argv: list[str]) -> None:
    check_run_args(parsed(["--arg_file", str(ARG_FILE), "--out_dir", str(tmp_path / "run"), *argv]))
    assert not (tmp_path / "run").exists()  # the check writes nothing that stays


@pytest.mark.parametrize("arg_file", ARG_FILES, ids=lambda p: f"ok-argfile-{p.stem}")
def test_shipped_arg_files_pass(tmp_path: Path, arg_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)  # relative --out_dir folders land (and are removed) here
    check_run_args(parsed(["--arg_file", str(arg_file)]))
    assert set(parsed(["--arg_file", str(arg_file)]).all_keys()) <= set(RUN_ARGS)


# ---------------------------------------------------------------- through `mimickit train`


def mimickit(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "mimickit.cli", *argv]
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def cli_cases(tmp: Path) -> dict[str, tuple[list[str], str]]:
    env = write(tmp, "bomb_env.yaml", "env_name: deepmimic\n" + bomb(9, 10).replace("\nl", "\n_l"))
    binary_args = write(tmp, "binary_args.txt", b"\x00\x01\x02--num_envs 8")
    base = ["--arg_file", str(ARG_FILE), "--out_dir", str(tmp / "run"), "--max_samples", "64"]
    return {
        "bomb": (["--arg_file", str(ARG_FILE), "--env_config", str(env), "--out_dir", str(tmp / "r1")], "alias bomb"),
        "typo": ([*base, "--num_env", "8"], "did you mean --num_envs?"),
        "num_envs_0": ([*base, "--num_envs", "0"], "--num_envs"),
        "toaster": ([*base, "--devices", "toaster"], "unknown device 'toaster'"),
        "binary_args": (["--arg_file", str(binary_args)], "binary file"),
        "phase": ([*base, "--env_config", str(env_yaml(tmp, num_phase_encoding=10**8))], "num_phase_encoding"),
        "beside": ([*base, "--env_config", str(env_yaml_beside(tmp, typo_key=1))], "unknown key 'typo_key'"),
    }


CLI_CASES = [
    pytest.param("bomb", id="err-cli-train-billion-laughs"),
    pytest.param("typo", id="err-cli-train-num-env-typo"),
    pytest.param("num_envs_0", id="err-cli-train-num-envs-0"),
    pytest.param("toaster", id="err-cli-train-devices-toaster"),
    pytest.param("binary_args", id="err-cli-train-binary-arg-file"),
    pytest.param("phase", id="err-cli-train-phase-encoding-1e8"),
    pytest.param("beside", id="err-cli-train-key-beside-env-block"),
]


@pytest.mark.integration
@pytest.mark.parametrize("case", CLI_CASES)
def test_cli_train_refuses_in_one_line(tmp_path: Path, case: str) -> None:
    argv, needle = cli_cases(tmp_path)[case]
    proc = mimickit("train", *argv, cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-3000:]
    assert lines[0].startswith("error: ") and needle in lines[0] and len(lines[0]) < MAX_LINE
    assert not (tmp_path / "run").exists() and not (tmp_path / "r1").exists()


@pytest.mark.integration
@one_case("err-cli-bench-clip-beside-env-block")
def test_cli_bench_refuses_a_key_beside_the_env_block(case: str, tmp_path: Path) -> None:
    env = env_yaml_beside(tmp_path, motion_file="/nonexistent/x.pkl")
    proc = mimickit("bench", "--env_config", str(env), "--num_envs", "1", "--steps", "1", cwd=tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr[-3000:]
    assert lines[0].startswith("error: ") and "'motion_file'" in lines[0] and str(env) in lines[0], lines[0]
