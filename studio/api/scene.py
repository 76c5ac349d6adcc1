"""Scene commands: load a clip on a character or a rollout of a checkpoint; play, pause, step, seek,
and the scene's state. The playback commands drive whichever is loaded (`mode`: clip or rollout)."""

from __future__ import annotations

import functools
import os
import re
import time
from pathlib import Path
from typing import Any, Literal

from fastapi import APIRouter, HTTPException, Query
from fastapi.responses import FileResponse
from pydantic import Field
from starlette.concurrency import run_in_threadpool

from mimickit.util.errors import MimicKitError
from studio.api import StudioDep, need
from studio.api.bodies import OneLineErrors, StrictBody
from studio.api.library import character_path
from studio.api.sources import checkpoint_of
from studio.library import characters_tried, no_character_line
from studio.runs.checkpoints import check_finite_checkpoint
from studio.scene.clip_pose import default_pose, pose_clip
from studio.scene.playable import Playable
from studio.scene.player import Player
from studio.scene.rollout import MAX_ENVS, RolloutPlayer, RolloutSource, source_for_checkpoint
from studio.security import confine, display_path, shown_path
from studio.services import Studio

router = APIRouter(prefix="/scene", tags=["scene"], route_class=OneLineErrors)


class LoadClip(StrictBody):
    path: str = Field(description="a clip: `data/motions/...` or a path inside the data/runs folders")
    char: str | None = Field(None, description="an MJCF character; guessed from the clip's frame width if absent")
    play: bool = Field(False, description="start playing at once")


class ShowCharacter(StrictBody):
    path: str = Field(description="an MJCF character under a data folder's `assets/`")


class LoadRollout(StrictBody):
    run_id: int | None = Field(None, description="a run: its `model.pt` and the configs copied into its folder")
    checkpoint: str | None = Field(None, description="a checkpoint file inside the data or runs folders")
    env_config: str | None = Field(None, description="env yaml, when the checkpoint has none beside it")
    agent_config: str | None = Field(None, description="agent yaml, when the checkpoint has none beside it")
    engine_config: str | None = Field(None, description="engine yaml (default: the one beside the checkpoint)")
    play: bool = Field(True, description="start stepping at once")
    b_run_id: int | None = Field(None, description="A/B: a second run, rolled out beside from the same clip starts")
    b_checkpoint: str | None = Field(None, description="A/B: a second checkpoint (its configs beside it)")
    num_envs: int = Field(1, ge=1, le=MAX_ENVS, description="envs stepped together; env 0 is the main one")
    layout: Literal["grid", "overlay"] = Field("grid", description="several envs: on a grid, or overlaid")


class ExportReplay(StrictBody):
    path: str | None = Field(None, description="a clip to export; default: what the scene shows (clip or rollout)")
    char: str | None = Field(None, description="the clip's MJCF character; guessed from its frame width if absent")
    follow: bool = Field(True, description="the world moves with the character (as the player's follow)")


class Step(StrictBody):
    frames: int = 1


class Seek(StrictBody):
    frame: int | None = None
    time: float | None = Field(None, description="seconds; used when `frame` is absent")


class Reset(StrictBody):
    same_start: bool = Field(False, description="start from the clip state the last episode started from")


class Push(StrictBody):
    body: str | None = Field(None, max_length=200, description="a body of the character; default: picked, else root")
    force: list[float] = Field(min_length=3, max_length=3, description="[x, y, z] newtons, world frame, z up")
    duration_s: float = Field(0.2, description="seconds, rounded to whole control steps")
    env: int = Field(0, description="which env of a rollout of several (0: the main one)")


class Configure(StrictBody):
    speed: float | None = None
    loop: bool | None = None
    follow: bool | None = Field(None, description="camera follows the character")


def _player(studio: Studio) -> Player:
    """The clip player (for loading clips)."""
    player = studio.scene.player
    need(player, "the 3D scene")
    return player


def _target(studio: Studio) -> Playable:
    """What the playback commands drive: the rollout while one is loaded, else the clip player."""
    target = studio.active()
    need(target, "the 3D scene")
    return target


def _rollout(studio: Studio) -> RolloutPlayer:
    rp = studio.scene.rollout
    if rp is None:
        raise HTTPException(409, "no rollout is loaded (POST /api/scene/load_rollout)")
    return rp


