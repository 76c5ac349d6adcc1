"""Library endpoints against the real server: health, clips from MimicKit's data, characters, configs,
uploads, and paths that try to leave the data and runs folders."""

from __future__ import annotations

import pickle
import re

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
    assert studio.get("/web/main.js").status_code == 200
    icon = re.search(r'<link rel="icon" href="([^"]+)"', page.text)  # without one, browsers ask /favicon.ico: 404
    assert icon and studio.get(icon[1]).headers["content-type"].startswith("image/svg+xml")
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


def test_config_files_open_read_only_with_what_they_train(studio: StudioProcess) -> None:
    r = studio.get("/api/configs/file", params={"path": "args/deepmimic_humanoid_demo_ppo_args.txt"})
    assert r.status_code == 200, r.text
    arg = r.json()
    assert arg["kind"] == "arg_file" and "--env_config data/envs/deepmimic_humanoid_env.yaml" in arg["text"]
    trains = arg["trains"]
    assert trains["env_config"] == {
        "file": "data/envs/deepmimic_humanoid_env.yaml",
        "resolved": "data/envs/deepmimic_humanoid_env.yaml",
        "exists": True,
    }
    clip = trains["motion_file"]
    assert (clip["file"], clip["kind"], clip["exists"], clip["from"]) == (
        "data/motions/humanoid_demo_squat.pkl",
        "clip",
        True,
        "env config",
    )
    assert trains["char_file"]["resolved"] == "data/assets/humanoid/humanoid.xml"

    # An arg file's own --motion_file wins over its env config's; one that is not there says so.
    (studio.runs_dir / "args" / "other_clip.txt").write_text(
        "--env_config data/envs/deepmimic_humanoid_env.yaml\n--motion_file data/motions/no_such_clip.pkl\n"
    )
    other = studio.get("/api/configs/file", params={"path": str(studio.runs_dir / "args" / "other_clip.txt")}).json()
    assert other["trains"]["motion_file"] == {
        "file": "data/motions/no_such_clip.pkl",
        "resolved": "data/motions/no_such_clip.pkl",
        "exists": False,
        "from": "arg file",
        "kind": "clip",
    }
    env = studio.get("/api/configs/file", params={"path": "data/envs/amp_location_humanoid_env.yaml"}).json()
    assert env["kind"] == "envs" and env["trains"]["motion_file"]["kind"] == "dataset"


def test_config_files_outside_the_config_folders_are_refused(studio: StudioProcess) -> None:
    def status(path: str) -> int:
        return studio.get("/api/configs/file", params={"path": path}).status_code

    assert status("../etc/passwd") == 403
    assert status("args/../../etc/passwd") == 403
    assert status("/etc/passwd") == 403
    assert status("data/motions/humanoid_demo_squat.pkl") == 403  # a data file, but not a config
    assert status("data/assets/humanoid/humanoid.xml") == 403
    assert status(str(studio.runs_dir / "registry.sqlite")) == 403
    (studio.runs_dir / "args" / "escape.txt").symlink_to("/etc/passwd")
    try:
        assert status(str(studio.runs_dir / "args" / "escape.txt")) == 403
    finally:
        (studio.runs_dir / "args" / "escape.txt").unlink()
    assert status("args/no_such_args.txt") == 404


def test_datasets_list_their_clips_and_weights(studio: StudioProcess, test_data) -> None:
    datasets = {d["name"]: d for d in studio.get("/api/configs").json()["datasets"]}
    walk_run = datasets["dataset_humanoid_locomotion_walk_run"]
    clips = walk_run["motions"]
    assert len(clips) > 1 and walk_run["missing"] == 0
    assert sum(c["share"] for c in clips) == pytest.approx(1.0)
    first = clips[0]
    assert first["file"] == "data/motions/humanoid/humanoid_run.pkl" and first["exists"]
    assert first["share"] == pytest.approx(first["weight"] / sum(c["weight"] for c in clips))
    opened = studio.get("/api/configs/file", params={"path": walk_run["path"]}).json()
    assert opened["kind"] == "datasets" and opened["motions"] == clips and "motions:" in opened["text"]


def _clip_bytes(width: int, frames: int = 5) -> bytes:
    return pickle.dumps({"loop_mode": 0, "fps": 30, "frames": [[0.0] * width for _ in range(frames)]})


def test_uploads_are_deduplicated_and_deletable(studio: StudioProcess) -> None:
    data = _clip_bytes(34, frames=7)  # bytes no other test uploads
    first = studio.post("/api/motions/upload?filename=dedup.pkl", content=data)
    assert first.status_code == 201 and not first.json()["duplicate"]
    again = studio.post("/api/motions/upload?filename=other_name.pkl", content=data)
    assert again.status_code == 200, again.text
    assert again.json()["duplicate"] and again.json()["path"] == first.json()["path"]
    assert again.json()["num_frames"] == 7
    uploads = studio.runs_dir / "uploads"
    assert sorted(p.name for p in uploads.glob("*.pkl")).count("dedup.pkl") == 1
    assert not (uploads / "other_name.pkl").exists() and not (uploads / "dedup_2.pkl").exists()

    def delete(path: str) -> int:
        return studio.client.delete("/api/motions/upload", params={"path": path}).status_code

    assert delete("data/motions/humanoid_demo_squat.pkl") == 403  # not an upload
    assert delete(str(DEMO_CLIP)) == 403
    assert delete("../registry.sqlite") == 403
    assert delete(str(uploads / ".." / "registry.sqlite")) == 403
    assert delete(str(studio.runs_dir / "registry.sqlite")) == 403
    (uploads / "link.pkl").symlink_to(DEMO_CLIP)
    assert delete("link.pkl") == 403 and DEMO_CLIP.is_file()
    (uploads / "link.pkl").unlink()
    assert delete(first.json()["path"]) == 204
    assert not (uploads / "dedup.pkl").exists()
    assert not any(m["name"] == "dedup" for m in studio.get("/api/motions").json())
    assert delete("dedup.pkl") == 404
    assert (studio.runs_dir / "registry.sqlite").is_file()


