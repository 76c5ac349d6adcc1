"""Every launch-form field reaches the real trainer (`mimickit train` started by the studio's run
manager, not a stand-in), checked in the run folder: args.json's effective values and seed, the
env_config.yaml as trained (its clip is the requested one), the metrics rows. Then, with the same real
runs: "again with this seed" repeats the rows, "continue" with a larger budget trains on from the
checkpoint with a resume marker, a learning rate of 1e4 ends "diverged" with its line (and the
metrics reach a browser as JSON it can parse), and the page (real Chromium) shows each run's seed,
progress and end state, draws the resume marker and marks the non-finite losses.

Runs are 2 iterations of 4 envs (128 samples each) on the project's demo arg file and humanoid: no
MimicKit data needed.
"""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import pytest
import yaml

from mimickit.learning.run_folder import ExitCode, RunFolder, is_event_row
from mimickit.util.paths import PROJECT_ROOT
from tests.conftest import write_shifted_demo_clip
from tests.studio.conftest import REAL_TRAINER, StudioProcess, wait_for

pytestmark = pytest.mark.integration

DEMO_ARGS = "args/deepmimic_humanoid_demo_ppo_args.txt"
PER_ITER = 4 * 32
RUN_TIMEOUT_S = 300.0
TIMING = ("time", "wall_time")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    runs_dir = tmp_path_factory.mktemp("real_runs")
    server = StudioProcess(runs_dir, trainer=REAL_TRAINER)
    yield server
    for run in server.get("/api/runs").json() if server.proc.poll() is None else []:
        if run["status"] in ("running", "queued"):
            server.post(f"/api/runs/{run['id']}/stop", {})
    server.stop()


def run_of(server: StudioProcess, run_id: int) -> dict:
    return server.get(f"/api/runs/{run_id}").json()


def ended(server: StudioProcess, run_id: int) -> dict:
    run = wait_for(
        lambda: (r := run_of(server, run_id))["status"] not in ("queued", "running", "stopping") and r,
        RUN_TIMEOUT_S,
        f"run {run_id} to end",
    )
    return run


def console(run: dict) -> str:
    return RunFolder(run["out_dir"]).console_file.read_text()[-3000:]


def data_rows(server: StudioProcess, run_id: int) -> list[dict]:
    rows = server.get(f"/api/runs/{run_id}/metrics", params={"follow": "false"}).json()
    return [r for r in rows if not is_event_row(r)]


def without_timing(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in TIMING and not k.startswith("time.")}


@pytest.fixture(scope="module")
def clip(server: StudioProcess) -> Path:
    """Another clip for the humanoid, in the runs folder's uploads."""
    return write_shifted_demo_clip(server.runs_dir / "uploads" / "squat_shifted.pkl")


@pytest.fixture(scope="module")
def fields_run(server: StudioProcess, clip: Path) -> dict:
    """A run launched with every field of the launch form, the arg file in the CLI's `args/` form."""
    body = {"arg_file": DEMO_ARGS, "name": "every field", "num_envs": 4, "max_samples": 2 * PER_ITER}
    r = server.post("/api/runs", {**body, "motion_file": str(clip), "rand_seed": 7})
    assert r.status_code == 201, r.text
    run = r.json()
    running = wait_for(lambda: (x := run_of(server, run["id"]))["pid"] and x, 60, "the trainer to start")
    # The trainer works in its run folder (MuJoCo's log and the like land there, not in the repo).
    assert Path(f"/proc/{running['pid']}/cwd").resolve() == Path(run["out_dir"]).resolve()
    done = ended(server, run["id"])
    assert done["status"] == "finished", console(done)
    return {**done, "rows": data_rows(server, run["id"])}