@router.post("/load_clip")
def load_clip(body: LoadClip, studio: StudioDep) -> dict[str, Any]:
    """Pose the clip on its character and show frame 0 (the character is rebuilt only if it changes)."""
    player = _player(studio)
    clip = confine(body.path, studio.settings.readable_roots)
    pose = pose_clip(clip, _char_for(studio, body.path, clip, body.char))
    return _show_clip(studio, player, pose, play=body.play)


@router.post("/show_character")
def show_character(body: ShowCharacter, studio: StudioDep) -> dict[str, Any]:
    """Show a character in its default pose (every DoF 0, standing on the ground) as a one-frame clip
    (`clip` and `char` in the state are the MJCF); its bodies and joints: `GET /api/characters/pose`."""
    player = _player(studio)
    pose = default_pose(character_path(studio, body.path))
    return _show_clip(studio, player, pose, play=False)


def _show_clip(studio: Studio, player: Player, pose: Any, *, play: bool) -> dict[str, Any]:
    """End any rollout and load `pose` in one scene command (nothing runs between); the state."""

    def show() -> dict[str, Any]:
        studio.end_rollout()
        player.load(pose, play=play)
        return player.snapshot()

    return studio.scene.thread.call(show)


@router.post("/load_rollout")
def load_rollout(body: LoadRollout, studio: StudioDep) -> dict[str, Any]:
    """Roll out a run's checkpoint (`run_id`) or a checkpoint file: its deterministic policy in one
    MuJoCo env built from the run's copied configs, stepped at the control rate, with the reference
    clip as a ghost. 400 with one message when the checkpoint does not fit (another character or
    observation size) or is not a checkpoint. The rollout reloads the file when it changes."""
    if (body.run_id is None) == (body.checkpoint is None):
        raise HTTPException(422, "give either `run_id` or `checkpoint`")
    if body.b_run_id is not None and body.b_checkpoint is not None:
        raise HTTPException(422, "give at most one of `b_run_id` and `b_checkpoint`")
    checkpoint, run_name = checkpoint_of(studio, body.run_id, body.checkpoint)
    partner = None
    if body.b_run_id is not None or body.b_checkpoint is not None:
        b_path, b_name = checkpoint_of(studio, body.b_run_id, body.b_checkpoint)
        partner = (b_path, body.b_run_id, b_name)
    roots = studio.settings.readable_roots
    configs = {
        k: confine(v, roots) if (v := getattr(body, k)) else None
        for k in ("env_config", "agent_config", "engine_config")
    }
    return roll_out(
        studio, checkpoint, configs, play=body.play, run_id=body.run_id, run_name=run_name, partner=partner,
        num_envs=body.num_envs, layout=body.layout,
    )  # fmt: skip


def roll_out(
    studio: Studio,
    checkpoint: Path,
    configs: dict[str, Path | None],
    *,
    play: bool,
    run_id: int | None = None,
    run_name: str | None = None,
    partner: tuple[Path, int | None, str | None] | None = None,
    num_envs: int = 1,
    layout: str = "grid",
) -> dict[str, Any]:
    """Show the rollout of `checkpoint` on `configs` (None: the ones beside it); its state. `partner`
    (checkpoint, run id, run name): B of an A/B rollout, on the configs beside it; `num_envs` envs drawn
    as `layout`. A broken checkpoint or config, or two that cannot pair, is a 400 with one line."""
    try:
        source = _source(studio, checkpoint, configs, run_id, run_name, side="A" if partner is not None else "")
        b = _source(studio, partner[0], {}, partner[1], partner[2], side="B") if partner is not None else None
        snap = studio.load_rollout(source, play=play, partner=b, num_envs=num_envs, layout=layout)
    except MimicKitError:
        raise
    except Exception as e:  # noqa: BLE001 - a broken config is the user's to fix: one line, not a traceback
        first = (str(e).strip().splitlines() or [""])[0]
        raise HTTPException(400, f"cannot roll out {checkpoint}: {e.__class__.__name__}: {first}") from None
    return snap


@router.get("/rollout/history")
def rollout_history(
    studio: StudioDep,
    since: int = Query(-1, description="only steps after this one"),
    limit: int = Query(2000, gt=0, le=10000),
) -> dict[str, Any]:
    """The loaded rollout's recorded steps: reward and each unweighted reward term per step (the
    last 60 s are kept), for plotting; poll with `since` = the last step received."""
    rp = _rollout(studio)
    snap = rp.snapshot()["rollout"]
    return {
        "step": snap["step"],
        "reward_weights": snap["reward_weights"],
        "rows": rp.history_rows(since, limit),
    }