def test_oversized_and_malformed_uploads_are_refused(studio: StudioProcess) -> None:
    chunk = b"\0" * (1 << 20)
    big = studio.post("/api/motions/upload?filename=big.pkl", content=iter([chunk] * 65))  # chunked, > 64 MiB
    assert big.status_code == 413 and "at most" in big.json()["detail"]
    junk = studio.post("/api/motions/upload?filename=junk.pkl", content=b"not a pickle at all")
    assert junk.status_code == 400 and "\n" not in junk.json()["detail"]
    names = (
        {p.name for p in (studio.runs_dir / "uploads").glob("*")} if (studio.runs_dir / "uploads").is_dir() else set()
    )
    assert "big.pkl" not in names and "junk.pkl" not in names


def test_a_clip_no_character_fits_says_which_were_tried(studio: StudioProcess, test_data) -> None:
    r = studio.post("/api/motions/upload?filename=ten_wide.pkl", content=_clip_bytes(10))
    assert r.status_code == 201, r.text
    try:
        clip = next(m for m in studio.get("/api/motions").json() if m["name"] == "ten_wide")
        assert clip["character"] is None
        line = clip["character_error"]
        assert line.startswith("no character fits 10 values per frame (6 root + 4 DoFs)")
        assert "humanoid.xml (28 DoFs: takes 34 values per frame)" in line and "go2.xml (12 DoFs" in line
        tried = {t["path"]: t["reason"] for t in clip["characters_tried"]}
        assert tried["data/assets/humanoid/humanoid.xml"] == "28 DoFs: takes 34 values per frame"
        loaded = studio.post("/api/scene/load_clip", {"path": r.json()["path"]})
        assert loaded.status_code == 400 and "humanoid.xml (28 DoFs" in loaded.json()["detail"]
    finally:
        studio.client.delete("/api/motions/upload", params={"path": r.json()["path"]})


def test_a_character_in_its_default_pose(studio: StudioProcess) -> None:
    r = studio.get("/api/characters/pose", params={"path": "data/assets/humanoid/humanoid.xml"})
    assert r.status_code == 200, r.text
    pose = r.json()
    assert (pose["dof_size"], pose["frame_dim"], len(pose["frame"])) == (28, 34, 34)
    bodies = {b["name"]: b for b in pose["bodies"]}
    assert bodies["pelvis"]["parent"] == -1 and bodies["pelvis"]["joint"]["type"] == "root"
    assert 0.85 < bodies["pelvis"]["pos"][2] < 0.95  # standing: lifted so that the feet touch the ground
    assert bodies["head"]["pos"][2] > bodies["pelvis"]["pos"][2] > bodies["left_foot"]["pos"][2] > 0
    assert bodies["right_shin"]["joint"]["type"] == "hinge" and len(bodies["right_shin"]["joint"]["low"]) == 1
    assert sum(b["joint"]["dof_dim"] for b in pose["bodies"]) == 28 and set(pose["feet"]) == {"left_foot", "right_foot"}

    shown = studio.post("/api/scene/show_character", {"path": "data/assets/humanoid/humanoid.xml"})
    assert shown.status_code == 200, shown.text
    s = shown.json()
    assert s["char"].endswith("humanoid/humanoid.xml") and s["num_frames"] == 1
    assert s["root_pos"][2] == pytest.approx(bodies["pelvis"]["pos"][2], abs=1e-4)

    for bad in ("../etc/passwd", "/etc/passwd", "data/envs/deepmimic_humanoid_env.yaml"):
        assert studio.get("/api/characters/pose", params={"path": bad}).status_code == 403
        assert studio.post("/api/scene/show_character", {"path": bad}).status_code == 403
    assert studio.get("/api/characters/pose", params={"path": "data/assets/nope.xml"}).status_code == 404


def test_a_character_that_does_not_load_is_listed_with_its_reason(tmp_path) -> None:
    data = tmp_path / "data"
    (data / "assets" / "broken").mkdir(parents=True)
    (data / "assets" / "broken" / "broken.xml").write_text("<mujoco><worldbody><body name='a'>")  # cut off
    (data / "motions").mkdir()
    (data / "motions" / "odd.pkl").write_bytes(_clip_bytes(10))
    (tmp_path / "runs").mkdir()
    server = StudioProcess(tmp_path / "runs", data, "--clip", "none")
    try:
        chars = {c["path"]: c for c in server.get("/api/characters").json()}
        broken = chars["data/assets/broken/broken.xml"]
        assert broken["error"] and "\n" not in broken["error"] and "dof_size" not in broken
        odd = next(m for m in server.get("/api/motions").json() if m["path"] == "data/motions/odd.pkl")
        tried = {t["path"]: t["reason"] for t in odd["characters_tried"]}
        assert tried["data/assets/broken/broken.xml"] == f"did not load: {broken['error']}"
        assert "broken.xml (did not load:" in odd["character_error"]
    finally:
        server.stop()
