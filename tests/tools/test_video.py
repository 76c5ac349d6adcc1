"""`mimickit video`: real offscreen MuJoCo rendering of the demo clip and the demo policy, decoded back."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from mimickit.tools.video import VideoOptions, motion_video, select_gl_backend
from mimickit.util.errors import MimicKitError
from mimickit.util.paths import PROJECT_DATA_DIR, PROJECT_ROOT, DataPaths
from tests.conftest import DEMO_CLIP, PROJECT_HUMANOID

pytestmark = pytest.mark.integration

W, H = 160, 120  # small: these tests share the machine with training runs
DEMO_MODEL = PROJECT_DATA_DIR / "models" / "deepmimic_humanoid_demo_model.pt"
DEMO_ARGS = PROJECT_ROOT / "args" / "deepmimic_humanoid_demo_ppo_args.txt"


def decode(path: Path) -> tuple[dict, list[np.ndarray]]:
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    w, h = meta["size"]
    return meta, [np.frombuffer(f, dtype=np.uint8).reshape(h, w, 3) for f in reader]


def character_mask(frame: np.ndarray) -> np.ndarray:
    """[H, W] True on the blue character (CHAR_COLOR under the headlight): blue well above red and green."""
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return (b > r + 40) & (b > g + 25)


def character_pixels(frame: np.ndarray) -> int:
    return int(character_mask(frame).sum())


@pytest.mark.slow
def test_clip_video_has_one_frame_per_control_step(tmp_path: Path) -> None:
    out, png = tmp_path / "clip.mp4", tmp_path / "last.png"
    info = motion_video(DEMO_CLIP, PROJECT_HUMANOID, out, VideoOptions(1.0, W, H, frame_png=png))
    meta, frames = decode(out)
    assert info.frames == len(frames) == 30 and meta["fps"] == 30
    assert meta["size"] == (W, H)
    first, last = frames[0], frames[-1]
    assert character_pixels(first) > 100 and character_pixels(last) > 100
    assert first.std() > 15  # character, floor grid and sky: not a blank frame
    assert np.abs(first.astype(int) - last.astype(int)).mean() > 0.5  # the clip moves the character
    assert png.is_file()


@pytest.mark.slow
def test_policy_video_from_the_cli(tmp_path: Path) -> None:
    out = tmp_path / "policy.mp4"
    cmd = [sys.executable, "-m", "mimickit.cli", "video", "--model_file", str(DEMO_MODEL), "--arg_file",
           str(DEMO_ARGS), "--out", str(out), "--seconds", "1", "--width", str(W), "--height", str(H)]  # fmt: skip
    proc = subprocess.run(cmd, cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "30 frames at 30 fps" in proc.stdout
    _, frames = decode(out)
    assert len(frames) == 30
    assert character_pixels(frames[-1]) > 100
    ghost = frames[-1][..., 1].astype(int) > frames[-1][..., 2].astype(int) + 15  # the green reference
    assert ghost.sum() > 50


def test_unusable_gl_backend_is_one_error(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("MUJOCO_GL", "glx")
    monkeypatch.setenv("DISPLAY", ":4242")  # no X server there: GLX cannot start
    with pytest.raises(MimicKitError, match=r"no offscreen OpenGL .*MUJOCO_GL=glx: .*libEGL"):
        select_gl_backend()
    assert os.environ["MUJOCO_GL"] == "glx"


def test_video_argument_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from mimickit import cli

    assert cli.main(["video", "--motion", str(DEMO_CLIP), "--out", str(tmp_path / "v.mp4")]) == 2
    assert "--char" in capsys.readouterr().err
    args = ["video", "--motion", str(DEMO_CLIP), "--char", str(PROJECT_HUMANOID), "--out", str(tmp_path / "v.gif")]
    assert cli.main(args) == 2
    assert "error: --out must be an .mp4 file" in capsys.readouterr().err
    # the arg file's --motion_file is the clip the policy is filmed on: read, so a missing one is refused
    arg_file = tmp_path / "args.txt"
    arg_file.write_text(DEMO_ARGS.read_text() + "\n--motion_file data/motions/no_such_clip.pkl\n")
    args = ["video", "--model_file", str(DEMO_MODEL), "--arg_file", str(arg_file), "--out", str(tmp_path / "p.mp4")]
    assert cli.main(args) == 2
    assert "error: --motion_file: file not found: data/motions/no_such_clip.pkl" in capsys.readouterr().err


def test_the_cli_renders_at_the_studios_size_unless_told(tmp_path: Path) -> None:
    from mimickit import cli

    out = tmp_path / "clip.mp4"
    args = ["video", "--motion", str(DEMO_CLIP), "--char", str(PROJECT_HUMANOID), "--out", str(out), "--seconds", "0.1"]
    assert cli.main(args) == 0
    assert decode(out)[0]["size"] == (640, 480)  # the studio's Export MP4 (was 320x240)
    assert cli.main([*args, "--width", "64", "--height", "48"]) == 0
    assert decode(out)[0]["size"] == (64, 48)


@pytest.mark.slow
def test_a_character_without_its_meshes_is_drawn_with_bones_and_framed(test_data: Path, tmp_path: Path) -> None:
    """MimicKit's PI+ (0.39 m root height) has no mesh files in its data: without bones only its foot boxes
    show (rows 82-105 of 120 in the first frame, 396 pixels); with them the figure spans more than half the
    frame's height (rows 42-105, 836 pixels), framed by a camera scaled to its size."""
    char, clip = (
        test_data / "assets/hightorque_pi_plus/pi_22dof.xml",
        test_data / "motions/hightorque_pi_plus/pi_plus_walk.pkl",
    )
    if not char.is_file() or not clip.is_file():
        pytest.skip(f"no PI+ asset and clip under {test_data}")
    out = tmp_path / "pi.mp4"
    with pytest.warns(UserWarning, match="mesh file"):
        motion_video(clip, char, out, VideoOptions(0.2, W, H, data_paths=DataPaths(test_data)))
    _, frames = decode(out)
    rows = np.flatnonzero(character_mask(frames[0]).any(axis=1))
    assert rows.max() - rows.min() > 0.4 * H, (rows.min(), rows.max())