def test_every_launch_field_reaches_the_trainer(fields_run: dict, clip: Path) -> None:
    folder = RunFolder(fields_run["out_dir"])
    record = folder.read_args()
    eff = record["effective"]
    assert (eff["num_envs"], eff["max_samples"], eff["motion_file"]) == (4, 2 * PER_ITER, str(clip))
    assert record["seed"] == 7 and record["seed_source"] == "rand_seed"
    assert eff["char_file"].endswith("humanoid/humanoid.xml") and eff["motion_file_from"] == "--motion_file"
    trained = yaml.safe_load(folder.config_file("env").read_text())
    assert trained["env"]["motion_file"] == str(clip)  # the clip trained on is the one asked for
    assert [(r["iteration"], r["samples"]) for r in fields_run["rows"]] == [(0, PER_ITER), (1, 2 * PER_ITER)]
    assert "every-field" in Path(fields_run["out_dir"]).name
    assert fields_run["exit_code"] == ExitCode.OK and folder.read_state().state.value == "finished"

    s = fields_run["summary"]  # what the run list shows, from the run folder
    assert (s["seed"], s["num_envs"], s["samples"], s["max_samples"]) == (7, 4, 2 * PER_ITER, 2 * PER_ITER)
    assert s["motion_file"] == str(clip) and not s["dataset"] and s["char_file"].endswith("humanoid.xml")
    assert s["end_state"] == "finished" and fields_run["reason"].startswith("reached max_samples 256")
    assert math.isfinite(s["test_return"]) and s["elapsed_s"] > 0 and s["samples_per_s"] > 0
    assert s["test_return"] == fields_run["rows"][-1]["test_return"]
    assert s["test_fail_frac"] == fields_run["rows"][-1]["test_fail_frac"] and 0.0 <= s["test_fail_frac"] <= 1.0


def test_again_with_this_seed_repeats_the_rows(server: StudioProcess, fields_run: dict) -> None:
    r = server.post(f"/api/runs/{fields_run['id']}/again", {})
    assert r.status_code == 201, r.text
    again = ended(server, r.json()["id"])
    assert again["status"] == "finished", console(again)
    assert again["config"] == {**fields_run["config"], "rand_seed": 7}
    assert RunFolder(again["out_dir"]).read_args()["seed"] == 7 and again["summary"]["seed"] == 7
    rows = data_rows(server, again["id"])
    assert [without_timing(r) for r in rows] == [without_timing(r) for r in fields_run["rows"]]


@pytest.fixture(scope="module")
def resumed_run(server: StudioProcess, fields_run: dict) -> dict:
    run_id = fields_run["id"]
    r = server.post(f"/api/runs/{run_id}/resume", {})
    assert r.status_code == 409 and "give a larger max_samples" in r.json()["detail"]
    r = server.post(f"/api/runs/{run_id}/resume", {"max_samples": 3 * PER_ITER})
    assert r.status_code == 200, r.text
    done = ended(server, run_id)
    assert done["status"] == "finished", console(done)
    return done


def test_continue_with_a_larger_budget(server: StudioProcess, fields_run: dict, resumed_run: dict) -> None:
    rows = server.get(f"/api/runs/{resumed_run['id']}/metrics", params={"follow": "false"}).json()
    assert [r.get("event") for r in rows] == [None, None, "resume", None]
    marker = rows[2]
    assert (marker["iteration"], marker["samples"], marker["max_samples"]) == (2, 2 * PER_ITER, 3 * PER_ITER)
    assert rows[:2] == fields_run["rows"] and (rows[3]["iteration"], rows[3]["samples"]) == (2, 3 * PER_ITER)
    argv = resumed_run["command"]
    assert argv[argv.index("--max_samples") + 1] == str(3 * PER_ITER)
    assert argv[argv.index("--model_file") + 1] == str(RunFolder(resumed_run["out_dir"]).model_file)
    s = resumed_run["summary"]
    assert (s["samples"], s["max_samples"], s["resumes"], s["seed"]) == (3 * PER_ITER, 3 * PER_ITER, 1, 7)
    assert resumed_run["attempts"] == 2 and resumed_run["reason"].startswith("reached max_samples 384")


