"""Replay export: a clip or a policy rollout as one standalone HTML file (or a .viser recording).

The files are read back the way viser's client reads them (base64 → zstd → msgpack): the recording
must hold one pose update per exported frame, a sleep of one frame period between them, and the
character's meshes. The browser side is test_replay_browser.py.
"""

from __future__ import annotations

import base64
import pickle
import re
import subprocess
import sys
from pathlib import Path

import msgspec
import numpy as np
import pytest
import zstandard

from mimickit.anim.mjcf_char_model import load_char_model
from mimickit.anim.motion import load_motion, save_motion
from mimickit.util.paths import PROJECT_DATA_DIR
from studio.scene.replay import export_clip_replay, export_policy_replay, frame_stride
from studio.scene.rollout import source_for_checkpoint
from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID
from tests.studio.conftest import StudioProcess

pytestmark = pytest.mark.integration

HUMANOID_BODIES = load_char_model(PROJECT_HUMANOID).get_body_names()
DEMO_MODEL = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"


def recording_of(path: Path) -> dict:
    """The recording in an exported file, decoded as viser's client decodes it."""
    raw = path.read_bytes()
    if path.suffix == ".html":
        m = re.search(rb'window\.__VISER_EMBED_DATA__="([A-Za-z0-9+/=]+)"', raw)
        assert m, "no embedded recording in the page"
        raw = base64.b64decode(m.group(1))
    inner_size = int.from_bytes(raw[:8], "little")
    inner = zstandard.ZstdDecompressor().decompress(raw[8:], max_output_size=inner_size)
    msgpack_len = int.from_bytes(inner[:8], "little")
    return msgspec.msgpack.decode(inner[8 : 8 + msgpack_len])


def frame_times(rec: dict) -> list[float]:
    """Distinct times at which the recording changes the scene (one per recorded pose)."""
    return sorted({round(t, 9) for t, _ in rec["messages"]})


def shortened_clip(tmp_path: Path, frames: int) -> Path:
    motion = pickle.loads(DEMO_CLIP.read_bytes())
    motion["frames"] = motion["frames"][:frames]
    path = tmp_path / f"demo_{frames}.pkl"
    path.write_bytes(pickle.dumps(motion))
    return path


def test_clip_replay_holds_every_frame_and_grows_with_frames(tmp_path: Path) -> None:
    sizes = {}
    for n in (10, 91):
        clip = DEMO_CLIP if n == 91 else shortened_clip(tmp_path, n)
        info = export_clip_replay(clip, PROJECT_HUMANOID, tmp_path / f"r{n}.html")
        assert (info.kind, info.frames, info.fps) == ("clip", n, 30.0)
        assert info.duration == pytest.approx((n - 1) / 30)
        assert info.bytes == (tmp_path / f"r{n}.html").stat().st_size
        rec = recording_of(tmp_path / f"r{n}.html")
        assert rec["durationSeconds"] == pytest.approx((n - 1) / 30)
        times = frame_times(rec)
        assert len(times) == n and np.allclose(np.diff(times), 1 / 30)
        types = {msg["type"] for _, msg in rec["messages"]}
        assert {"GridMessage", "CatmullRomSplineMessage"} <= types  # the ground and the root path
        meshes = {msg["name"].split("/")[2] for _, msg in rec["messages"] if msg["type"] == "BatchedGlbMessage"}
        assert meshes == set(HUMANOID_BODIES)  # mjviser's mesh of every body of the character
        sizes[n] = info.bytes
    assert sizes[91] > sizes[10] + 20_000  # ~0.4 kB of pose updates per frame after compression
    html = (tmp_path / "r91.html").read_text()
    assert html.lower().startswith("<!doctype html>")
    assert "http://" not in html.replace("http://www.w3.org", "") and "https://" not in html  # offline


