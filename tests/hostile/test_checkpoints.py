"""Hostile `.pt` checkpoints and hostile places to save one: each is refused with one clear line naming
the file and the key (`err-...`) or accepted (`ok-...`). The checkpoints are real ones written by a
real DeepMimic humanoid agent (MuJoCo), then edited: truncated, NaN weights, code in the pickle, a
`_train_state` of the wrong type, zip archives with the wrong entries."""

from __future__ import annotations

import errno
import io
import os
import pickle
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import torch

from mimickit.envs.env_builder import build_env
from mimickit.learning import checkpoint
from mimickit.learning.agent_builder import build_agent
from mimickit.learning.base_agent import BaseAgent
from mimickit.learning.checkpoint import TRAIN_STATE_KEY, nonfinite_tensors, read_checkpoint
from mimickit.tools.export_checkpoint import export_checkpoint
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT
from tests.hostile.read_only import read_only_dir

ENV_YAML = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"
ENGINE_YAML = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"
AGENT_YAML = PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_agent.yaml"
ARG_FILE = PROJECT_ROOT / "args" / "deepmimic_humanoid_ppo_args.txt"
MAX_LINE = 700


def one_case(case_id: str) -> pytest.MarkDecorator:
    """A single case with its `err-`/`ok-` id, so the suite counts it like the parametrized ones."""
    return pytest.mark.parametrize("case", [case_id], ids=[case_id])


@pytest.fixture(scope="module")
def agent() -> BaseAgent:
    env = build_env(ENV_YAML, ENGINE_YAML, 1, "cpu")
    return build_agent(AGENT_YAML, env, "cpu", verbose=False)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run folder after one real training iteration (2 envs), with a stale temp file planted first."""
    out = tmp_path_factory.mktemp("run")
    (out / ".model.pt.k9x2ab_q").write_bytes(b"half a checkpoint")  # what a kill -9 mid-write leaves
    proc = mimickit("train", "--arg_file", str(ARG_FILE), "--num_envs", "2", "--max_samples", "64",
                    "--out_dir", str(out), "--rand_seed", "1", cwd=out)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


def mimickit(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    cmd = [sys.executable, "-m", "mimickit.cli", *argv]
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def state_of(agent: BaseAgent, tmp_path: Path) -> dict[str, Any]:
    agent.save(tmp_path / "good.pt")
    return torch.load(tmp_path / "good.pt", weights_only=True)


def save(state: Any, path: Path) -> Path:
    torch.save(state, path)
    return path


def assert_one_line(e: pytest.ExceptionInfo[MimicKitError], *needles: str) -> None:
    msg = str(e.value)
    assert "\n" not in msg and len(msg) < MAX_LINE, msg[:1500]
    for n in needles:
        assert n in msg, msg


# ---------------------------------------------------------------- crafted files

Maker = Callable[[dict[str, Any], Path], Path]


class Evil:
    """Pickles to a call of os.system: a full unpickler would run the command."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[Any, ...]:
        return (os.system, (f"touch {self.marker}",))


def evil_pickle(protocol: int) -> Maker:
    def make(state: dict[str, Any], tmp: Path) -> Path:
        (tmp / "m.pt").write_bytes(pickle.dumps({**state, "x": Evil(tmp / "PWNED")}, protocol=protocol))
        return tmp / "m.pt"

    return make


def evil_torch_zip(state: dict[str, Any], tmp: Path) -> Path:
    buf = io.BytesIO()
    torch.save({"_model.x": Evil(tmp / "PWNED")}, buf)  # torch's own format, code in data.pkl
    (tmp / "m.pt").write_bytes(buf.getvalue())
    return tmp / "m.pt"