def test_a_wall_time_budget_ends_the_run_and_continue_takes_a_larger_one(server: StudioProcess) -> None:
    """`max_hours` reaches the trainer: a budget spent by the first iteration ends the run there, as
    finished, saying so; Continue needs a larger budget (in samples or hours) and trains on with it."""
    body = {"arg_file": DEMO_ARGS, "name": "hours", "num_envs": 4, "max_samples": 2 * PER_ITER, "max_hours": 1e-9}
    run_id = server.post("/api/runs", body).json()["id"]
    done = ended(server, run_id)
    assert done["status"] == "finished", console(done)
    assert done["reason"] == f"reached max_hours 1e-09 of recorded wall time at iteration 1, {PER_ITER} samples"
    assert done["summary"]["max_hours"] == 1e-9 and done["summary"]["samples"] == PER_ITER
    assert done["command"][done["command"].index("--max_hours") + 1] == "1e-09"

    r = server.post(f"/api/runs/{run_id}/resume", {})
    assert r.status_code == 409 and "give a larger max_samples or max_hours" in r.json()["detail"], r.text
    r = server.post(f"/api/runs/{run_id}/resume", {"max_samples": 3 * PER_ITER})  # the hours stay spent
    assert r.status_code == 409 and "its max_hours 1e-09; give a larger max_hours" in r.json()["detail"], r.text
    r = server.post(f"/api/runs/{run_id}/resume", {"max_hours": 1e-10})
    assert r.status_code == 409 and r.json()["detail"].startswith("max_hours 1e-10 is not more than the"), r.text
    r = server.post(f"/api/runs/{run_id}/resume", {"max_hours": 1})
    assert r.status_code == 200, r.text
    again = ended(server, run_id)
    assert again["status"] == "finished", console(again)
    assert again["reason"] == f"reached max_samples {2 * PER_ITER} at iteration 2, {2 * PER_ITER} samples"
    assert again["config"]["max_hours"] == 1 and again["summary"]["max_hours"] == 1


@pytest.fixture(scope="module")
def diverged_run(server: StudioProcess) -> dict:
    """The demo arg file with a learning rate of 1e4 (the issue's recipe for NaN losses), 8 envs."""
    agent = (PROJECT_ROOT / "data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml").read_text()
    assert agent.count("learning_rate: 1e-4") == 2
    args_dir = server.runs_dir / "args"
    args_dir.mkdir(exist_ok=True)
    (args_dir / "lr_1e4_agent.yaml").write_text(agent.replace("learning_rate: 1e-4", "learning_rate: 1e4"))
    demo = (PROJECT_ROOT / DEMO_ARGS).read_text()
    demo = demo.replace("data/agents/deepmimic_humanoid_ppo_cpu_agent.yaml", str(args_dir / "lr_1e4_agent.yaml"))
    (args_dir / "diverge.txt").write_text(demo)
    r = server.post("/api/runs", {"arg_file": "args/diverge.txt", "num_envs": 8, "max_samples": 4 * 8 * 32})
    assert r.status_code == 201, r.text
    return ended(server, r.json()["id"])


def test_a_diverged_run_says_so_with_its_line(server: StudioProcess, diverged_run: dict) -> None:
    run = diverged_run
    assert run["status"] == "diverged", console(run)
    assert run["exit_code"] == ExitCode.DIVERGED and run["reason"].startswith("diverged at iteration ")
    assert run["summary"]["end_state"] == "diverged" and run["summary"]["end_reason"] == run["reason"]
    listed = next(r for r in server.get("/api/runs").json() if r["id"] == run["id"])
    assert listed["status"] == "diverged" and listed["reason"] == run["reason"]
    # The non-finite values reach a browser as JSON it can parse: null, named in `nonfinite`.
    r = server.get(f"/api/runs/{run['id']}/metrics", params={"follow": "false"})
    assert "NaN" not in r.text and "Infinity" not in r.text
    last = r.json()[-1]
    assert last["nonfinite"] and all(last[k] is None for k in last["nonfinite"])
    assert set(last["nonfinite"].values()) <= {"nan", "inf", "-inf"}
    with server.client.stream("GET", f"/api/stream?run={run['id']}&topics=metrics", timeout=30) as stream:
        text = next(line for line in stream.iter_lines() if line.startswith("data: ") and '"rows"' in line)
    assert "NaN" not in text and '"nonfinite"' in text  # the live curves' rows, as the page gets them


