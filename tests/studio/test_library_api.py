"""Library endpoints against the real server: health, clips from MimicKit's data, characters, configs,
uploads, and paths that try to leave the data and runs folders."""

from __future__ import annotations

import pickle

import pytest

from tests.conftest import DEMO_CLIP
from tests.studio.conftest import StudioProcess

pytestmark = pytest.mark.integration


def test_health(studio: StudioProcess) -> None:
    r = studio.get("/api/health")
    assert r.status_code == 200
    body = r.json()
    assert body["status"] == "ok"
    assert body["viser_port"] > 0
    assert body["token_required"] is False
    assert studio.url.startswith("http://127.0.0.1:")


def test_page_and_docs_are_served(studio: StudioProcess) -> None:
    page = studio.get("/")
    assert page.status_code == 200 and "MimicKit Studio" in page.text and 'id="scene"' in page.text
    assert studio.get("/web/app.js").status_code == 200
    assert studio.get("/docs").status_code == 200
    paths = studio.get("/openapi.json").json()["paths"]
    for p in ("/api/health", "/api/motions", "/api/runs", "/api/runs/{run_id}/metrics", "/api/scene/load_clip"):
        assert p in paths


def test_lists_clips_of_the_reference_data(studio: StudioProcess, test_data) -> None:
    clips = {m["path"]: m for m in studio.get("/api/motions").json()}
    walk = clips["data/motions/humanoid/humanoid_walk.pkl"]
    assert (walk["fps"], walk["num_frames"], walk["loop_mode"], walk["frame_dim"]) == (120, 125, "wrap", 34)
    assert abs(walk["duration"] - 124 / 120) < 1e-6
    assert walk["nan_columns"] == [9, 10, 11]
    assert walk["character"] == "data/assets/humanoid/humanoid.xml"
    assert clips["data/motions/go2/go2_trot.pkl"]["character"] == "data/assets/go2/go2.xml"
    assert clips["data/motions/g1/g1_walk.pkl"]["character"] == "data/assets/g1/g1.xml"
    assert "data/motions/humanoid_demo_squat.pkl" in clips  # the project's own data is always there
    assert len(clips) > 200


def test_characters_and_configs(studio: StudioProcess, test_data) -> None:
    chars = {c["path"]: c for c in studio.get("/api/characters").json()}
    assert chars["data/assets/humanoid/humanoid.xml"]["dof_size"] == 28
    assert chars["data/assets/smpl/smpl.xml"]["frame_dim"] == 75
    assert not any("objects/" in p for p in chars)  # props have no DoFs: not characters
    configs = studio.get("/api/configs").json()
    assert {"envs", "agents", "engines", "arg_files", "datasets"} <= set(configs)
    assert any(a["name"] == "short" and a["args"]["fake_rows"] == ["8"] for a in configs["arg_files"])
    datasets = {d["name"]: d for d in configs["datasets"]}
    assert len(datasets["dataset_humanoid_locomotion"]["motions"]) > 1


def test_paths_outside_the_folders_are_refused(studio: StudioProcess, tmp_path) -> None:
    def load(path: str) -> int:
        return studio.post("/api/scene/load_clip", {"path": path}).status_code

    assert load("../etc/passwd") == 403
    assert load("data/../../../etc/passwd") == 403
    assert load("data/motions/%2e%2e/%2e%2e/etc/passwd") in (403, 404)
    assert load("/etc/passwd") == 403
    assert load(str(tmp_path / "elsewhere.pkl")) == 403
    # A symlink inside the runs folder that points out of it is refused too.
    uploads = studio.runs_dir / "uploads"
    uploads.mkdir(exist_ok=True)
    (uploads / "escape.pkl").symlink_to("/etc/passwd")
    assert load(str(uploads / "escape.pkl")) == 403
    (uploads / "escape.pkl").unlink()
    assert load("data/motions/no_such_clip.pkl") == 404
    r = studio.post("/api/runs", {"arg_file": "/etc/passwd"})
    assert r.status_code == 403


def test_upload_a_clip(studio: StudioProcess) -> None:
    r = studio.post("/api/motions/upload?filename=my%20squat.pkl", content=DEMO_CLIP.read_bytes())
    assert r.status_code == 201, r.text
    saved = r.json()
    assert saved["path"].endswith("uploads/my_squat.pkl") and saved["num_frames"] == 91
    listed = [m for m in studio.get("/api/motions").json() if m["upload"]]
    assert any(m["name"] == "my_squat" and m["character"] for m in listed)

    # A pickle that would run code is refused by the restricted unpickler, and nothing is written.
    class Evil:
        def __reduce__(self):  # noqa: ANN204
            return (print, ("pwned",))

    r = studio.post("/api/motions/upload?filename=evil.pkl", content=pickle.dumps(Evil()))
    assert r.status_code == 400 and "not a MimicKit clip" in r.json()["detail"]
    assert not (studio.runs_dir / "uploads" / "evil.pkl").exists()