def truncated(state: dict[str, Any], tmp: Path) -> Path:
    data = save(state, tmp / "full.pt").read_bytes()
    (tmp / "m.pt").write_bytes(data[: len(data) // 2])
    return tmp / "m.pt"


def zip_with(entries: dict[str, bytes], compress: int = zipfile.ZIP_STORED) -> Maker:
    def make(state: dict[str, Any], tmp: Path) -> Path:
        with zipfile.ZipFile(tmp / "m.pt", "w", compression=compress) as zf:
            for name, data in entries.items():
                zf.writestr(name, data)
        return tmp / "m.pt"

    return make


def data_pkl_replaced(state: dict[str, Any], tmp: Path) -> Path:
    src = save(state, tmp / "full.pt")
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(tmp / "m.pt", "w") as zout:
        for info in zin.infolist():
            data = b"\x80\x02garbage" if info.filename.endswith("data.pkl") else zin.read(info)
            zout.writestr(info, data)
    return tmp / "m.pt"


def edited(edit: Callable[[dict[str, Any]], Any]) -> Maker:
    def make(state: dict[str, Any], tmp: Path) -> Path:
        copy = dict(state)
        new = edit(copy)
        return save(new if new is not None else copy, tmp / "m.pt")

    return make


def set_key(key: str, value: Any) -> Maker:
    return edited(lambda s: s.__setitem__(key, value))


def set_ts(path: str, value: Any) -> Maker:
    """Set `_train_state.<path>` (dotted) to `value`."""

    def edit(s: dict[str, Any]) -> None:
        ts = s[TRAIN_STATE_KEY] = _deep_copy(s[TRAIN_STATE_KEY])
        *head, last = path.split(".")
        d = ts
        for part in head:
            d = d[int(part)] if isinstance(d, list) else d[part]
        d[last] = value

    return edited(edit)


def _deep_copy(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _deep_copy(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_deep_copy(v) for v in obj]
    return obj


def scaled_weights(factor: float, key: str = "_model._actor_layers.0.weight") -> Maker:
    def edit(s: dict[str, Any]) -> None:
        k = key if key in s else next(k for k in s if k.startswith("_model.") and k.endswith("weight"))
        s[k] = s[k] * factor

    return edited(edit)


def text(content: bytes) -> Maker:
    def make(state: dict[str, Any], tmp: Path) -> Path:
        (tmp / "m.pt").write_bytes(content)
        return tmp / "m.pt"

    return make


BAD_FILES = [
    pytest.param(text(b""), "empty file", id="err-pt-empty-file"),
    pytest.param(text(b"hello, I am a text file\n"), "not a readable checkpoint", id="err-pt-text-file"),
    pytest.param(text(b"\x89PNG\r\n\x1a\n" + b"\0" * 64), "not a readable checkpoint", id="err-pt-png"),
    pytest.param(truncated, "not a readable checkpoint", id="err-pt-truncated"),
    pytest.param(evil_pickle(2), "refused", id="err-pt-pickle-os-system-proto2"),
    pytest.param(evil_pickle(4), "not a readable checkpoint", id="err-pt-pickle-os-system-proto4"),
    pytest.param(evil_torch_zip, "refused", id="err-pt-torch-zip-os-system"),
    pytest.param(zip_with({"hello.txt": b"hi"}), "not a readable checkpoint", id="err-pt-zip-wrong-entries"),
    pytest.param(zip_with({}), "not a readable checkpoint", id="err-pt-zip-empty"),
    pytest.param(data_pkl_replaced, "not a readable checkpoint", id="err-pt-zip-garbage-data-pkl"),
    pytest.param(text(b"PK\x03\x04" + b"\xff" * 200), "not a readable checkpoint", id="err-pt-zip-header-only"),
    pytest.param(edited(lambda s: [1, 2, 3]), "expected a state dict, got list", id="err-pt-list-not-dict"),
    pytest.param(edited(lambda s: torch.zeros(3)), "expected a state dict, got Tensor", id="err-pt-bare-tensor"),
    pytest.param(edited(lambda s: {**s, 7: torch.zeros(1)}), "is not a string", id="err-pt-int-key"),
    pytest.param(set_key("_obs_norm._mean", [0.0] * 10), "'_obs_norm._mean' is not a tensor", id="err-pt-list-value"),
    pytest.param(set_key("_obs_norm._std", "1.0"), "'_obs_norm._std' is not a tensor", id="err-pt-string-value"),
    pytest.param(set_key("_model.extra", 3), "'_model.extra' is not a tensor", id="err-pt-int-value"),
    pytest.param(
        set_key("_obs_norm._mean", torch.zeros(3).to_sparse()), "not a dense tensor", id="err-pt-sparse-tensor"
    ),
    pytest.param(set_ts("test", None), "_train_state.test must be a mapping", id="err-ts-test-none"),
    pytest.param(set_key(TRAIN_STATE_KEY, [1, 2]), "_train_state must be a mapping, got list", id="err-ts-list"),
    pytest.param(set_key(TRAIN_STATE_KEY, "resume"), "_train_state must be a mapping, got str", id="err-ts-str"),
    pytest.param(set_key(TRAIN_STATE_KEY, torch.zeros(2)), "must be a mapping, got Tensor", id="err-ts-tensor"),
    pytest.param(set_ts("iteration", "5"), "_train_state.iteration must be an integer", id="err-ts-iteration-str"),
    pytest.param(set_ts("iteration", -1), "_train_state.iteration must be an integer", id="err-ts-iteration-neg"),
    pytest.param(set_ts("samples", 1.5), "_train_state.samples must be an integer", id="err-ts-samples-float"),
    pytest.param(set_ts("samples", True), "_train_state.samples must be an integer", id="err-ts-samples-bool"),
    pytest.param(set_ts("wall_time_hours", float("nan")), "wall_time_hours must be a finite", id="err-ts-wall-nan"),
    pytest.param(set_ts("agent_name", 3), "_train_state.agent_name must be a string", id="err-ts-agent-name-int"),
    pytest.param(set_ts("format", 99), "newer version", id="err-ts-format-99"),
    pytest.param(set_ts("test", [1]), "_train_state.test must be a mapping", id="err-ts-test-list"),
    pytest.param(set_ts("test.num_eps", "x"), "_train_state.test.num_eps", id="err-ts-test-num-eps-str"),
    pytest.param(set_ts("test.mean_return", float("inf")), "test.mean_return", id="err-ts-test-return-inf"),
    pytest.param(set_ts("optimizers", [1]), "_train_state.optimizers must be a mapping", id="err-ts-optimizers-list"),
    pytest.param(set_ts("optimizers.actor", {"steps": 1}), "optimizers.actor must be", id="err-ts-optimizer-no-state"),
    pytest.param(set_ts("optimizers.actor.steps", "many"), "optimizers.actor.steps", id="err-ts-optimizer-steps-str"),
    pytest.param(set_ts("optimizers.actor.optimizer.state", [1]), "'state' mapping", id="err-ts-torch-state-list"),
    pytest.param(
        set_ts("optimizers.actor.optimizer.state", {0: {"momentum_buffer": "x"}}),
        "state.0 must map names to tensors",
        id="err-ts-torch-state-str-buffer",
    ),
    pytest.param(
        set_ts("optimizers.actor.optimizer.param_groups.0.lr", "fast"), "param_groups.0.lr", id="err-ts-lr-str"
    ),
    pytest.param(
        set_ts("optimizers.actor.optimizer.param_groups.0.params", ["a"]), "'params' list", id="err-ts-params-str"
    ),
    pytest.param(
        set_ts("optimizers.actor.optimizer.param_groups", []), "optimizers.actor does not fit", id="err-ts-no-groups"
    ),
    pytest.param(scaled_weights(float("nan")), "non-finite weights", id="err-pt-nan-weights"),
    pytest.param(scaled_weights(float("inf")), "non-finite weights", id="err-pt-inf-weights"),
    pytest.param(set_key("_obs_norm._mean", torch.zeros(3)), "observation size differs", id="err-pt-obs-shape"),
    pytest.param(set_key("_a_norm._mean", torch.zeros(2)), "action size differs", id="err-pt-action-shape"),
    pytest.param(edited(lambda s: s.__delitem__("_obs_norm._std")), "keys missing", id="err-pt-missing-key"),
    pytest.param(set_key("_model.surprise", torch.zeros(1)), "unexpected keys", id="err-pt-unexpected-key"),
    pytest.param(
        edited(lambda s: s.__setitem__("_obs_norm._mean", s["_obs_norm._mean"].long())), "int64", id="err-pt-int-dtype"
    ),
]


@pytest.mark.parametrize("make, needle", BAD_FILES)
def test_hostile_checkpoint_is_refused(agent: BaseAgent, tmp_path: Path, make: Maker, needle: str) -> None:
    path = make(state_of(agent, tmp_path), tmp_path)
    before = agent.state_dict()["_obs_norm._mean"].clone()
    with pytest.raises(MimicKitError) as e:
        agent.load(path)
    assert_one_line(e, needle, str(path))
    assert not (tmp_path / "PWNED").exists()  # nothing in the file ran
    assert torch.equal(agent.state_dict()["_obs_norm._mean"], before)


@one_case("err-pt-zip-expands-past-limit")
def test_archive_expanding_past_the_limit(
    case: str, agent: BaseAgent, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """err-: a zip whose compressed entry expands past MAX_CHECKPOINT_BYTES (set low here) is refused unread."""
    monkeypatch.setattr(checkpoint, "MAX_CHECKPOINT_BYTES", 1 << 20)
    path = zip_with({"m/data.pkl": b"\0" * (4 << 20)}, zipfile.ZIP_DEFLATED)({}, tmp_path)
    assert path.stat().st_size < (1 << 20)
    with pytest.raises(MimicKitError) as e:
        read_checkpoint(path)
    assert_one_line(e, "expands to", "checkpoint limit")


@pytest.mark.parametrize(
    "make",
    [
        pytest.param(lambda tmp: tmp / "nope.pt", id="err-pt-missing-file"),
        pytest.param(lambda tmp: tmp, id="err-pt-is-a-folder"),
    ],
)
def test_not_a_file(agent: BaseAgent, tmp_path: Path, make: Callable[[Path], Path]) -> None:
    with pytest.raises(MimicKitError) as e:
        agent.load(make(tmp_path))
    assert_one_line(e, "model file not found")


# ---------------------------------------------------------------- accepted checkpoints


@one_case("ok-pt-own-checkpoint")
def test_own_checkpoint_loads(case: str, agent: BaseAgent, tmp_path: Path) -> None:  # ok-
    path = save(state_of(agent, tmp_path), tmp_path / "m.pt")
    agent.load(path)
    assert nonfinite_tensors(read_checkpoint(path)) == []


@one_case("ok-pt-reference-no-train-state")
def test_reference_checkpoint_loads(case: str, agent: BaseAgent, tmp_path: Path) -> None:  # ok-: no _train_state
    agent.save(tmp_path / "ref.pt", include_train_state=False)
    assert TRAIN_STATE_KEY not in read_checkpoint(tmp_path / "ref.pt")
    agent.load(tmp_path / "ref.pt")


@one_case("ok-pt-unknown-train-state-field-kept")
def test_future_train_state_field_is_kept(
    case: str, agent: BaseAgent, tmp_path: Path
) -> None:  # ok-: forward compatible
    path = set_ts("resumes", [{"iteration": 3}])(state_of(agent, tmp_path), tmp_path)
    assert read_checkpoint(path)[TRAIN_STATE_KEY]["resumes"] == [{"iteration": 3}]
    agent.load(path)


@pytest.mark.parametrize("reference", [pytest.param(False, id="ok-pt-exported"), pytest.param(True, id="ok-pt-ref")])
def test_exported_checkpoint_loads(agent: BaseAgent, tmp_path: Path, reference: bool) -> None:
    agent.save(tmp_path / "m.pt")
    export_checkpoint(tmp_path / "m.pt", tmp_path / "e.pt", reference=reference)
    agent.load(tmp_path / "e.pt")


@pytest.mark.integration
@one_case("ok-pt-trained-run-resumes-stale-temp-removed")
def test_trained_checkpoint_resumes_and_stale_temp_was_removed(case: str, agent: BaseAgent, trained: Path) -> None:
    """ok-: a real run's checkpoint (Adam/SGD states after a step) passes every check; the temp file
    planted before the run started is gone."""
    assert not list(trained.glob(".model.pt.*"))
    state = read_checkpoint(trained / "model.pt")
    assert state[TRAIN_STATE_KEY]["iteration"] >= 1 and nonfinite_tensors(state) == []
    agent.load(trained / "model.pt")
    assert agent.get_iteration() >= 1


# ---------------------------------------------------------------- non-finite listing


@one_case("ok-pt-nonfinite-tensors-listed")
def test_nonfinite_tensors_names_every_bad_tensor(case: str, agent: BaseAgent, tmp_path: Path) -> None:
    state = state_of(agent, tmp_path)
    keys = [k for k in state if k.startswith("_model.") and k.endswith("weight")][:2]
    state[keys[0]] = state[keys[0]].clone()
    state[keys[0]].view(-1)[3] = float("nan")
    state[keys[1]] = torch.full_like(state[keys[1]], float("-inf"))
    buffers = {0: {"momentum_buffer": torch.tensor([1.0, float("nan")])}}
    state[TRAIN_STATE_KEY]["optimizers"]["actor"]["optimizer"]["state"] = buffers
    assert nonfinite_tensors(state) == [*keys, "_train_state.optimizers.actor.optimizer.state.0.momentum_buffer"]
    assert nonfinite_tensors({"_obs_norm._count": torch.tensor([3])}) == []  # integer tensors are always finite


# ---------------------------------------------------------------- saving


@pytest.mark.integration
@one_case("err-save-read-only-folder")
def test_save_into_read_only_folder(case: str, agent: BaseAgent, tmp_path: Path) -> None:  # err-: the real thing
    with read_only_dir(tmp_path / "ro") as ro:
        with pytest.raises(MimicKitError) as e:
            agent.save(ro / "model.pt")
        assert_one_line(e, "cannot write checkpoint", str(ro / "model.pt"))
        assert list(ro.iterdir()) == []


@one_case("err-save-full-disk")
def test_save_on_full_disk(case: str, agent: BaseAgent, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """err-: ENOSPC at the write (simulated; the read-only test is the real one): one line, the old
    model.pt stays whole and no temp file is left."""
    agent.save(tmp_path / "model.pt")
    old = (tmp_path / "model.pt").read_bytes()

    def full(fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(MimicKitError) as e:
        agent.save(tmp_path / "model.pt")
    assert_one_line(e, "cannot write checkpoint", "No space left on device")
    assert (tmp_path / "model.pt").read_bytes() == old
    assert [p.name for p in tmp_path.iterdir()] == ["model.pt"]


@one_case("ok-save-removes-stale-temp-files")
def test_save_removes_stale_temp_files(case: str, agent: BaseAgent, tmp_path: Path) -> None:  # ok-
    stale = [tmp_path / ".model.pt.a1b2c3d4", tmp_path / ".model.pt.zz__99xx"]
    for p in stale:
        p.write_bytes(b"partial")
    keep = [tmp_path / ".model.pt.bak", tmp_path / "notes.txt", tmp_path / ".other.pt.a1b2c3d4"]
    for p in keep:
        p.write_bytes(b"x")
    agent.save(tmp_path / "model.pt")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["model.pt", *(p.name for p in keep)])
    assert checkpoint.remove_stale_temp_files(tmp_path) == [tmp_path / ".other.pt.a1b2c3d4"]


# ---------------------------------------------------------------- through `mimickit test`


CLI_CASES = [
    pytest.param(evil_pickle(2), "refused", id="err-cli-test-pickle-os-system"),
    pytest.param(scaled_weights(float("nan")), "non-finite weights", id="err-cli-test-nan-weights"),
    pytest.param(set_key(TRAIN_STATE_KEY, [1]), "_train_state must be a mapping", id="err-cli-test-train-state-list"),
    pytest.param(truncated, "not a readable checkpoint", id="err-cli-test-truncated"),
]


@pytest.mark.integration
@pytest.mark.parametrize("make, needle", CLI_CASES)
def test_cli_test_refuses_in_one_line(agent: BaseAgent, tmp_path: Path, make: Maker, needle: str) -> None:
    path = make(state_of(agent, tmp_path), tmp_path)
    proc = mimickit("test", "--arg_file", str(ARG_FILE), "--num_envs", "1", "--test_episodes", "1",
                    "--model_file", str(path), cwd=tmp_path)  # fmt: skip
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr[-3000:]
    assert needle in lines[0] and len(lines[0]) < MAX_LINE
    assert not (tmp_path / "PWNED").exists()