def test_a_refused_run_fails_with_the_trainers_line(server: StudioProcess) -> None:
    typo = server.runs_dir / "args" / "typo.txt"
    typo.parent.mkdir(exist_ok=True)
    typo.write_text((PROJECT_ROOT / DEMO_ARGS).read_text() + "--num_env 8\n")
    r = server.post("/api/runs", {"arg_file": "args/typo.txt"})
    assert r.status_code == 201, r.text
    run = ended(server, r.json()["id"])
    assert run["status"] == "failed" and run["exit_code"] == ExitCode.REFUSED
    assert run["reason"] == f"unknown argument --num_env in {typo} (did you mean --num_envs?)"
    assert RunFolder(run["out_dir"]).read_state() is None  # refused before anything started


def test_a_sweep_value_of_devices_trains_in_two_processes(server: StudioProcess) -> None:
    """A swept --devices ["cpu", "cpu"] (a list: each device one argv item) reaches the real trainer as two
    values: one run (a Ray job, with that executor) that is itself a two-process run."""
    values = {"devices": [["cpu", "cpu"]], "num_envs": [4], "max_samples": [2 * 2 * PER_ITER]}
    r = server.post("/api/sweeps", {"arg_file": DEMO_ARGS, "values": values, "name": "two procs", "rand_seed": 3})
    assert r.status_code == 201, r.text
    (run,) = r.json()["runs"]
    run = ended(server, run["id"])
    assert run["status"] == "finished", console(run)
    assert run["command"][run["command"].index("--devices") + 1 :][:2] == ["cpu", "cpu"]
    record = json.loads(RunFolder(run["out_dir"]).args_file.read_text())
    assert record["launch"]["world_size"] == 2, record["launch"]
    assert len(data_rows(server, run["id"])) >= 1


sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH")
def test_the_run_list_shows_seed_progress_and_end_state(
    server: StudioProcess, resumed_run: dict, diverged_run: dict, clip: Path
) -> None:
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, headless=True, args=["--no-sandbox", "--disable-gpu"])
        try:
            page = browser.new_page(viewport={"width": 1500, "height": 900})
            page.set_default_timeout(60_000)  # two shared cores under other work: be patient, not flaky
            page.goto(server.url)
            drop_scene(page)
            page.wait_for_selector(f"[data-run-id='{diverged_run['id']}']", timeout=30_000)
            # The launch form defaults to the demo arg file (trains without MimicKit data).
            assert page.locator("#arg-file").input_value() == str(PROJECT_ROOT / DEMO_ARGS)

            item = page.locator(f"[data-run-id='{resumed_run['id']}']")
            field = lambda name: item.locator(f"[data-field={name}]")  # noqa: E731
            assert field("status").inner_text() == "finished" and field("seed").inner_text() == "7"
            assert field("samples").inner_text() == "384 / 384 samples"
            bar = field("progress")
            assert (bar.get_attribute("value"), bar.get_attribute("max")) == ("384", "384")
            assert field("clip").inner_text() == clip.name and field("envs").inner_text() == "4 envs"
            assert field("char").inner_text() == "humanoid.xml" and "resumed 1×" in item.inner_text()
            assert field("test-return").inner_text() == f"{resumed_run['summary']['test_return']:.2f}"
            assert field("test-falls").inner_text() == f"{round(100 * resumed_run['summary']['test_fail_frac'])}%"

            bad = page.locator(f"[data-run-id='{diverged_run['id']}']")
            assert bad.locator("[data-field=status]").inner_text() == "diverged"
            assert bad.locator("[data-field=reason]").inner_text() == diverged_run["reason"]

            item.click()  # its curves: the resume drawn as a marker
            page.wait_for_selector("#curves [data-group=returns][data-markers='1']", timeout=15_000)
            # The share of test falls and the paper's two tracking errors, one plot per unit.
            for group, column in (("falls", "test_fail_frac"), ("pos_err", "paper_pos_err_m"),
                                  ("vel_err", "paper_dof_vel_err")):  # fmt: skip
                plot = page.locator(f"#curves [data-group={group}][data-series='1']")
                plot.wait_for(timeout=15_000)
                assert column in plot.inner_text()
            bad.click()  # the diverged run's losses: the non-finite iteration marked
            page.wait_for_selector("#curves [data-group=losses]:not([data-nonfinite='0'])", timeout=15_000)
            page_actions(page, server, clip)
        finally:
            browser.close()