@router.post("/rollout/reset")
def rollout_reset(studio: StudioDep, body: Reset | None = None) -> dict[str, Any]:
    """Start a new episode of the loaded rollout now (`same_start`: from the clip state the last one
    started from)."""
    rp = _rollout(studio)
    rp.reset((body or Reset()).same_start)
    return rp.snapshot()


@router.post("/rollout/push")
def rollout_push(body: Push, studio: StudioDep) -> dict[str, Any]:
    """Push a body of the rollout's character from the next simulated step; the state, whose
    `rollout.push.last` is the push given. 400 in one line for an unknown body, a force over the bound or
    not finite, a duration out of bounds."""
    rp = _rollout(studio)
    rp.push(body.body, body.force, body.duration_s, body.env)
    return rp.snapshot()


@router.post("/rollout/close")
def rollout_close(studio: StudioDep) -> dict[str, Any]:
    """Stop the rollout and go back to the clip player (empty until a clip is loaded)."""
    studio.end_rollout()
    target = studio.active()
    return target.snapshot() if target else {"mode": "clip"}


@router.post("/play")
def play(studio: StudioDep) -> dict[str, Any]:
    return studio.command(lambda t: t.play())


@router.post("/pause")
def pause(studio: StudioDep) -> dict[str, Any]:
    return studio.command(lambda t: t.pause())


@router.post("/toggle")
def toggle(studio: StudioDep) -> dict[str, Any]:
    """Play/pause, as the Enter key."""
    return studio.command(lambda t: t.toggle())


@router.post("/step")
def step(studio: StudioDep, body: Step | None = None) -> dict[str, Any]:
    """Pause and move by `frames` (default 1, as the Space key)."""
    frames = (body or Step()).frames
    return studio.command(lambda t: t.step(frames))


@router.post("/seek")
def seek(body: Seek, studio: StudioDep) -> dict[str, Any]:
    if body.frame is None and body.time is None:
        raise HTTPException(422, "give `frame` or `time`")
    return studio.command(lambda t: t.seek(frame=body.frame, time_s=body.time))


@router.post("/configure")
def configure(body: Configure, studio: StudioDep) -> dict[str, Any]:
    """Speed, loop and camera follow."""
    return studio.command(lambda t: t.configure(speed=body.speed, loop=body.loop, follow=body.follow))


@router.get("/state")
async def state(studio: StudioDep) -> dict[str, Any]:
    """`mode` (clip or rollout), frame, num_frames, time, playing, speed, loop, follow, scene updates
    sent and the drawn root position. Clip mode: clip, character and which feet touch the ground.
    Rollout mode: `rollout` with the checkpoint and its mtime, reloads, the step, the episode and its
    return, the last reward and reward terms, and the frame shown (the timeline is the history)."""
    target = _target(studio)
    # What the scene thread published after its last change: read on the event loop, never waiting
    # for a draw (a worker thread per request was most of this endpoint's cost under 50 clients).
    snap = target.published()
    return snap if snap is not None else await run_in_threadpool(target.snapshot)


REPLAYS_DIR = "replays"
_REPLAY_NAME = re.compile(r"^[A-Za-z0-9._-]+\.html$")


@router.post("/export_replay")
def export_replay(body: ExportReplay, studio: StudioDep) -> dict[str, Any]:
    """Write a standalone HTML replay (one file, plays offline from `file://`) of a clip, or of what
    the scene shows: the loaded clip, or the rollout's recorded timeline (the last 60 s). The file goes
    to `<runs-dir>/replays/` under a name of its own; `download` is its URL. 409 when that folder holds
    `replay_quota_bytes` already."""
    from studio.scene import replay  # viser's serializer: only when asked

    if body.path is not None:
        clip = confine(body.path, studio.settings.readable_roots)
        char = _char_for(studio, body.path, clip, body.char)
        stem, write = clip.stem, functools.partial(replay.export_clip_replay, clip, char, follow=body.follow)
    elif studio.scene.rollout is not None:
        rp, source = studio.scene.rollout, studio.scene.rollout.rollout.source
        stem = "rollout-" + (source.run_name or source.checkpoint.stem)
        write = functools.partial(replay.export_player_rollout, rp, follow=body.follow)
    elif studio.scene.player is not None and studio.scene.player.pose is not None:
        pose = studio.scene.player.pose
        stem, write = pose.path.stem, functools.partial(replay.write_clip_replay, pose, follow=body.follow)
    else:
        raise HTTPException(409, "nothing to export: load a clip or a rollout, or give `path`")
    out = _new_replay_file(studio.settings.runs_dir / REPLAYS_DIR, stem, studio.settings.replay_quota_bytes)
    try:
        info = write(out)
    except BaseException:
        out.unlink(missing_ok=True)  # the name reserved for it
        raise
    return {**info.to_json(), "download": f"/api/scene/replays/{out.name}"}


