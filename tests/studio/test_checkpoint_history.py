"""Checkpoint history (issue 37): a run launched with `save_int_models` (the launch form's checkbox, the
API's field) keeps `int_models/model_N.pt`; `GET /api/checkpoints` lists them with the run's `model.pt`,
grouped per run, each with the iteration and samples its weights have seen (from the file's name and the
run's metrics.jsonl, the same count as the checkpoint's `_train_state` and the rollout's label); the page
shows one <optgroup> per run and rolls out any of them, its label showing that checkpoint's iteration.

Runs are the real `mimickit train` on the project's demo arg file with 2 envs and 5 iterations (64
samples each), its agent copied with an output (a checkpoint) every 2 iterations and 2 test episodes:
int models after iterations 0, 2 and 4, i.e. 1, 3 and 5 iterations trained. No MimicKit data needed.
STUDIO_UPDATE_SCREENSHOTS=1 writes the page (the list shown open, the rollout running) to
docs/studio_checkpoints.png (1280×720).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from mimickit.learning.run_folder import INT_MODELS_DIR, RunFolder, int_model_name
from mimickit.util.paths import PROJECT_ROOT
from studio.cli import build_parser, sweep_body
from tests.studio.conftest import CHROMIUM, REAL_TRAINER, StudioProcess, scene_page, wait_for
from tests.studio.test_e2e_browser import HIDE_TOAST

pytestmark = pytest.mark.integration

DEMO_ARGS = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"
CPU_AGENT = "data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml"
NUM_ENVS, PER_ITER, ITERS = 2, 2 * 32, 5
INT_ITERATIONS = [5, 3, 1]  # iterations trained by int_models/model_{4,2,0}.pt, the newest first
RUN_TIMEOUT_S = 300.0
WAIT_S = 90  # the scene's software WebGL shares the page's main thread


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    runs_dir = tmp_path_factory.mktemp("checkpoint_history_runs")
    write_output_every_2_args(runs_dir / "args")
    s = StudioProcess(runs_dir, None, trainer=REAL_TRAINER)  # the project's own data only
    yield s
    for run in s.get("/api/runs").json() if s.proc.poll() is None else []:
        if run["status"] in ("running", "queued"):
            s.post(f"/api/runs/{run['id']}/stop", {})
    s.stop()


def write_output_every_2_args(args_dir: Path) -> Path:
    """`args/every2.txt`: the demo arg file, its CPU agent copied with a checkpoint every 2 iterations and 2
    test episodes per output (the reference's 100 and 32 would leave one int model and take longer)."""
    args_dir.mkdir(parents=True, exist_ok=True)
    agent = (PROJECT_ROOT / CPU_AGENT).read_text()
    assert agent.count("iters_per_output: 100") == 1 and agent.count("test_episodes: 32") == 1
    agent = agent.replace("iters_per_output: 100", "iters_per_output: 2").replace(
        "test_episodes: 32", "test_episodes: 2"
    )
    (args_dir / "every2_agent.yaml").write_text(agent)
    arg_file = args_dir / "every2.txt"
    arg_file.write_text(DEMO_ARGS.read_text().replace(CPU_AGENT, str(args_dir / "every2_agent.yaml")))
    return arg_file


def ended(server: StudioProcess, run_id: int) -> dict:
    def done() -> dict | None:
        run = server.get(f"/api/runs/{run_id}").json()
        return run if run["status"] not in ("queued", "running", "stopping") else None

    return wait_for(done, RUN_TIMEOUT_S, f"run {run_id} to end")


def console(run: dict) -> str:
    return RunFolder(run["out_dir"]).console_file.read_text()[-3000:]


def run_entries(server: StudioProcess, run: dict) -> list[dict]:
    """The run's checkpoints as the list gives them, after checking that they sit together in it."""
    listed = server.get("/api/checkpoints").json()
    where = [i for i, c in enumerate(listed) if c["run_id"] == run["id"]]
    assert where == list(range(where[0], where[0] + len(where))), "a run's checkpoints are one group"
    return [listed[i] for i in where]


@pytest.fixture(scope="module")
def api_run(server: StudioProcess) -> dict:
    body = {"arg_file": "args/every2.txt", "name": "int models", "num_envs": NUM_ENVS, "save_int_models": True}
    r = server.post("/api/runs", {**body, "max_samples": ITERS * PER_ITER})
    assert r.status_code == 201, r.text
    run = ended(server, r.json()["id"])
    assert run["status"] == "finished", console(run)
    return run


def test_the_list_gives_a_run_s_int_models_by_iteration(server: StudioProcess, api_run: dict) -> None:
    argv = api_run["command"]
    assert argv[argv.index("--save_int_models") + 1] == "true" and api_run["config"]["save_int_models"] is True
    int_dir = Path(api_run["out_dir"]) / INT_MODELS_DIR
    assert sorted(p.name for p in int_dir.iterdir()) == [int_model_name(i) for i in (0, 2, 4)]

    entries = run_entries(server, api_run)
    got = [(Path(c["path"]).name, c["iteration"], c["samples"], c["latest"]) for c in entries]
    assert got == [
        ("model.pt", ITERS, ITERS * PER_ITER, True),
        *((int_model_name(i - 1), i, i * PER_ITER, False) for i in INT_ITERATIONS),
    ]
    assert {c["group"] for c in entries} == {f"#{api_run['id']} int models"}
    assert all(c["has_configs"] and c["needs_data"] is None for c in entries)
    listed = server.get("/api/checkpoints").json()  # the shipped models after the runs, in their own group
    assert listed[-1]["group"] == "data folders: models/" and listed[-1]["iteration"] is None

    # The count is the checkpoint's own: what its _train_state says (and a rollout's label shows).
    middle = entries[2]
    inspected = server.get("/api/checkpoints/inspect", params={"path": middle["path"]}).json()
    assert (inspected["train_state"]["iteration"], inspected["train_state"]["samples"]) == (3, 3 * PER_ITER)
    assert (middle["iteration"], middle["samples"]) == (3, 3 * PER_ITER)


def test_save_int_models_is_a_strict_launch_field_and_one_value_per_sweep(server: StudioProcess) -> None:
    for value in ("true", 1):
        r = server.post("/api/runs", {"arg_file": "args/every2.txt", "save_int_models": value})
        assert r.status_code == 422 and "save_int_models: Input should be a valid boolean" in r.json()["detail"]
        assert "\n" not in r.json()["detail"]
    body = {"arg_file": "args/every2.txt", "values": {"save_int_models": [True, False]}}
    r = server.post("/api/sweeps", body)
    assert r.status_code == 400 and "save_int_models is one value for all of a sweep's runs" in r.json()["detail"]
    parser = build_parser()
    assert sweep_body(parser.parse_args(["sweep", "a.txt", "--save_int_models"]))["save_int_models"] is True
    assert "save_int_models" not in sweep_body(parser.parse_args(["sweep", "a.txt"]))


def option_texts(page, group: str) -> list[str]:
    return page.eval_on_selector_all(
        f"#checkpoint optgroup[label='{group}'] option", "os => os.map((o) => o.textContent)"
    )


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (apt-get install chromium)")
def test_the_page_lists_a_run_s_checkpoints_and_rolls_one_out(browser, server: StudioProcess, tmp_path: Path) -> None:
    """Launch through the form with the box ticked; the run's optgroup lists model.pt (latest) and its int
    models by iteration; rolling out the one of 3 iterations labels the rollout "iteration 3"."""
    page = scene_page(browser, server.url, 1280, 720, wait_s=WAIT_S)
    page.wait_for_selector("#arg-file option[value$='every2.txt']", state="attached", timeout=WAIT_S * 1000)
    page.click("#launch-box summary")
    page.select_option("#arg-file", value=str(server.runs_dir / "args" / "every2.txt"))
    page.fill("#run-name", "from the form")
    page.fill("#num-envs", str(NUM_ENVS))
    page.fill("#max-samples", str(ITERS * PER_ITER))
    page.check("#save-int-models")
    page.click("#launch-button")
    run = wait_for(
        lambda: next((r for r in server.get("/api/runs").json() if r["name"] == "from the form"), None), 30, "the run"
    )
    assert run["config"]["save_int_models"] is True
    run = ended(server, run["id"])
    assert run["status"] == "finished", console(run)
    page.click("#launch-box summary")  # folded again: the Checkpoints box is in view

    group = f"#{run['id']} from the form"
    want = [f"iter {ITERS} · {ITERS * PER_ITER} samples · latest"]
    want += [f"iter {i} · {i * PER_ITER} samples" for i in INT_ITERATIONS]
    wait_for(
        lambda: option_texts(page, group) == want, WAIT_S, lambda: f"the run's optgroup: {option_texts(page, group)}"
    )
    b_group = page.eval_on_selector_all(f"#checkpoint-b optgroup[label='{group}'] option", "os => os.length")
    assert b_group == len(want)  # B offers the same groups

    int_model = next(c for c in run_entries(server, run) if c["iteration"] == 3)
    page.select_option("#checkpoint", value=int_model["path"])
    page.click("#rollout-button")
    try:
        label = page.locator("#rollout-label")
        wait_for(lambda: "episode" in label.inner_text(), WAIT_S, "the rollout label")
        assert "iteration 3," in label.inner_text() and label.inner_text().startswith("int_models/model_0000000002.pt")
        state = server.get("/api/scene/state").json()["rollout"]
        assert (state["checkpoint"], state["iteration"], state["samples"]) == (int_model["path"], 3, 3 * PER_ITER)
        wait_for(lambda: "× real time" in page.locator("#clip-label").inner_text(), WAIT_S, "the real-time factor")
        screenshot(page, tmp_path)
    finally:
        server.post("/api/scene/rollout/close")
    assert page.errors == []


def screenshot(page, tmp_path: Path) -> None:
    """The page with the checkpoint list shown open (a select's popup is not in a screenshot: the list is
    drawn as a listbox for the picture, then put back)."""
    shot = PROJECT_ROOT / "docs" / "studio_checkpoints.png"
    if os.environ.get("STUDIO_UPDATE_SCREENSHOTS") != "1":
        shot = tmp_path / "studio_checkpoints.png"
    page.evaluate("document.getElementById('checkpoint').size = 9")
    page.locator("#scene").element_handle().content_frame().add_style_tag(content=HIDE_TOAST)
    page.locator("#checkpoints-box").scroll_into_view_if_needed()
    page.screenshot(path=str(shot))
    page.evaluate("document.getElementById('checkpoint').size = 0")
