"""A run launched through the API with the real `mimickit train` (not the stand-in): a tiny DeepMimic
PPO run on the project's demo clip goes running → finished with metrics rows and a checkpoint. Its
rollout is loaded while it trains (as soon as the first checkpoint is written), steps and reports each
reward term, and picks up the run's final checkpoint when the trainer writes it."""

from __future__ import annotations

from pathlib import Path

import pytest

from mimickit.envs.deepmimic_rewards import TERM_NAMES
from mimickit.util.paths import PROJECT_ROOT
from tests.studio.conftest import REAL_TRAINER, StudioProcess, wait_for

pytestmark = pytest.mark.integration

ARG_FILE = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"
TERMS = set(TERM_NAMES)  # every DeepMimic term (deepmimic_rewards.py), so a new one needs no edit here
RUN_TIMEOUT_S = 400.0  # ~2 minutes on two shared cores; more when other work runs beside it


@pytest.mark.slow
def test_real_training_run_and_its_rollout(tmp_path: Path) -> None:
    (tmp_path / "runs").mkdir()
    server = StudioProcess(tmp_path / "runs", trainer=REAL_TRAINER)
    try:
        r = server.post("/api/runs", {"arg_file": str(ARG_FILE), "name": "real", "num_envs": 8, "max_samples": 1500})
        assert r.status_code == 201, r.text
        run_id = r.json()["id"]
        run = wait_for(
            lambda: (x := server.get(f"/api/runs/{run_id}").json())["status"] != "queued" and x, 30, "the run to start"
        )
        assert run["status"] == "running", (Path(run["out_dir"]) / "console.log").read_text()[-2000:]
        argv = run["command"]
        assert argv[argv.index("--num_envs") + 1] == "8" and argv[argv.index("--max_samples") + 1] == "1500"

        # The first checkpoint is written after iteration 0: roll it out while the run goes on.
        wait_for(
            lambda: (
                server.get(f"/api/runs/{run_id}").json()["checkpoint"]
                or server.get(f"/api/runs/{run_id}").json()["status"] != "running"
            ),
            RUN_TIMEOUT_S,
            "the first checkpoint",
        )
        out_dir = Path(run["out_dir"])
        assert (out_dir / "env_config.yaml").is_file() and (out_dir / "agent_config.yaml").is_file()
        loaded = server.post("/api/scene/load_rollout", {"run_id": run_id})
        assert loaded.status_code == 200, loaded.text
        first = loaded.json()["rollout"]
        assert first["run_id"] == run_id and first["checkpoint"] == str(out_dir / "model.pt")
        s = wait_for(
            lambda: (st := server.get("/api/scene/state").json())["rollout"]["step"] >= 30 and st,
            60,
            "the rollout to advance",
        )
        # An untrained policy falls often: the frame shown may be an episode's first, which has no reward
        # yet, so the terms are read at the newest step that has them.
        latest = s["rollout"]["latest"]["reward_terms"]
        assert s["mode"] == "rollout" and set(latest) == TERMS
        assert all(0.0 <= v <= 1.0 for v in latest.values())

        done = wait_for(
            lambda: (x := server.get(f"/api/runs/{run_id}").json())["status"] not in ("queued", "running") and x,
            RUN_TIMEOUT_S,
            "the run to finish",
        )
        assert done["status"] == "finished", (out_dir / "console.log").read_text()[-2000:]
        assert done["exit_code"] == 0 and done["checkpoint"] == str(out_dir / "model.pt")
        rows = server.get(f"/api/runs/{run_id}/metrics", params={"follow": "false"}).json()
        assert len(rows) >= 5 and rows[-1]["samples"] >= 1500
        assert {f"reward_terms.{t}" for t in TERMS} <= set(rows[-1]) and "train_return" in rows[-1]

        # The final checkpoint is newer than the one the rollout started with: it is reloaded.
        final = out_dir.joinpath("model.pt").stat().st_mtime
        if final > first["checkpoint_mtime"]:
            s = wait_for(
                lambda: (st := server.get("/api/scene/state").json())["rollout"]["reloads"] >= 1 and st,
                10,
                "the final checkpoint to be reloaded",
            )
            assert s["rollout"]["checkpoint_mtime"] == pytest.approx(final) and s["rollout"]["error"] is None
        step = s["rollout"]["step"]
        wait_for(lambda: server.get("/api/scene/state").json()["rollout"]["step"] > step + 10, 10, "more steps")
    finally:
        for run in server.get("/api/runs").json() if server.proc.poll() is None else []:
            if run["status"] in ("running", "queued"):
                server.post(f"/api/runs/{run['id']}/stop")
        server.stop()