def test_120_fps_clip_is_recorded_at_60_hz_with_its_last_frame(tmp_path: Path, test_data: Path) -> None:
    walk = pickle.loads((test_data / "motions" / "humanoid" / "humanoid_walk.pkl").read_bytes())
    walk["frames"] = walk["frames"][:124]  # an even count: a stride of 2 steps over the last frame
    clip = tmp_path / "walk124.pkl"
    clip.write_bytes(pickle.dumps(walk))
    info = export_clip_replay(clip, PROJECT_HUMANOID, tmp_path / "walk.viser")
    assert frame_stride(120.0) == 2
    assert (info.frames, info.fps) == (63, 60.0)  # frames 0, 2, ..., 122, then 123
    rec = recording_of(tmp_path / "walk.viser")
    assert len(frame_times(rec)) == 63
    assert rec["durationSeconds"] == pytest.approx(123 / 120) == info.duration  # the clip's own duration


def test_policy_replay_of_the_shipped_model(tmp_path: Path) -> None:
    info = export_policy_replay(source_for_checkpoint(DEMO_MODEL), tmp_path / "policy.html", seconds=1.0)
    assert (info.kind, info.frames, info.fps) == ("rollout", 31, 30.0)
    rec = recording_of(tmp_path / "policy.html")
    assert len(frame_times(rec)) == 31 and rec["durationSeconds"] == pytest.approx(1.0)
    # The ghost (the reference clip) is drawn as its own translucent meshes.
    assert any(msg.get("name", "").startswith("/ghost/") for _, msg in rec["messages"])


def studio_cli(*args: object) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "studio.cli", *map(str, args)], capture_output=True, text=True)


def test_cli_export_replay(tmp_path: Path) -> None:
    out = tmp_path / "squat.html"
    r = studio_cli("export-replay", "--motion", "data/motions/humanoid_demo_squat.pkl", "--out", out)
    assert r.returncode == 0, r.stderr
    assert "91 poses at 30 Hz (3.00 s)" in r.stdout and out.is_file()  # the character was guessed
    assert len(frame_times(recording_of(out))) == 91


def test_cli_export_replay_says_a_clips_warning_once_on_one_line(tmp_path: Path) -> None:
    """NaN values read as 0 are warned of by each loader of the clip (the character guess, the replay's):
    the command collects them and prints each once."""
    clip = load_motion(DEMO_CLIP)
    clip.frames[2:4, 7] = np.nan
    save_motion(tmp_path / "nan.pkl", clip)
    r = studio_cli("export-replay", "--motion", tmp_path / "nan.pkl", "--out", tmp_path / "nan.html")
    assert r.returncode == 0, r.stderr
    warned = [line for line in r.stderr.splitlines() if "nan.pkl" in line]
    assert warned == [f"warning: {tmp_path / 'nan.pkl'}: non-finite values in columns [7] replaced by 0"], r.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--out", "x.html"], "give either --motion"),
        (["--motion", str(DEMO_CLIP), "--out", "x.mp4"], "must end in .html"),
        (["--motion", "nope.pkl", "--out", "x.html"], "nope.pkl"),
        (["--model_file", str(DEMO_CLIP), "--out", "x.html"], "env_config"),
    ],
)
def test_cli_export_replay_errors_are_one_line(tmp_path: Path, args: list[str], message: str) -> None:
    r = subprocess.run(
        [sys.executable, "-m", "studio.cli", "export-replay", *args], capture_output=True, text=True, cwd=tmp_path
    )
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], lines
    assert not list(tmp_path.iterdir())


def test_api_exports_the_shown_clip_and_a_named_one(studio: StudioProcess) -> None:
    r = studio.post("/api/scene/load_clip", {"path": "data/motions/humanoid_demo_squat.pkl"})
    assert r.status_code == 200, r.text
    r = studio.post("/api/scene/export_replay", {})
    assert r.status_code == 200, r.text
    info = r.json()
    assert (info["kind"], info["frames"]) == ("clip", 91) and info["download"].startswith("/api/scene/replays/")
    page = studio.get(info["download"])
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "attachment" in page.headers["content-disposition"]
    assert len(page.content) == info["bytes"] and b"__VISER_EMBED_DATA__" in page.content

    named = studio.post("/api/scene/export_replay", {"path": "data/motions/humanoid_demo_squat.pkl", "follow": False})
    assert named.status_code == 200 and named.json()["frames"] == 91
    assert studio.get("/api/scene/replays/..%2Fregistry.sqlite").status_code == 404
    assert studio.post("/api/scene/export_replay", {"path": "../etc/passwd"}).status_code in (400, 403, 404)