def drop_scene(page) -> None:
    """Blank the 3D scene's iframe: it is not what is tested here, and its software WebGL would take
    a core from the trainers."""
    page.wait_for_selector("#arg-file option", state="attached")  # the page's start-up has set its src
    page.evaluate("document.getElementById('scene').src = 'about:blank'")


def page_actions(page, server: StudioProcess, clip: Path) -> None:
    """Launch from the form (every field), Continue with a budget, Again with the seed: each a real run."""

    # The page reads the library when it loads; the library re-scans a listing in the background once
    # it is older than a few seconds: a reload shows the clip written after the server started.
    def clip_offered() -> int:
        page.reload()
        drop_scene(page)
        page.wait_for_selector("#arg-file option", state="attached")
        time.sleep(0.5)  # the clips arrive with the configs, in the same Promise.all
        return page.locator(f"#motion-file option[value='{clip}']").count()

    wait_for(clip_offered, 30, "the clip in the launch form")
    page.click("#launch-box summary")  # the form is folded away until asked for
    page.select_option("#motion-file", value=str(clip))
    page.fill("#run-name", "from the form")
    page.fill("#num-envs", "4")
    page.fill("#max-samples", str(PER_ITER))
    page.fill("#max-hours", "1")
    page.fill("#rand-seed", "11")
    page.click("#launch-button")
    run = wait_for(
        lambda: next((r for r in server.get("/api/runs").json() if r["name"] == "from the form"), None), 10, "the run"
    )
    done = ended(server, run["id"])
    assert done["status"] == "finished", console(done)
    record = RunFolder(done["out_dir"]).read_args()
    eff = record["effective"]
    assert (eff["num_envs"], eff["max_samples"], eff["motion_file"], record["seed"]) == (4, PER_ITER, str(clip), 11)
    assert eff["max_hours"] == 1
    assert eff["env_config"].endswith("deepmimic_humanoid_env.yaml")  # the demo arg file's, the form's default

    item = page.locator(f"[data-run-id='{run['id']}']")
    item.locator("[data-field=status]", has_text="finished").wait_for(timeout=15_000)
    # A budget it has already trained is refused: the reason shows in the panel, and no modal dialog
    # (an alert) holds the page after the prompt.
    dialogs: list[str] = []
    page.on("dialog", lambda d: dialogs.append(d.type))
    page.once("dialog", lambda d: d.accept(str(PER_ITER)))
    item.locator("button[data-action=continue]").click()
    page.locator("#run-error", has_text=f"run #{run['id']}: ").wait_for(timeout=15_000)
    assert "is not more than the" in page.locator("#run-error").inner_text()
    assert dialogs == ["prompt"] and run_of(server, run["id"])["attempts"] == 1
    page.once("dialog", lambda d: d.accept("0.000000001h"))  # a budget in hours, written "2h"
    item.locator("button[data-action=continue]").click()
    page.locator("#run-error", has_text="max_hours 1e-09 is not more than the").wait_for(timeout=15_000)
    assert run_of(server, run["id"])["attempts"] == 1

    page.once("dialog", lambda d: d.accept(str(2 * PER_ITER)))  # Continue asks for the new budget
    item.locator("button[data-action=continue]").click()
    wait_for(lambda: run_of(server, run["id"])["attempts"] == 2, 15, "the run to be continued")
    wait_for(lambda: page.locator("#run-error").inner_text() == "", 10, "the refusal's line to clear")
    assert ended(server, run["id"])["summary"]["samples"] == 2 * PER_ITER
    item = page.locator(f"[data-run-id='{run['id']}']")
    item.locator("[data-field=samples]", has_text="256 / 256 samples").wait_for(timeout=15_000)

    item.locator("button[data-action=again]").click()
    again = wait_for(lambda: next((r for r in server.get("/api/runs").json() if r["id"] > run["id"]), None), 10)
    assert again["config"]["rand_seed"] == 11 and again["config"]["motion_file"] == str(clip)
    server.post(f"/api/runs/{again['id']}/stop", {})
    assert ended(server, again["id"])["status"] == "stopped"