def _new_replay_file(folder: Path, stem: str, quota_bytes: int) -> Path:
    """A name of its own in `folder`, reserved by creating the file empty (exclusive, not following a
    link: two exports in one second, or a planted symlink, never share it), once the folder's quota is
    checked."""
    folder.mkdir(parents=True, exist_ok=True)
    if folder.is_symlink():
        raise HTTPException(409, f"{folder} is a symlink; replays are written only into a real folder")
    used = sum(e.stat(follow_symlinks=False).st_size for e in os.scandir(folder))
    if used >= quota_bytes:
        raise HTTPException(
            409,
            f"{folder} holds {used / 1e6:.0f} MB of replays, its quota is {quota_bytes / 1e6:.0f} MB "
            "(replay_quota_bytes): delete old replays there first",
        )
    base = f"{_safe_stem(stem)}-{time.strftime('%Y%m%d-%H%M%S')}"
    for n in range(1, 1000):
        out = folder / (f"{base}.html" if n == 1 else f"{base}-{n}.html")
        try:
            os.close(os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644))
        except FileExistsError:
            continue
        return out
    raise HTTPException(409, f"{folder}: too many replays named {base}*.html")


@router.get("/replays/{name}")
def download_replay(name: str, studio: StudioDep) -> FileResponse:
    """A replay written by `export_replay`, as a download."""
    folder = studio.settings.runs_dir / REPLAYS_DIR
    if not _REPLAY_NAME.match(name) or not (folder / name).is_file():
        raise HTTPException(404, f"no replay named {shown_path(name)!r}")
    # A symlink placed in the replays folder must not lead out of it.
    path = confine(str(folder / name), [folder])
    return FileResponse(path, media_type="text/html", filename=name)


def _source(
    studio: Studio,
    checkpoint: Path,
    configs: dict[str, Path | None],
    run_id: int | None,
    run_name: str | None,
    side: str = "",
) -> RolloutSource:
    """What to build a rollout of `checkpoint` from; an A/B side's error (`side` "A" or "B") says which."""
    try:
        source = source_for_checkpoint(
            checkpoint, run_id=run_id, run_name=run_name, fallback_data_dir=studio.settings.data_dir, **configs
        )
        check_finite_checkpoint(checkpoint)  # unreadable or diverged (NaN weights): one line, before any build
    except MimicKitError as e:
        if not side:
            raise
        raise MimicKitError(f"{side}: {e}") from None
    if missing := source.missing_clip():
        where = f"not in {source.data_dir}" if source.data_dir else "not shipped with the project"
        prefix = f"{side}: " if side else ""
        raise MimicKitError(
            f"{prefix}{display_path(checkpoint, studio.settings.data_dirs)} plays {missing}, which is {where}:"
            " start the studio with --data-dir pointing at MimicKit's data folder"
        )
    return source


def _char_for(studio: Studio, shown: str, clip: Path, char: str | None) -> Path:
    """`char` (confined), else the character whose DoF count fits the clip."""
    roots = studio.settings.readable_roots
    if char is not None:
        return confine(char, roots)
    info = next((m for m in studio.library.motions() if m["path"] in (shown, str(clip))), None)
    if info is None:  # not listed (yet): its header read now
        info = studio.library.motion_info(clip)
    if "error" in info:
        raise HTTPException(400, info["error"])
    chars = studio.library.characters()
    guessed = studio.library.character_for_width(info["frame_dim"], clip, chars)
    if guessed is None:
        why = no_character_line(info["frame_dim"], characters_tried(info["frame_dim"], chars))
        raise HTTPException(400, f"{shown}: {why}; name one with `char`")
    return confine(guessed, roots)


def _safe_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)[:80] or "replay"
