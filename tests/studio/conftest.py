"""The studio as a user runs it: `mimickit-studio serve` in a subprocess on free ports, talked to over
HTTP. Runs use `fake_trainer.py`, which keeps the `mimickit train` contract in a fraction of a second
(one slow test uses the real `mimickit train`). Rollouts and checkpoint inspection use checkpoints of
a freshly built (untrained) agent, written the way the trainer writes them, beside copies of its configs.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from mimickit.util.paths import PROJECT_DATA_DIR
from tests.conftest import test_data_dir

FAKE_TRAINER = Path(__file__).with_name("fake_trainer.py")
TRAINER = shlex.join([sys.executable, str(FAKE_TRAINER)])
REAL_TRAINER = shlex.join([sys.executable, "-m", "mimickit.cli", "train"])
START_TIMEOUT_S = 60.0
ENV_YAML = PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml"
AGENT_YAML = PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_agent.yaml"
ENGINE_YAML = PROJECT_DATA_DIR / "engines" / "mujoco_engine.yaml"


class StudioProcess:
    """One `mimickit-studio serve` subprocess; `url` is the one line it prints."""

    def __init__(
        self, runs_dir: Path, data_dir: Path | None = None, *extra: str, trainer: str = TRAINER, cwd: Path | None = None
    ) -> None:
        self.runs_dir = runs_dir
        argv = [sys.executable, "-m", "studio.cli", "serve", "--port", "0", "--viser-port", "0"]
        argv += ["--runs-dir", str(runs_dir), "--trainer", trainer, *extra]
        if data_dir is not None:
            argv += ["--data-dir", str(data_dir)]
        self.stderr_path = runs_dir / "server.stderr.log"
        with open(self.stderr_path, "a") as err:  # a file, not a pipe nobody reads that could fill up
            self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=err, text=True, cwd=cwd)
        self.url = self._read_url()
        # The header the dashboard sends: state-changing requests without it (or a JSON body) are refused.
        self.client = httpx.Client(base_url=self.url, timeout=30.0, headers={"X-Studio-Request": "1"})

    def _read_url(self) -> str:
        box: list[str] = []
        reader = threading.Thread(target=lambda: box.append(self.proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        line = box[0] if box else ""
        if "http://" not in line:
            self.proc.kill()
            raise RuntimeError(f"studio did not start: {line!r} {self.stderr_path.read_text()[-2000:]}")
        return line.split()[-1]

    def get(self, path: str, **kw: object) -> httpx.Response:
        return self.client.get(path, **kw)

    def post(self, path: str, json: object = None, **kw: object) -> httpx.Response:
        return self.client.post(path, json=json, **kw)

    def stop(self) -> None:
        self.client.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def kill9(self) -> None:
        self.client.close()
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait()


def wait_for(
    fn: Callable[[], object],
    timeout: float = 20.0,
    what: str | Callable[[], str] = "condition",
    page: Any = None,
) -> object:
    """Poll `fn` until it returns something truthy. `what` may be a function, called at a timeout, to say
    what was seen then. Give the `page` when `fn` reads what the page's event handlers (`page.on(...)`)
    collected: Playwright's sync API delivers events only while it is called, so the wait must be the page's
    (a `time.sleep` loop saw no websocket frame for 60 s in CI while they were arriving)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = fn()
        if value:
            return value
        if page is None:
            time.sleep(0.1)
        else:
            page.wait_for_timeout(100)
    raise AssertionError(f"timed out after {timeout} s waiting for {what() if callable(what) else what}")


# -- Chromium (Playwright over the apt browser) ------------------------------------------------------------
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMIUM_ARGS = ["--no-sandbox", "--disable-gpu"]
# The scene's software WebGL shares the page's main thread (same-origin iframe): on a loaded machine
# a click can wait for it well past Playwright's default 30 s.
ACTION_TIMEOUT_MS = 90_000


@pytest.fixture(scope="session")
def chromium() -> Iterator[Any]:
    """One headless Chromium for the session's browser tests (started once: a launch costs seconds on a
    loaded machine). Its tests run last (`pytest_collection_modifyitems` below)."""
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")
    if CHROMIUM is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def browser(chromium: Any) -> Iterator[Any]:
    """A fresh browser context of the shared Chromium per test module: its pages (and their software
    WebGL) are closed when the module ends, so they neither load nor share storage with the next."""
    context = chromium.new_context()
    yield context
    context.close()


def new_page(browser: Any, url: str | None, width: int = 1280, height: int = 720) -> Any:
    """A page of `browser` at `width`×`height`, with the long action timeout and `page.errors` collecting
    uncaught script errors (pageerror); opened at `url` unless None."""
    page = browser.new_page()
    page.set_viewport_size({"width": width, "height": height})
    page.set_default_timeout(ACTION_TIMEOUT_MS)
    page.errors = []
    page.on("pageerror", lambda e: page.errors.append(str(e)))
    if url is not None:
        page.goto(url)
    return page


