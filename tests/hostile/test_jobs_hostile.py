"""Hostile cases of the studio's background jobs (evals, videos) and exports, against a real
`mimickit-studio serve`: a server killed with `kill -9` while jobs run, an eval past its time limit, a
flood of queued jobs, a symlink planted at the next job folder's name, ids past 64 bits, folders and the
registry given as job inputs, exports in the same second and past their quota, export-replay and
`mimickit video` into /proc or /dev, and a checkpoint whose normaliser std is 0.

`err-...` cases expect one readable line (an HTTP 4xx `{"detail": ...}` or one `error:` line);
`ok-...` cases expect the request done as asked.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
import torch

from mimickit.util.paths import PROJECT_DATA_DIR
from tests.hostile.test_http import case, one_line
from tests.studio.conftest import StudioProcess, wait_for, write_checkpoint_dir
from tests.studio.test_evals_api import processes_in

pytestmark = pytest.mark.integration

SHIPPED = "data/models/deepmimic_humanoid_demo_model.pt"
SHIPPED_ARGS = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.txt"
DEMO_CLIP = PROJECT_DATA_DIR / "motions" / "humanoid_demo_squat.pkl"
DEMO_CHAR = PROJECT_DATA_DIR / "assets" / "humanoid" / "humanoid.xml"
TIME_LIMIT_S = 3
MAX_QUEUED = 2
LONG_EVAL = {"checkpoint": SHIPPED, "episodes": 256}  # minutes of work: it runs until stopped


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[StudioProcess]:
    """A server with a short eval time limit and a small queue."""
    runs_dir = tmp_path_factory.mktemp("jobs_runs")
    flags = ["--eval-time-limit", str(TIME_LIMIT_S), "--max-queued-jobs", str(MAX_QUEUED)]
    s = StudioProcess(runs_dir, None, *flags)
    yield s
    s.stop()


def stop_all(server: StudioProcess) -> None:
    for kind in ("evals", "videos"):
        for job in server.get(f"/api/{kind}").json():
            if job["status"] in ("queued", "running"):
                server.post(f"/api/{kind}/{job['id']}/stop", json={})


def status(server: StudioProcess, kind: str, job_id: int) -> dict:
    return server.get(f"/api/{kind}/{job_id}").json()


@case("ok-jobs-die-with-a-killed-server")
def test_jobs_die_with_a_killed_server(tmp_path: Path, case: str) -> None:
    """`kill -9` of the server: its running eval and video processes end too (no new server needed)."""
    s = StudioProcess(tmp_path, None)
    try:
        ev = s.post("/api/evals", LONG_EVAL).json()
        vid = s.post("/api/videos", {"checkpoint": SHIPPED, "seconds": 60, "width": 64, "height": 48}).json()
        folders = [Path(ev["folder"]), Path(vid["folder"])]
        for folder in folders:
            wait_for(lambda f=folder: processes_in(f), 120, f"a job process in {folder}")
    finally:
        s.kill9()
    for folder in folders:
        wait_for(lambda f=folder: not processes_in(f), 30, f"the processes in {folder} gone with the server")


@case("err-eval-past-its-time-limit")
def test_an_eval_past_its_time_limit_fails_in_one_line(server: StudioProcess, case: str) -> None:
    job = server.post("/api/evals", LONG_EVAL).json()
    done = wait_for(
        lambda: (j := status(server, "evals", job["id"]))["status"] not in ("queued", "running") and j,
        120,
        "the eval to end",
    )
    assert done["status"] == "failed", done
    assert done["error"] == f"mimickit eval took longer than {TIME_LIMIT_S} s and was stopped"
    wait_for(lambda: not processes_in(Path(job["folder"])), 20, "the eval's processes gone")


@case("err-queued-jobs-past-the-cap")
def test_queued_jobs_past_the_cap_are_refused_in_one_line(server: StudioProcess, case: str) -> None:
    try:
        answers = [server.post("/api/evals", LONG_EVAL) for _ in range(MAX_QUEUED + 2)]
        codes = [r.status_code for r in answers]
        # One may have started already (running, not queued): the cap counts the waiting ones.
        assert codes[:MAX_QUEUED] == [201] * MAX_QUEUED and codes[-1] == 429, codes
        assert "--max-queued-jobs" in one_line(answers[-1])
        queued = [j for j in server.get("/api/evals").json() if j["status"] == "queued"]
        assert len(queued) == MAX_QUEUED
    finally:
        stop_all(server)


@case("ok-planted-symlink-at-the-next-job-folder")
def test_a_planted_symlink_at_the_next_job_folder_gets_no_writes(
    server: StudioProcess, tmp_path: Path, case: str
) -> None:
    """Symlinks at every name the next job folder could have had (`<id>-<unix time>`) lead nowhere."""
    evals = server.runs_dir / "evals"
    evals.mkdir(exist_ok=True)
    outside = tmp_path / "outside"
    outside.mkdir()
    next_id = max([j["id"] for j in server.get("/api/evals").json()], default=0) + 1
    now = int(time.time())
    for t in range(now - 2, now + 30):
        (evals / f"{next_id:04d}-{t}").symlink_to(outside, target_is_directory=True)
    try:
        r = server.post("/api/evals", {"checkpoint": SHIPPED, "episodes": 1})  # writes args.txt into its folder
        assert r.status_code == 201, r.text
        job = r.json()
        folder = Path(job["folder"])
        assert job["id"] == next_id and folder.parent == evals and folder.is_dir() and not folder.is_symlink()
        assert (folder / "args.txt").is_file()
        assert list(outside.iterdir()) == []
    finally:
        stop_all(server)
        for link in evals.glob(f"{next_id:04d}-*"):
            if link.is_symlink():
                link.unlink()


@case("err-run-id-past-64-bits")
@pytest.mark.parametrize("kind", ["evals", "videos"])
def test_run_ids_past_64_bits_are_refused(server: StudioProcess, kind: str, case: str) -> None:
    r = server.post(f"/api/{kind}", {"run_id": 2**63})
    assert r.status_code == 422, r.text
    assert "run_id" in one_line(r)


@pytest.fixture(scope="module")
def odd_inputs(server: StudioProcess) -> dict[str, str]:
    """Files and folders of the runs folder that are not what a job takes."""
    runs = server.runs_dir
    ckpt_dir = write_checkpoint_dir(runs / "ckdir", save_model=False)  # real configs beside ...
    ckpt_dir.mkdir()  # ... a folder named model.pt
    (runs / "clips.pkl").mkdir()
    assert (runs / "registry.sqlite").is_file()
    return {"registry": str(runs / "registry.sqlite"), "ckpt_dir": str(ckpt_dir), "dir": str(runs / "clips.pkl")}


JOB_INPUTS = [
    ("evals", {"checkpoint": "registry", "arg_file": str(SHIPPED_ARGS)}, "checkpoint"),
    ("evals", {"checkpoint": "ckpt_dir"}, "checkpoint"),
    ("evals", {"checkpoint": SHIPPED, "arg_file": "registry"}, "arg_file"),
    ("evals", {"checkpoint": SHIPPED, "motion_file": "registry"}, "motion_file"),
    ("evals", {"checkpoint": SHIPPED, "motion_file": "dir"}, "motion_file"),
    ("videos", {"checkpoint": "ckpt_dir"}, "checkpoint"),
    ("videos", {"clip": "dir", "char": str(DEMO_CHAR)}, "clip"),
    ("videos", {"clip": str(DEMO_CLIP), "char": "registry"}, "char"),
]


@case("err-folder-or-registry-as-job-input")
@pytest.mark.parametrize(("kind", "body", "says"), JOB_INPUTS)
def test_folders_and_the_registry_are_not_job_inputs(
    server: StudioProcess, odd_inputs: dict[str, str], kind: str, body: dict, says: str, case: str
) -> None:
    body = {k: odd_inputs.get(v, v) if isinstance(v, str) else v for k, v in body.items()}
    try:
        r = server.post(f"/api/{kind}", body)
        assert r.status_code == 400, r.text
        assert one_line(r).startswith(says), r.text
    finally:
        stop_all(server)


@case("err-video-with-no-engine-config")
def test_a_video_with_no_engine_config_is_refused_by_the_api(server: StudioProcess, case: str) -> None:
    folder = server.runs_dir / "no-engine"
    folder.mkdir(exist_ok=True)
    shutil.copyfile(PROJECT_DATA_DIR / "envs" / "deepmimic_humanoid_env.yaml", folder / "env_config.yaml")
    shutil.copyfile(PROJECT_DATA_DIR / "agents" / "deepmimic_humanoid_ppo_agent.yaml", folder / "agent_config.yaml")
    shutil.copyfile(PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt", folder / "model.pt")
    try:
        r = server.post("/api/videos", {"checkpoint": str(folder / "model.pt"), "seconds": 1})
        assert r.status_code == 400, r.text
        assert "no engine config" in one_line(r)
    finally:
        stop_all(server)


def _export(server: StudioProcess, box: list[httpx.Response]) -> None:
    box.append(server.post("/api/scene/export_replay", {"path": str(DEMO_CLIP), "char": str(DEMO_CHAR)}))


@case("ok-two-exports-in-one-second")
def test_two_exports_in_one_second_write_two_files(server: StudioProcess, case: str) -> None:
    time.sleep(1.05 - time.time() % 1)  # both start early in one second: the same time stamp
    box: list[httpx.Response] = []
    threads = [threading.Thread(target=_export, args=(server, box)) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [r.status_code for r in box] == [200, 200], [r.text for r in box]
    paths = {r.json()["path"] for r in box}
    assert len(paths) == 2
    for r in box:
        assert Path(r.json()["path"]).stat().st_size == r.json()["bytes"]  # each its own, whole


@case("err-export-past-the-quota")
def test_an_export_past_the_replay_quota_is_refused_in_one_line(server: StudioProcess, case: str) -> None:
    replays = server.runs_dir / "replays"
    replays.mkdir(exist_ok=True)
    big = replays / "big.html"
    with open(big, "wb") as f:
        f.truncate(1024**3)  # sparse: the quota's worth of replays on no disk
    try:
        before = sorted(p.name for p in replays.iterdir())
        r = server.post("/api/scene/export_replay", {"path": str(DEMO_CLIP), "char": str(DEMO_CHAR)})
        assert r.status_code == 409, r.text
        assert "quota" in one_line(r)
        assert sorted(p.name for p in replays.iterdir()) == before
    finally:
        big.unlink()


EXPORTS = {
    "export-replay": ["studio.cli", "export-replay", "--motion", str(DEMO_CLIP)],
    "video": ["mimickit.cli", "video", "--motion", str(DEMO_CLIP), "--char", str(DEMO_CHAR), "--seconds", "0.2"],
}


@case("err-export-into-proc-or-dev")
@pytest.mark.parametrize("out", ["/proc/x", "/dev/full"])
@pytest.mark.parametrize("command", sorted(EXPORTS))
def test_an_export_into_proc_or_dev_is_one_error_line(command: str, out: str, case: str) -> None:
    """`mimickit-studio export-replay --out` and `mimickit video --out` there: one line, nothing written."""
    out += ".html" if command == "export-replay" else ".mp4"
    existed = os.path.lexists(out)
    argv = [sys.executable, "-m", *EXPORTS[command], "--out", out]
    try:
        proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 2, proc.stdout + proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and out in lines[0], proc.stderr
        assert os.path.lexists(out) == existed
    finally:
        if not existed and out.startswith("/dev/") and os.path.isfile(out):
            os.unlink(out)  # what the old code wrote there


@case("err-checkpoint-with-zero-std")
def test_a_checkpoint_whose_normaliser_std_is_zero_is_refused_in_one_line(tmp_path: Path, case: str) -> None:
    state = torch.load(PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt", weights_only=True)
    state["_obs_norm._std"] = torch.zeros_like(state["_obs_norm._std"])
    model = tmp_path / "zero_std.pt"
    torch.save(state, model)
    argv = [sys.executable, "-m", "mimickit.cli", "eval", "--arg_file", str(SHIPPED_ARGS)]
    argv += ["--model_file", str(model), "--episodes", "1"]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert proc.returncode != 0, proc.stdout + proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines == [f"error: {model}: normaliser _obs_norm has std 0 at entry 0 "
                     f"({state['_obs_norm._std'].numel()} of {state['_obs_norm._std'].numel()} not positive): "
                     "it would divide by zero; not rolling it out"], proc.stderr  # fmt: skip