def scene_page(browser: Any, url: str, width: int = 1280, height: int = 720, wait_s: float = 60) -> Any:
    """`new_page` at `url`, once the page shows the scene's state (its frame label is filled)."""
    page = new_page(browser, url, width, height)
    wait_for(lambda: page.locator("#frame-label").inner_text() != "–", wait_s, "the scene state on the page")
    return page


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The modules using the shared Chromium run after every other test. While Playwright's sync API is
    running, the thread has an asyncio loop: `asyncio.run` in a later test, or another test's own
    `sync_playwright()`, would fail."""
    shared = {item.module for item in items if "chromium" in getattr(item, "fixturenames", ())}
    items.sort(key=lambda item: getattr(item, "module", None) in shared)  # stable: order kept within each part


def write_arg_file(runs_dir: Path, name: str, rows: int = 10, period: float = 0.2, exit_code: int = 0) -> Path:
    """An arg file in `<runs-dir>/args/`, where the studio lists arg files saved beside the runs."""
    path = runs_dir / "args" / f"{name}.txt"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        f"# fake trainer settings\n--fake_rows {rows}\n--fake_period {period}\n--fake_exit_code {exit_code}\n"
    )
    return path


@pytest.fixture(scope="session")
def studio(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    """One server for the read-mostly tests, on MimicKit's reference data when it is there."""
    runs_dir = tmp_path_factory.mktemp("studio_runs")
    for name, rows in (("short", 8), ("long", 400)):
        write_arg_file(runs_dir, name, rows=rows)
    server = StudioProcess(runs_dir, test_data_dir())
    yield server
    server.stop()


def write_checkpoint_dir(
    folder: Path, env_yaml: str | None = None, save_model: bool = True, agent_yaml: Path | None = None
) -> Path:
    """A run-like folder: the configs a trainer copies (`env_yaml` text replaces the demo env's,
    `agent_yaml` the demo PPO agent's) and a `model.pt` of a fresh agent for them, saved with its train
    state as `mimickit train` saves it."""
    from mimickit.envs.env_builder import build_env
    from mimickit.learning.agent_builder import build_agent

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "env_config.yaml").write_text(env_yaml if env_yaml is not None else ENV_YAML.read_text())
    shutil.copyfile(agent_yaml or AGENT_YAML, folder / "agent_config.yaml")
    shutil.copyfile(ENGINE_YAML, folder / "engine_config.yaml")
    (folder / "args.json").write_text(json.dumps({"mode": ["train"], "out_dir": [str(folder)]}))
    if not save_model:
        return folder / "model.pt"
    env = build_env(folder / "env_config.yaml", folder / "engine_config.yaml", 1)
    agent = build_agent(folder / "agent_config.yaml", env, verbose=False)
    agent.save(folder / "model.pt")
    env.engine.close()
    return folder / "model.pt"


def smaller_obs_env_yaml() -> str:
    """The demo env with one target frame observed instead of three: another observation size."""
    text = ENV_YAML.read_text()
    assert "tar_obs_steps: [1, 2, 3]" in text
    return text.replace("tar_obs_steps: [1, 2, 3]", "tar_obs_steps: [1]")


@pytest.fixture(scope="session")
def demo_checkpoint(studio: StudioProcess) -> Path:
    """A checkpoint with its configs in the session server's runs folder."""
    return write_checkpoint_dir(studio.runs_dir / "ckpt-demo")


@pytest.fixture(scope="session")
def misfit_checkpoint(studio: StudioProcess) -> Path:
    """A checkpoint trained on another observation size, beside the demo env's configs."""
    other = write_checkpoint_dir(studio.runs_dir / "ckpt-other-obs", smaller_obs_env_yaml())
    folder = studio.runs_dir / "ckpt-misfit"
    write_checkpoint_dir(folder, save_model=False)
    shutil.copyfile(other, folder / "model.pt")
    return folder / "model.pt"


DEMO_CLIP_NAME = "data/motions/humanoid_demo_squat.pkl"


def write_demo_dataset(folder: Path, short_frames: int = 45) -> tuple[Path, Path]:
    """A two-clip dataset yaml the demo humanoid fits: the demo clip (`data/...`, weight 1) and a
    shortened, non-looping copy of it (`short_squat.pkl` beside the yaml, by absolute path, weight 2),
    whose episodes end at its end. (dataset, short clip)."""
    import dataclasses

    import yaml

    from mimickit.anim.motion import LoopMode, load_motion, save_motion

    folder.mkdir(parents=True, exist_ok=True)
    demo = load_motion(PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl")
    assert demo.num_frames > short_frames
    short = folder / "short_squat.pkl"
    save_motion(short, dataclasses.replace(demo, frames=demo.frames[:short_frames].copy(), loop_mode=LoopMode.CLAMP))
    dataset = folder / "two_squats.yaml"
    entries = [{"file": DEMO_CLIP_NAME, "weight": 1.0}, {"file": str(short), "weight": 2.0}]
    dataset.write_text(yaml.safe_dump({"motions": entries}, sort_keys=False))
    return dataset, short


def shipped_style_model(folder: Path, *extra_args: str) -> Path:
    """The shipped demo policy copied to `folder/models/x_model.pt` beside an arg file `x_model.txt`
    naming its configs (as data/models/ does) plus `extra_args`."""
    models = folder / "models"
    models.mkdir(parents=True)
    model = models / "x_model.pt"
    shutil.copyfile(PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt", model)
    sidecar = (PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.txt").read_text()
    model.with_suffix(".txt").write_text(sidecar + "".join(f"{a}\n" for a in extra_args))
    return model
